"""Expectation over transformations (EOT): the random cameras, lights, renders and pixels a robust attack averages.

An attack given ``eot=Transformations(...)`` (or ``eot=N``, ``N`` samples per step with the defaults below) no longer
optimises fixed views. Its views only define a *range*: azimuth, elevation and distance from the smallest to the
largest of the views (widened by ``widen_*``, so one view still spans a neighbourhood), or the ranges given
explicitly. At every step :meth:`EOTSampler.draw_step` draws ``samples`` fresh views from the whole range:

* camera: azimuth, elevation and distance uniform in their ranges, the views' field of view, and a sub-pixel camera
  shift (eye and target moved together in the image plane by up to ``shift`` pixels in x and y, uniform);
* lights: NMR's head light (:meth:`meshadv.render.Lights.default`), its direction perturbed by Gaussian noise of
  relative standard deviation ``light_direction`` and its colour and ambient scaled by ``1 + U[-x, x]`` with
  ``x = light_intensity`` (:meth:`meshadv.render.ViewSet.jitter`);
* render: a supersampling factor drawn from ``antialias`` and an image size scaled by ``U[image_scale]`` (a colour
  background only: a photo or a row crop keeps the setup's size; the victim resizes its input itself);
* pixels: a Gaussian blur of standard deviation ``U[0, blur]`` pixels and Gaussian noise of standard deviation
  ``U[0, noise]``, per image, clamped to ``[0, 1]`` (differentiable, :func:`transform_images`), applied to what the
  victim sees (:class:`TransformedVictim`), not to the renders the perceptual loss is computed on.

Success is never judged on those images. :meth:`EOTSampler.draw_check` and :meth:`EOTSampler.draw_eval` draw fresh
spherical views of the range (head lights, no shift, the setup's own render, no blur or noise: a plain camera at an
unseen pose): the attack keeps the least distorted parameters that hold on a check draw, and the result's success is
measured on an evaluation draw made after the optimisation. The three draws come from three generators seeded from the
attack's seed (:func:`stream_seed`), so a run is reproducible and the evaluation views do not depend on how many steps
or checks ran.

Example:
    >>> import torch
    >>> from meshadv.render import RenderSetup, ViewSet
    >>> views = ViewSet.orbit([150.0, 180.0, 210.0], elevation=10.0, distance=2.7)
    >>> sampler = EOTSampler(Transformations(samples=4), views, RenderSetup(image_size=64))
    >>> sampler.ranges.azimuth
    (140.0, 220.0)
    >>> draw = sampler.draw_step(torch.Generator().manual_seed(0))
    >>> len(draw.views), draw.setup.antialias in (1, 2)
    (4, True)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any, Dict, Optional, Sequence, Tuple, Union

import torch
import torch.nn.functional as F
from torch import Tensor

from meshadv import _validate
from meshadv.attacks.outputs import slice_output
from meshadv.render.camera import Camera
from meshadv.render.lighting import Lights
from meshadv.render.setup import RenderSetup
from meshadv.render.views import ViewSet

__all__ = ["Transformations", "ViewRange", "StepDraw", "EOTSampler", "TransformedVictim", "as_transformations",
           "check_margins", "transform_images", "stream_seed", "STEP_STREAM", "CHECK_STREAM", "EVAL_STREAM"]

#: Streams of :func:`stream_seed`: the step draws, the check draws and the evaluation draw.
STEP_STREAM, CHECK_STREAM, EVAL_STREAM = 0, 1, 2

Range = Tuple[float, float]


def stream_seed(seed: int, stream: int) -> int:
    """The seed of random stream ``stream`` of an attack seeded ``seed`` (a valid seed, distinct per stream).

    >>> stream_seed(0, 0) != stream_seed(0, 1)
    True
    """
    return (int(seed) * 1_000_003 + 7919 * int(stream)) % _validate.MAX_SEED


def _range(name: str, value: Any, *, low: Optional[float] = None) -> Optional[Range]:
    """``None`` or a ``(lo, hi)`` pair of finite floats with ``lo <= hi`` (and ``lo >= low``)."""
    if value is None:
        return None
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 2:
        raise TypeError(f"{name} must be None or a (low, high) pair, got {value!r}")
    lo = _validate.finite_float(f"{name}[0]", value[0], low=low)
    hi = _validate.finite_float(f"{name}[1]", value[1], low=low)
    if hi < lo:
        raise ValueError(f"{name} must be (low, high) with low <= high, got {value!r}")
    return lo, hi


@dataclass(frozen=True)
class Transformations:
    """The distribution of views, renders and pixels of an EOT attack (see the module docstring).

    Attributes:
        samples: views drawn afresh at every step (the gradient averages over them), ``>= 1``.
        azimuth: ``(low, high)`` degrees, or ``None``: the attack views' range widened by ``widen_azimuth``.
        elevation: ``(low, high)`` degrees, or ``None``: the views' range widened by ``widen_elevation``.
        distance: ``(low, high)`` camera distance, or ``None``: the views' range scaled by ``1 -+ widen_distance``.
        widen_azimuth: degrees added on both sides of the views' azimuth range, ``>= 0``.
        widen_elevation: degrees added on both sides of the views' elevation range, ``>= 0``.
        widen_distance: relative widening of the views' distance range, in ``[0, 1)``.
        shift: largest sub-pixel camera shift in x and y, pixels, ``>= 0``.
        light_direction: relative standard deviation of the head light's direction noise, ``>= 0``.
        light_intensity: largest relative change of the light colour and ambient, in ``[0, 1)``.
        antialias: supersampling factors drawn from (uniformly), each ``>= 1``.
        image_scale: ``(low, high)`` factor of the setup's image size, ``low > 0``.
        blur: largest Gaussian blur standard deviation, pixels, ``>= 0``.
        noise: largest Gaussian pixel-noise standard deviation (``[0, 1]`` images), ``>= 0``.
        check_views: fresh views of a success check, ``>= 1``.
        check_every: steps between checks (a check also follows a round's last step), ``>= 1``.
        eval_views: fresh views the result's success is measured on, ``>= 1``.

    Raises:
        TypeError / ValueError: a field of the wrong type or out of range, naming it.
    """

    samples: int = 4
    azimuth: Optional[Range] = None
    elevation: Optional[Range] = None
    distance: Optional[Range] = None
    widen_azimuth: float = 10.0
    widen_elevation: float = 5.0
    widen_distance: float = 0.1
    shift: float = 0.5
    light_direction: float = 0.3
    light_intensity: float = 0.3
    antialias: Tuple[int, ...] = (1, 2)
    image_scale: Range = (0.875, 1.125)
    blur: float = 0.7
    noise: float = 0.02
    check_views: int = 8
    check_every: int = 5
    eval_views: int = 12

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        for name in ("samples", "check_views", "check_every", "eval_views"):
            set_(self, name, _validate.positive_int(name, getattr(self, name), high=4096))
        set_(self, "azimuth", _range("azimuth", self.azimuth))
        set_(self, "elevation", _range("elevation", self.elevation))
        if self.elevation is not None and (self.elevation[0] < -89.0 or self.elevation[1] > 89.0):
            raise ValueError(f"elevation must lie within [-89, 89] degrees, got {self.elevation!r}")
        set_(self, "distance", _range("distance", self.distance, low=0.0))
        if self.distance is not None and self.distance[0] <= 0:
            raise ValueError(f"distance must be > 0, got {self.distance!r}")
        for name in ("widen_azimuth", "widen_elevation", "shift", "light_direction", "blur", "noise"):
            set_(self, name, _validate.finite_float(name, getattr(self, name), low=0.0))
        for name in ("widen_distance", "light_intensity"):
            set_(self, name, _validate.finite_float(name, getattr(self, name), low=0.0, high=1.0, high_open=True))
        if isinstance(self.antialias, (str, bytes)) or not hasattr(self.antialias, "__iter__"):
            raise TypeError(f"antialias must be a sequence of integers >= 1, got {self.antialias!r}")
        levels = tuple(_validate.positive_int(f"antialias[{i}]", a, high=8) for i, a in enumerate(self.antialias))
        if not levels:
            raise ValueError("antialias must hold at least one supersampling factor")
        set_(self, "antialias", levels)
        scale = _range("image_scale", self.image_scale, low=0.0)
        if scale is None or scale[0] <= 0 or scale[1] > 4:
            raise ValueError(f"image_scale must be (low, high) with 0 < low <= high <= 4, got {self.image_scale!r}")
        set_(self, "image_scale", scale)

    def config(self) -> Dict[str, Any]:
        """The fields as a JSON-able dict (tuples as lists); :func:`as_transformations` reads it back."""
        out: Dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            out[f.name] = list(value) if isinstance(value, tuple) else value
        return out


def as_transformations(value: Any, name: str = "eot") -> Optional[Transformations]:
    """``None`` (no EOT), a :class:`Transformations`, an int (that many samples, defaults otherwise) or a dict of
    its fields (a sweep file's table, a ``config()``).

    Raises:
        TypeError: another type, or ``bool``; ValueError: an unknown key or a bad value, naming it.
    """
    if value is None or isinstance(value, Transformations):
        return value
    if isinstance(value, bool):
        raise TypeError(f"{name} must be None, a sample count, a dict or a Transformations, got {value!r}")
    if isinstance(value, int):
        return Transformations(samples=value)
    if isinstance(value, dict):
        known = {f.name for f in fields(Transformations)}
        unknown = sorted(set(map(str, value)) - known)
        if unknown:
            raise ValueError(f"{name} has unknown keys {unknown}; known: {sorted(known)}")
        return Transformations(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in value.items()})
    raise TypeError(f"{name} must be None, a sample count, a dict or a Transformations, got {type(value).__name__}")


@dataclass(frozen=True)
class ViewRange:
    """The camera range views are drawn from: ``(low, high)`` azimuth and elevation (degrees) and distance, and the
    field of view (degrees)."""

    azimuth: Range
    elevation: Range
    distance: Range
    viewing_angle: float

    @classmethod
    def of(cls, views: ViewSet, eot: Transformations) -> "ViewRange":
        """The range of ``views`` (spherical cameras) widened as ``eot`` says, or ``eot``'s explicit ranges.

        Raises:
            ValueError: ``views`` has look-at cameras (no azimuth / elevation to draw from), or its views' fields of
                view differ.
        """
        cam = ViewSet.require(views).camera.detach()
        if not cam.is_spherical:
            raise ValueError("views must have spherical cameras (ViewSet.orbit) for an EOT attack: their azimuth, "
                             "elevation and distance range is what fresh views are drawn from")
        fov = cam.viewing_angle
        if float(fov.max() - fov.min()) > 1e-6:
            raise ValueError(f"views must share one field of view for an EOT attack, got {fov.tolist()}")

        def widened(values: Tensor, given: Optional[Range], pad: float) -> Range:
            if given is not None:
                return given
            return float(values.min()) - pad, float(values.max()) + pad

        el = widened(cam.elevation, eot.elevation, eot.widen_elevation)
        el = (max(el[0], -89.0), min(el[1], 89.0))
        if eot.distance is not None:
            dist = eot.distance
        else:
            dist = (float(cam.distance.min()) * (1 - eot.widen_distance),
                    float(cam.distance.max()) * (1 + eot.widen_distance))
        return cls(widened(cam.azimuth, eot.azimuth, eot.widen_azimuth), el, dist, float(fov[0]))


@dataclass(frozen=True)
class StepDraw:
    """One step's transformations: the views, the render setup and the per-image blur and noise.

    Attributes:
        views: ``V`` fresh views (look-at cameras when shifted).
        setup: the render setup of the step (the attack's with a drawn ``antialias`` and ``image_size``).
        blur: float ``(V,)`` Gaussian blur standard deviation per view, pixels.
        noise: float ``(V,)`` pixel-noise standard deviation per view.
        noise_seed: seed of the pixel noise of the step.
    """

    views: ViewSet
    setup: RenderSetup
    blur: Tensor
    noise: Tensor
    noise_seed: int

    def victim(self, victim: Any) -> "TransformedVictim":
        """``victim`` seen through this step's blur and noise (:class:`TransformedVictim`)."""
        return TransformedVictim(victim, self)

    def transform(self, images: Tensor) -> Tensor:
        """The step's blur and noise applied to its renders ``(K * V, 3, H, W)`` (mesh-major: image ``k V + v`` gets
        view ``v``'s); differentiable."""
        v = len(self.views)
        k = images.shape[0] // v
        generator = torch.Generator().manual_seed(self.noise_seed)
        return transform_images(images, self.blur.repeat(k), self.noise.repeat(k), generator)


class TransformedVictim:
    """A victim that sees a step's renders after the step's blur and noise (:meth:`StepDraw.transform`); every other
    attribute (``kind``, ``name``, ``class_names``, ...) is the wrapped victim's, so the attack step treats it as the
    victim while its perceptual term still sees the clean renders."""

    def __init__(self, victim: Any, draw: StepDraw) -> None:
        self.__dict__["_victim"], self.__dict__["_draw"] = victim, draw

    def __call__(self, images: Tensor) -> Any:
        """The wrapped victim's output on the transformed ``images``."""
        return self._victim(self._draw.transform(images))

    def __getattr__(self, name: str) -> Any:
        return getattr(self.__dict__["_victim"], name)


def check_margins(attack: Any, p: Tensor, criteria: Sequence[Any], mesh: Any, edges: Tensor, victim: Any,
                  setup: RenderSetup, views: ViewSet) -> Tensor:
    """Criterion margins ``(K, V)`` of parameters ``p (K, ...)`` of ``attack`` rendered from ``views`` with
    ``setup`` (no gradient, no blur or noise): target ``k`` against the bound ``criteria[k]``."""
    num_v = len(views)
    with torch.no_grad():
        verts, colors = attack.apply(p.detach(), mesh, edges)
        images, _ = setup.render(verts, mesh.faces, colors, views)
        output = victim(images)
        return torch.stack([c.margin(slice_output(output, a * num_v, (a + 1) * num_v)).detach()
                            for a, c in enumerate(criteria)])


def _uniform(generator: torch.Generator, count: int, bounds: Range) -> Tensor:
    lo, hi = bounds
    return lo + (hi - lo) * torch.rand(count, generator=generator, dtype=torch.float64)


def _gaussian_kernels(sigma: Tensor, radius: int) -> Tensor:
    """Normalised 1-D Gaussian kernels ``(B, 2 radius + 1)`` of standard deviations ``sigma (B,)`` (a delta for 0)."""
    x = torch.arange(-radius, radius + 1, dtype=torch.float64)
    s = sigma.double().clamp(min=1e-3).unsqueeze(1)
    k = torch.exp(-0.5 * (x.unsqueeze(0) / s) ** 2)
    return k / k.sum(dim=1, keepdim=True)


def transform_images(images: Tensor, blur: Tensor, noise: Tensor, generator: torch.Generator) -> Tensor:
    """Blur each image with a Gaussian of its own standard deviation, add Gaussian noise of its own standard deviation
    and clamp into ``[0, 1]`` (differentiable in ``images``; border pixels are repeated for the blur).

    Args:
        images: float ``(B, C, H, W)``.
        blur: ``(B,)`` blur standard deviations in pixels, ``>= 0`` (0: none).
        noise: ``(B,)`` noise standard deviations, ``>= 0`` (0: none).
        generator: CPU generator of the noise.

    Returns:
        ``(B, C, H, W)`` images of ``images``' dtype.

    Raises:
        ValueError: ``images`` is not 4-D, or ``blur`` / ``noise`` are not ``(B,)``.
    """
    if not isinstance(images, Tensor) or images.dim() != 4:
        raise ValueError(f"images must be (B, C, H, W), got {getattr(images, 'shape', type(images).__name__)}")
    b, c, h, w = images.shape
    if tuple(blur.shape) != (b,) or tuple(noise.shape) != (b,):
        raise ValueError(f"blur and noise must be ({b},), got {tuple(blur.shape)} and {tuple(noise.shape)}")
    out = images
    if bool((blur > 0).any()):
        radius = max(1, int(math.ceil(3.0 * float(blur.max()))))
        kern = _gaussian_kernels(blur, radius).to(images.dtype).to(images.device)
        kern = kern.repeat_interleave(c, dim=0)  # (B*C, k)
        x = out.reshape(1, b * c, h, w)
        x = F.pad(x, (radius, radius, 0, 0), mode="replicate")
        x = F.conv2d(x, kern.view(b * c, 1, 1, -1), groups=b * c)
        x = F.pad(x, (0, 0, radius, radius), mode="replicate")
        x = F.conv2d(x, kern.view(b * c, 1, -1, 1), groups=b * c)
        out = x.view(b, c, h, w)
    if bool((noise > 0).any()):
        eps = torch.randn(images.shape, generator=generator, dtype=torch.float32).to(images.dtype)
        out = out + eps.to(images.device) * noise.to(images.dtype).to(images.device).view(b, 1, 1, 1)
        out = out.clamp(0.0, 1.0)
    return out


class EOTSampler:
    """Draws of one attack call: the range of its views, the step draws and the check / evaluation views.

    Args:
        eot: the transformations.
        views: the attack's views (spherical cameras): the range (:meth:`ViewRange.of`).
        setup: the attack's render setup (sizes and antialias are drawn around it).

    Raises:
        ValueError: see :meth:`ViewRange.of`.
    """

    def __init__(self, eot: Transformations, views: ViewSet, setup: RenderSetup) -> None:
        self.eot = eot
        self.ranges = ViewRange.of(views, eot)
        self.setup = setup
        self.resizable = not setup.has_photo and setup.crop_rows is None

    def _poses(self, generator: torch.Generator, count: int) -> Tuple[Tensor, Tensor, Tensor]:
        r = self.ranges
        az = _uniform(generator, count, r.azimuth)
        el = _uniform(generator, count, r.elevation)
        dist = _uniform(generator, count, r.distance)
        return az.float(), el.float(), dist.float()

    def plain_views(self, generator: torch.Generator, count: int) -> ViewSet:
        """``count`` spherical views of the range with NMR's head light (no shift, no light noise)."""
        az, el, dist = self._poses(generator, count)
        return ViewSet.orbit(az, elevation=el, distance=dist, viewing_angle=self.ranges.viewing_angle)

    def draw_check(self, generator: torch.Generator) -> ViewSet:
        """``check_views`` fresh plain views (a success check)."""
        return self.plain_views(generator, self.eot.check_views)

    def draw_eval(self, generator: torch.Generator) -> ViewSet:
        """``eval_views`` fresh plain views (the result's success)."""
        return self.plain_views(generator, self.eot.eval_views)

    def draw_step(self, generator: torch.Generator) -> StepDraw:
        """One step's ``samples`` views, render setup, blur and noise (see the module docstring); the numbers are
        drawn from ``generator`` in a fixed order."""
        eot, n = self.eot, self.eot.samples
        az, el, dist = self._poses(generator, n)
        base = ViewSet.orbit(az, elevation=el, distance=dist, viewing_angle=self.ranges.viewing_angle)
        lit = base.jitter(generator, light_direction=eot.light_direction, light_intensity=eot.light_intensity)
        antialias = eot.antialias[int(torch.randint(len(eot.antialias), (1,), generator=generator))]
        scale = float(_uniform(generator, 1, eot.image_scale))
        setup = replace(self.setup, antialias=antialias)
        if self.resizable:
            h, w = self.setup.image_size  # type: ignore[misc]
            setup = replace(setup, image_size=(max(8, round(h * scale)), max(8, round(w * scale))))
        shift = (torch.rand(n, 2, generator=generator, dtype=torch.float64) * 2 - 1) * eot.shift
        views = _shifted(lit, shift.float(), setup.image_size[1]) if eot.shift > 0 else lit  # type: ignore[index]
        blur = torch.rand(n, generator=generator, dtype=torch.float64).float() * eot.blur
        noise = torch.rand(n, generator=generator, dtype=torch.float64).float() * eot.noise
        noise_seed = int(torch.randint(0, 2**62, (1,), generator=generator))
        return StepDraw(views, setup, blur, noise, noise_seed)


def _shifted(views: ViewSet, shift: Tensor, width: int) -> ViewSet:
    """``views`` (spherical) with eye and target moved together by ``shift (V, 2)`` pixels along the image's x and y
    axes (the pixel size at the target's depth for an image ``width`` pixels wide): look-at cameras, same lights."""
    cam = views.camera.detach()
    rot = cam.rotation()  # rows: x, y, z view axes in world space
    pixel = 2.0 * cam.distance * torch.tan(torch.deg2rad(cam.viewing_angle) / 2.0) / float(width)
    offset = (shift[:, :1] * rot[:, 0] + shift[:, 1:] * rot[:, 1]) * pixel.unsqueeze(1)
    eye = cam.eye() + offset
    camera = Camera.look_at(eye, offset, torch.tensor([0.0, 1.0, 0.0]).expand_as(eye), viewing_angle=cam.viewing_angle,
                            near=cam.near, far=cam.far, tilt=cam.tilt)
    return ViewSet(camera, Lights(views.lights.directions, views.lights.colors, views.lights.ambient))


TransformationsLike = Union[None, int, Dict[str, Any], Transformations]
