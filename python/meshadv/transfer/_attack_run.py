"""Run a black-box attack with its :class:`~meshadv.transfer.robust.Robustness` settings and measure the result in
meshadv: the steps :mod:`meshadv.transfer.blackbox`'s pipelines share, built on the tools of
:mod:`meshadv.transfer.robust`."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Callable, Optional

import torch
from torch import Tensor

from meshadv.render.setup import RenderSetup
from meshadv.transfer.robust import DEFAULT_JITTER, NoisyVictim, Robustness, WithMargin, eot_views

if TYPE_CHECKING:
    from meshadv.render import ViewSet

__all__ = ["attack_estimated", "meshadv_margins", "pixel_noise_where", "robust_rate"]


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
    from meshadv.attacks import evaluate

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
