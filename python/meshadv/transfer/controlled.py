"""Controlled-parameter transfer: re-render a sweep's adversarial meshes with Mitsuba 3 and test the victims.

Every adversarial mesh is re-rendered under the *same* camera and lights it was attacked with (the paper's Table 3
and Fig. 5). Every Mitsuba render runs in a child process (:mod:`meshadv.transfer.render`), so a crash fails one
evaluation, never the sweep.

The cases come from a sweep's database (:mod:`meshadv.transfer.cases`); saved renders are named after what they
show, ``<class>_c<configuration>_to_<target>_<perturbation>_<victim>_<job id's first 8 hex digits>_v<view>.png``
(:func:`~meshadv.transfer.cases.case_name`), and ``index.csv`` in the same folder lists every file with its full job id
and outcome (:mod:`meshadv.transfer.images`). Those names are re-exported here.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Optional, Sequence, Union

import torch

from meshadv import _validate
from meshadv.transfer._scoring import class_names, classifier_criteria, images_tensor, top1_names
from meshadv.transfer.benign_control import benign_verdicts
from meshadv.transfer.cases import TransferCase, case_name, cases_from_store
from meshadv.transfer.images import INDEX_COLUMNS, save_images, write_image_index
from meshadv.transfer.render import MitsubaImage, MitsubaRenderError, render_scenes
from meshadv.transfer.results import ControlledResult
from meshadv.transfer.spec import MeshObject, SceneSpec, scene_spec

__all__ = [
    "ControlledResult",
    "INDEX_COLUMNS",
    "TransferCase",
    "case_name",
    "write_image_index",
    "cases_from_store",
    "controlled_transfer",
    "evaluate_case",
    "mitsuba_specs_for_case",
    "save_images",
]


def mitsuba_specs_for_case(case: TransferCase, *, spp: int = 64, max_depth: int = 8, seed: int = 0,
                           benign: bool = False) -> list[SceneSpec]:
    """One Mitsuba scene per view of ``case``: same camera, lights, image size and background.

    Args:
        case: the case.
        spp: samples per pixel.
        max_depth: path depth.
        seed: sampler seed of view 0 (view ``i`` gets ``seed + i``).
        benign: the scenes of the case's benign mesh instead of its adversarial one.

    Returns:
        The scene specs, in view order.

    Raises:
        ValueError: ``benign`` for a case without a benign mesh.
    """
    if benign and case.benign_mesh is None:
        raise ValueError(f"case {case.case_id} has no benign_mesh to render")
    obj = MeshObject.from_mesh(case.benign_mesh if benign else case.mesh)
    return [scene_spec(obj, rec, lights=rec, image_size=case.image_size, spp=spp, max_depth=max_depth,
                       background=case.background, seed=seed + i) for i, rec in enumerate(case.views)]


def evaluate_case(
    case: TransferCase,
    victim: Any,
    mitsuba_images: Sequence[MitsubaImage],
    benign_images: Optional[Sequence[MitsubaImage]] = None,
) -> list[ControlledResult]:
    """Evaluate one case on its meshadv renders and its Mitsuba renders (classifier victims).

    Args:
        case: the case.
        victim: a classifier victim.
        mitsuba_images: the case's Mitsuba renders, one per view (:func:`mitsuba_specs_for_case`).
        benign_images: Mitsuba's renders of the case's benign mesh, one per view (``benign=True``), or ``None``.

    Returns:
        One :class:`~meshadv.transfer.results.ControlledResult` per view: ``success_meshadv`` / ``success_mitsuba``
        (targeted when the case has a target, else untargeted), ``untargeted_meshadv`` / ``untargeted_mitsuba``, the
        top-1 labels, the Mitsuba variant and, with ``benign_images``, ``benign_correct_mitsuba`` and
        ``top1_benign_mitsuba`` (the benign control).

    Raises:
        ValueError: ``benign_images`` of another number of views.
    """
    if benign_images is not None and len(benign_images) != len(case.views):
        raise ValueError(f"benign_images has {len(benign_images)} renders for {len(case.views)} views")
    untargeted, targeted = classifier_criteria(victim, case.true_class, case.target)
    control = None if benign_images is None else benign_verdicts(victim, benign_images, untargeted)
    ours, images_ours = _meshadv_verdicts(case, victim, untargeted, targeted)
    images_theirs = images_tensor(mitsuba_images)
    theirs = _victim_verdicts(victim, images_theirs, untargeted, targeted)
    diff = (images_ours - images_theirs).abs().mean(dim=(1, 2, 3)).tolist()
    return [
        ControlledResult(
            **_identity(case, v),
            success_meshadv=ours.targeted[v],
            success_mitsuba=theirs.targeted[v],
            untargeted_meshadv=ours.untargeted[v],
            untargeted_mitsuba=theirs.untargeted[v],
            top1_meshadv=ours.top1[v],
            top1_mitsuba=theirs.top1[v],
            mean_abs_image_difference=float(diff[v]),
            variant=mitsuba_images[v].variant,
            benign_correct=case.benign_correct,
            benign_correct_mitsuba=None if control is None else control.correct[v],
            top1_benign_mitsuba=None if control is None else control.top1[v],
        )
        for v in range(len(case.views))
    ]


@dataclass(frozen=True)
class _Verdicts:
    """One renderer's verdicts on the views of a case.

    Attributes:
        untargeted: per view, the victim's top-1 is outside the true class.
        targeted: per view, the case's success: targeted for a targeted case, else ``untargeted``.
        top1: per view, the victim's top-1 class name.
    """

    untargeted: list[bool]
    targeted: list[bool]
    top1: list[str]


def _meshadv_verdicts(case: TransferCase, victim: Any, untargeted: Any,
                      targeted: Optional[Any]) -> tuple[_Verdicts, torch.Tensor]:
    """The verdicts on meshadv's renders of the case (its image size, background and the attack's supersampling,
    scored as the attack scores them) and those renders ``(V, 3, H, W)``."""
    from meshadv.attacks import evaluate
    from meshadv.render import RenderSetup, ViewSet

    views = ViewSet.from_records(list(case.views))
    criteria = [untargeted] if targeted is None else [untargeted, targeted]
    setup = RenderSetup(image_size=case.image_size, background=case.background, antialias=case.antialias)
    scored = evaluate(case.mesh, views, victim, criteria, setup=setup)
    un = [bool(x) for x in (scored.margins[0] > 0).tolist()]
    success = un if targeted is None else [bool(x) for x in (scored.margins[1] > 0).tolist()]
    return _Verdicts(un, success, class_names(victim, scored.top1[0].tolist())), scored.images[0]


def _victim_verdicts(victim: Any, images: torch.Tensor, untargeted: Any, targeted: Optional[Any]) -> _Verdicts:
    """The verdicts of ``victim`` on ``images`` ``(V, 3, H, W)`` (Mitsuba's renders)."""
    with torch.no_grad():
        logits = victim(images)
    un = [bool(x) for x in untargeted.is_adversarial(logits).tolist()]
    success = un if targeted is None else [bool(x) for x in targeted.is_adversarial(logits).tolist()]
    return _Verdicts(un, success, top1_names(victim, logits))


def _identity(case: TransferCase, view: int) -> dict[str, Any]:
    """The fields that name a result row: the case, its victim, classes, perturbation and the view."""
    return {"case_id": case.case_id, "victim": case.victim, "true_class": case.true_class,
            "target": case.target or "", "perturbation": case.perturbation, "view": view}


def controlled_transfer(
    cases: Sequence[TransferCase],
    *,
    spp: int = 64,
    max_depth: int = 8,
    variant: Optional[str] = None,
    timeout: float = 1800.0,
    victim_loader: Optional[Callable[[str], Any]] = None,
    image_dir: Optional[Union[str, Path]] = None,
    on_error: str = "record",
) -> list[ControlledResult]:
    """Re-render each case with Mitsuba under its own camera and lights and test the victims (Table 3 / Fig. 5).

    A case with a ``benign_mesh`` (every case of :func:`cases_from_store` and of ``meshadv transfer attack``) has
    its benign mesh rendered too, under the same views: the control of untargeted transfer
    (:mod:`meshadv.transfer.benign_control`).

    Args:
        cases: the adversarial meshes (see :func:`cases_from_store`).
        spp: Mitsuba samples per pixel.
        max_depth: path depth (>= 3 adds interreflection; 2 is direct light with shadows only).
        variant: Mitsuba variant (default: the best that works).
        timeout: seconds per case.
        victim_loader: ``name -> victim`` (default ``meshadv.victims.load_victim``); victims are loaded once.
        image_dir: when given, Mitsuba renders are saved there as ``<name>_v<view>.png`` (``TransferCase.name``,
            else its ``case_id``), the benign control's as ``<name>_benign_v<view>.png``.
        on_error: ``"record"`` keeps going and records a result with an ``error`` for a failed render; ``"raise"``
            re-raises.

    Returns:
        One :class:`~meshadv.transfer.results.ControlledResult` per (case, view) (see :func:`evaluate_case`); a
        failed render gives results with ``error`` set and no success.

    Raises:
        TypeError: a case is not a :class:`~meshadv.transfer.cases.TransferCase`, ``victim_loader`` is not
            callable, or ``spp``, ``max_depth`` or ``timeout`` has the wrong type.
        ValueError: unknown ``on_error``, ``spp < 1``, ``max_depth`` neither ``>= 1`` nor ``-1``, or ``timeout <= 0``.
        MitsubaRenderError: a render failed and ``on_error == "raise"``.
    """
    cases = list(cases)
    _check_transfer_options(cases, spp, max_depth, timeout, victim_loader, on_error)
    if victim_loader is None:
        from meshadv.victims import load_victim

        victim_loader = load_victim
    victims: dict[str, Any] = {}
    rows: list[ControlledResult] = []
    for case in cases:
        specs = mitsuba_specs_for_case(case, spp=spp, max_depth=max_depth)
        if case.benign_mesh is not None:  # the benign control, in the same child process
            specs += mitsuba_specs_for_case(case, spp=spp, max_depth=max_depth, benign=True)
        try:
            rendered = render_scenes(specs, variant=variant, timeout=timeout)
        except MitsubaRenderError as exc:
            if on_error == "raise":
                raise
            rows.extend(_failed(case, exc))
            continue
        views = len(case.views)
        images, benign = rendered[:views], (rendered[views:] if case.benign_mesh is not None else None)
        if case.victim not in victims:
            victims[case.victim] = victim_loader(case.victim)
        rows.extend(evaluate_case(case, victims[case.victim], images, benign))
        if image_dir is not None:
            stem = case.name or case.case_id
            save_images(images, Path(image_dir), stem)
            if benign is not None:
                save_images(benign, Path(image_dir), f"{stem}_benign")
    return rows


def _check_transfer_options(cases: Sequence[Any], spp: Any, max_depth: Any, timeout: Any, victim_loader: Any,
                            on_error: Any) -> None:
    """Raise naming the first bad argument of :func:`controlled_transfer`, before any case is rendered."""
    for i, case in enumerate(cases):
        if not isinstance(case, TransferCase):
            raise TypeError(f"cases[{i}] must be a TransferCase, got {type(case).__name__}")
    _validate.positive_int("spp", spp)
    if _validate.integer("max_depth", max_depth) < 1 and max_depth != -1:
        raise ValueError(f"max_depth must be >= 1 (or -1 for unlimited), got {max_depth}")
    _validate.positive_float("timeout", timeout)
    if victim_loader is not None and not callable(victim_loader):
        raise TypeError(f"victim_loader must be a callable or None, got {type(victim_loader).__name__}")
    if on_error not in ("record", "raise"):
        raise ValueError(f"on_error must be 'record' or 'raise', got {on_error!r}")


def _failed(case: TransferCase, error: MitsubaRenderError) -> list[ControlledResult]:
    """One result per view of ``case`` whose Mitsuba render failed: no successes, ``error`` says why."""
    return [
        ControlledResult(**_identity(case, v), success_meshadv=None, success_mitsuba=None, error=str(error))
        for v in range(len(case.views))
    ]
