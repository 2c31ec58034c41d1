"""The black-box transfer pipeline: attack a Mitsuba "photo" whose camera and lights are unknown.

The paper's pipeline (:func:`blackbox_classifier`, :func:`blackbox_detector`): a "photo" is rendered by Mitsuba
under hidden parameters (:class:`~meshadv.transfer.hidden.HiddenScene`); the camera is estimated from the object's
mask, the lights from the masked image (:func:`~meshadv.transfer.photo.estimate_parameters`); the attack runs in
meshadv with random jitter of the estimates at every step (:mod:`meshadv.transfer.robust`); the adversarial mesh is
re-rendered by Mitsuba under the hidden parameters and tested, and, as a diagnostic, under the estimates
(:mod:`meshadv.transfer.compositing`). Every Mitsuba render runs in a child process (:mod:`meshadv.transfer.render`).

This module holds the two pipelines and what their result rows share; the steps live in their own modules and are
re-exported here (``HiddenScene``, ``Estimation``, ``estimate_parameters``, ``estimated_view_spec``, ``composite``,
``occlusion_mask``, ``detection_scores``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Optional, Sequence

import numpy as np
import torch

from meshadv.attacks.families import check_perturbation
from meshadv.render.setup import RenderSetup, split_setup_options
from meshadv.transfer._attack_run import attack_estimated, meshadv_margins, pixel_noise_where, robust_rate
from meshadv.transfer._scoring import detection_scores, images_tensor, top1_names
from meshadv.transfer.compositing import composite, estimated_view_spec
from meshadv.transfer.hidden import HiddenScene
from meshadv.transfer.object_attacks import check_smoothing, object_attack
from meshadv.transfer.objects import merge_meshes, object_range, occlusion_mask
from meshadv.transfer.photo import Estimation, background_photo, estimate_parameters
from meshadv.transfer.render import MitsubaImage, render_scenes
from meshadv.transfer.results import BlackBoxResult
from meshadv.transfer.robust import DEFAULT_JITTER, Occluded, Robustness, restore_photo

__all__ = [
    "Estimation",
    "HiddenScene",
    "blackbox_classifier",
    "blackbox_detector",
    "composite",
    "detection_scores",
    "estimate_parameters",
    "estimated_view_spec",
    "occlusion_mask",
]


# ----------------------------------------------------------------------------------------------------------------------
# Steps shared by the two pipelines
# ----------------------------------------------------------------------------------------------------------------------


def _attack_options(attack_kwargs: Optional[dict[str, Any]],
                    jitter: Optional[dict[str, float]]) -> tuple[dict[str, Any], dict[str, Any]]:
    """Split ``attack_kwargs`` into render-setup options and the attack's keyword arguments, the latter with the
    per-step ``jitter`` of the estimates unless given (default :data:`DEFAULT_JITTER`; ``{}``: none)."""
    setup_options, kwargs = split_setup_options(dict(attack_kwargs or {}))
    kwargs.setdefault("jitter", dict(DEFAULT_JITTER if jitter is None else jitter) or None)
    return setup_options, kwargs


def _attack_setup(setup_options: dict[str, Any], image_size: tuple[int, int], background: torch.Tensor) -> RenderSetup:
    """The attack's render setup: the photo's image size and ``background`` unless ``setup_options`` set them."""
    return RenderSetup(**{"image_size": image_size, "background": background, **setup_options})


@dataclass(frozen=True)
class _Run:
    """What the steps of one black-box run share once the camera and lights are estimated.

    Attributes:
        hidden: the hidden world.
        est: the estimation (views, photo, errors).
        background: ``(3, H, W)`` what meshadv's renders are composited over during the attack (the photo, or the
            world without the known objects), and Mitsuba's render under the estimates after it.
        setup: the attack's render setup.
        robustness: the run's robustness settings.
        variant: Mitsuba variant; timeout: seconds per Mitsuba call.
    """

    hidden: HiddenScene
    est: Estimation
    background: torch.Tensor
    setup: RenderSetup
    robustness: Robustness
    variant: Optional[str]
    timeout: float


@dataclass(frozen=True)
class _Measured:
    """What a black-box run measures of its adversarial mesh after the attack.

    Attributes:
        margin_meshadv: 0-dim tensor: the criterion's margin on meshadv's render of the estimated view (the attack's
            render setup, the victim without pixel noise).
        image_meshadv: ``(3, H, W)`` that render.
        robust_rate: :func:`~meshadv.transfer._attack_run.robust_rate` (None when not verified).
        adversarial_mitsuba: Mitsuba's render under the hidden parameters.
        estimated_mitsuba: ``(3, H, W)`` Mitsuba's render under the estimates, composited over the background.
    """

    margin_meshadv: torch.Tensor
    image_meshadv: torch.Tensor
    robust_rate: Optional[float]
    adversarial_mitsuba: MitsubaImage
    estimated_mitsuba: torch.Tensor

    def victim_batch(self, photo: torch.Tensor) -> torch.Tensor:
        """``(3, 3, H, W)``: the photo (the benign object under the hidden parameters), then the adversarial mesh by
        Mitsuba under the hidden parameters and under the estimates."""
        return torch.cat([photo[None], images_tensor([self.adversarial_mitsuba]), self.estimated_mitsuba[None]])


def _measure(run: _Run, seen: Any, adversarial: Any, victim: Any, bound: Any,
             occluded: Optional[torch.Tensor] = None) -> _Measured:
    """Measure the attack's result: meshadv's margin and robust rate on the estimated view, Mitsuba's renders.

    Args:
        run: the run.
        seen: what meshadv and Mitsuba-under-the-estimates render (the adversarial object, or the merged scene).
        adversarial: the adversarial object, placed in the hidden world.
        victim: the victim the attack saw (without pixel noise); ``bound`` its bound criterion.
        occluded: ``(H, W)`` pixels where the photo is put back in both images, or None.
    """
    views = run.est.views
    margins, image = meshadv_margins(run.setup, seen, views, victim, bound)
    rate = robust_rate(run.setup, seen, views, victim, bound, run.robustness)
    # the benign render under the hidden parameters is the photo the estimation was made from
    specs = [run.hidden.spec(adversarial), estimated_view_spec(seen, views.to_records()[0], run.hidden)]
    images = render_scenes(specs, variant=run.variant, timeout=run.timeout)
    estimated = composite(images[1], run.background)
    if occluded is not None:
        estimated = restore_photo(estimated, run.est.photo, occluded)
        image = restore_photo(image, run.est.photo, occluded)
    return _Measured(margins[0], image, rate, images[0], estimated)


def _attack_record(attack: Any, setup: RenderSetup, result: Any) -> dict[str, Any]:
    """Hyper-parameters and cost of the attack (and the setup's supersampling), as result-row entries."""
    config = attack.config()
    record = {k: config[k] for k in ("steps", "lr", "lambda_perceptual", "loss", "kappa", "early_stop")}
    record["antialias"] = setup.antialias
    record.update(steps_run=int(result.steps), steps_to_success=result.steps_to_success[0],
                  attack_time=float(result.wall_time))
    record.update({k: float(v) for k, v in result.distances[0].items()})
    return record


def _hwc(image: torch.Tensor) -> np.ndarray:
    """A ``(3, H, W)`` tensor as an ``(H, W, 3)`` array."""
    return image.detach().permute(1, 2, 0).cpu().numpy()


def _finish_row(row: dict[str, Any], run: _Run, attack: Any, result: Any, measured: _Measured,
                adversarial: Any) -> BlackBoxResult:
    """Add what every black-box row shares to ``row`` (robustness and attack settings, estimation errors) and wrap
    it with the images (Mitsuba benign = the estimation's photo / adversarial under the hidden parameters /
    adversarial under the estimates, meshadv's render), the adversarial mesh and the attack's result."""
    row.update(run.robustness.to_record())
    row["pixel_noise_on"] = pixel_noise_where(run.setup, run.robustness)
    row.update(_attack_record(attack, run.setup, result))
    row.update({k: float(v) for k, v in run.est.errors.items()})
    images = {"benign_mitsuba": _hwc(run.est.photo), "adversarial_mitsuba": measured.adversarial_mitsuba.image,
              "adversarial_mitsuba_estimated": _hwc(measured.estimated_mitsuba),
              "adversarial_meshadv": _hwc(measured.image_meshadv)}
    return BlackBoxResult(row=dict(row), images=images, adversarial_mesh=adversarial, attack_result=result)


def _victim_name(victim: Any) -> str:
    """The victim's name for the result row (its class name when it has none)."""
    return getattr(victim, "name", type(victim).__name__)


# ----------------------------------------------------------------------------------------------------------------------
# Classifier
# ----------------------------------------------------------------------------------------------------------------------


def blackbox_classifier(
    mesh: Any,
    hidden: HiddenScene,
    *,
    victim: Any,
    true_class: str,
    target: Optional[str] = None,
    perturbation: str = "texture",
    attack_kwargs: Optional[dict[str, Any]] = None,
    jitter: Optional[dict[str, float]] = None,
    robustness: Optional[Robustness] = None,
    texture_smoothing: Optional[int] = None,
    num_lights: int = 5,
    camera_steps: int = 60,
    light_steps: int = 120,
    variant: Optional[str] = None,
    timeout: float = 1800.0,
    case_id: str = "blackbox_classifier",
    callback: Optional[Callable[[Any], None]] = None,
) -> BlackBoxResult:
    """The paper's black-box pipeline against a classifier (e.g. an aeroplane in an outdoor scene).

    1-2. :func:`estimate_parameters`; 3. attack in meshadv on the estimated view with jitter (``robustness.eot``
    jittered samples per step), the renders composited over the photo's background; 4. re-render the adversarial
    mesh with Mitsuba under the hidden parameters and test. As a diagnostic, Mitsuba also renders it under the
    *estimated* parameters (:func:`estimated_view_spec`).

    Args:
        mesh: the benign mesh.
        hidden: the hidden world.
        victim: a classifier victim.
        true_class: the object's class.
        target: target class (None = untargeted).
        perturbation: ``"shape"`` or ``"texture"``.
        attack_kwargs: keyword arguments of the attack (steps, lr, antialias, ...).
        jitter: per-step jitter of the estimates (default :data:`~meshadv.transfer.robust.DEFAULT_JITTER`; ``{}`` =
            none).
        robustness: EOT samples, required margin, pixel noise (default
            :class:`~meshadv.transfer.robust.Robustness` ``()``, the plain pipeline).
        texture_smoothing: ``None`` for the paper's per-face texture; an int ``k >= 0`` for a smoothed per-vertex
            colour field (:class:`~meshadv.attacks.SmoothTextureAttack`, ``k`` rounds), for meshes
            with many faces per pixel. Texture attacks only.
        num_lights: directional lights to estimate.
        camera_steps: camera estimation steps.
        light_steps: light estimation steps.
        variant: Mitsuba variant.
        timeout: seconds per Mitsuba call.
        case_id: identifier of the result row.
        callback: passed to the attack (called with a ``meshadv.attacks.StepInfo`` after every step).

    Returns:
        A result row (see :mod:`meshadv.transfer.results`): the estimation errors; ``success_meshadv`` (the final
        mesh on the estimated view, meshadv's render with the attack's settings, clean victim, margin 0),
        ``success_mitsuba_estimated`` (Mitsuba, estimated camera and lights), ``success_mitsuba`` (Mitsuba, hidden
        parameters), the matching ``margin_*`` (logits, > 0 = adversarial) and ``top1_*``, ``robust_rate_meshadv``
        (fresh views around the estimate, :data:`~meshadv.transfer.robust.DEFAULT_JITTER`),
        ``benign_correct_mitsuba``, the attack's settings and distortion. Wrapped in a
        :class:`~meshadv.transfer.results.BlackBoxResult` with the images, the adversarial mesh and the
        AttackResult.

    Raises:
        ValueError: unknown ``perturbation``, or ``texture_smoothing`` given for a shape attack or negative.
    """
    from meshadv.attacks import Misclassification, TargetedMisclassification

    check_perturbation(perturbation)
    check_smoothing(texture_smoothing, perturbation)
    robustness = Robustness() if robustness is None else robustness
    est = estimate_parameters(mesh, hidden, num_lights=num_lights, camera_steps=camera_steps,
                              light_steps=light_steps, variant=variant, timeout=timeout)
    background = background_photo(hidden, variant=variant, timeout=timeout)
    setup_options, kwargs = _attack_options(attack_kwargs, jitter)
    setup = _attack_setup(setup_options, hidden.image_size, background)
    attack = object_attack(perturbation, texture_smoothing, kwargs)
    criterion = TargetedMisclassification(target) if target else Misclassification(true_class)
    result = attack_estimated(attack, mesh, est.views, victim, criterion, robustness, setup, callback)
    adversarial = result.mesh
    bound = criterion.bind(victim)
    run = _Run(hidden, est, background, setup, robustness, variant, timeout)
    measured = _measure(run, adversarial, adversarial, victim, bound)
    with torch.no_grad():
        top1_meshadv = top1_names(victim, victim(measured.image_meshadv[None]))[0]
        logits = victim(measured.victim_batch(est.photo))
    benign_correct = not bool(Misclassification(true_class).bind(victim).is_adversarial(logits[:1])[0])
    margins = bound.margin(logits).tolist()
    names = top1_names(victim, logits)
    row: dict[str, Any] = {
        "case_id": case_id,
        "victim": _victim_name(victim),
        "true_class": true_class,
        "target": target or "",
        "perturbation": perturbation,
        "view": 0,
        "success_meshadv": bool(measured.margin_meshadv > 0),
        "success_mitsuba_estimated": margins[2] > 0,
        "success_mitsuba": margins[1] > 0,
        "benign_adversarial_mitsuba": margins[0] > 0,
        "benign_correct_mitsuba": benign_correct,
        "margin_meshadv": float(measured.margin_meshadv),
        "margin_mitsuba_estimated": float(margins[2]),
        "margin_mitsuba": float(margins[1]),
        "margin_benign_mitsuba": float(margins[0]),
        "robust_rate_meshadv": measured.robust_rate,
        "top1_meshadv": top1_meshadv,
        "top1_mitsuba_estimated": names[2],
        "top1_benign_mitsuba": names[0],
        "top1_adversarial_mitsuba": names[1],
        "texture_smoothing": texture_smoothing,
        "spp": hidden.spp,
        "variant": measured.adversarial_mitsuba.variant,
    }
    return _finish_row(row, run, attack, result, measured, adversarial)


# ----------------------------------------------------------------------------------------------------------------------
# Detector
# ----------------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _DetectorContext:
    """What the attack of :func:`blackbox_detector` renders and what its victim sees (one of its contexts).

    Attributes:
        background: ``(3, H, W)`` what meshadv's renders are composited over.
        attacked: the mesh given to the attack (the attacked object, or the merged scene).
        attack: the attack (masked to the attacked object within a merged scene).
        part: the rows of ``attacked``'s face colours (texture) or vertices (shape) that are the attacked object.
        victim: the victim the attack sees (:class:`~meshadv.transfer.robust.Occluded` where the photo hides it).
        occluded: ``(H, W)`` pixels where another known object hides the attacked one (``"photo"`` only).
    """

    background: torch.Tensor
    attacked: Any
    attack: Any
    part: slice
    victim: Any
    occluded: Optional[torch.Tensor] = None


def _photo_context(objects: Sequence[Any], index: int, est: Estimation, victim: Any, image_size: tuple[int, int],
                   perturbation: str, texture_smoothing: Optional[int], kwargs: dict[str, Any]) -> _DetectorContext:
    """The ``"photo"`` context: the attacked object alone, rendered over the photo; the photo put back where another
    known object hides it in the estimated view."""
    occluded = occlusion_mask(objects, index, est.views, image_size)
    seen_victim = Occluded(victim, est.photo, occluded) if bool(occluded.any()) else victim
    attack = object_attack(perturbation, texture_smoothing, kwargs)
    return _DetectorContext(est.photo, objects[index], attack, slice(0, None), seen_victim, occluded)


def _render_context(objects: Sequence[Any], index: int, merged: Any, background: torch.Tensor, victim: Any,
                    perturbation: str, texture_smoothing: Optional[int],
                    kwargs: dict[str, Any]) -> _DetectorContext:
    """The ``"render"`` context: every known object rendered (only object ``index`` may change) over ``background``
    (the world without them)."""
    part = "faces" if perturbation == "texture" else "vertices"
    start, stop = object_range(objects, index, part)
    mask = torch.zeros(int(getattr(merged, part).shape[0]), dtype=torch.bool)
    mask[start:stop] = True
    attack = object_attack(perturbation, texture_smoothing, kwargs, mask)
    return _DetectorContext(background, merged, attack, slice(start, stop), victim)


def _attacked_object(attacked_mesh: Any, obj: Any, perturbation: str, part: slice) -> Any:
    """``obj`` with the face colours (texture) or vertices (shape) of rows ``part`` of the attack's result."""
    if perturbation == "texture":
        return obj.with_face_colors(attacked_mesh.face_colors.detach()[part].clone())
    return obj.with_vertices(attacked_mesh.vertices.detach()[part].clone())


def _check_detector_options(num_objects: int, object_index: int, perturbation: str, context: str, light_fit: str,
                            texture_smoothing: Optional[int], score_threshold: float) -> None:
    """Raise ValueError naming the first bad argument of :func:`blackbox_detector`."""
    if not 0 <= object_index < num_objects:
        raise ValueError(f"object_index {object_index} out of range for {num_objects} objects")
    check_perturbation(perturbation)
    if context not in ("photo", "render"):
        raise ValueError(f"context must be 'photo' or 'render', got {context!r}")
    if light_fit not in ("object", "known"):
        raise ValueError(f"light_fit must be 'object' or 'known', got {light_fit!r}")
    check_smoothing(texture_smoothing, perturbation)
    if not 0.0 < score_threshold <= 1.0:
        raise ValueError(f"score_threshold must be in (0, 1], got {score_threshold}")


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
        Wrapped in a :class:`~meshadv.transfer.results.BlackBoxResult` as by :func:`blackbox_classifier`.

    Raises:
        ValueError: ``object_index`` out of range, unknown ``perturbation``, ``context`` or ``light_fit``, a bad
            ``score_threshold``, or ``texture_smoothing`` given for a shape attack or negative.
    """
    from meshadv.attacks import Disappearance

    objects = list(scene_objects)
    _check_detector_options(len(objects), object_index, perturbation, context, light_fit, texture_smoothing,
                            score_threshold)
    robustness = Robustness() if robustness is None else robustness
    target_obj = objects[object_index]
    merged = merge_meshes(objects)
    light_faces = object_range(objects, object_index) if light_fit == "object" else None
    est = estimate_parameters(target_obj, hidden, known=merged, light_faces=light_faces, num_lights=num_lights,
                              camera_steps=camera_steps, light_steps=light_steps, variant=variant, timeout=timeout)
    setup_options, kwargs = _attack_options(attack_kwargs, jitter)
    if context == "photo":
        ctx = _photo_context(objects, object_index, est, victim, hidden.image_size, perturbation, texture_smoothing,
                             kwargs)
    else:
        background = background_photo(hidden, background_exclude, variant=variant, timeout=timeout)
        ctx = _render_context(objects, object_index, merged, background, victim, perturbation, texture_smoothing,
                              kwargs)
    setup = _attack_setup(setup_options, hidden.image_size, ctx.background)
    criterion = Disappearance(hide_class, threshold=score_threshold)
    result = attack_estimated(ctx.attack, ctx.attacked, est.views, ctx.victim, criterion, robustness, setup,
                               callback)
    adversarial = _attacked_object(result.mesh, target_obj, perturbation, ctx.part)
    if context == "photo":
        seen = adversarial
    else:
        seen = merge_meshes([adversarial if i == object_index else o for i, o in enumerate(objects)])
    run = _Run(hidden, est, ctx.background, setup, robustness, variant, timeout)
    measured = _measure(run, seen, adversarial, ctx.victim, criterion.bind(victim), ctx.occluded)
    scores = detection_scores(victim, measured.victim_batch(est.photo), hide_class)
    row: dict[str, Any] = {
        "case_id": case_id,
        "victim": _victim_name(victim),
        "true_class": hide_class,
        "target": "",
        "perturbation": perturbation,
        "view": 0,
        "context": context,
        "light_fit": light_fit,
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
        "occluded_pixels": None if ctx.occluded is None else int(ctx.occluded.sum()),
        "texture_smoothing": texture_smoothing,
        "spp": hidden.spp,
        "variant": measured.adversarial_mitsuba.variant,
    }
    return _finish_row(row, run, ctx.attack, result, measured, adversarial)
