"""The default row ids and the update rule (``--method``) of ``meshadv transfer blackbox-classifier`` /
``blackbox-detector`` (no Mitsuba: the pipeline functions are replaced by stand-ins that record what they are
given)."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import pytest


class _Captured(Exception):
    """Raised by the stand-in pipeline once it has the case id."""


def _invoke(monkeypatch: pytest.MonkeyPatch, command: str, args: list[str]) -> tuple[Any, dict[str, Any]]:
    """Run ``meshadv transfer COMMAND ARGS`` with the stand-in pipeline; the CLI result and the keyword arguments
    the pipeline got (empty when the command refused its options)."""
    from typer.testing import CliRunner

    import meshadv.transfer.blackbox as blackbox
    import meshadv.transfer.setups as setups
    import meshadv.victims as victims
    from meshadv.cli import build_app
    from meshadv.mesh import builtin_mesh

    seen: dict[str, Any] = {}

    def pipeline(*_args: Any, **kwargs: Any) -> None:
        seen.update(kwargs)
        raise _Captured

    monkeypatch.setattr(blackbox, "blackbox_classifier", pipeline)
    monkeypatch.setattr(blackbox, "blackbox_detector", pipeline)
    monkeypatch.setattr(setups, "default_aeroplane", lambda: builtin_mesh("chair"))
    monkeypatch.setattr(setups, "outdoor_classifier_setup", lambda *a, **k: None)
    monkeypatch.setattr(setups, "indoor_detector_setup",
                        lambda **k: SimpleNamespace(objects=(builtin_mesh("cube"), builtin_mesh("sphere")),
                                                    object_index=1, hidden=None, background_exclude=()))
    monkeypatch.setattr(victims, "load_victim", lambda name: name)
    result = CliRunner().invoke(build_app({"transfer": "transfer:transfer"}), ["transfer", command, *args])
    return result, seen


def _run(monkeypatch: pytest.MonkeyPatch, command: str, args: list[str]) -> str:
    """The case id the command gives the pipeline."""
    result, seen = _invoke(monkeypatch, command, args)
    assert isinstance(result.exception, _Captured), result.output
    return seen["case_id"]


@pytest.mark.parametrize("args, expected", [
    ([], "outdoor_aeroplane_texture_untargeted"),  # Adam, the default: the id of the rows recorded before --method
    (["--method", "ddn"], "outdoor_aeroplane_texture_untargeted_ddn"),
    (["--perturbation", "shape", "--target", "bird", "--eot", "4", "--margin", "2", "--steps", "50", "--spp", "16",
      "--method", "ddn"],
     "outdoor_aeroplane_shape_bird_eot4_margin2_steps50_spp16_ddn"),
    (["--jitter", "0.5", "--light-jitter", "2", "--pixel-noise", "0.01", "--antialias", "3", "--seed", "7",
      "--texture-smoothing", "4"],
     "outdoor_aeroplane_texture_untargeted_jitter0.5_lightjitter2_noise0.01_aa3_seed7_smooth4"),
])
def test_blackbox_classifier_default_case_id(monkeypatch: pytest.MonkeyPatch, args: list[str], expected: str) -> None:
    assert _run(monkeypatch, "blackbox-classifier", args) == expected


@pytest.mark.parametrize("args, expected", [
    ([], "indoor_bunny_hide_dining_table"),
    (["--method", "ddn"], "indoor_bunny_hide_dining_table_ddn"),
    (["--hide", "chair", "--perturbation", "shape", "--context", "render", "--light-fit", "known",
      "--object-scale", "1.5", "--eot", "2", "--spp", "32", "--method", "ddn"],
     "indoor_bunny_hide_chair_shape_render_lightsknown_scale1.5_eot2_spp32_ddn"),
    (["--texture-smoothing", "2", "--steps", "10", "--jitter", "0"],
     "indoor_bunny_hide_dining_table_jitter0_steps10_smooth2"),
])
def test_blackbox_detector_default_case_id(monkeypatch: pytest.MonkeyPatch, args: list[str], expected: str) -> None:
    assert _run(monkeypatch, "blackbox-detector", args) == expected


@pytest.mark.parametrize("command", ["blackbox-classifier", "blackbox-detector"])
def test_blackbox_method_option(monkeypatch: pytest.MonkeyPatch, command: str) -> None:
    """``--method`` reaches the attack (Adam by default, as every recorded black-box run; the attack built from the
    kwargs runs the rule asked for); Adam's
    own options and ``--texture-smoothing`` (a parametrisation ddn cannot step) are refused with ddn, in one line,
    before anything runs; an unknown rule is refused."""
    from meshadv.transfer.blackbox import attack_options
    from meshadv.transfer.robust import object_attack

    for args, method in (([], "adam"), (["--method", "ddn"], "ddn"), (["--lr", "0.1"], "adam")):
        result, seen = _invoke(monkeypatch, command, args)
        assert isinstance(result.exception, _Captured), result.output
        kwargs = seen["attack_kwargs"]
        assert kwargs["method"] == method and ("lr" in kwargs) == ("--lr" in args)
        _, attack_kwargs = attack_options(kwargs, seen["jitter"])  # as the pipelines build their attack
        attack = object_attack(seen["perturbation"], seen["texture_smoothing"], attack_kwargs)
        assert attack.config()["method"] == method
    for bad in (["--method", "ddn", "--lr", "0.1"], ["--method", "ddn", "--lambda-perceptual", "1e-5"],
                ["--method", "ddn", "--texture-smoothing", "4"]):
        result, seen = _invoke(monkeypatch, command, bad)
        assert result.exit_code == 2 and not seen, bad
        assert "apply to --method adam only" in " ".join(result.output.replace("│", " ").split()), result.output
    result, seen = _invoke(monkeypatch, command, ["--method", "bogus"])
    assert result.exit_code == 2 and not seen and "bogus" in result.output


@pytest.mark.parametrize("command, attacked", [("blackbox-classifier", "chair"), ("blackbox-detector", "sphere")])
def test_blackbox_ddn_shape_lengths_follow_the_object(monkeypatch: pytest.MonkeyPatch, command: str,
                                                      attacked: str) -> None:
    """A ddn shape attack's lengths are scaled to the attacked object's bounding-box diagonal (as in
    ``meshadv attack-scene``); a ddn texture attack and an Adam shape attack get no ``method_options``."""
    from meshadv.attacks.budget import DDN_DEFAULTS, DDN_REFERENCE_DIAGONAL
    from meshadv.mesh import builtin_mesh

    result, seen = _invoke(monkeypatch, command, ["--perturbation", "shape", "--method", "ddn"])
    assert isinstance(result.exception, _Captured), result.output
    scale = float(builtin_mesh(attacked).bbox_diagonal()) / DDN_REFERENCE_DIAGONAL
    options = seen["attack_kwargs"]["method_options"]
    assert set(options) == {"init_budget", "step_size", "final_step_size", "min_budget"}
    for name, value in options.items():
        assert value == pytest.approx(DDN_DEFAULTS["shape"][name] * scale), name
    for args in (["--perturbation", "texture", "--method", "ddn"], ["--perturbation", "shape"]):
        result, seen = _invoke(monkeypatch, command, args)
        assert isinstance(result.exception, _Captured) and "method_options" not in seen["attack_kwargs"], args


def test_blackbox_rows_record_the_method() -> None:
    """A black-box row names its update rule; a ddn row records its options and no Adam learning rate or
    perceptual weight (ddn uses neither), an Adam row its lr and lambda as before."""
    from types import SimpleNamespace

    from meshadv.attacks import ShapeAttack, TextureAttack
    from meshadv.transfer.blackbox import _attack_record

    result = SimpleNamespace(steps=3, steps_to_success=[2], wall_time=1.0, distances=[{"color_rmse": 0.1}])
    setup = SimpleNamespace(antialias=1)
    ddn = _attack_record(TextureAttack(method="ddn", steps=3), setup, result)
    assert ddn["method"] == "ddn" and ddn["lr"] is None and ddn["lambda_perceptual"] is None
    assert ddn["method_options"] == TextureAttack(method="ddn").config()["method_options"]
    adam = _attack_record(ShapeAttack(steps=3, lr=0.02), setup, result)
    assert adam["method"] == "adam" and adam["lr"] == 0.02 and adam["lambda_perceptual"] == 0.05
    assert "method_options" not in adam
