"""The black-box pipeline against a detector (:func:`blackbox_detector`): change one of several known objects of
a hidden world (e.g. the bunny on the indoor desk) so that a class disappears, the camera and lights estimated from
Mitsuba's photo.

The steps are described in :mod:`meshadv.transfer.blackbox`, which re-exports this pipeline.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Optional, Sequence

import torch

from meshadv import _validate
from meshadv.attacks.families import check_perturbation
from meshadv.transfer._attack_run import attack_estimated
from meshadv.transfer._pipeline import (
    BlackBoxRun,
    Measured,
    attack_options,
    attack_setup,
    check_run_options,
    finish_row,
    measure,
    row_head,
)
from meshadv.transfer._scoring import detection_scores
from meshadv.transfer.hidden import HiddenScene
from meshadv.transfer.object_attacks import check_smoothing, object_attack
from meshadv.transfer.objects import merge_meshes, object_range, occlusion_mask
from meshadv.transfer.photo import Estimation, background_photo, estimate_parameters
from meshadv.transfer.results import BlackBoxResult
from meshadv.transfer.robust import Occluded, Robustness

__all__ = ["blackbox_detector"]


@dataclass(frozen=True)
class _DetectorContext:
    """What the attack of :func:`blackbox_detector` renders and what its victim sees (one of its contexts).

    Attributes:
        background: ``(3, H, W)`` what meshadv's renders are composited over.
        attacked: the mesh given to the attack (the attacked object, or the merged scene).
        victim: the victim the attack sees (:class:`~meshadv.transfer.robust.Occluded` where the photo hides it).
        occluded: ``(H, W)`` pixels where another known object hides the attacked one (``"photo"`` only).
    """

    background: torch.Tensor
    attacked: Any
    victim: Any
    occluded: Optional[torch.Tensor] = None


def _scene_attack(context: str, objects: Sequence[Any], index: int, merged: Any, perturbation: str,
                  texture_smoothing: Optional[int], kwargs: dict[str, Any]) -> tuple[Any, slice]:
    """The attack of object ``index`` and the rows of the attacked mesh's face colours (texture) or vertices (shape)
    that are that object: the object alone (``"photo"``), or the merged scene with the attack masked to the object
    (``"render"``)."""
    if context == "photo":
        return object_attack(perturbation, texture_smoothing, kwargs), slice(0, None)
    part = "faces" if perturbation == "texture" else "vertices"
    start, stop = object_range(objects, index, part)
    mask = torch.zeros(int(getattr(merged, part).shape[0]), dtype=torch.bool)
    mask[start:stop] = True
    return object_attack(perturbation, texture_smoothing, kwargs, mask), slice(start, stop)


def _context(context: str, objects: Sequence[Any], index: int, merged: Any, est: Estimation, hidden: HiddenScene,
             victim: Any, background_exclude: Sequence[str], variant: Optional[str],
             timeout: float) -> _DetectorContext:
    """The attack's context. ``"photo"``: the attacked object alone, rendered over the photo, the photo put back
    where another known object hides it in the estimated view. ``"render"``: every known object rendered (only
    object ``index`` may change) over Mitsuba's photo of the world without them (``background_exclude``)."""
    if context == "photo":
        occluded = occlusion_mask(objects, index, est.views, hidden.image_size)
        seen_victim = Occluded(victim, est.photo, occluded) if bool(occluded.any()) else victim
        return _DetectorContext(est.photo, objects[index], seen_victim, occluded)
    background = background_photo(hidden, background_exclude, variant=variant, timeout=timeout)
    return _DetectorContext(background, merged, victim)


def _attacked_object(attacked_mesh: Any, obj: Any, perturbation: str, part: slice) -> Any:
    """``obj`` with the face colours (texture) or vertices (shape) of rows ``part`` of the attack's result."""
    if perturbation == "texture":
        return obj.with_face_colors(attacked_mesh.face_colors.detach()[part].clone())
    return obj.with_vertices(attacked_mesh.vertices.detach()[part].clone())


def _check_detector_options(objects: Sequence[Any], object_index: Any, perturbation: str, context: str,
                            light_fit: str, texture_smoothing: Optional[int], score_threshold: Any,
                            background_exclude: Any) -> None:
    """Raise naming the first bad argument of :func:`blackbox_detector` that is its own (TypeError for a wrong
    type, ValueError for a bad value)."""
    for i, obj in enumerate(objects):
        if not all(hasattr(obj, a) for a in ("vertices", "faces", "face_colors")):
            raise TypeError(f"scene_objects[{i}] must be a meshadv.mesh.Mesh, got {type(obj).__name__}")
    _validate.integer("object_index", object_index)
    if not 0 <= object_index < len(objects):
        raise ValueError(f"object_index {object_index} out of range for {len(objects)} objects")
    check_perturbation(perturbation)
    if context not in ("photo", "render"):
        raise ValueError(f"context must be 'photo' or 'render', got {context!r}")
    if light_fit not in ("object", "known"):
        raise ValueError(f"light_fit must be 'object' or 'known', got {light_fit!r}")
    check_smoothing(texture_smoothing, perturbation)
    _validate.finite_float("score_threshold", score_threshold)
    if not 0.0 < score_threshold <= 1.0:
        raise ValueError(f"score_threshold must be in (0, 1], got {score_threshold}")
    if isinstance(background_exclude, str) or not all(isinstance(name, str) for name in background_exclude):
        raise TypeError(f"background_exclude must be a sequence of shape names (strings), got {background_exclude!r}")


def blackbox_detector(
    scene_objects: Sequence[Any],
    object_index: int,
    hidden: HiddenScene,
    *,
    victim: Any,
    hide_class: str,
    perturbation: str = "texture",
    context: str = "photo",
    light_fit: str = "object",
    background_exclude: Sequence[str] = (),
    attack_kwargs: Optional[dict[str, Any]] = None,
    jitter: Optional[dict[str, float]] = None,
    robustness: Optional[Robustness] = None,
    texture_smoothing: Optional[int] = None,
    num_lights: int = 5,
    camera_steps: int = 60,
    light_steps: int = 120,
    variant: Optional[str] = None,
    timeout: float = 1800.0,
    score_threshold: float = 0.3,
    case_id: str = "blackbox_detector",
    callback: Optional[Callable[[Any], None]] = None,
) -> BlackBoxResult:
    """The black-box pipeline against a detector: change one object so that ``hide_class`` disappears.

    The attacker knows the geometry of ``scene_objects`` (world space; e.g. the indoor scene's desk, chair and bunny)
    but not the camera or lights. (1-2) The camera and lights are estimated from the Mitsuba photo (mask and shading
    of the known objects); (3) a texture (or shape) attack on the attacked object, with jitter, seen in a context
    chosen by ``context``; (4) the adversarial object is re-rendered by Mitsuba under the hidden parameters and the
    detector is run. The attack's criterion is :class:`~meshadv.attacks.Disappearance` at ``score_threshold`` (the
    threshold the success is measured at), with ``robustness.margin`` on top (in score units).

    Contexts:
        * ``"photo"`` (the paper's compositing): meshadv renders only the attacked object, over the Mitsuba photo
          itself; the rest of the scene is the photo's pixels (where another known object hides the attacked one
          in the estimated view, the photo is put back, :class:`~meshadv.transfer.robust.Occluded`). The photo
          still shows the benign object behind the rendered one: exact for texture attacks (same silhouette), a
          faint ghost where a shape attack moves the surface inward.
        * ``"render"``: meshadv renders every known object (only the attacked one may change) over the photo of
          the world without them (``background_exclude``); the detector then sees meshadv's shading of the whole
          scene, which differs from Mitsuba's (the indoor table scores 0.75 in meshadv, 0.96 in Mitsuba).

    Args:
        scene_objects: ``meshadv.mesh.Mesh`` objects in world space.
        object_index: which of them is perturbed (it is the object of ``hidden.spec``; the others must be part of
            ``hidden`` through its base scene or ``extra_objects``).
        hidden: the hidden world.
        victim: a detector victim.
        hide_class: the class to hide (a name of ``victim.class_names``, e.g. ``"chair"``).
        perturbation: ``"texture"`` (the object's face colours) or ``"shape"`` (its vertices).
        context: ``"photo"`` or ``"render"`` (see above).
        light_fit: ``"object"``: fit the lights on the attacked object's visible pixels only (the light where it
            stands); ``"known"``: on every known object (one lighting for the whole scene).
        background_exclude: base-scene shapes to drop for the background render (the known objects; ``"render"``).
        attack_kwargs: keyword arguments of the attack.
        jitter: per-step jitter (default :data:`~meshadv.transfer.robust.DEFAULT_JITTER`; ``{}`` = none).
        robustness: EOT samples, required margin (score units), pixel noise (default
            :class:`~meshadv.transfer.robust.Robustness` ``()``).
        texture_smoothing: ``None`` for the paper's per-face texture; an int ``k >= 0`` for a smoothed per-vertex
            colour field (:class:`~meshadv.attacks.SmoothTextureAttack`, ``k`` rounds), for meshes
            with many faces per pixel. Texture attacks only.
        num_lights: directional lights to estimate.
        camera_steps: camera estimation steps.
        light_steps: light estimation steps.
        variant: Mitsuba variant.
        timeout: seconds per Mitsuba call.
        score_threshold: detection score at or above which ``hide_class`` counts as detected, in (0, 1].
        case_id: identifier of the result row.
        callback: passed to the attack (called with a ``meshadv.attacks.StepInfo`` after every step).

    Returns:
        A result row with the estimation errors, the best ``hide_class`` score of meshadv's render on the estimated
        view (``hide_score_meshadv``), of Mitsuba's under the estimates (``hide_score_mitsuba_estimated``, in the
        same context) and under the hidden parameters (benign and adversarial), the matching ``success_*`` (score
        below the threshold), ``robust_rate_meshadv``, ``occluded_pixels`` (``"photo"``) and the attack's settings.
        Wrapped in a :class:`~meshadv.transfer.results.BlackBoxResult` as by
        :func:`~meshadv.transfer.classifier_pipeline.blackbox_classifier`.

    Raises:
        TypeError: an argument of the wrong type (see :func:`~meshadv.transfer._pipeline.check_run_options`; also
            ``scene_objects``, ``object_index``, ``score_threshold``, ``background_exclude``), or an unknown attack
            option.
        ValueError: ``object_index`` out of range, unknown ``perturbation``, ``context`` or ``light_fit``, a bad
            ``score_threshold``, a ``hide_class`` the victim does not know, ``texture_smoothing`` given for a shape
            attack or negative, a bad count, ``timeout`` or render-setup option; all before any render.
    """
    from meshadv.attacks import Disappearance

    objects = list(scene_objects)
    # every argument is checked (the attack and its criterion built) before the first Mitsuba render
    _check_detector_options(objects, object_index, perturbation, context, light_fit, texture_smoothing,
                            score_threshold, background_exclude)
    robustness = check_run_options(hidden, victim, robustness, attack_kwargs, jitter, num_lights, camera_steps,
                                   light_steps, timeout, case_id)
    setup_options, kwargs = attack_options(attack_kwargs, jitter)
    attack_setup(setup_options, hidden.image_size)
    criterion = Disappearance(hide_class, threshold=score_threshold)
    bound = criterion.bind(victim)
    target_obj = objects[object_index]
    merged = merge_meshes(objects)
    attack, part = _scene_attack(context, objects, object_index, merged, perturbation, texture_smoothing, kwargs)
    light_faces = object_range(objects, object_index) if light_fit == "object" else None
    est = estimate_parameters(target_obj, hidden, known=merged, light_faces=light_faces, num_lights=num_lights,
                              camera_steps=camera_steps, light_steps=light_steps, variant=variant, timeout=timeout)
    ctx = _context(context, objects, object_index, merged, est, hidden, victim, background_exclude, variant, timeout)
    setup = attack_setup(setup_options, hidden.image_size, ctx.background)
    result = attack_estimated(attack, ctx.attacked, est.views, ctx.victim, criterion, robustness, setup, callback)
    adversarial = _attacked_object(result.mesh, target_obj, perturbation, part)
    if context == "photo":
        seen = adversarial
    else:
        seen = merge_meshes([adversarial if i == object_index else o for i, o in enumerate(objects)])
    run = BlackBoxRun(hidden, est, ctx.background, setup, robustness, variant, timeout)
    measured = measure(run, seen, adversarial, ctx.victim, bound, ctx.occluded)
    row = row_head(case_id, victim, hide_class, None, perturbation)
    row.update(context=context, light_fit=light_fit)
    row.update(_detector_outcome(victim, hide_class, score_threshold, measured, est.photo))
    row["occluded_pixels"] = None if ctx.occluded is None else int(ctx.occluded.sum())
    return finish_row(row, run, attack, result, measured, adversarial, texture_smoothing)


def _detector_outcome(victim: Any, hide_class: str, score_threshold: float, measured: Measured,
                      photo: torch.Tensor) -> dict[str, Any]:
    """The detector row's outcome: the best ``hide_class`` score and the success (score below the threshold) on
    meshadv's render of the estimated view, on Mitsuba's renders of the adversarial object under the estimates and
    under the hidden parameters, and on the photo (the benign object, which the victim should detect)."""
    scores = detection_scores(victim, measured.victim_batch(photo), hide_class)  # photo, hidden, estimated
    return {
        "success_meshadv": bool(measured.margin_meshadv > 0),
        "success_mitsuba_estimated": scores[2] < score_threshold,
        "success_mitsuba": scores[1] < score_threshold,
        "benign_correct_mitsuba": scores[0] >= score_threshold,
        "score_threshold": float(score_threshold),
        "hide_score_meshadv": float(score_threshold - measured.margin_meshadv),
        "hide_score_mitsuba_estimated": scores[2],
        "hide_score_benign_mitsuba": scores[0],
        "hide_score_adversarial_mitsuba": scores[1],
        "robust_rate_meshadv": measured.robust_rate,
    }
