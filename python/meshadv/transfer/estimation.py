"""Estimate the camera and the lights of a photo of a known object (the black-box pipeline's steps 1-2).

1. Camera (:func:`estimate_camera`): minimise ``||R_mask(S; P) - M||^2`` over azimuth, elevation and distance
   through meshadv's differentiable silhouette, from several starting views (a coarse grid scored without
   gradients, the best few refined with Adam, all in one batch).
2. Lights (:func:`estimate_lights`): with the camera fixed, minimise the masked image error
   ``||M * (R(S; P, L) - I')||^2`` over ``K`` directional lights (direction, colour) and an ambient colour;
   :func:`light_errors` compares light sets and :func:`masked_rmse` images.

The inputs (a mask, an image, a mesh's geometry) may be numpy arrays or tensors (:func:`as_mask`, :func:`as_image`,
:func:`as_geometry`). Needs torch and :mod:`meshadv.render`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import torch

from meshadv import _validate
from meshadv.render import Camera, Lights, render, render_silhouette, shade

__all__ = [
    "CameraEstimate", "LightEstimate", "as_geometry", "as_image", "as_mask", "estimate_camera", "estimate_lights",
    "light_errors", "masked_rmse",
]


def as_mask(mask: Any, name: str = "mask") -> torch.Tensor:
    """(H, W) float32 tensor in [0, 1] from an array / tensor of shape (H, W), (1, H, W) or (1, 1, H, W).

    Raises:
        ValueError: another shape, or values that are not finite (``name`` in the message).
    """
    t = torch.as_tensor(np.asarray(mask.detach().cpu() if hasattr(mask, "detach") else mask), dtype=torch.float32)
    while t.dim() > 2 and t.shape[0] == 1:
        t = t[0]
    if t.dim() != 2:
        raise ValueError(f"{name} must have shape (H, W), got {tuple(t.shape)}")
    if not bool(torch.isfinite(t).all()):
        raise ValueError(f"{name} contains NaN or Inf")
    return t.clamp(0.0, 1.0)


def as_image(image: Any, name: str = "image") -> torch.Tensor:
    """(3, H, W) float32 tensor from an array / tensor of shape (3, H, W), (H, W, 3) or (1, 3, H, W).

    Raises:
        ValueError: another shape (``name`` in the message).
    """
    img = torch.as_tensor(np.asarray(image.detach().cpu() if hasattr(image, "detach") else image), dtype=torch.float32)
    if img.dim() == 4 and img.shape[0] == 1:
        img = img[0]
    if img.dim() == 3 and img.shape[-1] == 3 and img.shape[0] != 3:
        img = img.permute(2, 0, 1)
    if img.dim() != 3 or img.shape[0] != 3:
        raise ValueError(f"{name} must have shape (3, H, W) or (H, W, 3), got {tuple(img.shape)}")
    return img


def as_geometry(vertices: Any, faces: Any) -> tuple[torch.Tensor, torch.Tensor]:
    """``(N, 3)`` float32 vertices (detached: the estimation never changes the mesh) and ``(M, 3)`` int64 faces.

    Raises:
        ValueError: ``vertices`` or ``faces`` does not have shape ``(N, 3)`` / ``(M, 3)`` with ``M > 0``.
    """
    verts = torch.as_tensor(vertices, dtype=torch.float32).detach()
    faces_t = torch.as_tensor(faces, dtype=torch.int64)
    if verts.dim() != 2 or verts.shape[1] != 3:
        raise ValueError(f"vertices must have shape (N, 3), got {tuple(verts.shape)}")
    if faces_t.dim() != 2 or faces_t.shape[1] != 3 or faces_t.shape[0] == 0:
        raise ValueError(f"faces must have shape (M, 3) with M > 0, got {tuple(faces_t.shape)}")
    return verts, faces_t


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


@dataclass(frozen=True)
class LightEstimate:
    """Lights estimated from a masked image.

    Attributes:
        lights: the estimated ``meshadv.render.Lights`` (batch 1, ``K`` directional lights + ambient).
        loss: final masked mean squared error.
    """

    lights: Lights
    loss: float


def _unit_sphere_directions(count: int, toward: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    """``count`` directions spread over the hemisphere around ``toward`` (a Fibonacci spiral, randomly rotated)."""
    golden = math.pi * (3.0 - math.sqrt(5.0))
    offset = float(torch.rand(1, generator=generator)) * 2 * math.pi
    dirs = []
    for i in range(count):
        z = 1.0 - (i + 0.5) / count  # hemisphere: z in (0, 1]
        r = math.sqrt(max(0.0, 1.0 - z * z))
        phi = i * golden + offset
        dirs.append([r * math.cos(phi), r * math.sin(phi), z])
    local = torch.tensor(dirs, dtype=torch.float32).reshape(count, 3)  # (0, 3) when there are no lights
    w = toward / toward.norm()
    helper = torch.tensor([0.0, 1.0, 0.0]) if abs(float(w[1])) < 0.9 else torch.tensor([1.0, 0.0, 0.0])
    u = torch.linalg.cross(helper, w)
    u = u / u.norm()
    v = torch.linalg.cross(w, u)
    return local[:, :1] * u + local[:, 1:2] * v + local[:, 2:3] * w


def _inv_softplus(x: float) -> float:
    """The value whose softplus is ``x`` (> 0)."""
    return math.log(math.expm1(x))


class _LightParameters:
    """What :func:`estimate_lights` optimises: ``K`` light directions (normalised on use) and the colours and the
    ambient before a softplus (which keeps them non-negative).

    The directions start spread over the hemisphere facing the camera (:func:`_unit_sphere_directions`, seeded),
    the colours at a total of about 0.3, the ambient at 0.3.
    """

    def __init__(self, num_lights: int, toward_camera: torch.Tensor, seed: int) -> None:
        gen = torch.Generator().manual_seed(seed)
        self.num_lights = num_lights
        self.dirs = _unit_sphere_directions(num_lights, toward_camera, gen).requires_grad_(True)
        self.raw_colors = torch.full((num_lights, 3), _inv_softplus(0.3 / max(num_lights, 1) + 1e-3),
                                     requires_grad=True)
        self.raw_ambient = torch.full((3,), _inv_softplus(0.3), requires_grad=True)

    def tensors(self) -> list[torch.Tensor]:
        """The leaf tensors to optimise (the ambient only when there is no directional light)."""
        return [self.raw_ambient] + ([self.dirs, self.raw_colors] if self.num_lights else [])

    def lights(self) -> Lights:
        """The lights of the current parameters (unit directions, softplus colours and ambient)."""
        n = self.num_lights
        d = self.dirs / self.dirs.norm(dim=-1, keepdim=True).clamp_min(1e-6) if n else torch.zeros(0, 3)
        c = torch.nn.functional.softplus(self.raw_colors) if n else torch.zeros(0, 3)
        return Lights(d, c, torch.nn.functional.softplus(self.raw_ambient))


def _masked_pixel_faces(verts: torch.Tensor, faces: torch.Tensor, colors: torch.Tensor, camera: Camera,
                        lights: Lights, size: tuple[int, int], mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The face drawn at every pixel (``(H*W,)``, background clamped to face 0) and the pixels' weights (the mask
    where a face is drawn, 0 elsewhere).

    Geometry and camera are fixed while the lights are fitted: rasterize once, then each step only re-shades the
    faces (exactly what ``render()`` computes at antialias 1: the pixel takes the shaded colour of the face drawn
    there).
    """
    with torch.no_grad():
        face_index = render(verts, faces, colors, camera, lights, size).face_index[0]
    covered = face_index >= 0
    weight = (mask * covered).reshape(-1)
    return face_index.reshape(-1).clamp_min(0), weight


def estimate_lights(
    image: Any,
    mask: Any,
    vertices: torch.Tensor,
    faces: torch.Tensor,
    face_colors: torch.Tensor,
    camera: Camera,
    *,
    num_lights: int = 5,
    steps: int = 150,
    lr: float = 0.05,
    seed: int = 0,
) -> LightEstimate:
    """Estimate ``num_lights`` directional lights and an ambient colour from a photo of a known object.

    Minimises the masked error ``mean(M * (R(S; P, L) - I')^2)`` with Adam. Light colours and the ambient are kept
    non-negative (softplus); the initial directions are spread over the hemisphere facing the camera. The mesh is
    rasterized once (camera and geometry are fixed) and only the shading is recomputed per step.

    Args:
        image: (3, H, W) or (H, W, 3) photo in [0, 1] (array or tensor).
        mask: (H, W) object mask.
        vertices: (N, 3) mesh vertices.
        faces: (M, 3) faces.
        face_colors: (M, 3) known reflectance.
        camera: the (estimated) camera, batch 1.
        num_lights: number of directional lights ``K`` (>= 0).
        steps: Adam steps.
        lr: Adam learning rate.
        seed: seed of the initial directions.

    Returns:
        The :class:`LightEstimate`.

    Raises:
        TypeError: ``camera`` is not a ``meshadv.render.Camera``, or ``num_lights``, ``steps``, ``lr`` or ``seed`` has
            the wrong type.
        ValueError: bad shapes, empty mask, negative ``num_lights``/``steps``/``seed`` or a non-positive ``lr``.
    """
    _check_light_options(camera, num_lights, steps, lr, seed)
    img = as_image(image)
    m = as_mask(mask)
    if tuple(m.shape) != tuple(img.shape[1:]):
        raise ValueError(f"mask shape {tuple(m.shape)} does not match image shape {tuple(img.shape[1:])}")
    if float(m.sum()) < 1.0:
        raise ValueError("mask is empty")
    size = (int(img.shape[1]), int(img.shape[2]))
    verts, faces_t = as_geometry(vertices, faces)
    colors = torch.as_tensor(face_colors, dtype=torch.float32).detach()
    toward_camera = (camera.eye() - camera.target())[0].detach().float()
    params = _LightParameters(num_lights, toward_camera, seed)
    opt = torch.optim.Adam(params.tensors(), lr=lr)
    best_loss, best = float("inf"), None
    pix_faces, weight = _masked_pixel_faces(verts, faces_t, colors, camera, params.lights().detach(), size, m)
    target = img.reshape(3, -1).T
    denom = weight.sum().clamp_min(1.0) * 3.0
    for _ in range(steps + 1):
        opt.zero_grad()
        lights = params.lights()
        shaded = shade(verts, faces_t, colors, lights, camera, two_sided=True)[0]
        loss = (((shaded[pix_faces] - target) ** 2).sum(dim=1) * weight).sum() / denom
        if float(loss.detach()) < best_loss:
            best_loss = float(loss.detach())
            best = lights.detach()
        loss.backward()
        opt.step()
    return LightEstimate(best, best_loss)


def _check_light_options(camera: Camera, num_lights: int, steps: int, lr: float, seed: int) -> None:
    """Raise naming the first bad argument of :func:`estimate_lights`."""
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a meshadv.render.Camera, got {type(camera).__name__}")
    _validate.non_negative_int("num_lights", num_lights)
    _validate.non_negative_int("steps", steps)
    _validate.positive_float("lr", lr)
    _validate.seed("seed", seed)


def light_errors(estimated: Lights, true: Lights) -> dict[str, float]:
    """Summary errors between two light sets (which may have different numbers of lights).

    * ``direction_error``: angle (degrees) between the colour-weighted mean light directions (the direction a face
      must point to receive the most direct light);
    * ``intensity_error``: relative error of the total directional intensity ``sum_j mean(colour_j)``;
    * ``ambient_error``: mean absolute error of the ambient colour.

    Args:
        estimated: lights of batch 1.
        true: lights of batch 1.
    """

    def summary(lights: Lights) -> tuple[torch.Tensor, float, torch.Tensor]:
        """Colour-weighted sum of the unit directions, total directional intensity, ambient colour."""
        d = lights.directions[0].detach().float()
        d = d / d.norm(dim=-1, keepdim=True).clamp_min(1e-9)
        w = lights.colors[0].detach().float().mean(dim=-1)
        return (w[:, None] * d).sum(dim=0), float(w.sum()), lights.ambient[0].detach().float()

    v_e, s_e, a_e = summary(estimated)
    v_t, s_t, a_t = summary(true)
    if float(v_e.norm()) < 1e-9 or float(v_t.norm()) < 1e-9:
        angle = float("nan")
    else:
        cos = float(torch.dot(v_e, v_t) / (v_e.norm() * v_t.norm()))
        angle = math.degrees(math.acos(max(-1.0, min(1.0, cos))))
    return {
        "direction_error": angle,
        "intensity_error": abs(s_e - s_t) / max(s_t, 1e-9),
        "ambient_error": float((a_e - a_t).abs().mean()),
    }


def masked_rmse(a: Any, b: Any, mask: Any) -> float:
    """Root mean squared difference of two (3, H, W) / (H, W, 3) images inside ``mask``.

    Raises:
        ValueError: the shapes differ or the mask is empty.
    """
    x = np.asarray(a, dtype=np.float64)
    y = np.asarray(b, dtype=np.float64)
    m = np.asarray(mask, dtype=np.float64)
    if x.shape != y.shape:
        raise ValueError(f"images must have the same shape, got {x.shape} and {y.shape}")
    if x.ndim == 3 and x.shape[0] == 3:
        x, y = x.transpose(1, 2, 0), y.transpose(1, 2, 0)
    if m.shape != x.shape[:2]:
        raise ValueError(f"mask shape {m.shape} does not match image {x.shape[:2]}")
    if m.sum() < 1:
        raise ValueError("mask is empty")
    return float(np.sqrt((((x - y) ** 2) * m[..., None]).sum() / (3 * m.sum())))



