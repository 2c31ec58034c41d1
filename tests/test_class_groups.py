"""One definition of "is this render its class" (the class group, :func:`meshadv.attacks.criteria.resolve_true_class`)
behind every true-class verdict: the untargeted criterion, ``meshadv attack``'s benign check, a sweep job's benign
verdict, the rendering set's judge and the transfer's untargeted count and benign control. A top-1 inside the true
class's group is neither an untargeted success nor a wrong benign render; outside it is (stand-in victims whose top-1
is chosen by colour, fake Mitsuba renders: no weights, no Mitsuba)."""

from __future__ import annotations

from typing import Any, Tuple

import numpy as np
import pytest
import torch

from meshadv.attacks import Misclassification, TargetedMisclassification
from meshadv.attacks.criteria import resolve_true_class
from meshadv.mesh import builtin_mesh
from meshadv.render import RenderSetup, ViewSet, native_available
from meshadv.victims.labels import PASCAL3D_TO_IMAGENET, imagenet_class_names, pascal_class_of

needs_native = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")

AIRLINER, WARPLANE, ZEBRA = 404, 895, 340


def _colour_victim(classes: Tuple[int, int, int] = (AIRLINER, WARPLANE, ZEBRA)) -> Any:
    from stand_in_victims import ColourClassifier

    return ColourClassifier(classes)


def _logits(*top1: int) -> torch.Tensor:
    logits = torch.zeros(len(top1), 1000)
    for row, cls in enumerate(top1):
        logits[row, cls] = 5.0
    return logits


def test_a_member_of_a_group_stands_for_its_group_and_a_class_of_none_for_itself() -> None:
    aeroplane = (tuple(PASCAL3D_TO_IMAGENET["aeroplane"]), "aeroplane")
    for spec in ("aeroplane", "airliner", "Warplane", WARPLANE, str(AIRLINER)):
        assert resolve_true_class(spec) == aeroplane, spec
    assert resolve_true_class("beer bottle") == (tuple(PASCAL3D_TO_IMAGENET["bottle"]), "bottle")
    assert resolve_true_class("zebra") == ((ZEBRA,), "zebra")  # no group: the class alone
    assert resolve_true_class([AIRLINER]) == ((AIRLINER,), "airliner")  # a list names exactly its classes
    assert resolve_true_class([AIRLINER, ZEBRA])[0] == (AIRLINER, ZEBRA)
    assert pascal_class_of(WARPLANE) == "aeroplane" and pascal_class_of(ZEBRA) is None
    with pytest.raises(ValueError, match="true_class"):
        resolve_true_class("aeroplan")
    # a target is still the class it names
    assert TargetedMisclassification("warplane").bind(_colour_victim()).indices == (WARPLANE,)


def test_untargeted_success_needs_the_top1_to_leave_the_group() -> None:
    victim = _colour_victim()
    logits = _logits(WARPLANE, AIRLINER, ZEBRA)
    for true in ("airliner", "aeroplane", AIRLINER):
        crit = Misclassification(true).bind(victim)
        assert crit.is_adversarial(logits).tolist() == [False, False, True], true
        assert crit.label == "untargeted(true=aeroplane)"
    exact = Misclassification([AIRLINER]).bind(victim)  # one class exactly: a warplane leaves it
    assert exact.is_adversarial(logits).tolist() == [True, False, True]
    alone = Misclassification("zebra").bind(victim)  # no group: every other class is a misclassification
    assert alone.is_adversarial(logits).tolist() == [True, True, False]
    # the untargeted loss pushes out of the whole group: a warplane top-1 is no easier than an airliner one
    ce = Misclassification("airliner").bind(victim).loss(_logits(WARPLANE, AIRLINER))
    assert torch.allclose(ce[0], ce[1])


@needs_native
def test_the_benign_check_takes_a_render_inside_the_group_as_right() -> None:
    from meshadv.attacks.benign import check_benign

    mesh, setup = builtin_mesh("chair"), RenderSetup(image_size=16)
    views = ViewSet.orbit([0.0, 120.0], elevation=20.0, distance=2.6)
    warplane = _colour_victim((WARPLANE,) * 3)  # every render: warplane
    inside = check_benign(mesh, views, warplane, [TargetedMisclassification(ZEBRA)], source="airliner", setup=setup)
    assert inside.top1 == ("warplane", "warplane") and inside.wrong_views == []
    assert inside.source_group == "aeroplane" and "its group aeroplane" in inside.describe_source()
    outside = check_benign(mesh, views, _colour_victim((ZEBRA,) * 3), [TargetedMisclassification(WARPLANE)],
                           source="airliner", setup=setup)
    assert outside.wrong_views == [0, 1]
    exact = check_benign(mesh, views, warplane, [TargetedMisclassification(ZEBRA)], source=[AIRLINER], setup=setup)
    assert exact.wrong_views == [0, 1] and exact.source_group is None


@needs_native
def test_a_sweep_job_and_the_rendering_set_judge_by_the_group() -> None:
    from meshadv.datasets.rendering_set.judging import Judge
    from meshadv.experiments.jobs import JobContext

    mesh, setup = builtin_mesh("bottle"), RenderSetup(image_size=16)
    views = ViewSet.orbit([0.0, 90.0], elevation=20.0, distance=3.0)
    for top1, right in ((WARPLANE, True), (ZEBRA, False)):
        victim = _colour_victim((top1,) * 3)
        for source in ("aeroplane", "airliner"):
            context = JobContext(spec={"source_class": source}, views=views, eval_views=None, victim=victim,
                                 victim_optimize=False, setup=setup, attack_options={}, required_margin=0.0)
            assert context.benign_verdict(mesh).correct is right, (top1, source)
        judged, names = Judge(victim, 0.5, imagenet_class_names())(torch.full((2, 3, 8, 8), 0.5), "aeroplane")
        assert judged == [right, right] and names == [imagenet_class_names()[top1]] * 2


def _flat(color: Tuple[float, float, float]) -> Any:
    from meshadv.transfer.mitsuba_process import MitsubaImage

    image = np.empty((16, 16, 3), dtype=np.float32)
    image[:] = color
    return MitsubaImage(image, np.ones((16, 16), dtype=np.float32), "fake")


RED, GREEN, BLUE = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)  # airliner, warplane, zebra


@needs_native
def test_untargeted_transfer_and_the_benign_control_count_by_the_group() -> None:
    from meshadv.transfer.controlled import TransferCase, evaluate_case
    from meshadv.transfer.results import transfer_table

    victim = _colour_victim()
    mesh = builtin_mesh("bottle")
    views = ViewSet.orbit([20.0, 60.0, 100.0], elevation=15.0, distance=3.0).to_records()
    # Mitsuba: the adversarial mesh is a warplane, a zebra, a warplane; the benign one an airliner, a warplane, a zebra
    adversarial, benign = [_flat(GREEN), _flat(BLUE), _flat(GREEN)], [_flat(RED), _flat(GREEN), _flat(BLUE)]
    for true_class in ("airliner", "aeroplane"):
        case = TransferCase("c", mesh, tuple(views), "colour", true_class, image_size=16, benign_mesh=mesh)
        rows = evaluate_case(case, victim, adversarial, benign)
        assert [r.untargeted_mitsuba for r in rows] == [False, True, False], true_class
        assert [r.benign_correct_mitsuba for r in rows] == [True, True, False]  # a benign warplane is right
        assert [r.untargeted_counted for r in rows] == [False, True, None]
        table = transfer_table([r.to_record() for r in rows])[0]
        assert table["untargeted_mitsuba"] == 0.5 and table["n_benign_mitsuba_correct"] == 2
    # a class of no group is itself alone: a warplane render of a zebra counts, a benign zebra render is right
    zebra = TransferCase("z", mesh, tuple(views), "colour", "zebra", image_size=16, benign_mesh=mesh)
    alone = evaluate_case(zebra, victim, adversarial, [_flat(BLUE)] * 3)
    assert [r.untargeted_mitsuba for r in alone] == [True, False, True]
    assert [r.benign_correct_mitsuba for r in alone] == [True, True, True]


def test_an_attack_folder_names_its_source_class() -> None:
    from meshadv.transfer.controlled import source_class_of_record

    top1 = {"original_top1_names": ["airliner", "warplane"]}
    assert source_class_of_record({**top1, "input": {"source_class": "aeroplane", "path": "/d/pascal3d/boat/1.ply"}}) \
        == "aeroplane"
    untargeted = {"criteria": [{"criterion": "Misclassification", "true_class": "chair"}]}
    assert source_class_of_record({**top1, **untargeted, "input": {"path": "/d/pascal3d/boat/1.ply"}}) == "chair"
    assert source_class_of_record({**top1, "input": {"source_class": None, "path": "/d/pascal3d/boat/1.ply"}}) \
        == "boat"
    assert source_class_of_record({**top1, "input": {"path": "/d/meshes/thing.ply"}}) == "airliner"
    assert resolve_true_class(source_class_of_record(top1))[1] == "aeroplane"  # judged as its group
    with pytest.raises(ValueError, match="source class"):
        source_class_of_record({})
