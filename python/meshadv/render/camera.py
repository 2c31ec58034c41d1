"""Cameras in Neural Mesh Renderer (NMR) conventions, differentiable in PyTorch.

A :class:`Camera` holds a batch of ``B`` views. It is built either from spherical angles around the origin
(:meth:`Camera.spherical`, NMR ``get_points_from_angles``) or from an explicit eye / at / up triple
(:meth:`Camera.look_at`). Every quantity is a torch tensor, so gradients reach ``distance``, ``azimuth``,
``elevation``, ``tilt``, ``viewing_angle``, ``eye`` and ``at`` through autograd.

Conventions (see docs/ARCHITECTURE.md): world space is right-handed, Y up; angles are in degrees;
``eye = d * (cos(el) sin(az), sin(el), -cos(el) cos(az))``; the view basis is NMR's
``z = normalize(at - eye)``, ``x = normalize(cross(up, z))``, ``y = cross(z, x)``; tilt rotates the up vector
counter-clockwise in the image about the viewing axis; perspective ``x_ndc = x_view / (z_view * tan(fov / 2))``.

Degenerate up vectors (stable choice):
    * Spherical cameras compute the view basis in closed form from the angles:
      ``x = s * (cos(az), 0, sin(az))`` with ``s = +1`` when ``cos(el) >= 0`` and ``-1`` otherwise (decided on the
      elevation in degrees wrapped to [-90, 270), so ``s = +1`` exactly on [-90, 90] in any precision). This is exactly
      ``normalize(cross(+Y, z))`` wherever that is defined (so NMR's picture, including its 180 degree flip past the
      pole), and at ``elevation = +-90`` it is the limit from the equator side. Its gradient with respect to azimuth is
      therefore finite and correct everywhere, including at the poles.
    * Explicit ``look_at`` cameras normalise with ``eps``; when ``|cross(up, z)|`` is below ``1e-6`` the world axis
      least aligned with ``z`` is used as the up vector instead (the gradient then flows only through ``z``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Union

import torch

from ..util.spherical import spherical_direction
from ._checks import as_float_tensor, batch_selector, require_instance
from ._ops import small_matmul
from .rasterize import _native

__all__ = ["Camera", "TensorLike"]

#: Scalars, sequences or tensors accepted wherever a camera parameter is expected.
TensorLike = Union[float, int, Sequence[float], torch.Tensor]

_EPS = 1e-12
_DEGENERATE = 1e-6


def _common_dtype(values: Sequence[TensorLike]) -> torch.dtype:
    """The floating dtype of the first floating tensor among ``values`` (float32 if none)."""
    for v in values:
        if isinstance(v, torch.Tensor) and v.is_floating_point():
            return v.dtype
    return torch.float32


def _common_device(values: Sequence[TensorLike]) -> torch.device:
    """The device of the first tensor among ``values`` (CPU if none)."""
    for v in values:
        if isinstance(v, torch.Tensor):
            return v.device
    return torch.device("cpu")


def _batch_scalars(named: dict, dtype: torch.dtype, device: torch.device) -> dict:
    """Turn scalar-or-(B,) parameters into tensors of one common shape (B,)."""
    tensors = {}
    for name, value in named.items():
        t = as_float_tensor(value, name, dtype, device)
        if t.dim() > 1:
            raise ValueError(f"{name} must be a scalar or a 1-D tensor of shape (B,), got shape {tuple(t.shape)}")
        tensors[name] = t.reshape(-1)
    sizes = {t.shape[0] for t in tensors.values()}
    sizes.discard(1)
    if len(sizes) > 1:
        shapes = {k: tuple(v.shape) for k, v in tensors.items()}
        raise ValueError(f"camera parameters have incompatible batch sizes: {shapes}")
    batch = sizes.pop() if sizes else 1
    if batch == 0:
        raise ValueError("camera parameters must hold at least one view (batch size 0)")
    return {k: v.expand(batch) if v.shape[0] != batch else v for k, v in tensors.items()}


def _batch_vectors(named: dict, dtype: torch.dtype, device: torch.device, batch: int) -> dict:
    """Turn (3,)-or-(B,3) parameters into tensors of shape (B,3) broadcast to ``batch``."""
    out = {}
    for name, value in named.items():
        t = as_float_tensor(value, name, dtype, device)
        if t.dim() == 1:
            t = t.unsqueeze(0)
        if t.dim() != 2 or t.shape[1] != 3:
            raise ValueError(f"{name} must have shape (3,) or (B, 3), got {tuple(t.shape)}")
        if t.shape[0] == 0:
            raise ValueError(f"{name} must hold at least one view (batch size 0)")
        out[name] = t
    sizes = {t.shape[0] for t in out.values()} | {batch}
    sizes.discard(1)
    if len(sizes) > 1:
        shapes = {k: tuple(v.shape) for k, v in out.items()}
        raise ValueError(f"camera vectors have incompatible batch sizes: {shapes}")
    b = sizes.pop() if sizes else 1
    return {k: v.expand(b, 3) if v.shape[0] != b else v for k, v in out.items()}


def _normalize(v: torch.Tensor) -> torch.Tensor:
    """Normalise the last axis, eps-safe (zero vectors stay zero with zero gradient) and overflow-safe.

    The vector is first divided by its largest absolute component, so squaring inside the norm cannot overflow
    (``[0, 1e20, 0]`` in float32 would otherwise have an infinite norm and normalise to zero).
    """
    scale = v.detach().abs().amax(dim=-1, keepdim=True)
    scale = torch.where(scale > 0, scale, torch.ones_like(scale))
    v = v / scale
    return v / v.norm(dim=-1, keepdim=True).clamp_min(_EPS)


def _min_viewing_angle() -> float:
    """The narrowest perspective field of view in degrees, the native core's ``MIN_VIEWING_ANGLE`` (narrower views
    project unit coordinates beyond float32 screen coordinates; the render binary refuses the same)."""
    return float(_native().MIN_VIEWING_ANGLE)


@dataclass(frozen=True)
class Camera:
    """A batch of ``B`` pinhole (or orthographic) cameras in NMR conventions.

    Build with :meth:`Camera.spherical` or :meth:`Camera.look_at`; the dataclass fields are the batched parameters.
    Exactly one of the two groups (``distance``/``azimuth``/``elevation``) or (``eye_position``/``at``/``up``) is set.

    Attributes:
        viewing_angle: (B,) full field of view in degrees (perspective).
        tilt: (B,) roll of the up vector about the viewing axis, degrees, counter-clockwise in the image.
        near: (B,) near clipping depth (view-space z).
        far: (B,) far clipping depth.
        ortho_scale: (B,) half the visible extent for orthographic cameras.
        orthographic: True for an orthographic projection (one flag for the whole batch).
        distance: (B,) distance from the origin (spherical cameras), else None.
        azimuth: (B,) degrees (spherical cameras), else None.
        elevation: (B,) degrees (spherical cameras), else None.
        eye_position: (B,3) camera position (look-at cameras), else None.
        at: (B,3) point looked at (look-at cameras), else None.
        up: (B,3) up vector before tilt (look-at cameras), else None.

    Example:
        >>> cam = Camera.spherical(2.7, azimuth=[0.0, 90.0], elevation=30.0)
        >>> cam.project(torch.zeros(1, 3)).shape
        torch.Size([2, 1, 3])
    """

    viewing_angle: torch.Tensor
    tilt: torch.Tensor
    near: torch.Tensor
    far: torch.Tensor
    ortho_scale: torch.Tensor
    orthographic: bool = False
    distance: torch.Tensor | None = None
    azimuth: torch.Tensor | None = None
    elevation: torch.Tensor | None = None
    eye_position: torch.Tensor | None = None
    at: torch.Tensor | None = None
    up: torch.Tensor | None = None

    # ------------------------------------------------------------------ constructors
    @classmethod
    def spherical(
        cls,
        distance: TensorLike,
        azimuth: TensorLike = 0.0,
        elevation: TensorLike = 0.0,
        tilt: TensorLike = 0.0,
        viewing_angle: TensorLike = 30.0,
        near: TensorLike = 0.1,
        far: TensorLike = 100.0,
        orthographic: bool = False,
        ortho_scale: TensorLike = 1.0,
    ) -> Camera:
        """Cameras on a sphere around the origin, looking at it (NMR ``get_points_from_angles``).

        Args:
            distance: scalar or (B,) distance from the origin (> 0).
            azimuth: scalar or (B,) degrees; 0 puts the camera on the -Z axis, 90 on +X.
            elevation: scalar or (B,) degrees above the XZ plane.
            tilt: scalar or (B,) degrees, counter-clockwise roll in the image.
            viewing_angle: scalar or (B,) full field of view in degrees, in (0, 180).
            near: scalar or (B,) near clipping depth (> 0 for perspective).
            far: scalar or (B,) far clipping depth (> near).
            orthographic: use an orthographic projection.
            ortho_scale: scalar or (B,) half the visible extent (orthographic only, > 0).

        Returns:
            A camera whose batch size is the common size of the (B,) arguments (1 if all are scalars).

        Raises:
            ValueError: non-finite values, bad shapes, incompatible batch sizes or out-of-range values.
        """
        values = [distance, azimuth, elevation, tilt, viewing_angle, near, far, ortho_scale]
        dtype, device = _common_dtype(values), _common_device(values)
        p = _batch_scalars(
            {
                "distance": distance,
                "azimuth": azimuth,
                "elevation": elevation,
                "tilt": tilt,
                "viewing_angle": viewing_angle,
                "near": near,
                "far": far,
                "ortho_scale": ortho_scale,
            },
            dtype,
            device,
        )
        if not orthographic and bool((p["distance"].detach() <= 0).any()):
            raise ValueError(f"distance must be > 0, got {p['distance'].detach().cpu().tolist()}")
        return cls._checked(p, orthographic)

    @classmethod
    def look_at(
        cls,
        eye: TensorLike,
        at: TensorLike = (0.0, 0.0, 0.0),
        up: TensorLike = (0.0, 1.0, 0.0),
        viewing_angle: TensorLike = 30.0,
        near: TensorLike = 0.1,
        far: TensorLike = 100.0,
        tilt: TensorLike = 0.0,
        orthographic: bool = False,
        ortho_scale: TensorLike = 1.0,
    ) -> Camera:
        """Cameras from explicit eye, target and up vectors (NMR ``look_at``).

        Args:
            eye: (3,) or (B,3) camera positions.
            at: (3,) or (B,3) points looked at.
            up: (3,) or (B,3) up vectors (need not be unit or orthogonal to the view direction).
            viewing_angle: scalar or (B,) full field of view in degrees.
            near: scalar or (B,) near clipping depth.
            far: scalar or (B,) far clipping depth.
            tilt: scalar or (B,) extra roll in degrees, counter-clockwise in the image.
            orthographic: use an orthographic projection.
            ortho_scale: scalar or (B,) half the visible extent (orthographic only).

        Returns:
            A camera of batch size B.

        Raises:
            ValueError: bad shapes, non-finite values, ``eye == at`` or a zero ``up`` vector.
        """
        values = [eye, at, up, viewing_angle, near, far, tilt, ortho_scale]
        dtype, device = _common_dtype(values), _common_device(values)
        p = _batch_scalars(
            {
                "viewing_angle": viewing_angle,
                "near": near,
                "far": far,
                "tilt": tilt,
                "ortho_scale": ortho_scale,
            },
            dtype,
            device,
        )
        batch = p["near"].shape[0]
        v = _batch_vectors({"eye": eye, "at": at, "up": up}, dtype, device, batch)
        b = v["eye"].shape[0]
        p = {k: t.expand(b) if t.shape[0] != b else t for k, t in p.items()}
        direction = (v["at"] - v["eye"]).detach()
        if not bool(torch.isfinite(direction).all()):
            raise ValueError(f"at - eye overflows {dtype} (got {direction.cpu().tolist()}); use smaller coordinates")
        if bool((direction.abs().amax(dim=-1) <= 1e-9).any()):
            raise ValueError("eye and at must differ (the viewing direction is undefined)")
        if bool((v["up"].detach().abs().amax(dim=-1) <= 1e-9).any()):
            raise ValueError("up must be a non-zero vector")
        return cls._checked({**p, "eye_position": v["eye"], "at": v["at"], "up": v["up"]}, orthographic)

    @classmethod
    def _checked(cls, fields: dict[str, torch.Tensor], orthographic: bool) -> Camera:
        """A camera from its batched tensor fields (by field name), after :meth:`_check_ranges`."""
        cam = cls(orthographic=bool(orthographic), **fields)
        cam._check_ranges()
        return cam

    def _check_ranges(self) -> None:
        """Validate the clipping range, field of view and orthographic scale."""
        near, far = self.near.detach(), self.far.detach()
        if not self.orthographic and bool((near <= 0).any()):
            raise ValueError(f"near must be > 0 for a perspective camera, got {near.cpu().tolist()}")
        if bool((near < 0).any()):
            raise ValueError(f"near must be >= 0, got {near.cpu().tolist()}")
        if bool((far <= near).any()):
            raise ValueError(f"far must be > near, got near={near.cpu().tolist()} far={far.cpu().tolist()}")
        fov = self.viewing_angle.detach()
        low = _min_viewing_angle()
        if not self.orthographic and bool(((fov < low) | (fov >= 180)).any()):
            raise ValueError(f"viewing_angle must be in [{low}, 180) degrees, got {fov.cpu().tolist()}")
        if self.orthographic and bool((self.ortho_scale.detach() <= 0).any()):
            raise ValueError(f"ortho_scale must be > 0, got {self.ortho_scale.detach().cpu().tolist()}")

    # ------------------------------------------------------------------ properties
    @property
    def is_spherical(self) -> bool:
        """True when the camera was built from spherical angles."""
        return self.distance is not None

    @property
    def batch_size(self) -> int:
        """Number of views B."""
        return int(self.near.shape[0])

    def __len__(self) -> int:
        return self.batch_size

    @property
    def dtype(self) -> torch.dtype:
        """Floating dtype of the parameters."""
        return self.near.dtype

    @property
    def device(self) -> torch.device:
        """Device of the parameters."""
        return self.near.device

    def _fields(self) -> dict:
        """All tensor fields (None for the unused group)."""
        names = [
            "viewing_angle",
            "tilt",
            "near",
            "far",
            "ortho_scale",
            "distance",
            "azimuth",
            "elevation",
            "eye_position",
            "at",
            "up",
        ]
        return {n: getattr(self, n) for n in names}

    def _replace(self, fn: Callable[[torch.Tensor], torch.Tensor]) -> Camera:
        """A camera with ``fn`` applied to each tensor field."""
        fields = {k: (fn(v) if v is not None else None) for k, v in self._fields().items()}
        return Camera(orthographic=self.orthographic, **fields)

    def to(self, device: str | torch.device | None = None, dtype: torch.dtype | None = None) -> Camera:
        """Move the parameters to ``device`` and/or cast them to ``dtype``."""
        return self._replace(lambda t: t.to(device=device, dtype=dtype))

    def detach(self) -> Camera:
        """A copy without autograd history."""
        return self._replace(lambda t: t.detach())

    def __getitem__(self, index: int | slice | torch.Tensor | Sequence[int]) -> Camera:
        """Select views; an integer keeps a batch of one.

        Raises:
            TypeError: ``index`` is not an int, slice, sequence of ints or integer/boolean tensor.
            IndexError: an index is out of range.
            ValueError: the selection is empty.
        """
        index = batch_selector(index, self.batch_size, "camera", self.device)
        return self._replace(lambda t: t[index])

    @staticmethod
    def cat(cameras: Sequence[Camera]) -> Camera:
        """Concatenate cameras along the batch axis.

        Raises:
            ValueError: empty list, or cameras of different kinds (spherical vs look-at, perspective vs orthographic).
        """
        cameras = list(cameras)
        if not cameras:
            raise ValueError("cameras must be a non-empty sequence")
        kinds = {(c.is_spherical, c.orthographic) for c in cameras}
        if len(kinds) != 1:
            raise ValueError("cameras must all be spherical or all look-at, and share the orthographic flag")
        first = cameras[0]
        fields = {}
        for name, value in first._fields().items():
            fields[name] = None if value is None else torch.cat([getattr(c, name) for c in cameras], dim=0)
        return Camera(orthographic=first.orthographic, **fields)

    # ------------------------------------------------------------------ geometry
    def eye(self) -> torch.Tensor:
        """Camera positions in world space, shape (B,3)."""
        if self.is_spherical:
            return spherical_direction(self.azimuth, self.elevation) * self.distance.unsqueeze(-1)
        return self.eye_position

    def target(self) -> torch.Tensor:
        """Points looked at, shape (B,3) (the origin for spherical cameras)."""
        if self.is_spherical:
            return torch.zeros(self.batch_size, 3, dtype=self.dtype, device=self.device)
        return self.at

    def rotation(self) -> torch.Tensor:
        """World-to-view rotation ``R`` (B,3,3) whose rows are the view axes x, y, z (tilt applied)."""
        if self.is_spherical:
            az, el = torch.deg2rad(self.azimuth), torch.deg2rad(self.elevation)
            ce, se, ca, sa = torch.cos(el), torch.sin(el), torch.cos(az), torch.sin(az)
            z = torch.stack([-ce * sa, -se, ce * ca], dim=-1)
            # sign(cos el) decided on the angle in degrees (wrapped to [-90, 270)), not on a rounded cosine: in
            # float32, cos(deg2rad(90)) is -4e-8, which would flip the image at the pole.
            wrapped = torch.remainder(self.elevation.detach() + 90.0, 360.0) - 90.0
            sign = torch.where(wrapped <= 90.0, torch.ones_like(ce), -torch.ones_like(ce))
            x0 = torch.stack([ca, torch.zeros_like(ca), sa], dim=-1) * sign.unsqueeze(-1)
        else:
            z = _normalize(self.at - self.eye_position)
            up = _normalize(self.up)
            cross = torch.cross(up, z, dim=-1)
            bad = cross.detach().norm(dim=-1) < _DEGENERATE * up.detach().norm(dim=-1).clamp_min(_EPS)
            if bool(bad.any()):
                axes = torch.eye(3, dtype=z.dtype, device=z.device)
                alt = axes[z.detach().abs().argmin(dim=-1)]
                cross = torch.where(bad.unsqueeze(-1), torch.cross(alt, z, dim=-1), cross)
            x0 = _normalize(cross)
        y0 = torch.cross(z, x0, dim=-1)
        t = torch.deg2rad(self.tilt).unsqueeze(-1)
        ct, st = torch.cos(t), torch.sin(t)
        x = ct * x0 + st * y0
        y = ct * y0 - st * x0
        return torch.stack([x, y, z], dim=-2)

    def view_direction(self) -> torch.Tensor:
        """Unit viewing directions (the view-space +z axis in world space), shape (B,3)."""
        return self.rotation()[:, 2, :]

    def _batch_verts(self, verts: torch.Tensor, name: str = "verts") -> torch.Tensor:
        """Broadcast (N,3) or (B',3) vertices against the camera batch; returns (B,N,3)."""
        require_instance(verts, torch.Tensor, name)
        if verts.dim() == 2:
            verts = verts.unsqueeze(0)
        if verts.dim() != 3 or verts.shape[-1] != 3:
            raise ValueError(f"{name} must have shape (N,3) or (B,N,3), got {tuple(verts.shape)}")
        b = self.batch_size
        if verts.shape[0] not in (1, b) and b != 1:
            raise ValueError(f"{name} batch size {verts.shape[0]} does not match the camera batch size {b}")
        out_b = max(b, verts.shape[0])
        return verts.expand(out_b, -1, -1) if verts.shape[0] != out_b else verts

    def world_to_view(self, verts_world: torch.Tensor) -> torch.Tensor:
        """Transform world-space points to view space (NMR ``look_at``).

        Args:
            verts_world: (N,3) or (B,N,3) points.

        Returns:
            (B,N,3) ``verts_view = (verts_world - eye) @ R^T``; the camera looks down +z.
        """
        verts = self._batch_verts(verts_world, "verts_world")
        rot = self.rotation().to(verts.dtype)
        eye = self.eye().to(verts.dtype)
        if rot.shape[0] != verts.shape[0]:
            rot = rot.expand(verts.shape[0], 3, 3)
            eye = eye.expand(verts.shape[0], 3)
        return small_matmul(verts - eye.unsqueeze(1), rot.transpose(1, 2))

    def project(self, verts_world: torch.Tensor) -> torch.Tensor:
        """Project world-space points to screen space.

        Args:
            verts_world: (N,3) or (B,N,3) points.

        Returns:
            (B,N,3) ``(x_ndc, y_ndc, z_view)``: NDC in [-1, 1] (+y up) for visible points, and the view depth.
            Points with ``z_view <= 0`` get meaningless NDC coordinates (the rasterizer clips them by ``near``).
        """
        verts_view = self.world_to_view(verts_world)
        x, y, z = verts_view.unbind(-1)
        b = verts_view.shape[0]
        scale = self._projection_scale(verts_view.dtype).expand(b).unsqueeze(-1)
        if self.orthographic:
            return torch.stack([x / scale, y / scale, z], dim=-1)
        # Keep the division finite for points at or behind the eye; those are clipped by near anyway.
        z_safe = torch.where(z.abs() < 1e-12, torch.full_like(z, 1e-12), z)
        return torch.stack([x / (z_safe * scale), y / (z_safe * scale), z], dim=-1)

    def _projection_scale(self, dtype: torch.dtype) -> torch.Tensor:
        """(B,) what :meth:`project` divides view coordinates by: ``ortho_scale`` (orthographic), else
        ``tan(viewing_angle / 2)`` (then times the depth), computed in ``dtype``."""
        if self.orthographic:
            return self.ortho_scale.to(dtype)
        return torch.tan(torch.deg2rad(self.viewing_angle.to(dtype)) / 2)

    def spherical_params(self) -> dict:
        """Distance, azimuth and elevation (degrees) of the eye relative to the target, as (B,) tensors.

        For spherical cameras these are the stored tensors; for look-at cameras they are derived from ``eye - at``.
        """
        if self.is_spherical:
            return {"distance": self.distance, "azimuth": self.azimuth, "elevation": self.elevation}
        rel = self.eye_position - self.at
        d = rel.norm(dim=-1)
        el = torch.rad2deg(torch.asin((rel[:, 1] / d.clamp_min(_EPS)).clamp(-1, 1)))
        az = torch.rad2deg(torch.atan2(rel[:, 0], -rel[:, 2]))
        return {"distance": d, "azimuth": az, "elevation": el}
