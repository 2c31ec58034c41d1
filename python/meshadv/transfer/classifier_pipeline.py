"""The paper's black-box pipeline against a classifier (:func:`blackbox_classifier`): an object in a hidden
world (e.g. an aeroplane in an outdoor scene) whose camera and lights are estimated from Mitsuba's photo of it.

The steps are described in :mod:`meshadv.transfer.blackbox`, which re-exports this pipeline.
"""

from __future__ import annotations

from typing import Any, Callable, Optional

import torch

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
from meshadv.transfer._scoring import classifier_criteria, top1_names
from meshadv.transfer.hidden import HiddenScene
from meshadv.transfer.object_attacks import check_smoothing, object_attack
from meshadv.transfer.photo import background_photo, estimate_parameters
from meshadv.transfer.results import BlackBoxResult
from meshadv.transfer.robust import Robustness

__all__ = ["blackbox_classifier"]


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

    1-2. :func:`~meshadv.transfer.photo.estimate_parameters`; 3. attack in meshadv on the estimated view with
    jitter (``robustness.eot`` jittered samples per step), the renders composited over the photo's background;
    4. re-render the adversarial mesh with Mitsuba under the hidden parameters and test. As a diagnostic, Mitsuba
    also renders it under the *estimated* parameters (:func:`~meshadv.transfer.compositing.estimated_view_spec`).

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
            :func:`~meshadv.transfer._pipeline.check_run_options`), or an unknown attack option.
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
