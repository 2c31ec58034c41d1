"""Command-line ergonomics: one-line errors, ranges, victim lists, the input frame, comparison images."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from typer.testing import CliRunner

from meshadv.cli import app
from meshadv.commands._common import VICTIMS, parse_azimuth_range
from meshadv.commands._common_options import one_line_error

runner = CliRunner()


def test_victim_list_in_help_matches_the_registry() -> None:
    from meshadv.victims import available_victims

    assert list(VICTIMS) == available_victims()
    result = runner.invoke(app, ["attack", "--help"], terminal_width=200)
    text = " ".join(result.output.replace("│", " ").split())  # rich wraps help inside a box
    assert all(name in text for name in VICTIMS), text
    assert "--weights" in text and "--cfg" in text


@pytest.mark.parametrize("text, expected", [("150:210", (150.0, 210.0)), ("150-210", (150.0, 210.0)),
                                            ("-30:30", (-30.0, 30.0)), ("-30--10", (-30.0, -10.0))])
def test_azimuth_ranges(text: str, expected: tuple) -> None:
    assert parse_azimuth_range(text) == expected


@pytest.mark.parametrize("text", ["150", "a:b", "210:150"])
def test_bad_azimuth_ranges(text: str) -> None:
    with pytest.raises(ValueError, match="--azimuths"):
        parse_azimuth_range(text)


def test_mistakes_end_in_one_line_not_a_traceback(tmp_path: Path) -> None:
    pytest.importorskip("meshadv._raster")
    result = runner.invoke(app, ["render", "builtin:sphere", "--views", "1", "--image-size", "0", "-o",
                                 str(tmp_path)])
    assert result.exit_code == 2 and "--image-size" in result.output and "Traceback" not in result.output
    import typer

    from meshadv.commands._common_options import install

    def fails(size: int = typer.Option(1)) -> None:
        raise ValueError(f"size must be even, got {size}")

    def crashes() -> None:
        raise RuntimeError("a bug")

    small = typer.Typer()
    small.command("fails")(fails)
    small.command("crashes")(crashes)
    install(small)
    result = runner.invoke(small, ["fails", "--size", "3", "--threads", "1"])
    assert result.exit_code == 1 and "Traceback" not in result.output, result.output
    assert "size must be even, got 3" in result.output and len(result.output.strip().splitlines()) <= 4
    result = runner.invoke(small, ["crashes"])
    assert isinstance(result.exception, RuntimeError)  # bugs keep their traceback
    result = runner.invoke(app, ["render", "builtin:sphere", "--views", "1", "--image-size", "16", "--azimuths",
                                 "150-210", "-o", str(tmp_path)])
    assert result.exit_code == 0, result.output


def test_one_line_error_messages() -> None:
    missing = ModuleNotFoundError("No module named 'mitsuba'", name="mitsuba")
    assert "pip install 'meshadv[transfer]'" in one_line_error(missing)
    assert "meshadv[cluster]" in one_line_error(ModuleNotFoundError("x", name="ray"))
    assert one_line_error(ModuleNotFoundError("x", name="meshadv.nothing")) is None  # a bug: keep the traceback
    assert one_line_error(ImportError("cannot import name 'x'")) is None
    assert one_line_error(ImportError("the ray backend needs Ray: pip install 'ray>=2.9'")) == \
        "the ray backend needs Ray: pip install 'ray>=2.9'"
    assert one_line_error(FileNotFoundError(2, "No such file or directory", "a.ply")) == \
        "No such file or directory: a.ply"
    assert one_line_error(ValueError("steps must be >= 1")) == "steps must be >= 1"
    assert one_line_error(RuntimeError("boom")) is None


def test_misspelt_class_gets_a_suggestion() -> None:
    from meshadv.attacks.criteria import resolve_imagenet_classes

    with pytest.raises(ValueError, match="did you mean 'bicycle'"):
        resolve_imagenet_classes("bicylce", "target_class")


def test_attack_saves_the_input_frame_and_a_comparison(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("meshadv._raster")
    from stand_in_victims import PooledLinearClassifier

    import meshadv.victims as victims
    from meshadv.mesh import load_mesh, save_mesh
    from meshadv.mesh.shapes import builtin_mesh

    monkeypatch.setattr(victims, "load_victim", lambda name, **kwargs: PooledLinearClassifier())
    box = builtin_mesh("cube")
    box = box.with_vertices(box.vertices * 5.0 + torch.tensor([10.0, 0.0, 0.0]))  # a 10-unit box off the origin
    save_mesh(box, tmp_path / "box.ply")
    out = tmp_path / "a"
    result = runner.invoke(app, ["attack", str(tmp_path / "box.ply"), "--target", "7", "--views", "2",
                                 "--image-size", "32", "--steps", "2", "--quiet", "--threads", "1", "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert "taken as Y-up" in result.output and "--z-up" in result.output
    record = json.loads((out / "result.json").read_text())
    assert record["input"]["path"] == str((tmp_path / "box.ply").resolve())
    assert record["input"]["z_up"] is False and record["input"]["normalize_transform"]["scale"] == pytest.approx(0.2)
    moved = load_mesh(out / "adversarial_input_frame.ply")
    extent = moved.vertices.max(0).values - moved.vertices.min(0).values
    assert extent.max().item() == pytest.approx(10.0, rel=0.05)
    assert moved.vertices[:, 0].mean().item() == pytest.approx(10.0, abs=0.5)
    from PIL import Image

    with Image.open(out / "comparison.png") as image:
        assert image.width >= 2 * 320 and image.height >= 2 * 320  # two views, each cell at least 320 px
    assert (out / "comparison.png").stat().st_mode & 0o777 == 0o666 & ~_umask()

    pytest.importorskip("mitsuba", reason="Mitsuba 3 not installed (pip install 'meshadv[transfer]')")
    from meshadv.transfer.controlled import transfer_attack_folder

    rows = transfer_attack_folder(out, spp=4, max_depth=2, victim_loader=lambda name: PooledLinearClassifier())
    assert [r.view for r in rows] == [0, 1]
    assert all(isinstance(r.success_mitsuba, bool) for r in rows)
    assert json.loads((out / "transfer.json").read_text())["rows"] == [r.to_record() for r in rows]
    assert (out / "mitsuba_v0.png").is_file() and (out / "mitsuba_v1.png").is_file()


def _umask() -> int:
    import os

    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_sweep_dry_run_finds_what_would_fail_every_job(tmp_path: Path) -> None:
    import copy

    from meshadv.commands._sweep_check import check_jobs
    from meshadv.experiments.config import expand_jobs, load_config

    config = Path(__file__).resolve().parents[1] / "configs" / "paper_small.toml"
    jobs = expand_jobs(load_config(config))[:3]
    bad = copy.deepcopy(jobs)
    for job in bad:  # built-in meshes: the check does not depend on the shared data being here
        job["mesh"] = {"source": "builtin", "name": "chair"}
    assert check_jobs(bad) == []
    bad[0]["victim"] = "efficientnet_lite3"
    bad[1]["mesh"] = {"source": "files", "path": str(tmp_path / "missing.ply")}
    bad[2]["target"] = "bicylce"
    problems = check_jobs(bad)
    assert len(problems) == 3
    assert "did you mean 'efficientnet_lite2'" in problems[0]
    assert "missing.ply does not exist" in problems[1] and "did you mean 'bicycle'" in problems[2]
    text = config.read_text().replace('names = ["efficientnet_lite0"]', 'names = ["efficientnet_lite3"]')
    (tmp_path / "bad.toml").write_text(text.replace('output = "../out/paper_small"', 'output = "out"'))
    result = runner.invoke(app, ["sweep", str(tmp_path / "bad.toml"), "--dry-run"])
    assert result.exit_code == 1 and "efficientnet_lite2" in result.output, result.output  # problems found, not a crash


def test_report_explains_a_config_and_lists_failed_jobs(tmp_path: Path) -> None:
    from meshadv.experiments import ResultStore
    from meshadv.experiments.config import expand_jobs, load_config

    config = Path(__file__).resolve().parents[1] / "configs" / "paper_small.toml"
    result = runner.invoke(app, ["report", str(config), "-o", str(tmp_path / "r")])
    assert result.exit_code == 2 and "run `meshadv sweep" in " ".join(result.output.replace("│", " ").split())
    jobs = expand_jobs(load_config(config))[:2]
    with ResultStore(tmp_path / "results.db") as store:
        store.add_jobs(jobs)
        failed = store.rows()[0].job_id
        store.mark_running(failed)
        store.mark_failed(failed, "Traceback (most recent call last):\n  ...\nValueError: no such class")
    result = runner.invoke(app, ["report", str(tmp_path / "results.db"), "-o", str(tmp_path / "r")])
    assert result.exit_code == 0, result.output
    assert f"{failed[:12]} (1 attempts): ValueError: no such class" in result.output
    index = (tmp_path / "r" / "index.csv").read_text().splitlines()
    assert len(index) == 3 and any(line.startswith(failed) and "no such class" in line for line in index)
    # the job folder from the index's folder: ../jobs/<2>/<id>, no path of this machine
    assert f",../jobs/{failed[:2]}/{failed}," in "\n".join(index) and str(tmp_path) not in "\n".join(index)


def test_attack_scene_refuses_when_nothing_is_detected() -> None:
    pytest.importorskip("meshadv._raster")
    import types

    import typer
    from stand_in_victims import DarkBlobDetector

    from meshadv.attacks import Disappearance
    from meshadv.commands.attack_scene import _require_something_to_hide
    from meshadv.mesh.shapes import builtin_mesh
    from meshadv.render import RenderSetup, ViewSet

    dark = builtin_mesh("sphere", color=(0.05, 0.05, 0.05))

    def setup_at(distance: float) -> object:
        views = ViewSet.orbit([0.0], distance=distance)
        return types.SimpleNamespace(mesh=dark, views=lambda: views,
                                     render_setup=lambda antialias: RenderSetup(image_size=64))

    detector = DarkBlobDetector()
    _require_something_to_hide(setup_at(3.0), detector, Disappearance("blob", threshold=0.5), "blob", 0.5)
    with pytest.raises(typer.BadParameter, match="nothing to hide: the detector finds no 'blob'"):
        _require_something_to_hide(setup_at(80.0), detector, Disappearance("blob", threshold=0.5), "blob", 0.5)


def test_missing_shared_data_says_what_it_is(monkeypatch: pytest.MonkeyPatch) -> None:
    import meshadv.data as data

    monkeypatch.setattr(data, "shared_data_dir", lambda: None)
    with pytest.raises(FileNotFoundError, match="PASCAL3D\\+ CAD models.*Set MESHADV_DATA"):
        data.require_shared_data("pascal3d/chair/01.ply")


@pytest.mark.parametrize("module, argv, hint", [
    ("mitsuba", ["transfer", "attack", "."], "meshadv[transfer]"),
    ("ray", ["sweep", "CONFIG", "--backend", "ray"], "pip install 'ray"),
])
def test_missing_optional_packages_are_one_line(monkeypatch: pytest.MonkeyPatch, tmp_path: Path, module: str,
                                                argv: list, hint: str) -> None:
    import sys

    monkeypatch.setitem(sys.modules, module, None)  # `import module` now fails as if it were not installed
    config = Path(__file__).resolve().parents[1] / "configs" / "paper_small.toml"
    argv = [str(config) if a == "CONFIG" else a for a in argv] + (["--db", str(tmp_path / "r.db"), "--output",
                                                                    str(tmp_path)] if argv[0] == "sweep" else [])
    monkeypatch.chdir(tmp_path)
    result = runner.invoke(app, argv)
    assert result.exit_code == 1 and "Traceback" not in result.output, result.output
    assert hint in " ".join(result.output.replace("│", " ").split())


def test_transfer_controlled_without_successes_mentions_all(tmp_path: Path) -> None:
    from meshadv.experiments import ResultStore
    from meshadv.experiments.config import expand_jobs, load_config

    config = Path(__file__).resolve().parents[1] / "configs" / "paper_small.toml"
    with ResultStore(tmp_path / "results.db") as store:
        store.add_jobs(expand_jobs(load_config(config))[:1])
    result = runner.invoke(app, ["transfer", "controlled", str(tmp_path / "results.db")])
    assert result.exit_code == 1 and "--all" in result.output
    limit = runner.invoke(app, ["transfer", "controlled", str(tmp_path / "results.db"), "--limit", "0"])
    assert limit.exit_code == 2 and "--limit" in limit.output and "Traceback" not in limit.output


def test_version_and_python_dash_m() -> None:
    import subprocess
    import sys

    from meshadv import __version__

    result = runner.invoke(app, ["--version"])
    assert result.exit_code == 0 and result.output.strip() == f"meshadv {__version__}"
    out = subprocess.run([sys.executable, "-m", "meshadv", "--version"], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == f"meshadv {__version__}"
