"""What the two black-box pipelines (:mod:`~meshadv.transfer.classifier_pipeline`,
:mod:`~meshadv.transfer.detector_pipeline`) share once the camera and lights are estimated: the attack's options
and render setup, the measurements of the adversarial mesh (meshadv's margin and robust rate, Mitsuba's renders)
and the parts of the result row that every run has."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Optional

import numpy as np
import torch

from meshadv import _validate
from meshadv.render.setup import RenderSetup, split_setup_options
from meshadv.transfer._attack_run import meshadv_margins, pixel_noise_where, robust_rate
from meshadv.transfer._scoring import images_tensor
from meshadv.transfer.compositing import composite, estimated_view_spec
from meshadv.transfer.hidden import HiddenScene
from meshadv.transfer.photo import Estimation
from meshadv.transfer.render import MitsubaImage, render_scenes
from meshadv.transfer.results import BlackBoxResult
from meshadv.transfer.robust import DEFAULT_JITTER, Robustness, restore_photo

__all__ = ["BlackBoxRun", "Measured", "attack_options", "attack_setup", "check_run_options", "finish_row", "measure",
           "row_head"]


def check_run_options(hidden: Any, victim: Any, robustness: Any, attack_kwargs: Any, jitter: Any, num_lights: Any,
                      camera_steps: Any, light_steps: Any, timeout: Any, case_id: Any) -> Robustness:
    """Raise naming the first bad argument that both pipelines take, before any render; return the robustness
    settings (``Robustness()`` for None).

    Raises:
        TypeError: ``hidden`` is not a :class:`~meshadv.transfer.hidden.HiddenScene`, ``victim`` is not callable,
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
