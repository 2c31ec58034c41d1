"""Making an attack found with *estimated* parameters survive a different renderer and the true parameters, and
running it.

* :class:`~meshadv.attacks.WithMargin` (in :mod:`meshadv.attacks.criteria`) counts an image as adversarial only when
  the wrapped criterion holds with a margin (logit units for classifiers, score units for detectors), so the kept
  step is the least distorted one that holds with the margin rather than a borderline one.
* :func:`eot_views`: expectation over transformation, ``K`` copies of the estimated view that the attack's per-step
  ``jitter`` perturbs independently; success at a step needs every sample to be adversarial.
* :class:`NoisyVictim`: the victim sees every render with fresh Gaussian noise on the rendered object, so the
  texture does not depend on exact pixel values that a path tracer's Monte-Carlo noise changes.
* :class:`Occluded`: puts back the photo's pixels where, in the photo, another object hides the attacked one.
* :class:`Robustness`: the settings that combine these tools; :data:`DEFAULT_JITTER`, the per-step jitter of the
  estimated camera and lights (:func:`scaled_jitter` scales it).
* :func:`object_attack`: the attack of a black-box run (shape, per-face texture or smoothed per-vertex texture,
  restricted to one object of a merged scene by a mask); :func:`attack_estimated` runs it with the robustness
  settings, :func:`meshadv_margins` and :func:`robust_rate` measure the result in meshadv.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Optional

import torch
from torch import Tensor

from meshadv import _validate
from meshadv.attacks import ShapeAttack, SmoothTextureAttack, TextureAttack, evaluate
from meshadv.attacks.criteria import WithMargin
from meshadv.render import ViewSet
from meshadv.render.setup import RenderSetup

if TYPE_CHECKING:
    from meshadv.render import ViewSet

__all__ = [
    "DEFAULT_JITTER", "NoisyVictim", "Occluded", "Robustness", "attack_estimated", "check_smoothing", "eot_views",
    "meshadv_margins", "object_attack", "pixel_noise_where", "restore_photo", "robust_rate", "scaled_jitter",
    "texture_attack",
]


#: Jitter of the estimated camera and lights at every attack step (the paper's step 3).
DEFAULT_JITTER = {"azimuth": 5.0, "elevation": 5.0, "distance": 0.05, "light_direction": 0.2, "light_intensity": 0.2}


def scaled_jitter(scale: float, light_scale: Optional[float] = None) -> dict[str, float]:
    """:data:`DEFAULT_JITTER` with the camera entries times ``scale`` and the light entries times ``light_scale``
    (default ``scale``).

    Raises:
        ValueError: ``scale`` or ``light_scale`` is negative.
    """
    if not scale >= 0:
        raise ValueError(f"scale must be >= 0, got {scale}")
    if light_scale is not None and not light_scale >= 0:
        raise ValueError(f"light_scale must be >= 0, got {light_scale}")
    light = scale if light_scale is None else light_scale
    return {k: v * (light if k.startswith("light_") else scale) for k, v in DEFAULT_JITTER.items()}


def eot_views(views: ViewSet, samples: int) -> ViewSet:
    """``samples`` copies of every view of ``views`` (view-major blocks: all views, then all views again, ...).

    Passed to an attack that has a ``jitter``, each copy is jittered independently at every step: an
    expectation-over-transformation batch of ``samples`` random cameras and lights per view.

    Args:
        views: a ``meshadv.render.ViewSet``.
        samples: copies per view, ``>= 1`` (1 returns ``views`` itself).

    Returns:
        A ``ViewSet`` of ``samples * len(views)`` views.

    Raises:
        TypeError: ``samples`` is not an int, or ``views`` is not a ``ViewSet``.
        ValueError: ``samples < 1``.
    """
    _validate.positive_int("samples", samples)
    ViewSet.require(views)
    return views if samples == 1 else ViewSet.cat([views] * samples)


def restore_photo(images: Tensor, photo: Tensor, mask: Tensor) -> Tensor:
    """``images * (1 - mask) + photo * mask``: the photo put back where ``mask`` is 1 (where, in the photo, another
    object hides the one rendered over it).

    Args:
        images: ``(3, H, W)`` or ``(B, 3, H, W)``.
        photo: ``(3, H, W)``.
        mask: ``(H, W)`` in ``[0, 1]``.

    Returns:
        Images of the shape of ``images``; gradients flow to the unmasked pixels.
    """
    return images * (1.0 - mask) + photo * mask


class _VictimWrapper:
    """A victim seen through a transform of its input images: everything but the call (``kind``, ``name``,
    ``class_names``, ``class_index``, ...) is the wrapped victim's, so an attack or a criterion treats the wrapper as
    the victim itself.

    Raises:
        TypeError: ``victim`` is not callable.
    """

    def __init__(self, victim: Any) -> None:
        if not callable(victim):
            raise TypeError(f"victim must be a callable victim, got {type(victim).__name__}")
        self.__dict__["victim"] = victim

    def __getattr__(self, name: str) -> Any:
        return getattr(self.__dict__["victim"], name)


class NoisyVictim(_VictimWrapper):
    """A victim that adds Gaussian pixel noise to the images it is given (an expectation-over-noise transform).

    With ``background`` (the photo the attack composites its renders over), the noise goes only where an image
    differs from the background, i.e. on the pixels meshadv rendered: the photo already carries the path tracer's
    own noise, and noise over the whole image changes what the victim sees of the scene (SSD stops detecting the
    indoor table under noise of standard deviation 0.06 alone). A pixel the render does not cover is exactly the
    background (``render + (1 - alpha) * background`` with ``alpha = 0``), so the test is exact. Without
    ``background`` every pixel gets noise.

    Everything but the call (``kind``, ``name``, ``class_names``, ``class_index``, ...) is the wrapped victim's, so an
    attack or a criterion treats it as the victim itself. Images are clamped to ``[0, 1]`` after the noise, as a
    renderer's output is. Use it for the attack only: its outputs are random.

    Args:
        victim: a ``meshadv.victims`` victim (classifier or detector).
        std: standard deviation of the noise (image units, ``[0, 1]`` scale), ``> 0``.
        seed: seed of the noise generator (the sequence of noises is reproducible).
        background: optional ``(3, H, W)`` image: noise only where the images differ from it.

    Raises:
        TypeError: ``victim`` is not callable, ``std`` is not a number, or ``background`` is not a tensor.
        ValueError: ``std`` is not positive and finite, or ``background`` is not ``(3, H, W)`` (or, at call time,
            does not match the images).

    Example:
        >>> noisy = NoisyVictim(victim, 0.05, background=photo)  # doctest: +SKIP
        >>> logits = noisy(images)  # victim(images + noise on the rendered object)  # doctest: +SKIP
    """

    def __init__(self, victim: Any, std: float, *, seed: int = 0, background: Any = None) -> None:
        super().__init__(victim)
        _validate.positive_float("std", std)
        if background is not None and not isinstance(background, Tensor):
            raise TypeError(f"background must be None or a (3, H, W) tensor, got {type(background).__name__}")
        if background is not None and (background.dim() != 3 or background.shape[0] != 3):
            raise ValueError(f"background must be None or a (3, H, W) tensor, got shape {tuple(background.shape)}")
        self.__dict__["std"] = float(std)
        self.__dict__["background"] = None if background is None else background.detach()
        self.__dict__["_generator"] = torch.Generator().manual_seed(int(seed))

    def __call__(self, images: Tensor) -> Any:
        """``victim(clamp(images + mask * N(0, std^2), 0, 1))``; gradients flow to ``images``."""
        noise = torch.randn(images.shape, generator=self._generator, dtype=images.dtype).to(images.device)
        if self.background is not None:
            if tuple(images.shape[1:]) != tuple(self.background.shape):
                raise ValueError(f"images {tuple(images.shape[1:])} must match the background "
                                 f"{tuple(self.background.shape)}")
            rendered = (images.detach() != self.background.to(images)).any(dim=1, keepdim=True)
            noise = noise * rendered
        return self.victim((images + self.std * noise).clamp(0.0, 1.0))

    def __repr__(self) -> str:
        where = "rendered pixels" if self.background is not None else "every pixel"
        return f"NoisyVictim({getattr(self.victim, 'name', type(self.victim).__name__)}, std={self.std:g}, {where})"


class Occluded(_VictimWrapper):
    """A victim that first restores ``photo`` where ``mask`` is 1: the pixels where, in the photo, something in
    front hides the object being attacked (which the attack renders alone over the photo).

    Everything but the call is the wrapped victim's (as :class:`NoisyVictim`). The mask is fixed: under view jitter
    it is the occlusion of the estimated view.

    Args:
        victim: a victim (or another wrapper).
        photo: ``(3, H, W)`` the photo.
        mask: ``(H, W)`` occluded pixels in ``[0, 1]`` (1 = show the photo).

    Raises:
        TypeError: ``victim`` is not callable, or ``photo`` or ``mask`` is not a tensor.
        ValueError: shapes that do not match, or a mask outside ``[0, 1]``.

    Example:
        >>> victim = Occluded(victim, photo, occluded)        # doctest: +SKIP
    """

    def __init__(self, victim: Any, photo: Tensor, mask: Tensor) -> None:
        super().__init__(victim)
        for name, value in (("photo", photo), ("mask", mask)):
            if not isinstance(value, Tensor):
                raise TypeError(f"{name} must be a tensor, got {type(value).__name__}")
        if photo.dim() != 3 or photo.shape[0] != 3:
            raise ValueError(f"photo must be a (3, H, W) tensor, got {tuple(photo.shape)}")
        if tuple(mask.shape) != tuple(photo.shape[1:]):
            raise ValueError(f"mask must be an (H, W) tensor matching the photo {tuple(photo.shape[1:])}, "
                             f"got {getattr(mask, 'shape', type(mask).__name__)}")
        if mask.numel() and (float(mask.min()) < 0 or float(mask.max()) > 1):
            raise ValueError("mask values must be in [0, 1]")
        self.__dict__["photo"] = photo.detach().float()
        self.__dict__["mask"] = mask.detach().float()

    def __call__(self, images: Tensor) -> Any:
        """``victim(images * (1 - mask) + photo * mask)``; gradients flow to the unoccluded pixels."""
        if tuple(images.shape[-2:]) != tuple(self.mask.shape):
            raise ValueError(f"images {tuple(images.shape[-2:])} must match the occlusion mask "
                             f"{tuple(self.mask.shape)}")
        return self.victim(restore_photo(images, self.photo.to(images), self.mask.to(images)))

    def __repr__(self) -> str:
        return f"Occluded({self.victim!r}, {int((self.mask > 0).sum())} pixels)"


@dataclass(frozen=True)
class Robustness:
    """How a black-box attack is made to survive the change of renderer and the error of the estimates.

    The defaults reproduce the plain pipeline (one jittered sample per step, the
    least distorted success kept, no pixel noise).

    Attributes:
        eot: jittered samples of the estimated view per Adam step, rendered as one batch (expectation over
            transformation); success at a step needs all of them. ``>= 1``.
        margin: margin with which the criterion must hold on every sample of a step for the step to count as a
            success (:class:`~meshadv.attacks.WithMargin`): logits for classifiers, detection score for
            detectors. ``>= 0``.
        pixel_noise: standard deviation of the Gaussian noise added to the rendered object's pixels of every image
            the victim sees during the attack (:class:`~meshadv.transfer.robust.NoisyVictim`; the photo behind it
            already has its own noise), ``>= 0`` (0 = none).
        verify_samples: fresh samples around the estimated view, drawn with :data:`DEFAULT_JITTER` (whatever the
            attack's jitter), on which the adversarial mesh is re-rendered in meshadv after the attack
            (``robust_rate_meshadv`` of the result row), ``>= 0`` (0 = skip).
        seed: seed of the pixel noise and of the verification samples.

    Raises:
        TypeError: a field of the wrong type (a float ``eot``, a string ``margin``, ...), naming it.
        ValueError: a field out of range, naming it.
    """

    eot: int = 1
    margin: float = 0.0
    pixel_noise: float = 0.0
    verify_samples: int = 16
    seed: int = 0

    def __post_init__(self) -> None:
        # stored as Python ints (a NumPy integer would not be JSON-able in the result row)
        object.__setattr__(self, "eot", _validate.positive_int("eot", self.eot))
        object.__setattr__(self, "verify_samples", _validate.non_negative_int("verify_samples", self.verify_samples))
        object.__setattr__(self, "seed", _validate.integer("seed", self.seed))
        for name in ("margin", "pixel_noise"):
            _validate.finite_float(name, getattr(self, name), low=0.0)

    def to_record(self) -> dict[str, Any]:
        """The fields as result-row entries (``required_margin`` for ``margin``)."""
        return {"eot": self.eot, "required_margin": float(self.margin), "pixel_noise": float(self.pixel_noise),
                "verify_samples": self.verify_samples, "robust_seed": self.seed}


def _photo_background(setup: RenderSetup) -> Optional[Tensor]:
    """The setup's background when it is a ``(3, H, W)`` photo (the pixel noise then goes on rendered pixels
    only), else ``None`` (a plain colour: the noise goes everywhere)."""
    return setup.background if setup.has_photo else None  # type: ignore[return-value]


def attack_estimated(attack: Any, mesh: Any, views: ViewSet, victim: Any, criterion: Any, robustness: Robustness,
                     setup: RenderSetup, callback: Optional[Callable[[Any], None]] = None) -> Any:
    """Run ``attack`` with ``setup`` on the estimated ``views`` with the EOT batch, the margin and the pixel noise
    of ``robustness``."""
    attack_victim = victim
    if robustness.pixel_noise > 0:
        attack_victim = NoisyVictim(victim, robustness.pixel_noise, seed=robustness.seed,
                                    background=_photo_background(setup))
    return attack(mesh, eot_views(views, robustness.eot), attack_victim, WithMargin(criterion, robustness.margin),
                  setup=setup, callback=callback)


def pixel_noise_where(setup: RenderSetup, robustness: Robustness) -> Optional[str]:
    """Where :func:`attack_estimated` puts the pixel noise: ``"rendered pixels"``, ``"whole image"`` or None."""
    if robustness.pixel_noise == 0:
        return None
    return "rendered pixels" if _photo_background(setup) is not None else "whole image"


def meshadv_margins(setup: RenderSetup, mesh: Any, views: ViewSet, victim: Any, bound: Any,
                    chunk: int = 8) -> tuple[torch.Tensor, Any]:
    """Margins (V,) of ``bound`` on meshadv's renders of ``mesh`` (the attack's render setup, clean victim),
    and the first image (3, H, W)."""
    margins, first = [], None
    for start in range(0, len(views), chunk):
        part = evaluate(mesh, views[start:start + chunk], victim, bound, setup=setup)
        first = part.images[0, 0] if first is None else first
        margins.append(part.margins[0])
    return torch.cat(margins), first


def robust_rate(setup: RenderSetup, mesh: Any, views: ViewSet, victim: Any, bound: Any,
                robustness: Robustness) -> Optional[float]:
    """Fraction of ``robustness.verify_samples`` fresh views around the estimated ``views``, drawn with
    :data:`DEFAULT_JITTER` whatever jitter the attack used (one yardstick for every run), on which ``mesh`` is
    adversarial in meshadv."""
    if robustness.verify_samples == 0:
        return None
    generator = torch.Generator().manual_seed(robustness.seed + 7919)  # not the attack's samples
    samples = eot_views(views, robustness.verify_samples).jitter(generator, **DEFAULT_JITTER)
    margins, _ = meshadv_margins(setup, mesh, samples, victim, bound)
    return float((margins > 0).float().mean())


def check_smoothing(texture_smoothing: Optional[int], perturbation: str) -> None:
    """Check that ``texture_smoothing`` is None, or an int >= 0 with ``perturbation == "texture"``.

    Raises:
        TypeError: ``texture_smoothing`` is neither None nor an int.
        ValueError: it is negative, or given for a shape attack.
    """
    if texture_smoothing is None:
        return
    if perturbation != "texture":
        raise ValueError("texture_smoothing applies to texture attacks only (perturbation='texture')")
    _validate.non_negative_int("texture_smoothing", texture_smoothing)


def texture_attack(smoothing: Optional[int], face_mask: Optional[torch.Tensor], kwargs: dict[str, Any]) -> Any:
    """The paper's per-face texture attack (``smoothing`` None) or the smoothed per-vertex one."""
    if smoothing is None:
        return TextureAttack(face_mask=face_mask, **kwargs)
    return SmoothTextureAttack(smoothing=smoothing, face_mask=face_mask, **kwargs)


def object_attack(perturbation: str, smoothing: Optional[int], kwargs: dict[str, Any],
                   mask: Optional[torch.Tensor] = None) -> Any:
    """The attack of a black-box run: a texture attack (:func:`texture_attack`, ``mask`` its face mask) or a
    ``ShapeAttack`` (``mask`` its vertex mask); ``mask`` None: the whole mesh may change."""
    if perturbation == "texture":
        return texture_attack(smoothing, mask, kwargs)
    return ShapeAttack(**kwargs) if mask is None else ShapeAttack(vertex_mask=mask, **kwargs)
