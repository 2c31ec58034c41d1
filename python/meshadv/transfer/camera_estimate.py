"""Step 1 of the black-box pipeline: the camera of a photo of a known object, estimated from its mask.

Minimise ``||R_mask(S; P) - M||^2`` over azimuth, elevation and distance through meshadv's differentiable silhouette
(NMR gradients), from several starting views: a coarse grid scored without gradients, the best few refined with
Adam, all in one batch (:func:`estimate_camera`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import torch

from meshadv import _validate
from meshadv.render import Camera, render_silhouette
from meshadv.transfer._inputs import as_geometry, as_mask

__all__ = ["CameraEstimate", "estimate_camera"]


def _wrap_degrees(angle: float) -> float:
    """Wrap an angle difference to (-180, 180]."""
    return (angle + 180.0) % 360.0 - 180.0


@dataclass(frozen=True)
class CameraEstimate:
    """A spherical camera estimated from a mask.

    Attributes:
        distance: distance from the origin.
        azimuth: degrees in [0, 360).
        elevation: degrees.
        viewing_angle: the (known) field of view in degrees.
        loss: final mean squared silhouette error.
        iou: IoU of the estimated silhouette with the mask.
    """

    distance: float
    azimuth: float
    elevation: float
    viewing_angle: float
    loss: float
    iou: float

    def camera(self) -> Camera:
        """The estimate as a ``meshadv.render.Camera`` (batch 1)."""
        return Camera.spherical(self.distance, self.azimuth, self.elevation, viewing_angle=self.viewing_angle)

    def errors(self, distance: float, azimuth: float, elevation: float) -> dict[str, float]:
        """Errors against the true camera: absolute azimuth and elevation error (degrees), relative distance error."""
        return {
            "azimuth_error": abs(_wrap_degrees(self.azimuth - azimuth)),
            "elevation_error": abs(self.elevation - elevation),
            "distance_error": abs(self.distance - distance) / distance,
        }


def _silhouettes(
    vertices: torch.Tensor,
    faces: torch.Tensor,
    dist: torch.Tensor,
    az: torch.Tensor,
    el: torch.Tensor,
    viewing_angle: float,
    size: tuple[int, int],
    antialias: int,
) -> torch.Tensor:
    """(B, H, W) silhouettes of the mesh under spherical cameras ``(dist, az, el)`` (each ``(B,)``)."""
    camera = Camera.spherical(dist, az, el, viewing_angle=viewing_angle)
    return render_silhouette(vertices, faces, camera, size, antialias=antialias)[:, 0]


def _blur(images: torch.Tensor, sigma: float) -> torch.Tensor:
    """Separable Gaussian blur of (B, H, W) images (differentiable; identity for sigma < 0.3 pixel)."""
    if sigma < 0.3:
        return images
    radius = max(1, int(math.ceil(3 * sigma)))
    x = torch.arange(-radius, radius + 1, dtype=images.dtype)
    k = torch.exp(-0.5 * (x / sigma) ** 2)
    k = k / k.sum()
    out = images.unsqueeze(1)
    out = torch.nn.functional.conv2d(torch.nn.functional.pad(out, (radius, radius, 0, 0)), k.view(1, 1, 1, -1))
    out = torch.nn.functional.conv2d(torch.nn.functional.pad(out, (0, 0, radius, radius)), k.view(1, 1, -1, 1))
    return out.squeeze(1)


def estimate_camera(
    mask: Any,
    vertices: torch.Tensor,
    faces: torch.Tensor,
    *,
    viewing_angle: float = 30.0,
    azimuths: Sequence[float] = tuple(range(0, 360, 15)),
    elevations: Sequence[float] = tuple(range(-10, 80, 10)),
    reference_distance: float = 2.732,
    refine: int = 4,
    steps: int = 80,
    lr: float = 2.0,
    antialias: int = 2,
    coarse_size: int = 48,
    blur: float = 0.04,
) -> CameraEstimate:
    """Estimate the spherical camera that makes the mesh's silhouette match ``mask``.

    Coarse to fine, because the silhouette error of thin or off-centre geometry (chair slats, a scene whose objects
    are not at the origin) has narrow basins: every (azimuth, elevation) start is scored without gradients on small
    (``coarse_size``), Gaussian-blurred silhouettes, with its distance set so that the silhouette area matches the
    mask's (area scales as 1 / distance^2); the ``refine`` best are then optimised jointly with Adam (angles in
    degrees, distance in log space) on ``||blur(R_mask(S; P)) - blur(M)||^2`` with a blur that shrinks to zero over
    the first two thirds of the steps. The start with the lowest final (unblurred) error wins.

    Args:
        mask: (H, W) target silhouette in [0, 1] (array or tensor).
        vertices: (N, 3) mesh vertices (world space).
        faces: (M, 3) faces.
        viewing_angle: the camera's (known) field of view in degrees.
        azimuths: azimuth starts in degrees.
        elevations: elevation starts in degrees.
        reference_distance: distance at which the starts are first rendered.
        refine: number of starts refined by gradient descent.
        steps: Adam steps.
        lr: Adam learning rate (degrees per step for the angles; a hundredth of it for log distance).
        antialias: supersampling of the silhouette during refinement (smoother objective).
        coarse_size: image side used to score the starts.
        blur: initial Gaussian blur, as a fraction of the image side.

    Returns:
        The :class:`CameraEstimate`.

    Raises:
        TypeError: an argument of the wrong type (e.g. a float ``steps``), naming it.
        ValueError: an empty mask, bad shapes, or an argument out of range (``steps < 0``, ``refine < 1``, empty
            ``azimuths``/``elevations``, ``coarse_size < 8``, ...), naming it.

    Example:
        >>> est = estimate_camera(mask, mesh.vertices, mesh.faces)  # doctest: +SKIP
        >>> est.azimuth, est.elevation
    """
    target = as_mask(mask)
    _check_camera_options(target, viewing_angle, azimuths, elevations, reference_distance, refine, steps, lr,
                          antialias, coarse_size, blur)
    verts, faces_t = as_geometry(vertices, faces)
    az, el, dist = _coarse_starts(verts, faces_t, target, azimuths, elevations, viewing_angle, reference_distance,
                                  refine, coarse_size, blur)
    a, e, d = _refine_starts(verts, faces_t, target, az, el, dist, viewing_angle, steps, lr, antialias, blur)
    final, iou = _silhouette_fit(verts, faces_t, target, d, a, e, viewing_angle)
    return CameraEstimate(d, a % 360.0, e, float(viewing_angle), final, iou)


def _check_camera_options(target: torch.Tensor, viewing_angle: float, azimuths: Sequence[float],
                          elevations: Sequence[float], reference_distance: float, refine: int, steps: int, lr: float,
                          antialias: int, coarse_size: int, blur: float) -> None:
    """Raise naming the first bad argument of :func:`estimate_camera` (TypeError for a wrong type, ValueError for a
    bad value)."""
    if float(target.sum()) < 1.0:
        raise ValueError("mask is empty: the object is not visible")
    _validate.finite_float("viewing_angle", viewing_angle, low=0.0, high=180.0, low_open=True, high_open=True)
    if not azimuths or not elevations:
        raise ValueError("azimuths and elevations must be non-empty")
    for name, values in (("azimuths", azimuths), ("elevations", elevations)):
        for i, value in enumerate(values):
            _validate.finite_float(f"{name}[{i}]", value)
    _validate.positive_float("reference_distance", reference_distance)
    _validate.positive_int("refine", refine)
    _validate.non_negative_int("steps", steps)
    _validate.positive_float("lr", lr)
    _validate.positive_int("antialias", antialias)
    _validate.integer("coarse_size", coarse_size, low=8)
    _validate.finite_float("blur", blur, low=0.0)


def _coarse_starts(verts: torch.Tensor, faces: torch.Tensor, target: torch.Tensor, azimuths: Sequence[float],
                   elevations: Sequence[float], viewing_angle: float, reference_distance: float, refine: int,
                   coarse_size: int, blur: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The ``refine`` best (azimuth, elevation) starts of the grid and their distances, each ``(R,)``.

    Every start is scored without gradients on ``coarse_size`` blurred silhouettes, at the distance that makes its
    silhouette's area match the mask's (area scales as 1 / distance^2).
    """
    grid_az = torch.tensor([float(a) for a in azimuths for _ in elevations])
    grid_el = torch.tensor([float(e) for _ in azimuths for e in elevations])
    coarse = (min(coarse_size, int(target.shape[0])), min(coarse_size, int(target.shape[1])))
    target_c = torch.nn.functional.adaptive_avg_pool2d(target[None, None], coarse)[0, 0]
    sigma_c = blur * max(coarse)
    with torch.no_grad():
        ref = torch.full_like(grid_az, float(reference_distance))
        sil = _silhouettes(verts, faces, ref, grid_az, grid_el, viewing_angle, coarse, 2)
        area = sil.sum(dim=(1, 2)).clamp_min(1e-3)
        dist = ref * torch.sqrt(area / target_c.sum().clamp_min(1e-3))
        sil = _silhouettes(verts, faces, dist, grid_az, grid_el, viewing_angle, coarse, 2)
        loss = ((_blur(sil, sigma_c) - _blur(target_c[None], sigma_c)) ** 2).mean(dim=(1, 2))
    best = torch.argsort(loss)[: min(refine, len(loss))]
    return grid_az[best], grid_el[best], dist[best]


def _refine_starts(verts: torch.Tensor, faces: torch.Tensor, target: torch.Tensor, az0: torch.Tensor,
                   el0: torch.Tensor, dist0: torch.Tensor, viewing_angle: float, steps: int, lr: float,
                   antialias: int, blur: float) -> tuple[float, float, float]:
    """Adam on all starts at once (angles in degrees, distance in log space) with a blur that shrinks to zero over
    the first two thirds of the steps; the (azimuth, elevation, distance) with the lowest unblurred error."""
    size = (int(target.shape[0]), int(target.shape[1]))
    az = az0.clone().requires_grad_(True)
    el = el0.clone().requires_grad_(True)
    log_d = torch.log(dist0).clone().requires_grad_(True)
    opt = torch.optim.Adam([{"params": [az, el], "lr": lr}, {"params": [log_d], "lr": lr / 100.0}])
    best_state = (az.detach().clone(), el.detach().clone(), log_d.detach().clone())
    best_loss = torch.full((len(az0),), float("inf"))
    sigma0 = blur * max(size)
    blur_steps = max(1, (2 * steps) // 3)
    for step in range(steps + 1):
        sigma = sigma0 * max(0.0, 1.0 - step / blur_steps)
        opt.zero_grad()
        sil = _silhouettes(verts, faces, log_d.exp(), az, el, viewing_angle, size, antialias)
        per_view = ((_blur(sil, sigma) - _blur(target[None], sigma)) ** 2).mean(dim=(1, 2))
        if sigma < 0.3:  # only unblurred errors are comparable between steps
            with torch.no_grad():
                better = per_view < best_loss
                best_loss = torch.where(better, per_view.detach(), best_loss)
                best_state = tuple(torch.where(better, p.detach(), s) for p, s in zip((az, el, log_d), best_state))
        per_view.sum().backward()
        opt.step()
        with torch.no_grad():
            el.clamp_(-89.0, 89.0)
    i = int(torch.argmin(best_loss))
    a, e, d = (float(s[i]) for s in best_state)
    return a, e, math.exp(d)


def _silhouette_fit(verts: torch.Tensor, faces: torch.Tensor, target: torch.Tensor, distance: float,
                    azimuth: float, elevation: float, viewing_angle: float) -> tuple[float, float]:
    """The mean squared error and the IoU of the camera's silhouette (no supersampling) against ``target``."""
    size = (int(target.shape[0]), int(target.shape[1]))
    with torch.no_grad():
        sil = _silhouettes(verts, faces, torch.tensor([distance]), torch.tensor([azimuth]), torch.tensor([elevation]),
                           viewing_angle, size, 1)[0]
        hard = sil > 0.5
        tgt = target > 0.5
        iou = float((hard & tgt).sum()) / max(float((hard | tgt).sum()), 1.0)
        final = float(((sil - target) ** 2).mean())
    return final, iou
