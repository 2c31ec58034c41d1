"""Mitsuba's photos of a black-box experiment: the photo of the hidden world with the camera and lights estimated from
it (:func:`estimate_parameters`), the photo of the world without the attacker's objects (:func:`background_photo`),
and what the attack optimised rendered by Mitsuba under the *estimated* camera and lights, composited over the
background photo (:func:`estimated_view_spec`, :func:`composite`: the diagnostic of renderer vs parameter
mismatch).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Optional, Sequence

import torch

from meshadv import _validate
from meshadv.render import Lights, ViewSet, render
from meshadv.transfer.estimation import as_geometry, estimate_camera, estimate_lights, light_errors, masked_rmse
from meshadv.transfer.mitsuba_process import MitsubaImage, render_mask, render_scenes
from meshadv.transfer.mitsuba_spec import MitsubaLights, SceneSpec, scene_spec
from meshadv.transfer.setups import HiddenScene

if TYPE_CHECKING:
    from meshadv.render import Camera, Lights, ViewSet
    from meshadv.transfer.estimation import CameraEstimate

__all__ = ["Estimation", "background_photo", "composite", "estimate_parameters", "estimated_view_spec"]


@dataclass(frozen=True)
class Estimation:
    """Camera and light estimates of a black-box experiment and their errors.

    Attributes:
        views: the estimated ``ViewSet`` (one view) the attack uses.
        errors: camera errors (``azimuth_error``, ``elevation_error`` in degrees, ``distance_error`` relative), the
            masked RMSE of meshadv's re-render under the estimates vs the photo (``light_rmse``), the mask IoU
            (``mask_iou``) and, when the true lights are directional, ``direction_error`` etc.
        photo: (3, H, W) the Mitsuba photo (the benign object under the hidden parameters; the pipelines score
            it as the benign render); mask: (H, W) the object's mask.
    """

    views: ViewSet
    errors: dict[str, float]
    photo: torch.Tensor
    mask: torch.Tensor


def estimate_parameters(
    mesh: Any,
    hidden: HiddenScene,
    *,
    known: Optional[Any] = None,
    light_faces: Optional[tuple[int, int]] = None,
    num_lights: int = 5,
    camera_steps: int = 60,
    light_steps: int = 120,
    camera_size: int = 128,
    variant: Optional[str] = None,
    timeout: float = 1800.0,
) -> Estimation:
    """Steps 1-2 of the pipeline: render the photo with Mitsuba, estimate the camera from the mask, then the lights.

    Args:
        mesh: the benign object (world space) placed in the hidden world.
        hidden: the hidden world.
        known: the geometry the attacker knows and segments in the photo (its mask and shading are fitted); default
            ``mesh``. For a scene, the merged mesh of its known objects.
        light_faces: ``(start, stop)``: fit the lights only on the pixels where one of the faces ``start:stop`` of
            ``known`` is the visible surface (the attacked object of a scene: the lighting where it stands, which in a
            room with an area light differs from the average over the scene; occlusion by the other objects is
            respected). ``None``: every pixel of ``known``. The camera is always fitted on all of ``known``.
        num_lights: directional lights to estimate.
        camera_steps: Adam steps of the camera estimation.
        light_steps: Adam steps of the light estimation.
        camera_size: the mask is average-pooled to at most this size for the camera fit.
        variant: Mitsuba variant.
        timeout: seconds per Mitsuba call.

    Returns:
        The :class:`Estimation`; ``errors["light_rmse"]`` is measured over the pixels the lights were fitted on,
        ``errors["light_fit_pixels"]`` counts them.

    Raises:
        TypeError: ``hidden`` is not a :class:`~meshadv.transfer.setups.HiddenScene`; ``num_lights``,
            ``camera_steps`` or ``light_steps`` is not an integer.
        ValueError: ``light_faces`` is not a non-empty range of ``known``'s faces, or selects no visible pixel;
            ``camera_size`` < 8; a negative ``num_lights``, ``camera_steps`` or ``light_steps``.
    """
    if not isinstance(hidden, HiddenScene):
        raise TypeError(f"hidden must be a HiddenScene, got {type(hidden).__name__}")
    if isinstance(camera_size, bool) or not isinstance(camera_size, int) or camera_size < 8:
        raise ValueError(f"camera_size must be an int >= 8, got {camera_size!r}")
    for name, value in (("num_lights", num_lights), ("camera_steps", camera_steps), ("light_steps", light_steps)):
        _validate.non_negative_int(name, value)  # checked here, not after the photo is rendered
    known = mesh if known is None else known
    _check_light_faces(light_faces, int(known.faces.shape[0]))
    photo, mask = _photo_and_mask(mesh, known, hidden, variant, timeout)
    verts, faces = as_geometry(known.vertices, known.faces)
    colors = torch.as_tensor(known.face_colors, dtype=torch.float32).detach()
    cam_est = estimate_camera(_pooled(mask, camera_size), verts, faces, viewing_angle=hidden.viewing_angle,
                              steps=camera_steps)
    camera = cam_est.camera()
    light_mask = mask if light_faces is None else _light_mask(mask, light_faces, verts, faces, colors, camera,
                                                              hidden.image_size)
    light_est = estimate_lights(photo, light_mask, verts, faces, colors, camera, num_lights=num_lights,
                                steps=light_steps)
    errors = _estimation_errors(hidden, cam_est, light_est.lights, photo, light_mask, verts, faces, colors)
    return Estimation(ViewSet(camera, light_est.lights), errors, photo, mask)


def _photo_and_mask(mesh: Any, known: Any, hidden: HiddenScene, variant: Optional[str],
                    timeout: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Mitsuba's photo of ``mesh`` in the hidden world ``(3, H, W)`` and the mask of the ``known`` geometry under
    the hidden camera ``(H, W)`` (the attacker's segmentation of the photo)."""
    photo = render_scenes([hidden.spec(mesh)], variant=variant, timeout=timeout)[0]
    mask = render_mask(known, hidden.mitsuba_camera(), hidden.image_size, variant=variant, timeout=timeout)
    return torch.from_numpy(photo.chw()), torch.from_numpy(mask)


def _estimation_errors(hidden: HiddenScene, cam_est: CameraEstimate, lights: Lights, photo: torch.Tensor,
                       light_mask: torch.Tensor, verts: torch.Tensor, faces: torch.Tensor,
                       colors: torch.Tensor) -> dict[str, float]:
    """The errors of :class:`Estimation`: the camera's against the hidden one, the mask IoU, the light fit on the
    fitted pixels, the lights' against the hidden world's directional lights (when it has some) and the estimated
    camera itself."""
    errors = cam_est.errors(hidden.camera["distance"], hidden.camera["azimuth"], hidden.camera["elevation"])
    errors["mask_iou"] = cam_est.iou
    errors.update(_light_fit_errors(photo, light_mask, verts, faces, colors, cam_est.camera(), lights,
                                    hidden.image_size))
    if hidden.lights is not None:
        errors.update(_true_light_errors(lights, hidden.lights, hidden.environment is not None))
    errors.update(estimated_azimuth=cam_est.azimuth, estimated_elevation=cam_est.elevation,
                  estimated_distance=cam_est.distance)
    return errors


def _check_light_faces(light_faces: Optional[tuple[int, int]], num_faces: int) -> None:
    """Raise ValueError unless ``light_faces`` is None or a non-empty ``(start, stop)`` range of ``num_faces``."""
    if light_faces is not None and not (len(light_faces) == 2 and 0 <= light_faces[0] < light_faces[1] <= num_faces):
        raise ValueError(f"light_faces must be (start, stop) with 0 <= start < stop <= {num_faces}, got {light_faces}")


def _pooled(mask: torch.Tensor, size: int) -> torch.Tensor:
    """``mask`` average-pooled to ``size`` when larger: the silhouette fit does not need full resolution (NDC is
    size-independent)."""
    if mask.shape[-1] > size:
        return torch.nn.functional.adaptive_avg_pool2d(mask[None, None], size)[0, 0]
    return mask


def _light_mask(mask: torch.Tensor, light_faces: tuple[int, int], verts: torch.Tensor, faces: torch.Tensor,
                colors: torch.Tensor, camera: Camera, image_size: tuple[int, int]) -> torch.Tensor:
    """``mask`` restricted to the pixels where one of the faces ``light_faces`` is visible under ``camera``.

    Raises:
        ValueError: those faces cover no pixel of ``mask``.
    """
    with torch.no_grad():
        visible = render(verts, faces, colors, camera, Lights.default(), image_size).face_index[0]
    light_mask = mask * ((visible >= light_faces[0]) & (visible < light_faces[1])).float()
    if float(light_mask.sum()) < 1.0:
        raise ValueError("light_faces: those faces cover no pixel of the photo under the estimated camera")
    return light_mask


def _light_fit_errors(photo: torch.Tensor, light_mask: torch.Tensor, verts: torch.Tensor, faces: torch.Tensor,
                      colors: torch.Tensor, camera: Camera, lights: Lights,
                      image_size: tuple[int, int]) -> dict[str, float]:
    """``light_rmse`` (meshadv's render under the estimates vs the photo, on the fitted pixels meshadv covers) and
    ``light_fit_pixels`` (their count)."""
    with torch.no_grad():
        ours = render(verts, faces, colors, camera, lights, image_size, background=(0.0, 0.0, 0.0))
    both = (light_mask.numpy() > 0.5) & (ours.alpha[0, 0].numpy() > 0.5)
    rmse = masked_rmse(ours.image[0].numpy(), photo.numpy(), both) if both.any() else float("nan")
    return {"light_rmse": rmse, "light_fit_pixels": float(both.sum())}


def _true_light_errors(estimated: Lights, true_lights: MitsubaLights, has_environment: bool) -> dict[str, float]:
    """Errors of the estimated lights against the hidden world's directional lights (no ``ambient_error`` when
    ``has_environment``: the environment map is the true ambient, no single colour to compare with)."""
    true = Lights(torch.from_numpy(true_lights.directions), torch.from_numpy(true_lights.colors),
                  torch.from_numpy(true_lights.ambient))
    errors = light_errors(estimated, true)
    if has_environment:
        errors.pop("ambient_error", None)
    return errors


def background_photo(hidden: HiddenScene, exclude: Sequence[str] = (), *, variant: Optional[str] = None,
                     timeout: float = 1800.0) -> torch.Tensor:
    """The hidden world rendered by Mitsuba without the attacker's objects (:meth:`HiddenScene.background_spec`):
    ``(3, H, W)``.

    It stands for a photo of the background taken without the object, composited behind meshadv's renders during
    the attack (the paper composites its renders over the real photo).

    Args:
        hidden: the hidden world.
        exclude: base-scene shapes to drop as well (the attacker's known objects).
        variant: Mitsuba variant.
        timeout: seconds for the Mitsuba call.

    Raises:
        MitsubaRenderError: the render failed.
    """
    spec = hidden.background_spec(exclude)
    return torch.from_numpy(render_scenes([spec], variant=variant, timeout=timeout)[0].chw())


def estimated_view_spec(mesh: Any, record: dict[str, Any], hidden: HiddenScene, *, seed: int = 0) -> SceneSpec:
    """Mitsuba's scene of what the attack optimised: ``mesh`` under the *estimated* camera and lights.

    Directional lights and a constant ambient (no environment map, no base scene), direct light only
    (``max_depth = 2``), black background: composite the result over the background photo with its alpha
    (:func:`composite`). Comparing this render with meshadv's separates the renderer mismatch (anti-aliasing,
    Monte-Carlo noise, shadows, ambient occlusion) from the parameter mismatch (estimated vs true camera and lights).

    Args:
        mesh: the object (or the merged known objects) in world space.
        record: the estimated view (``ViewSet.to_records()[0]``).
        hidden: the hidden world (for the image size and samples per pixel).
        seed: Mitsuba sampler seed.

    Returns:
        The scene spec.
    """
    return scene_spec(mesh, record, lights=record, image_size=hidden.image_size, spp=hidden.spp, max_depth=2,
                      background=(0.0, 0.0, 0.0), seed=seed)


def composite(image: MitsubaImage, background: torch.Tensor) -> torch.Tensor:
    """A Mitsuba render made over black (premultiplied by its alpha) composited over a background.

    Args:
        image: the render (its ``alpha`` is the coverage).
        background: ``(3, H, W)`` tensor in ``[0, 1]``.

    Returns:
        ``(3, H, W)`` float32 ``clamp(rgb + (1 - alpha) * background, 0, 1)``.

    Raises:
        TypeError: ``background`` is not a tensor.
        ValueError: the background's shape does not match the image.
    """
    if not isinstance(background, torch.Tensor):
        raise TypeError(f"background must be a (3, H, W) torch tensor, got {type(background).__name__}")
    rgb = torch.from_numpy(image.chw())
    if tuple(background.shape) != tuple(rgb.shape):
        raise ValueError(f"background {tuple(background.shape)} must match the image {tuple(rgb.shape)}")
    alpha = torch.from_numpy(image.alpha)[None]
    return (rgb + (1.0 - alpha) * background.to(rgb.dtype)).clamp(0.0, 1.0)
