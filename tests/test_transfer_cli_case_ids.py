"""The default row ids of ``meshadv transfer blackbox-classifier`` / ``blackbox-detector`` (no Mitsuba: the pipeline
functions are replaced by stand-ins that record the id they are given)."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import pytest


class _Captured(Exception):
    """Raised by the stand-in pipeline once it has the case id."""


def _run(monkeypatch: pytest.MonkeyPatch, command: str, args: list[str]) -> str:
    from typer.testing import CliRunner

    import meshadv.transfer.blackbox as blackbox
    import meshadv.transfer.setups as setups
    import meshadv.victims as victims
    from meshadv.cli import build_app

    seen: dict[str, Any] = {}

    def pipeline(*_args: Any, case_id: str, **_kwargs: Any) -> None:
        seen["case_id"] = case_id
        raise _Captured

    monkeypatch.setattr(blackbox, "blackbox_classifier", pipeline)
    monkeypatch.setattr(blackbox, "blackbox_detector", pipeline)
    monkeypatch.setattr(setups, "default_aeroplane", lambda: None)
    monkeypatch.setattr(setups, "outdoor_classifier_setup", lambda *a, **k: None)
    monkeypatch.setattr(setups, "indoor_detector_setup",
                        lambda **k: SimpleNamespace(objects=(), object_index=0, hidden=None, background_exclude=()))
    monkeypatch.setattr(victims, "load_victim", lambda name: name)
    result = CliRunner().invoke(build_app({"transfer": "transfer:transfer"}), ["transfer", command, *args])
    assert isinstance(result.exception, _Captured), result.output
    return seen["case_id"]


@pytest.mark.parametrize("args, expected", [
    ([], "outdoor_aeroplane_texture_untargeted"),
    (["--perturbation", "shape", "--target", "bird", "--eot", "4", "--margin", "2", "--steps", "50", "--spp", "16"],
     "outdoor_aeroplane_shape_bird_eot4_margin2_steps50_spp16"),
    (["--jitter", "0.5", "--light-jitter", "2", "--pixel-noise", "0.01", "--antialias", "3", "--seed", "7",
      "--texture-smoothing", "4"],
     "outdoor_aeroplane_texture_untargeted_jitter0.5_lightjitter2_noise0.01_aa3_seed7_smooth4"),
])
def test_blackbox_classifier_default_case_id(monkeypatch: pytest.MonkeyPatch, args: list[str], expected: str) -> None:
    assert _run(monkeypatch, "blackbox-classifier", args) == expected


@pytest.mark.parametrize("args, expected", [
    ([], "indoor_bunny_hide_dining_table"),
    (["--hide", "chair", "--perturbation", "shape", "--context", "render", "--light-fit", "known",
      "--object-scale", "1.5", "--eot", "2", "--spp", "32"],
     "indoor_bunny_hide_chair_shape_render_lightsknown_scale1.5_eot2_spp32"),
    (["--texture-smoothing", "2", "--steps", "10", "--jitter", "0"],
     "indoor_bunny_hide_dining_table_jitter0_steps10_smooth2"),
])
def test_blackbox_detector_default_case_id(monkeypatch: pytest.MonkeyPatch, args: list[str], expected: str) -> None:
    assert _run(monkeypatch, "blackbox-detector", args) == expected
