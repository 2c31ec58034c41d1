"""The black-box transfer pipelines: attack a Mitsuba "photo" whose camera and lights are unknown.

A "photo" is rendered by Mitsuba under hidden parameters (:class:`~meshadv.transfer.setups.HiddenScene`); the camera
is estimated from the object's mask, the lights from the masked image
(:func:`~meshadv.transfer.photos.estimate_parameters`); the attack runs in meshadv with random jitter of the
estimates at every step (:mod:`meshadv.transfer.robust`); the adversarial mesh is re-rendered by Mitsuba under the
hidden parameters and tested, and, as a diagnostic, under the estimates. Every Mitsuba render runs in a child
process (:mod:`meshadv.transfer.mitsuba_process`).

* :func:`blackbox_classifier`: an object in a hidden world (e.g. an aeroplane outdoors) against a classifier.
* :func:`blackbox_detector`: change one of several known objects of a hidden world (e.g. the bunny on the indoor
  desk) so that a class disappears from a detector's detections.
* :func:`blackbox_case_id`, :func:`finished_blackbox` and :func:`save_blackbox_outputs`: a run's default row id,
  whether a database already holds it, and its output folder.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Optional, Sequence, Union

import numpy as np
import torch

from meshadv import _validate
from meshadv.attacks import Disappearance
from meshadv.attacks.budget import shape_options_for
from meshadv.attacks.families import check_perturbation
from meshadv.mesh import save_mesh
from meshadv.render.setup import RenderSetup, split_setup_options
from meshadv.transfer.mitsuba_process import MitsubaImage, render_scenes
from meshadv.transfer.photos import Estimation, background_photo, composite, estimate_parameters, estimated_view_spec
from meshadv.transfer.results import BlackBoxResult, load_transfer_rows
from meshadv.transfer.robust import (
    DEFAULT_JITTER,
    Occluded,
    Robustness,
    attack_estimated,
    check_smoothing,
    meshadv_margins,
    object_attack,
    pixel_noise_where,
    restore_photo,
    robust_rate,
)
from meshadv.transfer.scoring import classifier_criteria, detection_scores, images_tensor, top1_names
from meshadv.transfer.setups import HiddenScene, merge_meshes, object_range, occlusion_mask
from meshadv.util.atomic import write_text_atomic
from meshadv.util.png import save_png

__all__ = [
    "blackbox_classifier", "blackbox_detector", "ddn_shape_options", "finished_blackbox", "save_blackbox_outputs",
    "settings_suffix",
]


def check_run_options(hidden: Any, victim: Any, robustness: Any, attack_kwargs: Any, jitter: Any, num_lights: Any,
                      camera_steps: Any, light_steps: Any, timeout: Any, case_id: Any) -> Robustness:
    """Raise naming the first bad argument that both pipelines take, before any render; return the robustness
    settings (``Robustness()`` for None).

    Raises:
        TypeError: ``hidden`` is not a :class:`~meshadv.transfer.setups.HiddenScene`, ``victim`` is not callable,
            ``robustness`` is not a :class:`~meshadv.transfer.robust.Robustness` (or None), ``attack_kwargs`` or
            ``jitter`` is not a mapping (or None), ``case_id`` is not a string, or a count or ``timeout`` is not a
            number of the right kind.
        ValueError: a negative count, a non-positive ``timeout`` or an empty ``case_id``.
    """
    if not isinstance(hidden, HiddenScene):
        raise TypeError(f"hidden must be a HiddenScene, got {type(hidden).__name__}")
    if not callable(victim):
        raise TypeError(f"victim must be a callable meshadv victim, got {type(victim).__name__}")
    if robustness is not None and not isinstance(robustness, Robustness):
        raise TypeError(f"robustness must be a Robustness or None, got {type(robustness).__name__}")
    for name, value in (("attack_kwargs", attack_kwargs), ("jitter", jitter)):
        if value is not None and not isinstance(value, Mapping):
            raise TypeError(f"{name} must be a dict or None, got {type(value).__name__}")
    for name, value in (("num_lights", num_lights), ("camera_steps", camera_steps), ("light_steps", light_steps)):
        _validate.non_negative_int(name, value)
    _validate.positive_float("timeout", timeout)
    if not isinstance(case_id, str):
        raise TypeError(f"case_id must be a string, got {type(case_id).__name__}")
    if not case_id:
        raise ValueError("case_id must be a non-empty string")
    return Robustness() if robustness is None else robustness


def attack_options(attack_kwargs: Optional[dict[str, Any]],
                    jitter: Optional[dict[str, float]]) -> tuple[dict[str, Any], dict[str, Any]]:
    """Split ``attack_kwargs`` into render-setup options and the attack's keyword arguments, the latter with the
    per-step ``jitter`` of the estimates unless given (default :data:`DEFAULT_JITTER`; ``{}``: none)."""
    setup_options, kwargs = split_setup_options(dict(attack_kwargs or {}))
    kwargs.setdefault("jitter", dict(DEFAULT_JITTER if jitter is None else jitter) or None)
    return setup_options, kwargs


def attack_setup(setup_options: dict[str, Any], image_size: tuple[int, int],
                 background: Optional[torch.Tensor] = None) -> RenderSetup:
    """The attack's render setup: the photo's image size and ``background`` unless ``setup_options`` set them.

    Called without ``background`` (before the photo is rendered), it checks ``setup_options`` early.

    Raises:
        TypeError, ValueError: a bad render-setup option (from :class:`~meshadv.render.setup.RenderSetup`).
    """
    defaults: dict[str, Any] = {"image_size": image_size}
    if background is not None:
        defaults["background"] = background
    return RenderSetup(**{**defaults, **setup_options})


@dataclass(frozen=True)
class BlackBoxRun:
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
class Measured:
    """What a black-box run measures of its adversarial mesh after the attack.

    Attributes:
        margin_meshadv: 0-dim tensor: the criterion's margin on meshadv's render of the estimated view (the attack's
            render setup, the victim without pixel noise).
        image_meshadv: ``(3, H, W)`` that render.
        robust_rate: :func:`~meshadv.transfer.robust.robust_rate` (None when not verified).
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


def measure(run: BlackBoxRun, seen: Any, adversarial: Any, victim: Any, bound: Any,
             occluded: Optional[torch.Tensor] = None) -> Measured:
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
    return Measured(margins[0], image, rate, images[0], estimated)


def _attack_record(attack: Any, setup: RenderSetup, result: Any) -> dict[str, Any]:
    """Hyper-parameters and cost of the attack (and the setup's supersampling), as result-row entries.

    The update rule is ``method`` (with its ``method_options``); ``lr`` and ``lambda_perceptual`` are ``None`` for a
    rule that uses neither (ddn: a distortion budget, no Adam, no perceptual weight)."""
    config = attack.config()
    record = {k: config[k] for k in ("steps", "lr", "lambda_perceptual", "loss", "kappa", "early_stop")}
    record["method"] = config.get("method", "adam")
    if record["method"] != "adam":
        record.update(lr=None, lambda_perceptual=None, method_options=config.get("method_options"))
    record["antialias"] = setup.antialias
    record.update(steps_run=int(result.steps), steps_to_success=result.steps_to_success[0],
                  attack_time=float(result.wall_time), interrupted=bool(getattr(result, "interrupted", False)))
    record.update({k: float(v) for k, v in result.distances[0].items()})
    return record


def _hwc(image: torch.Tensor) -> np.ndarray:
    """A ``(3, H, W)`` tensor as an ``(H, W, 3)`` array."""
    return image.detach().permute(1, 2, 0).cpu().numpy()


def row_head(case_id: str, victim: Any, true_class: str, target: Optional[str], perturbation: str) -> dict[str, Any]:
    """The first entries of every black-box row: the case, the victim's name (its class name when it has none),
    the classes (``target`` ``""`` when untargeted), the perturbation and the view (always 0)."""
    return {"case_id": case_id, "victim": getattr(victim, "name", type(victim).__name__), "true_class": true_class,
            "target": target or "", "perturbation": perturbation, "view": 0}


def finish_row(row: dict[str, Any], run: BlackBoxRun, attack: Any, result: Any, measured: Measured,
               adversarial: Any, texture_smoothing: Optional[int]) -> BlackBoxResult:
    """Add what every black-box row shares to ``row`` (texture smoothing, samples per pixel, Mitsuba variant,
    robustness and attack settings, estimation errors) and wrap it with the images (Mitsuba benign = the
    estimation's photo / adversarial under the hidden parameters / adversarial under the estimates, meshadv's
    render), the adversarial mesh and the attack's result."""
    row.update(texture_smoothing=texture_smoothing, spp=run.hidden.spp, variant=measured.adversarial_mitsuba.variant)
    row.update(run.robustness.to_record())
    row["pixel_noise_on"] = pixel_noise_where(run.setup, run.robustness)
    row.update(_attack_record(attack, run.setup, result))
    row.update({k: float(v) for k, v in run.est.errors.items()})
    images = {"benign_mitsuba": _hwc(run.est.photo), "adversarial_mitsuba": measured.adversarial_mitsuba.image,
              "adversarial_mitsuba_estimated": _hwc(measured.estimated_mitsuba),
              "adversarial_meshadv": _hwc(measured.image_meshadv)}
    return BlackBoxResult(row=dict(row), images=images, adversarial_mesh=adversarial, attack_result=result)


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

    1-2. :func:`~meshadv.transfer.photos.estimate_parameters`; 3. attack in meshadv on the estimated view with
    jitter (``robustness.eot`` jittered samples per step), the renders composited over the photo's background;
    4. re-render the adversarial mesh with Mitsuba under the hidden parameters and test. As a diagnostic, Mitsuba
    also renders it under the *estimated* parameters (:func:`~meshadv.transfer.photos.estimated_view_spec`).

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
        TypeError: an argument of the wrong type (see
            :func:`~meshadv.transfer.blackbox.check_run_options`), or an unknown attack option.
        ValueError: unknown ``perturbation``, a class the victim does not know, ``texture_smoothing`` given for a
            shape attack or negative, a bad count, ``timeout`` or render-setup option; all before any render.
    """
    # every argument is checked (the attack and its criterion built) before the first Mitsuba render
    check_perturbation(perturbation)
    check_smoothing(texture_smoothing, perturbation)
    robustness = check_run_options(hidden, victim, robustness, attack_kwargs, jitter, num_lights, camera_steps,
                                   light_steps, timeout, case_id)
    setup_options, kwargs = attack_options(attack_kwargs, jitter)
    attack_setup(setup_options, hidden.image_size)
    attack = object_attack(perturbation, texture_smoothing, kwargs)
    untargeted, targeted = classifier_criteria(victim, true_class, target)
    criterion = untargeted if targeted is None else targeted
    est = estimate_parameters(mesh, hidden, num_lights=num_lights, camera_steps=camera_steps,
                              light_steps=light_steps, variant=variant, timeout=timeout)
    background = background_photo(hidden, variant=variant, timeout=timeout)
    setup = attack_setup(setup_options, hidden.image_size, background)
    result = attack_estimated(attack, mesh, est.views, victim, criterion, robustness, setup, callback)
    adversarial = result.mesh
    run = BlackBoxRun(hidden, est, background, setup, robustness, variant, timeout)
    measured = measure(run, adversarial, adversarial, victim, criterion)
    row = row_head(case_id, victim, true_class, target, perturbation)
    row.update(_classifier_outcome(victim, criterion, untargeted, measured, est.photo))
    return finish_row(row, run, attack, result, measured, adversarial, texture_smoothing)


def _classifier_outcome(victim: Any, bound: Any, untargeted: Any, measured: Measured,
                        photo: torch.Tensor) -> dict[str, Any]:
    """The classifier row's outcome: success, margin and top-1 class on meshadv's render of the estimated view, on
    Mitsuba's renders of the adversarial mesh under the estimates and under the hidden parameters, and on the
    photo (the benign object), whose ``untargeted`` verdict says whether the victim classifies it correctly."""
    with torch.no_grad():
        top1_meshadv = top1_names(victim, victim(measured.image_meshadv[None]))[0]
        logits = victim(measured.victim_batch(photo))  # the photo, Mitsuba hidden, Mitsuba estimated
    benign_correct = not bool(untargeted.is_adversarial(logits[:1])[0])
    margins = bound.margin(logits).tolist()
    names = top1_names(victim, logits)
    return {
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
    }


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
        :func:`~meshadv.transfer.blackbox.blackbox_classifier`.

    Raises:
        TypeError: an argument of the wrong type (see :func:`~meshadv.transfer.blackbox.check_run_options`; also
            ``scene_objects``, ``object_index``, ``score_threshold``, ``background_exclude``), or an unknown attack
            option.
        ValueError: ``object_index`` out of range, unknown ``perturbation``, ``context`` or ``light_fit``, a bad
            ``score_threshold``, a ``hide_class`` the victim does not know, ``texture_smoothing`` given for a shape
            attack or negative, a bad count, ``timeout`` or render-setup option; all before any render.
    """
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





def settings_suffix(jitter: float, eot: int, margin: float, pixel_noise: float, antialias: int, steps: int,
                    default_steps: int, light_jitter: Optional[float] = None, seed: int = 0,
                    texture_smoothing: Optional[int] = None, spp: int = 64, method: str = "adam") -> str:
    """The non-default settings of a black-box run, for its default case id (e.g. ``_eot8_margin10_aa3_seed1``).

    The update rule is named unless it is ``"adam"`` (e.g. ``_ddn``), so a ddn run never takes an Adam run's id.
    """
    parts = [f"_jitter{jitter:g}" if jitter != 1.0 else "",
             f"_lightjitter{light_jitter:g}" if light_jitter is not None else ""]
    parts += [f"_eot{eot}" if eot != 1 else "", f"_margin{margin:g}" if margin else "",
              f"_noise{pixel_noise:g}" if pixel_noise else "", f"_aa{antialias}" if antialias != 1 else "",
              f"_steps{steps}" if steps != default_steps else "", f"_seed{seed}" if seed != 0 else ""]
    parts += [f"_smooth{texture_smoothing}" if texture_smoothing is not None else "", f"_spp{spp}" if spp != 64 else ""]
    parts += [f"_{method}" if method != "adam" else ""]
    return "".join(parts)


def ddn_shape_options(method: str, perturbation: str, mesh: Any) -> dict[str, Any]:
    """``{"method_options": ...}`` of a ddn shape attack on ``mesh``, its lengths scaled to the object's size
    (:func:`~meshadv.attacks.budget.shape_options_for`); ``{}`` for another rule or a texture attack (colour units
    need no scale)."""
    if method != "ddn" or perturbation != "shape":
        return {}
    return {"method_options": shape_options_for(mesh)}


def finished_blackbox(db_path: Union[str, Path], experiment: str, case_id: str) -> bool:
    """Whether the database ``db_path`` (possibly missing) holds the black-box row ``case_id`` of ``experiment``."""
    if not Path(db_path).is_file():
        return False
    return any(r.get("case_id") == case_id for r in load_transfer_rows(db_path, experiment=experiment, kind="blackbox"))


def save_blackbox_outputs(result: BlackBoxResult, out: Union[str, Path]) -> None:
    """Write a black-box run into the folder ``out`` (created), every file atomically: its images as PNGs, the
    adversarial mesh (``adversarial.ply``), the attack's loss history and the row (``blackbox.json``)."""
    import json

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for name, im in result.images.items():
        save_png(im, out / f"{name}.png")
    save_mesh(result.adversarial_mesh.detach(), out / "adversarial.ply")
    write_text_atomic(out / "loss_history.json", json.dumps(list(result.attack_result.loss_history), default=str))
    write_text_atomic(out / "blackbox.json", json.dumps(result.to_record(), indent=2, default=str))
