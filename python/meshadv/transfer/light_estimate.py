"""Step 2 of the black-box pipeline: the lights of a photo of a known object seen by a known camera.

Minimise the masked image error ``||M * (R(S; P, L) - I')||^2`` over ``K`` directional lights (direction, colour)
and an ambient colour (:func:`estimate_lights`); compare light sets (:func:`light_errors`) and images
(:func:`masked_rmse`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from meshadv import _validate
from meshadv.render import Camera, Lights, render, shade
from meshadv.transfer._inputs import as_geometry, as_image, as_mask

__all__ = ["LightEstimate", "estimate_lights", "light_errors", "masked_rmse"]


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
