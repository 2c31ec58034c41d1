"""The benign check before ``meshadv attack``: refuse (or warn) when the benign render is not the source class on
some views, leave out targets that already hold, and say "nothing to do" when every target does (stand-in victim);
and the ``--cap`` option's help text matching the default cap."""

from __future__ import annotations

from typing import Any, Tuple

import pytest
import typer

from meshadv.attacks import TargetedMisclassification, evaluate
from meshadv.attacks.benign import check_benign, source_class_of_path
from meshadv.commands._benign_gate import benign_gate, source_class
from meshadv.mesh import builtin_mesh
from meshadv.render import RenderSetup, ViewSet, native_available

needs_native = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")


def _subject() -> Tuple[Any, Any, Any, RenderSetup, Tuple[int, ...]]:
    """The builtin chair on three views, the stand-in victim, the setup and the benign top-1 per view."""
    from stand_in_victims import PooledLinearClassifier

    mesh, victim, setup = builtin_mesh("chair"), PooledLinearClassifier(), RenderSetup(image_size=48)
    views = ViewSet.orbit([0.0, 120.0, 240.0], elevation=20.0, distance=2.6)
    scored = evaluate(mesh, views, victim, TargetedMisclassification(0), setup=setup)
    assert scored.top1 is not None
    return mesh, views, victim, setup, tuple(scored.top1[0].tolist())


@needs_native
def test_check_benign_finds_wrong_views_and_targets_that_already_hold() -> None:
    mesh, views, victim, setup, top1 = _subject()
    first = top1[0]
    wrong = [v for v, c in enumerate(top1) if c != first]
    check = check_benign(mesh, views, victim, [TargetedMisclassification(first), TargetedMisclassification(999)],
                         source=str(first), setup=setup)
    assert check.wrong_views == wrong
    assert check.top1 == tuple(victim.class_names[c] for c in top1)
    # the first view's own top-1 holds there; it holds on every view only when the views agree
    assert check.adversarial[0][0] and check.already_held[0] == (not wrong)
    assert check.already_held[1] == (999 in top1 and all(c == 999 for c in top1))
    unknown = check_benign(mesh, views, victim, [TargetedMisclassification(999)], setup=setup)
    assert unknown.source is None and unknown.source_correct is None and unknown.wrong_views == []


@needs_native
def test_the_gate_refuses_a_wrong_benign_unless_told_to_go_on(capsys: pytest.CaptureFixture) -> None:
    mesh, views, victim, setup, top1 = _subject()
    other = next(c for c in range(1000) if c not in top1)  # a class no benign view shows
    target = [TargetedMisclassification(next(c for c in range(1000) if c not in top1 and c != other))]
    with pytest.raises(typer.Exit) as refused:
        benign_gate(mesh, views, victim, target, source=str(other), setup=setup, success_fraction=1.0, go_on=False)
    assert refused.value.exit_code == 1
    err = capsys.readouterr().err
    assert f"the benign render is not {other} on views 0, 1, 2" in err and "--benign-wrong-ok" in err
    kept = benign_gate(mesh, views, victim, target, source=str(other), setup=setup, success_fraction=1.0, go_on=True)
    assert kept == target and "warning: the benign render" in capsys.readouterr().err
    right = str(top1[0]) if len(set(top1)) == 1 else None
    assert benign_gate(mesh, views, victim, target, source=right, setup=setup, success_fraction=1.0,
                       go_on=False) == target


@needs_native
def test_the_gate_says_nothing_to_do_when_every_target_already_holds(capsys: pytest.CaptureFixture) -> None:
    mesh, views, victim, setup, top1 = _subject()
    held = TargetedMisclassification(top1[0])
    fraction = sum(c == top1[0] for c in top1) / len(top1)  # the views where it already holds
    fresh = TargetedMisclassification(next(c for c in range(1000) if c not in top1))
    with pytest.raises(typer.Exit) as done:
        benign_gate(mesh, views, victim, [held], source=None, setup=setup, success_fraction=fraction, go_on=False)
    assert done.value.exit_code == 0 and "nothing to do" in capsys.readouterr().out
    left = benign_gate(mesh, views, victim, [held, fresh], source=None, setup=setup, success_fraction=fraction,
                       go_on=False)
    assert left == [fresh] and "left out" in capsys.readouterr().out


def test_the_source_class_comes_from_the_option_the_untargeted_class_or_the_folder() -> None:
    assert source_class("sofa", "chair", "/d/pascal3d/boat/01.ply") == "sofa"
    assert source_class(None, "chair", "/d/pascal3d/boat/01.ply") == "chair"
    assert source_class(None, None, "/d/pascal3d/boat/01.ply") == "boat"
    assert source_class(None, None, "/d/meshes/thing.ply") is None and source_class(None, None, None) is None
    assert source_class_of_path("/x/Chair/3.obj", ["chair"]) == "chair"


def test_cap_help_spells_out_the_default_cap() -> None:
    from meshadv.commands._cap_option import CAP_HELP, parse_cap
    from meshadv.perceptibility import DEFAULT_CAP
    from meshadv.perceptibility.geometry import EDGE_STRAIN_FLOOR

    cap = DEFAULT_CAP
    assert cap.max_displacement is not None and cap.normal_change_p95_deg is not None
    assert cap.color_change_p95 is not None
    assert f"largest vertex move {100 * cap.max_displacement:g}% of the bounding-box diagonal" in CAP_HELP
    assert f"at most {cap.normal_change_p95_deg:g} degrees" in CAP_HELP
    assert cap.edge_strain_p95 is not None
    assert f"stretched or squeezed by at most {100 * cap.edge_strain_p95:g}%" in CAP_HELP
    assert cap.edge_strain_max is not None
    assert f"no edge's length changed by more than {100 * cap.edge_strain_max:g}%" in CAP_HELP
    assert (f"shorter than {100 * EDGE_STRAIN_FLOOR:g}% of the diagonal: by more than "
            f"{100 * EDGE_STRAIN_FLOOR * cap.edge_strain_max:g}% of the diagonal") in CAP_HELP
    assert f"changing colour by at most {cap.color_change_p95:g}" in CAP_HELP
    assert parse_cap("default") == DEFAULT_CAP and parse_cap("none") is None
    with pytest.raises(ValueError, match="--cap"):
        parse_cap("max_move=1")
