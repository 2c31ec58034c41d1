"""Bad input to the public API and to the render binary: clear errors naming the argument, the same refusals in both.

The binary is the one built in this checkout (``target/release`` or ``target/debug``); its cases skip when it is not
built (``cargo build --release -p meshadv-render-cli``).
"""

from __future__ import annotations

import os
import struct
import subprocess
from pathlib import Path
from typing import Any, Optional

import pytest
import torch

from meshadv import _raster
from meshadv.mesh import Mesh, MeshLoadError, builtin_mesh, load_mesh, normalize_mesh, resample_mesh
from meshadv.mesh.io import max_file_bytes
from meshadv.render import Camera, Lights, RenderSetup, render

ROOT = Path(__file__).resolve().parents[1]
TRIANGLE = "v -1 -1 0\nv 1 -1 0\nv 0 1 0\nf 1 2 3\n"


def _binary() -> Optional[Path]:
    for profile in ("release", "debug"):
        path = ROOT / "target" / profile / "meshadv-render"
        if path.is_file():
            return path
    return None


def _binary_refuses(mesh: Path, *options: str) -> str:
    """Run the binary and return its error line; fail when it renders."""
    binary = _binary()
    if binary is None:
        pytest.skip("the meshadv-render binary is not built (cargo build --release -p meshadv-render-cli)")
    camera = ["--azimuth", "0", "--elevation", "0", "--distance", "4", "--size", "16"]
    out = subprocess.run([str(binary), str(mesh), *camera, *options, "-o", str(mesh.with_suffix(".png"))],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 1, f"the binary rendered {mesh.name} {options}: {out.stderr}"
    assert "panicked" not in out.stderr
    return out.stderr


def _python_render(mesh: Mesh, **camera: Any) -> None:
    cam = Camera.spherical(distance=4.0, azimuth=0.0, elevation=0.0, **camera)
    render(mesh.vertices, mesh.faces, mesh.face_colors, cam, Lights.default(cam), image_size=16)


# ----------------------------------------------------------------------------------------------- the binary and Python


def test_a_nan_or_fractional_index_in_a_ply_double_list_is_refused_by_both(tmp_path: Path) -> None:
    head = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\nproperty double z\n"
            "element face 1\nproperty list double double vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n")
    for name, face, needle in (("nan.ply", "3 0 nan 2", "not an integer"), ("frac.ply", "3.9 0 1 2", "3.9")):
        path = tmp_path / name
        path.write_text(head + face + "\n")
        assert needle in _binary_refuses(path)
        with pytest.raises(MeshLoadError, match=name):
            load_mesh(path)


def test_a_zero_area_mesh_is_refused_by_both(tmp_path: Path) -> None:
    path = tmp_path / "flat.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n")
    assert "every face is degenerate" in _binary_refuses(path, "--normalize")
    with pytest.raises(MeshLoadError, match="every face is degenerate"):
        load_mesh(path)


def test_a_narrow_viewing_angle_is_refused_by_both_with_the_native_bound(tmp_path: Path) -> None:
    path = tmp_path / "tri.obj"
    path.write_text(TRIANGLE)
    low = _raster.MIN_VIEWING_ANGLE
    for angle in (1e-40, low / 2):
        assert "viewing_angle" in _binary_refuses(path, "--viewing-angle", repr(angle))
        with pytest.raises(ValueError, match=r"^viewing_angle must be in \["):
            Camera.spherical(distance=4.0, azimuth=0.0, elevation=0.0, viewing_angle=angle)
    _python_render(load_mesh(path), viewing_angle=low)  # the bound itself is allowed


def test_a_zero_light_direction_is_refused_by_both(tmp_path: Path) -> None:
    path = tmp_path / "tri.obj"
    path.write_text(TRIANGLE)
    assert "light_directions" in _binary_refuses(path, "--light-dir", "0,0,0")
    with pytest.raises(ValueError, match="directions must be non-zero"):
        Lights.single(direction=(0.0, 0.0, 0.0))
    tiny = _raster.MIN_LIGHT_DIRECTION
    assert "light_directions" in _binary_refuses(path, "--light-dir", f"{tiny},0,0")
    with pytest.raises(ValueError, match="directions must be non-zero"):
        Lights.single(direction=(tiny, 0.0, 0.0))


def test_the_binary_normalizes_float32_extremes_as_python_does(tmp_path: Path) -> None:
    binary = _binary()
    if binary is None:
        pytest.skip("the meshadv-render binary is not built (cargo build --release -p meshadv-render-cli)")
    masks = []
    for name, scale in (("huge.obj", 3e38), ("unit.obj", 1.0)):
        path = tmp_path / name
        path.write_text(f"v {-scale} {-scale} 0\nv {scale} {-scale} 0\nv 0 {scale} 0\nf 1 2 3\n")
        out = subprocess.run([str(binary), str(path), "--azimuth", "0", "--elevation", "0", "--distance", "4",
                              "--size", "32", "--normalize", "--mask", "-o", str(path.with_suffix(".png"))],
                             capture_output=True, text=True, timeout=60)
        assert out.returncode == 0, out.stderr
        masks.append(path.with_suffix(".png").read_bytes())
        unit, _ = normalize_mesh(load_mesh(path))
        assert float(unit.vertices.abs().max()) == pytest.approx(1.0)
    assert masks[0] == masks[1]


def test_ply_list_counts_below_three_are_refused_by_both(tmp_path: Path) -> None:
    head = ("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 2\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n"
            "3 0 1 2\n")
    for count, face in ((0, "0"), (2, "2 0 2")):
        path = tmp_path / f"count{count}.ply"
        path.write_text(head + face + "\n")
        assert "at least 3" in _binary_refuses(path)
        with pytest.raises(MeshLoadError, match=f"face 1 has {count} vertex indices"):
            load_mesh(path)


def test_ply_header_counts_that_disagree_with_the_body_are_refused_by_both(tmp_path: Path) -> None:
    verts = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)]
    head = ("ply\nformat {fmt} 1.0\nelement vertex 9\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 3\nproperty list uchar int vertex_indices\nend_header\n")
    ascii_path = tmp_path / "nine_of_eight.ply"
    ascii_path.write_text(head.format(fmt="ascii") + "".join(f"{x} {y} {z}\n" for x, y, z in verts)
                          + "3 0 1 2\n2 0 2\n3 4 5 6\n3 4 6 7\n")
    binary_path = tmp_path / "nine_of_eight_binary.ply"
    body = b"".join(struct.pack("<3f", *v) for v in verts)
    body += b"".join(struct.pack("<B3i", 3, *f) for f in ((0, 1, 2), (0, 2, 3), (4, 5, 6), (4, 6, 7)))
    binary_path.write_bytes(head.format(fmt="binary_little_endian").encode() + body)
    for path in (ascii_path, binary_path):
        _binary_refuses(path)
        with pytest.raises(MeshLoadError, match=path.name):
            load_mesh(path)


# ------------------------------------------------------------------------------------------------------ the Python API


def test_mesh_refuses_nan_vertices() -> None:
    verts = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [float("nan"), 1.0, 0.0]])
    faces, colors = torch.tensor([[0, 1, 2]]), torch.full((1, 3), 0.5)
    with pytest.raises(ValueError, match="^vertices must be finite: 1 vertices .* vertex 2"):
        Mesh(verts, faces, colors)
    cube = builtin_mesh("cube")
    with pytest.raises(ValueError, match="^vertices must be finite"):
        cube.with_vertices(torch.full_like(cube.vertices, float("inf")))


def test_normalize_mesh_of_an_empty_mesh_names_the_mesh() -> None:
    empty = Mesh(torch.zeros(0, 3), torch.zeros(0, 3, dtype=torch.long), torch.zeros(0, 3))
    with pytest.raises(ValueError, match="^mesh has no vertices"):
        normalize_mesh(empty)


def test_lights_default_refuses_what_is_not_a_camera() -> None:
    with pytest.raises(TypeError, match="^camera must be a Camera, got str"):
        Lights.default("camera")  # type: ignore[arg-type]


@pytest.mark.parametrize(
    "kwargs, error, message",
    [
        ({"background": "white"}, TypeError, "^background must be 3 numbers"),
        ({"background": float("nan")}, TypeError, "^background must be 3 numbers"),
        ({"background": (1.0, float("nan"), 1.0)}, ValueError, "^background must be finite"),
        ({"image_size": 100000}, ValueError, "^image_size must be between 1 and 16384"),
        ({"image_size": 4096, "antialias": 8}, ValueError, r"^image_size \* antialias must be between"),
        ({"antialias": 9}, ValueError, r"^antialias must be an int in \[1, 8\]"),
        ({"image_size": 8, "background": torch.full((3, 8, 8), float("nan"))}, ValueError,
         "^background image contains NaN"),
    ],
)
def test_render_setup_validates_at_construction(kwargs: dict, error: type, message: str) -> None:
    with pytest.raises(error, match=message):
        RenderSetup(**kwargs)


def test_load_mesh_names_a_bad_path_or_colour(tmp_path: Path) -> None:
    path = tmp_path / "tri.obj"
    path.write_text(TRIANGLE)
    with pytest.raises(TypeError, match="^path must be a path .*bytes"):
        load_mesh(os.fsencode(path))  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="^default_color must be 3 numbers .*'red'"):
        load_mesh(path, default_color="red")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"^default_color\[0\] must be a number >= 0.0 and <= 1.0"):
        load_mesh(path, default_color=(2.0, 0.0, 0.0))
    assert load_mesh(path, default_color=(0.1, 0.2, 0.3)).face_colors[0].tolist() == pytest.approx([0.1, 0.2, 0.3])


def test_load_mesh_refuses_a_file_over_the_native_limit_before_reading_it(tmp_path: Path) -> None:
    path = tmp_path / "huge.ply"
    with path.open("wb") as handle:  # sparse: 8 GiB of size, no blocks
        handle.write(b"ply\nformat ascii 1.0\n")
        handle.truncate(8 << 30)
    assert max_file_bytes() == _raster.MAX_MESH_FILE_BYTES == 1 << 30
    with pytest.raises(MeshLoadError, match="larger than the 1073741824-byte limit"):
        load_mesh(path)


def test_resample_names_a_cache_dir_that_is_a_file(tmp_path: Path) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    for cache_dir in (blocker, blocker / "below"):
        with pytest.raises(ValueError, match="^cache_dir must be a folder"):
            resample_mesh(builtin_mesh("cube"), target_faces=100, cache_dir=cache_dir)
    with pytest.raises(TypeError, match="^cache_dir must be a path"):
        resample_mesh(builtin_mesh("cube"), target_faces=100, cache_dir=123)  # type: ignore[arg-type]


def test_load_victim_names_weights_and_cfg_that_are_not_paths() -> None:
    from meshadv.victims import load_victim

    with pytest.raises(TypeError, match="^weights must be a path .*int 123"):
        load_victim("efficientnet_lite0", weights=123)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="^cfg must be a path"):
        load_victim("yolov3", weights="w", cfg=b"c")  # type: ignore[arg-type]


def test_a_nan_background_photo_is_refused_before_any_render() -> None:
    photo = torch.rand(3, 16, 16)
    photo[1, 3, 4] = float("nan")
    with pytest.raises(ValueError, match="^background image contains NaN"):
        RenderSetup(image_size=16, background=photo)


# ------------------------------------------------------------------------------------------------------- the commands

_SWEEP = """[experiment]
name = "bad"
seeds = [0]
output = "{output}"

[meshes]
source = "builtin"
classes = {classes}
builtin = [{{ name = "cube", class = "chair" }}]

[render]
image_size = {image_size}
configurations = 1

[victims]
names = ["efficientnet_lite0"]

[attack]
perturbations = ["shape"]
"""


def _sweep_error(tmp_path: Path, config: Path, *extra: str) -> str:
    from cli_output import unwrapped
    from typer.testing import CliRunner

    from meshadv.cli import app

    result = CliRunner().invoke(app, ["sweep", str(config), *extra])
    text = unwrapped(result.output)
    assert result.exit_code in (1, 2), text
    assert "Traceback" not in text, text
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    return text


@pytest.mark.parametrize(
    "fields, message",
    [
        ({"classes": "5"}, "meshes.classes must be a list of class names, got 5"),
        ({"image_size": '"big"'}, "render.image_size must be an integer >= 8, got 'big'"),
        ({"image_size": "64.5"}, "render.image_size must be an integer >= 8, got 64.5"),
    ],
)
def test_sweep_config_errors_are_one_clear_line(tmp_path: Path, fields: dict, message: str) -> None:
    values = {"output": "out", "classes": '["chair"]', "image_size": "32", **fields}
    config = tmp_path / "bad.toml"
    config.write_text(_SWEEP.format(**values))
    assert message in _sweep_error(tmp_path, config, "--dry-run")


def test_sweep_names_a_folder_given_as_the_config_and_report_one_given_as_the_database(tmp_path: Path) -> None:
    from cli_output import unwrapped
    from typer.testing import CliRunner

    from meshadv.cli import app

    folder = tmp_path / "a_folder.toml"
    folder.mkdir()
    assert f"config file {folder} is a folder" in _sweep_error(tmp_path, folder)
    result = CliRunner().invoke(app, ["report", str(tmp_path), "-o", str(tmp_path / "r")])
    assert result.exit_code == 2 and f"{tmp_path} is a folder; give the results.db" in unwrapped(result.output)


def test_sweep_into_a_folder_it_cannot_write_says_so_in_one_line(tmp_path: Path) -> None:
    unwritable = Path("/proc/self")  # a folder no user can create files in
    if not unwritable.is_dir():
        pytest.skip("needs /proc (Linux)")
    config = tmp_path / "ro.toml"
    config.write_text(_SWEEP.format(output=unwritable, classes='["chair"]', image_size=32))
    text = _sweep_error(tmp_path, config)
    assert "cannot open or create the results database there" in text and "OperationalError" not in text
