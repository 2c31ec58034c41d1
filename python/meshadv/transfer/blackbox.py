"""The black-box transfer pipeline: attack a Mitsuba "photo" whose camera and lights are unknown.

The paper's pipeline (:func:`blackbox_classifier`, :func:`blackbox_detector`): a "photo" is rendered by Mitsuba
under hidden parameters (:class:`HiddenScene`); the camera is estimated from the object's mask, the lights from the
masked image (:func:`estimate_parameters`); the attack runs in meshadv with random jitter of the estimates at every
step (:mod:`meshadv.transfer.robust`); the adversarial mesh is re-rendered by Mitsuba under the hidden parameters and
tested. Every Mitsuba render runs in a child process (:mod:`meshadv.transfer.render`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable, Optional, Sequence

import numpy as np
import torch

from meshadv.transfer.controlled import _images_tensor, _top1_names
from meshadv.attacks.families import check_perturbation
from meshadv.render.setup import RenderSetup, split_setup_options
from meshadv.transfer.object_attacks import _check_smoothing, _texture_attack
from meshadv.transfer.render import MitsubaImage, render_mask, render_scenes
from meshadv.transfer.results import BlackBoxResult
from meshadv.transfer.robust import (
    DEFAULT_JITTER,
    Occluded,
    Robustness,
    _attack_estimated,
    _meshadv_margins,
    _noise_where,
    _robust_rate,
)
from meshadv.transfer.spec import MeshObject, MitsubaCamera, MitsubaLights, SceneSpec

__all__ = [
    "Estimation",
    "HiddenScene",
    "blackbox_classifier",
    "blackbox_detector",
    "composite",
    "detection_scores",
    "estimate_parameters",
    "estimated_view_spec",
    "occlusion_mask",
]

#: A one-triangle stand-in used where a scene spec needs a mesh that is then dropped.
_PLACEHOLDER_MESH = MeshObject(np.eye(3, dtype=np.float32), np.array([[0, 1, 2]]), np.ones((1, 3), np.float32))


@dataclass(frozen=True)
class HiddenScene:
    """The hidden "real world" of a black-box experiment: what Mitsuba renders, unknown to the attacker.

    Attributes:
        camera: the true spherical camera (distance, azimuth, elevation in degrees).
        viewing_angle: field of view (assumed known to the attacker).
        lights: true directional lights + ambient (or None).
        environment: optional lat-long environment map (e.g. :func:`~meshadv.transfer.environment.outdoor_environment`).
        environment_scale: multiplier of ``environment``.
        ground: optional ground plane (height, colour).
        base_scene: optional Mitsuba scene file the object is placed in.
        base_exclude: shapes of the base scene to drop (the object it replaces).
        image_size: (H, W).
        spp: samples per pixel; max_depth: path depth.
        extra_objects: other meshes of the world (beside the object and the base scene).
    """

    camera: dict[str, float]
    viewing_angle: float = 30.0
    lights: Optional[MitsubaLights] = None
    environment: Optional[np.ndarray] = None
    environment_scale: float = 1.0
    ground: Optional[tuple[float, tuple[float, float, float]]] = None
    base_scene: Optional[str] = None
    base_exclude: tuple[str, ...] = ()
    image_size: tuple[int, int] = (224, 224)
    spp: int = 64
    max_depth: int = 8
    extra_objects: tuple[MeshObject, ...] = field(default=())

    def mitsuba_camera(self) -> MitsubaCamera:
        """The true camera for Mitsuba."""
        c = self.camera
        return MitsubaCamera.spherical(c["distance"], c["azimuth"], c["elevation"], c.get("tilt", 0.0),
                                       self.viewing_angle)

    def spec(self, mesh: Any, *, seed: int = 0) -> SceneSpec:
        """The Mitsuba scene of ``mesh`` in this hidden world (the object first, then any extra objects)."""
        obj = mesh if isinstance(mesh, MeshObject) else MeshObject.from_mesh(mesh)
        return SceneSpec(
            objects=(obj,) + tuple(self.extra_objects),
            camera=self.mitsuba_camera(),
            lights=self.lights,
            image_size=self.image_size,
            spp=self.spp,
            max_depth=self.max_depth,
            background=None,
            base_scene=self.base_scene,
            base_exclude=self.base_exclude,
            environment=self.environment,
            environment_scale=self.environment_scale,
            ground=self.ground,
            seed=seed,
        )


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

    views: Any
    errors: dict[str, float]
    photo: torch.Tensor
    mask: torch.Tensor


def _merge_meshes(meshes: Sequence[Any]) -> Any:
    """One ``meshadv.mesh.Mesh`` holding all ``meshes`` (faces re-indexed, in order)."""
    from meshadv.mesh import Mesh

    verts, faces, colors, offset = [], [], [], 0
    for m in meshes:
        verts.append(torch.as_tensor(m.vertices, dtype=torch.float32))
        faces.append(torch.as_tensor(m.faces, dtype=torch.int64) + offset)
        colors.append(torch.as_tensor(m.face_colors, dtype=torch.float32))
        offset += int(m.vertices.shape[0])
    return Mesh(torch.cat(verts), torch.cat(faces), torch.cat(colors))


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
        ValueError: ``light_faces`` is not a non-empty range of ``known``'s faces, or selects no visible pixel.
    """
    from meshadv.render import Lights, ViewSet, render
    from meshadv.transfer.estimate import estimate_camera, estimate_lights, light_errors, masked_rmse

    known = mesh if known is None else known
    num_faces = int(known.faces.shape[0])
    if light_faces is not None and not (len(light_faces) == 2 and 0 <= light_faces[0] < light_faces[1] <= num_faces):
        raise ValueError(f"light_faces must be (start, stop) with 0 <= start < stop <= {num_faces}, got {light_faces}")
    photo_img = render_scenes([hidden.spec(mesh)], variant=variant, timeout=timeout)[0]
    mask_np = render_mask(known, hidden.mitsuba_camera(), hidden.image_size, variant=variant, timeout=timeout)
    photo = torch.from_numpy(photo_img.chw())
    mask = torch.from_numpy(mask_np)
    verts = torch.as_tensor(known.vertices, dtype=torch.float32).detach()
    faces = torch.as_tensor(known.faces, dtype=torch.int64)
    colors = torch.as_tensor(known.face_colors, dtype=torch.float32).detach()
    cam_mask = mask
    if mask.shape[-1] > camera_size:  # the silhouette fit does not need full resolution (NDC is size-independent)
        cam_mask = torch.nn.functional.adaptive_avg_pool2d(mask[None, None], camera_size)[0, 0]
    cam_est = estimate_camera(cam_mask, verts, faces, viewing_angle=hidden.viewing_angle, steps=camera_steps)
    camera = cam_est.camera()
    light_mask = mask
    if light_faces is not None:
        with torch.no_grad():
            visible = render(verts, faces, colors, camera, Lights.default(), hidden.image_size).face_index[0]
        light_mask = mask * ((visible >= light_faces[0]) & (visible < light_faces[1])).float()
        if float(light_mask.sum()) < 1.0:
            raise ValueError("light_faces: those faces cover no pixel of the photo under the estimated camera")
    light_est = estimate_lights(photo, light_mask, verts, faces, colors, camera, num_lights=num_lights,
                                steps=light_steps)
    errors = cam_est.errors(hidden.camera["distance"], hidden.camera["azimuth"], hidden.camera["elevation"])
    errors["mask_iou"] = cam_est.iou
    with torch.no_grad():
        ours = render(verts, faces, colors, camera, light_est.lights, hidden.image_size, background=(0.0, 0.0, 0.0))
    both = (light_mask.numpy() > 0.5) & (ours.alpha[0, 0].numpy() > 0.5)
    errors["light_rmse"] = masked_rmse(ours.image[0].numpy(), photo.numpy(), both) if both.any() else float("nan")
    errors["light_fit_pixels"] = float(both.sum())
    if hidden.lights is not None:
        true = Lights(torch.from_numpy(hidden.lights.directions), torch.from_numpy(hidden.lights.colors),
                      torch.from_numpy(hidden.lights.ambient))
        errors.update(light_errors(light_est.lights, true))
        if hidden.environment is not None:  # the environment is the true ambient: no single colour to compare with
            errors.pop("ambient_error", None)
    errors.update(estimated_azimuth=cam_est.azimuth, estimated_elevation=cam_est.elevation,
                  estimated_distance=cam_est.distance)
    return Estimation(ViewSet(camera, light_est.lights), errors, photo, mask)


def _background_image(hidden: HiddenScene, exclude: Sequence[str], variant: Optional[str],
                      timeout: float) -> torch.Tensor:
    """The hidden world rendered by Mitsuba without the attacker's objects: (3, H, W).

    It stands for a photo of the background taken without the object, composited behind meshadv's renders during
    the attack (the paper composites its renders over the real photo).
    """
    spec = hidden.spec(_PLACEHOLDER_MESH)
    spec = replace(spec, objects=(), base_exclude=tuple(hidden.base_exclude) + tuple(exclude))
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
    return SceneSpec(
        objects=(MeshObject.from_mesh(mesh),),
        camera=MitsubaCamera.from_record(record),
        lights=MitsubaLights.from_record(record),
        image_size=hidden.image_size,
        spp=hidden.spp,
        max_depth=2,
        background=(0.0, 0.0, 0.0),
        seed=seed,
    )


def composite(image: MitsubaImage, background: torch.Tensor) -> torch.Tensor:
    """A Mitsuba render made over black (premultiplied by its alpha) composited over a (3, H, W) background.

    Raises:
        ValueError: the background's shape does not match the image.
    """
    rgb = torch.from_numpy(image.chw())
    if tuple(background.shape) != tuple(rgb.shape):
        raise ValueError(f"background {tuple(background.shape)} must match the image {tuple(rgb.shape)}")
    alpha = torch.from_numpy(image.alpha)[None]
    return (rgb + (1.0 - alpha) * background.to(rgb.dtype)).clamp(0.0, 1.0)


def _attack_record(attack: Any, setup: RenderSetup, result: Any) -> dict[str, Any]:
    """Hyper-parameters and cost of the attack (and the setup's supersampling), as result-row entries."""
    config = attack.config()
    record = {k: config[k] for k in ("steps", "lr", "lambda_perceptual", "loss", "kappa", "early_stop")}
    record["antialias"] = setup.antialias
    record.update(steps_run=int(result.steps), steps_to_success=result.steps_to_success[0],
                  attack_time=float(result.wall_time))
    record.update({k: float(v) for k, v in result.distances[0].items()})
    return record


def _hwc(image: torch.Tensor) -> np.ndarray:
    return image.detach().permute(1, 2, 0).cpu().numpy()


def _finish_row(row: dict[str, Any], attack: Any, setup: RenderSetup, result: Any, robustness: Robustness,
                est: Estimation,
                adversarial_render: MitsubaImage, estimated_image: torch.Tensor, ours_image: torch.Tensor,
                adversarial: Any) -> BlackBoxResult:
    """Add what every black-box row shares to ``row`` (robustness and attack settings, estimation errors) and wrap
    it with the images (Mitsuba benign = the estimation's photo / adversarial under the hidden parameters /
    adversarial under the estimates, meshadv's render), the adversarial mesh and the attack's result."""
    row.update(robustness.to_record())
    row["pixel_noise_on"] = _noise_where(setup, robustness)
    row.update(_attack_record(attack, setup, result))
    row.update({k: float(v) for k, v in est.errors.items()})
    images = {"benign_mitsuba": _hwc(est.photo), "adversarial_mitsuba": adversarial_render.image,
              "adversarial_mitsuba_estimated": _hwc(estimated_image), "adversarial_meshadv": _hwc(ours_image)}
    return BlackBoxResult(row=dict(row), images=images, adversarial_mesh=adversarial, attack_result=result)


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

    1-2. :func:`estimate_parameters`; 3. attack in meshadv on the estimated view with jitter (``robustness.eot``
    jittered samples per step), the renders composited over the photo's background; 4. re-render the adversarial
    mesh with Mitsuba under the hidden parameters and test. As a diagnostic, Mitsuba also renders it under the
    *estimated* parameters (:func:`estimated_view_spec`).

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
        ValueError: unknown ``perturbation``, or ``texture_smoothing`` given for a shape attack or negative.
    """
    from meshadv.attacks import Misclassification, ShapeAttack, TargetedMisclassification

    check_perturbation(perturbation)
    _check_smoothing(texture_smoothing, perturbation)
    robustness = Robustness() if robustness is None else robustness
    jitter = dict(DEFAULT_JITTER if jitter is None else jitter)
    est = estimate_parameters(mesh, hidden, num_lights=num_lights, camera_steps=camera_steps,
                              light_steps=light_steps, variant=variant, timeout=timeout)
    background = _background_image(hidden, (), variant, timeout)
    setup_options, kwargs = split_setup_options(dict(attack_kwargs or {}))
    setup = RenderSetup(**{"image_size": hidden.image_size, "background": background, **setup_options})
    kwargs.setdefault("jitter", jitter or None)
    attack = _texture_attack(texture_smoothing, None, kwargs) if perturbation == "texture" else ShapeAttack(**kwargs)
    criterion = TargetedMisclassification(target) if target else Misclassification(true_class)
    result = _attack_estimated(attack, mesh, est.views, victim, criterion, robustness, setup, callback)
    adversarial = result.mesh
    bound = criterion.bind(victim)
    ours_margin, ours_image = _meshadv_margins(setup, adversarial, est.views, victim, bound)
    with torch.no_grad():
        ours_top1 = _top1_names(victim, victim(ours_image[None]))[0]
    robust_rate = _robust_rate(setup, adversarial, est.views, victim, bound, robustness)
    record = est.views.to_records()[0]
    # the benign render under the hidden parameters is the photo the estimation was made from
    images = render_scenes([hidden.spec(adversarial), estimated_view_spec(adversarial, record, hidden)],
                           variant=variant, timeout=timeout)
    estimated_image = composite(images[1], background)
    with torch.no_grad():
        logits = victim(torch.cat([est.photo[None], _images_tensor(images[:1]), estimated_image[None]]))
    margins = bound.margin(logits).tolist()
    bound_untargeted = Misclassification(true_class).bind(victim)
    names = _top1_names(victim, logits)
    row: dict[str, Any] = {
        "case_id": case_id,
        "victim": getattr(victim, "name", type(victim).__name__),
        "true_class": true_class,
        "target": target or "",
        "perturbation": perturbation,
        "view": 0,
        "success_meshadv": bool(ours_margin[0] > 0),
        "success_mitsuba_estimated": margins[2] > 0,
        "success_mitsuba": margins[1] > 0,
        "benign_adversarial_mitsuba": margins[0] > 0,
        "benign_correct_mitsuba": not bool(bound_untargeted.is_adversarial(logits[:1])[0]),
        "margin_meshadv": float(ours_margin[0]),
        "margin_mitsuba_estimated": float(margins[2]),
        "margin_mitsuba": float(margins[1]),
        "margin_benign_mitsuba": float(margins[0]),
        "robust_rate_meshadv": robust_rate,
        "top1_meshadv": ours_top1,
        "top1_mitsuba_estimated": names[2],
        "top1_benign_mitsuba": names[0],
        "top1_adversarial_mitsuba": names[1],
        "texture_smoothing": texture_smoothing,
        "spp": hidden.spp,
        "variant": images[0].variant,
    }
    return _finish_row(row, attack, setup, result, robustness, est, images[0], estimated_image, ours_image,
                       adversarial)


def occlusion_mask(objects: Sequence[Any], index: int, views: Any, image_size: Any) -> torch.Tensor:
    """Pixels where object ``index`` alone would be drawn but another of ``objects`` is in front of it.

    Args:
        objects: ``meshadv.mesh.Mesh`` objects in world space.
        index: the object of interest.
        views: a one-view ``ViewSet`` (the estimated view).
        image_size: int or (H, W).

    Returns:
        (H, W) float32, 1 where the object is occluded.

    Raises:
        ValueError: ``index`` out of range.
    """
    from meshadv.render import render

    if not 0 <= index < len(objects):
        raise ValueError(f"index {index} out of range for {len(objects)} objects")
    merged = _merge_meshes(objects)
    start = sum(int(o.faces.shape[0]) for o in objects[:index])
    stop = start + int(objects[index].faces.shape[0])
    obj = objects[index]
    with torch.no_grad():
        scene = render(merged.vertices, merged.faces, merged.face_colors, views.camera, views.lights,
                       image_size).face_index[0]
        alone = render(obj.vertices, obj.faces, obj.face_colors, views.camera, views.lights, image_size).face_index[0]
    visible = (scene >= start) & (scene < stop)
    return ((alone >= 0) & ~visible).float()


def blackbox_detector(
    scene_objects: Sequence[Any],
    object_index: int,
    hidden: HiddenScene,
    *,
    victim: Any,
    hide_class: str,
    perturbation: str = "texture",
    context: str = "photo",
    light_fit: str = "object",
    background_exclude: Sequence[str] = (),
    attack_kwargs: Optional[dict[str, Any]] = None,
    jitter: Optional[dict[str, float]] = None,
    robustness: Optional[Robustness] = None,
    texture_smoothing: Optional[int] = None,
    num_lights: int = 5,
    camera_steps: int = 60,
    light_steps: int = 120,
    variant: Optional[str] = None,
    timeout: float = 1800.0,
    score_threshold: float = 0.3,
    case_id: str = "blackbox_detector",
    callback: Optional[Callable[[Any], None]] = None,
) -> BlackBoxResult:
    """The black-box pipeline against a detector: change one object so that ``hide_class`` disappears.

    The attacker knows the geometry of ``scene_objects`` (world space; e.g. the indoor scene's desk, chair and bunny)
    but not the camera or lights. (1-2) The camera and lights are estimated from the Mitsuba photo (mask and shading
    of the known objects); (3) a texture (or shape) attack on the attacked object, with jitter, seen in a context
    chosen by ``context``; (4) the adversarial object is re-rendered by Mitsuba under the hidden parameters and the
    detector is run. The attack's criterion is :class:`~meshadv.attacks.Disappearance` at ``score_threshold`` (the
    threshold the success is measured at), with ``robustness.margin`` on top (in score units).

    Contexts:
        * ``"photo"`` (the paper's compositing): meshadv renders only the attacked object, over the Mitsuba photo
          itself; the rest of the scene is the photo's pixels (where another known object hides the attacked one
          in the estimated view, the photo is put back, :class:`~meshadv.transfer.robust.Occluded`). The photo
          still shows the benign object behind the rendered one: exact for texture attacks (same silhouette), a
          faint ghost where a shape attack moves the surface inward.
        * ``"render"``: meshadv renders every known object (only the attacked one may change) over the photo of
          the world without them (``background_exclude``); the detector then sees meshadv's shading of the whole
          scene, which differs from Mitsuba's (the indoor table scores 0.75 in meshadv, 0.96 in Mitsuba).

    Args:
        scene_objects: ``meshadv.mesh.Mesh`` objects in world space.
        object_index: which of them is perturbed (it is the object of ``hidden.spec``; the others must be part of
            ``hidden`` through its base scene or ``extra_objects``).
        hidden: the hidden world.
        victim: a detector victim.
        hide_class: the class to hide (a name of ``victim.class_names``, e.g. ``"chair"``).
        perturbation: ``"texture"`` (the object's face colours) or ``"shape"`` (its vertices).
        context: ``"photo"`` or ``"render"`` (see above).
        light_fit: ``"object"``: fit the lights on the attacked object's visible pixels only (the light where it
            stands); ``"known"``: on every known object (one lighting for the whole scene).
        background_exclude: base-scene shapes to drop for the background render (the known objects; ``"render"``).
        attack_kwargs: keyword arguments of the attack.
        jitter: per-step jitter (default :data:`~meshadv.transfer.robust.DEFAULT_JITTER`; ``{}`` = none).
        robustness: EOT samples, required margin (score units), pixel noise (default
            :class:`~meshadv.transfer.robust.Robustness` ``()``).
        texture_smoothing: ``None`` for the paper's per-face texture; an int ``k >= 0`` for a smoothed per-vertex
            colour field (:class:`~meshadv.attacks.SmoothTextureAttack`, ``k`` rounds), for meshes
            with many faces per pixel. Texture attacks only.
        num_lights: directional lights to estimate.
        camera_steps: camera estimation steps.
        light_steps: light estimation steps.
        variant: Mitsuba variant.
        timeout: seconds per Mitsuba call.
        score_threshold: detection score at or above which ``hide_class`` counts as detected, in (0, 1].
        case_id: identifier of the result row.
        callback: passed to the attack (called with a ``meshadv.attacks.StepInfo`` after every step).

    Returns:
        A result row with the estimation errors, the best ``hide_class`` score of meshadv's render on the estimated
        view (``hide_score_meshadv``), of Mitsuba's under the estimates (``hide_score_mitsuba_estimated``, in the
        same context) and under the hidden parameters (benign and adversarial), the matching ``success_*`` (score
        below the threshold), ``robust_rate_meshadv``, ``occluded_pixels`` (``"photo"``) and the attack's settings.
        Wrapped in a :class:`~meshadv.transfer.results.BlackBoxResult` as by :func:`blackbox_classifier`.

    Raises:
        ValueError: ``object_index`` out of range, unknown ``perturbation``, ``context`` or ``light_fit``, a bad
            ``score_threshold``, or ``texture_smoothing`` given for a shape attack or negative.
    """
    from meshadv.attacks import Disappearance, ShapeAttack

    objects = list(scene_objects)
    if not 0 <= object_index < len(objects):
        raise ValueError(f"object_index {object_index} out of range for {len(objects)} objects")
    check_perturbation(perturbation)
    if context not in ("photo", "render"):
        raise ValueError(f"context must be 'photo' or 'render', got {context!r}")
    if light_fit not in ("object", "known"):
        raise ValueError(f"light_fit must be 'object' or 'known', got {light_fit!r}")
    _check_smoothing(texture_smoothing, perturbation)
    if not 0.0 < score_threshold <= 1.0:
        raise ValueError(f"score_threshold must be in (0, 1], got {score_threshold}")
    robustness = Robustness() if robustness is None else robustness
    jitter = dict(DEFAULT_JITTER if jitter is None else jitter)
    target_obj = objects[object_index]
    merged = _merge_meshes(objects)
    first_face = sum(int(o.faces.shape[0]) for o in objects[:object_index])
    light_faces = (first_face, first_face + int(target_obj.faces.shape[0])) if light_fit == "object" else None
    est = estimate_parameters(target_obj, hidden, known=merged, light_faces=light_faces, num_lights=num_lights,
                              camera_steps=camera_steps, light_steps=light_steps, variant=variant, timeout=timeout)
    setup_options, kwargs = split_setup_options(dict(attack_kwargs or {}))
    setup_options.setdefault("image_size", hidden.image_size)
    kwargs.setdefault("jitter", jitter or None)
    occluded: Optional[torch.Tensor] = None
    seen_victim = victim
    if context == "photo":
        background = est.photo
        setup_options.setdefault("background", background)
        occluded = occlusion_mask(objects, object_index, est.views, hidden.image_size)
        if bool(occluded.any()):
            seen_victim = Occluded(victim, est.photo, occluded)
        attacked = target_obj
        attack = (_texture_attack(texture_smoothing, None, kwargs) if perturbation == "texture"
                  else ShapeAttack(**kwargs))
        start, stop = 0, None
    else:
        background = _background_image(hidden, background_exclude, variant, timeout)
        setup_options.setdefault("background", background)
        attacked = merged
        if perturbation == "texture":
            start = sum(int(o.faces.shape[0]) for o in objects[:object_index])
            stop = start + int(target_obj.faces.shape[0])
            face_mask = torch.zeros(int(merged.faces.shape[0]), dtype=torch.bool)
            face_mask[start:stop] = True
            attack = _texture_attack(texture_smoothing, face_mask, kwargs)
        else:
            start = sum(int(o.vertices.shape[0]) for o in objects[:object_index])
            stop = start + int(target_obj.vertices.shape[0])
            vertex_mask = torch.zeros(int(merged.vertices.shape[0]), dtype=torch.bool)
            vertex_mask[start:stop] = True
            attack = ShapeAttack(vertex_mask=vertex_mask, **kwargs)
    setup = RenderSetup(**setup_options)
    criterion = Disappearance(hide_class, threshold=score_threshold)
    result = _attack_estimated(attack, attacked, est.views, seen_victim, criterion, robustness, setup, callback)
    if perturbation == "texture":
        adversarial = target_obj.with_face_colors(result.mesh.face_colors.detach()[start:stop].clone())
    else:
        adversarial = target_obj.with_vertices(result.mesh.vertices.detach()[start:stop].clone())
    if context == "photo":
        seen = adversarial
    else:
        seen = _merge_meshes([adversarial if i == object_index else o for i, o in enumerate(objects)])
    bound = criterion.bind(victim)
    ours_margin, ours_image = _meshadv_margins(setup, seen, est.views, seen_victim, bound)
    robust_rate = _robust_rate(setup, seen, est.views, seen_victim, bound, robustness)
    record = est.views.to_records()[0]
    # the benign render under the hidden parameters is the photo the estimation was made from
    images = render_scenes([hidden.spec(adversarial), estimated_view_spec(seen, record, hidden)], variant=variant,
                           timeout=timeout)
    estimated_image = composite(images[1], background)
    if occluded is not None:
        estimated_image = estimated_image * (1.0 - occluded) + est.photo * occluded
        ours_image = ours_image * (1.0 - occluded) + est.photo * occluded
    scores = detection_scores(victim, torch.cat([est.photo[None], _images_tensor(images[:1]), estimated_image[None]]),
                              hide_class)
    row: dict[str, Any] = {
        "case_id": case_id,
        "victim": getattr(victim, "name", type(victim).__name__),
        "true_class": hide_class,
        "target": "",
        "perturbation": perturbation,
        "view": 0,
        "context": context,
        "light_fit": light_fit,
        "success_meshadv": bool(ours_margin[0] > 0),
        "success_mitsuba_estimated": scores[2] < score_threshold,
        "success_mitsuba": scores[1] < score_threshold,
        "benign_correct_mitsuba": scores[0] >= score_threshold,
        "score_threshold": float(score_threshold),
        "hide_score_meshadv": float(score_threshold - ours_margin[0]),
        "hide_score_mitsuba_estimated": scores[2],
        "hide_score_benign_mitsuba": scores[0],
        "hide_score_adversarial_mitsuba": scores[1],
        "robust_rate_meshadv": robust_rate,
        "occluded_pixels": None if occluded is None else int(occluded.sum()),
        "texture_smoothing": texture_smoothing,
        "spp": hidden.spp,
        "variant": images[0].variant,
    }
    return _finish_row(row, attack, setup, result, robustness, est, images[0], estimated_image, ours_image,
                       adversarial)


def detection_scores(victim: Any, images: torch.Tensor, class_name: str) -> list[float]:
    """Best score of ``class_name`` among a detector's outputs, per image (0 when absent).

    Raises:
        ValueError: ``class_name`` is not one of the victim's classes.
    """
    k = victim.class_index(class_name)
    with torch.no_grad():
        out = victim(images)
        scores = out.scores()
    return [float(v) for v in scores[..., k].amax(dim=-1).tolist()]


