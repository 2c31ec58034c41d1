"""Transfer evaluations: adversarial meshes re-rendered with Mitsuba 3 and fed to the victims.

* **Controlled parameters** (:func:`controlled_transfer`): every adversarial mesh of a sweep is re-rendered with
  Mitsuba under the *same* camera and lights it was attacked with (the paper's Table 3 and Fig. 5).
* **Unknown parameters** (:func:`blackbox_classifier`, :func:`blackbox_detector`), the paper's pipeline: a "photo" is
  rendered by Mitsuba under hidden parameters; the camera is estimated from the object's mask, the lights from the
  masked image; the attack runs in meshadv with random jitter of the estimates at every step; the adversarial mesh is
  re-rendered by Mitsuba under the hidden parameters and tested.

Every Mitsuba render runs in a child process (:mod:`meshadv.transfer.render`), so a crash fails one evaluation, never
the sweep.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Optional, Sequence, Union

import numpy as np
import torch

from meshadv.transfer.render import MitsubaImage, MitsubaRenderError, render_mask, render_scenes
from meshadv.transfer.scene import MeshObject, MitsubaCamera, MitsubaLights, SceneSpec

#: A one-triangle stand-in used where a scene spec needs a mesh that is then dropped.
_PLACEHOLDER_MESH = MeshObject(np.eye(3, dtype=np.float32), np.array([[0, 1, 2]]), np.ones((1, 3), np.float32))

#: Jitter of the estimated camera and lights at every attack step (the paper's step 3).
DEFAULT_JITTER = {"azimuth": 5.0, "elevation": 5.0, "distance": 0.05, "light_direction": 0.2, "light_intensity": 0.2}


@dataclass(frozen=True)
class TransferCase:
    """One adversarial mesh to transfer, with the views it was attacked under.

    Attributes:
        case_id: identifier (the sweep job id, or any string).
        mesh: the adversarial ``meshadv.mesh.Mesh``.
        views: ``ViewSet.to_records()`` records of the views (camera + lights).
        victim: victim name (``meshadv.victims.load_victim``).
        true_class: the class of the benign object (PASCAL3D+ name or ImageNet spec).
        target: the target class of a targeted attack, or None for an untargeted one.
        attack_type: ``"shape"`` or ``"texture"``.
        image_size: (H, W) of the renders.
        background: RGB background of the renders.
        benign_correct: whether the victim classified the benign render correctly (from the sweep), if known.
        antialias: meshadv's supersampling factor for the reference render (the attack's own, so that
            ``success_meshadv`` is the attack's success).
    """

    case_id: str
    mesh: Any
    views: tuple[dict[str, Any], ...]
    victim: str
    true_class: str
    target: Optional[str] = None
    attack_type: str = ""
    image_size: tuple[int, int] = (224, 224)
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    benign_correct: Optional[bool] = None
    antialias: int = 1

    def __post_init__(self) -> None:
        if not self.views:
            raise ValueError("views must hold at least one view record")
        object.__setattr__(self, "views", tuple(self.views))
        size = self.image_size
        size = (int(size), int(size)) if isinstance(size, (int, float)) else (int(size[0]), int(size[1]))
        object.__setattr__(self, "image_size", size)


def cases_from_store(
    db_path: Union[str, Path], *, limit: Optional[int] = None, only_successful: bool = True
) -> list[TransferCase]:
    """Collect the adversarial meshes of a finished sweep (single-view attack jobs) as transfer cases.

    Reads the ``jobs`` table of the sweep database (``meshadv.experiments.ResultStore``); for each done job, the
    adversarial mesh ``adversarial.ply`` and the views of its ``result.json`` in the job's folder.

    Args:
        db_path: the sweep's ``results.db``.
        limit: at most this many cases.
        only_successful: keep only attacks that succeeded in meshadv (as the paper does).

    Returns:
        The cases, in database order.

    Raises:
        FileNotFoundError: ``db_path`` does not exist.
    """
    from meshadv.experiments import ResultStore
    from meshadv.mesh import load_mesh

    if not Path(db_path).is_file():
        raise FileNotFoundError(f"db_path {db_path} does not exist")
    cases: list[TransferCase] = []
    with ResultStore(db_path) as store:
        rows = store.rows("done")
    for row in rows:
        spec, record = row.spec, row.record or {}
        if spec.get("kind", "single") != "single" or record.get("skipped") or not row.out_dir:
            continue
        if only_successful and not record.get("success"):
            continue
        out = Path(row.out_dir)
        result_path = out / "result.json"
        if not result_path.is_file():
            continue
        result = json.loads(result_path.read_text())
        meshes = result.get("meshes") or [["adversarial.ply", "adversarial.obj"]]
        mesh_path = out / meshes[0][0]
        if not mesh_path.is_file() or not result.get("views"):
            continue
        target = spec.get("target")
        if target in ("", "untargeted", None):
            target = None
        size = result.get("config", {}).get("image_size") or spec.get("image_size") or 224
        cases.append(
            TransferCase(
                case_id=row.job_id,
                mesh=load_mesh(mesh_path),
                views=tuple(result["views"]),
                victim=str(spec.get("victim", result.get("victim"))),
                true_class=str(spec.get("source_class", spec.get("mesh", {}).get("class", ""))),
                target=None if target is None else str(target),
                attack_type=str(spec.get("perturbation", result.get("perturbation", ""))),
                image_size=tuple(size) if isinstance(size, (list, tuple)) else (int(size), int(size)),
                benign_correct=None if record.get("benign_correct") is None else bool(record["benign_correct"]),
                antialias=int(result.get("config", {}).get("antialias") or 1),
            )
        )
        if limit is not None and len(cases) >= limit:
            break
    return cases


def mitsuba_specs_for_case(case: TransferCase, *, spp: int = 64, max_depth: int = 8, seed: int = 0) -> list[SceneSpec]:
    """One Mitsuba scene per view of ``case``: same camera, lights, image size and background."""
    obj = MeshObject.from_mesh(case.mesh)
    return [
        SceneSpec(
            objects=(obj,),
            camera=MitsubaCamera.from_record(rec),
            lights=MitsubaLights.from_record(rec),
            image_size=case.image_size,
            spp=spp,
            max_depth=max_depth,
            background=case.background,
            seed=seed + i,
        )
        for i, rec in enumerate(case.views)
    ]


def _images_tensor(images: Sequence[MitsubaImage]) -> torch.Tensor:
    return torch.from_numpy(np.stack([im.chw() for im in images])).float()


def _criteria(case: TransferCase, victim: Any) -> tuple[Any, Optional[Any]]:
    from meshadv.attacks import Misclassification, TargetedMisclassification

    untargeted = Misclassification(case.true_class).bind(victim)
    targeted = TargetedMisclassification(case.target).bind(victim) if case.target else None
    return untargeted, targeted


def _top1_names(victim: Any, logits: torch.Tensor) -> list[str]:
    names = list(getattr(victim, "class_names", []) or [])
    top = logits.argmax(dim=1).tolist()
    return [names[i] if i < len(names) else str(i) for i in top]


def evaluate_case(
    case: TransferCase,
    victim: Any,
    mitsuba_images: Sequence[MitsubaImage],
) -> list[dict[str, Any]]:
    """Evaluate one case on its meshadv renders and its Mitsuba renders (classifier victims).

    Returns:
        One row per view with ``success_meshadv`` / ``success_mitsuba`` (targeted when the case has a target, else
        untargeted), ``untargeted_meshadv`` / ``untargeted_mitsuba``, the top-1 labels and the Mitsuba variant.
    """
    from meshadv.render import ViewSet, render

    views = ViewSet.from_records(list(case.views))
    mesh = case.mesh
    with torch.no_grad():
        ours = render(mesh.vertices, mesh.faces, mesh.face_colors, views.camera, views.lights, case.image_size,
                      background=case.background, antialias=case.antialias).image
        theirs = _images_tensor(mitsuba_images)
        logits_ours, logits_theirs = victim(ours), victim(theirs)
    untargeted, targeted = _criteria(case, victim)
    un_ours = untargeted.is_adversarial(logits_ours).tolist()
    un_theirs = untargeted.is_adversarial(logits_theirs).tolist()
    if targeted is not None:
        t_ours = targeted.is_adversarial(logits_ours).tolist()
        t_theirs = targeted.is_adversarial(logits_theirs).tolist()
    else:
        t_ours, t_theirs = un_ours, un_theirs
    top_ours, top_theirs = _top1_names(victim, logits_ours), _top1_names(victim, logits_theirs)
    diff = (ours - theirs).abs().mean(dim=(1, 2, 3)).tolist()
    rows = []
    for v in range(len(case.views)):
        rows.append(
            {
                "case_id": case.case_id,
                "victim": case.victim,
                "true_class": case.true_class,
                "target": case.target or "",
                "attack_type": case.attack_type,
                "view": v,
                "success_meshadv": bool(t_ours[v]),
                "success_mitsuba": bool(t_theirs[v]),
                "untargeted_meshadv": bool(un_ours[v]),
                "untargeted_mitsuba": bool(un_theirs[v]),
                "top1_meshadv": top_ours[v],
                "top1_mitsuba": top_theirs[v],
                "mean_abs_image_difference": float(diff[v]),
                "variant": mitsuba_images[v].variant,
                "benign_correct": case.benign_correct,
            }
        )
    return rows


def controlled_transfer(
    cases: Sequence[TransferCase],
    *,
    spp: int = 64,
    max_depth: int = 8,
    variant: Optional[str] = None,
    timeout: float = 1800.0,
    victim_loader: Optional[Callable[[str], Any]] = None,
    image_dir: Optional[Union[str, Path]] = None,
    on_error: str = "record",
) -> list[dict[str, Any]]:
    """Re-render each case with Mitsuba under its own camera and lights and test the victims (Table 3 / Fig. 5).

    Args:
        cases: the adversarial meshes (see :func:`cases_from_store`).
        spp: Mitsuba samples per pixel.
        max_depth: path depth (>= 3 adds interreflection; 2 is direct light with shadows only).
        variant: Mitsuba variant (default: the best that works).
        timeout: seconds per case.
        victim_loader: ``name -> victim`` (default ``meshadv.victims.load_victim``); victims are loaded once.
        image_dir: when given, Mitsuba renders are saved there as ``<case_id>_v<view>.png``.
        on_error: ``"record"`` keeps going and records a row with an ``error`` for a failed render; ``"raise"``
            re-raises.

    Returns:
        One row per (case, view) (see :func:`evaluate_case`); failed renders give rows with ``error`` and no success.

    Raises:
        ValueError: unknown ``on_error``.
        MitsubaRenderError: a render failed and ``on_error == "raise"``.
    """
    if on_error not in ("record", "raise"):
        raise ValueError(f"on_error must be 'record' or 'raise', got {on_error!r}")
    if victim_loader is None:
        from meshadv.victims import load_victim

        victim_loader = load_victim
    victims: dict[str, Any] = {}
    rows: list[dict[str, Any]] = []
    for case in cases:
        try:
            images = render_scenes(mitsuba_specs_for_case(case, spp=spp, max_depth=max_depth), variant=variant,
                                   timeout=timeout)
        except MitsubaRenderError as exc:
            if on_error == "raise":
                raise
            rows.extend(
                {"case_id": case.case_id, "victim": case.victim, "true_class": case.true_class,
                 "target": case.target or "", "attack_type": case.attack_type, "view": v,
                 "success_meshadv": None, "success_mitsuba": None, "error": str(exc)}
                for v in range(len(case.views))
            )
            continue
        if case.victim not in victims:
            victims[case.victim] = victim_loader(case.victim)
        rows.extend(evaluate_case(case, victims[case.victim], images))
        if image_dir is not None:
            save_images(images, Path(image_dir), case.case_id)
    return rows


def save_images(images: Sequence[MitsubaImage], out_dir: Path, stem: str) -> list[Path]:
    """Save Mitsuba renders as 8-bit PNGs ``<stem>_v<i>.png`` (linear values, as meshadv's images)."""
    from PIL import Image

    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, im in enumerate(images):
        path = out_dir / f"{stem}_v{i}.png"
        Image.fromarray(np.round(im.image * 255).astype(np.uint8)).save(path)
        paths.append(path)
    return paths


# ----------------------------------------------------------------------------------------------------------------------
# Unknown parameters: the black-box pipeline
# ----------------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class HiddenScene:
    """The hidden "real world" of a black-box experiment: what Mitsuba renders, unknown to the attacker.

    Attributes:
        camera: the true spherical camera (distance, azimuth, elevation in degrees).
        viewing_angle: field of view (assumed known to the attacker).
        lights: true directional lights + ambient (or None).
        environment: optional lat-long environment map (e.g. :func:`~meshadv.transfer.scene.outdoor_environment`).
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
        photo: (3, H, W) the Mitsuba photo; mask: (H, W) the object's mask.
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
        num_lights: directional lights to estimate.
        camera_steps: Adam steps of the camera estimation.
        light_steps: Adam steps of the light estimation.
        camera_size: the mask is average-pooled to at most this size for the camera fit.
        variant: Mitsuba variant.
        timeout: seconds per Mitsuba call.

    Returns:
        The :class:`Estimation`.
    """
    from meshadv.render import Lights, ViewSet, render
    from meshadv.transfer.estimate import estimate_camera, estimate_lights, light_errors, masked_rmse

    known = mesh if known is None else known
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
    light_est = estimate_lights(photo, mask, verts, faces, colors, camera, num_lights=num_lights, steps=light_steps)
    errors = cam_est.errors(hidden.camera["distance"], hidden.camera["azimuth"], hidden.camera["elevation"])
    errors["mask_iou"] = cam_est.iou
    with torch.no_grad():
        ours = render(verts, faces, colors, camera, light_est.lights, hidden.image_size, background=(0.0, 0.0, 0.0))
    both = (mask.numpy() > 0.5) & (ours.alpha[0, 0].numpy() > 0.5)
    errors["light_rmse"] = masked_rmse(ours.image[0].numpy(), photo.numpy(), both) if both.any() else float("nan")
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


def blackbox_classifier(
    mesh: Any,
    hidden: HiddenScene,
    *,
    victim: Any,
    true_class: str,
    target: Optional[str] = None,
    attack_type: str = "texture",
    attack_kwargs: Optional[dict[str, Any]] = None,
    jitter: Optional[dict[str, float]] = None,
    num_lights: int = 5,
    camera_steps: int = 60,
    light_steps: int = 120,
    variant: Optional[str] = None,
    timeout: float = 1800.0,
    case_id: str = "blackbox_classifier",
) -> dict[str, Any]:
    """The paper's black-box pipeline against a classifier (e.g. an aeroplane in an outdoor scene).

    1-2. :func:`estimate_parameters`; 3. attack in meshadv on the estimated view with jitter, the renders composited
    over the photo's background; 4. re-render the adversarial mesh with Mitsuba under the hidden parameters and test.

    Args:
        mesh: the benign mesh.
        hidden: the hidden world.
        victim: a classifier victim.
        true_class: the object's class.
        target: target class (None = untargeted).
        attack_type: ``"shape"`` or ``"texture"``.
        attack_kwargs: keyword arguments of the attack (steps, lr, ...).
        jitter: per-step jitter of the estimates (default :data:`DEFAULT_JITTER`).
        num_lights: directional lights to estimate.
        camera_steps: camera estimation steps.
        light_steps: light estimation steps.
        variant: Mitsuba variant.
        timeout: seconds per Mitsuba call.
        case_id: identifier of the result row.

    Returns:
        A result row (see :mod:`meshadv.transfer.results`) with estimation errors, ``success_meshadv`` (on the
        estimated view), ``success_mitsuba`` (under the hidden parameters) and ``benign_correct_mitsuba``.

    Raises:
        ValueError: unknown ``attack_type``.
    """
    from meshadv.attacks import Misclassification, ShapeAttack, TargetedMisclassification, TextureAttack

    if attack_type not in ("shape", "texture"):
        raise ValueError(f"attack_type must be 'shape' or 'texture', got {attack_type!r}")
    est = estimate_parameters(mesh, hidden, num_lights=num_lights, camera_steps=camera_steps,
                              light_steps=light_steps, variant=variant, timeout=timeout)
    background = _background_image(hidden, (), variant, timeout)
    kwargs = dict(attack_kwargs or {})
    kwargs.setdefault("image_size", hidden.image_size)
    kwargs.setdefault("background", background)
    kwargs.setdefault("jitter", DEFAULT_JITTER if jitter is None else jitter)
    attack = (ShapeAttack if attack_type == "shape" else TextureAttack)(**kwargs)
    criterion = TargetedMisclassification(target) if target else Misclassification(true_class)
    result = attack(mesh, est.views, victim, criterion)
    adversarial = result.mesh
    images = render_scenes([hidden.spec(mesh), hidden.spec(adversarial)], variant=variant, timeout=timeout)
    with torch.no_grad():
        logits = victim(_images_tensor(images))
    bound_untargeted = Misclassification(true_class).bind(victim)
    bound = criterion.bind(victim)
    adv = bound.is_adversarial(logits).tolist()
    names = _top1_names(victim, logits)
    row: dict[str, Any] = {
        "case_id": case_id,
        "victim": getattr(victim, "name", type(victim).__name__),
        "true_class": true_class,
        "target": target or "",
        "attack_type": attack_type,
        "view": 0,
        "success_meshadv": bool(result.succeeded[0]),
        "success_mitsuba": bool(adv[1]),
        "benign_adversarial_mitsuba": bool(adv[0]),
        "benign_correct_mitsuba": not bool(bound_untargeted.is_adversarial(logits[:1])[0]),
        "top1_benign_mitsuba": names[0],
        "top1_adversarial_mitsuba": names[1],
        "variant": images[0].variant,
    }
    row.update({k: float(v) for k, v in est.errors.items()})
    row["_images"] = images
    row["_adversarial_mesh"] = adversarial
    return row


def blackbox_detector(
    scene_objects: Sequence[Any],
    object_index: int,
    hidden: HiddenScene,
    *,
    victim: Any,
    hide_class: str,
    background_exclude: Sequence[str] = (),
    attack_kwargs: Optional[dict[str, Any]] = None,
    jitter: Optional[dict[str, float]] = None,
    num_lights: int = 5,
    camera_steps: int = 60,
    light_steps: int = 120,
    variant: Optional[str] = None,
    timeout: float = 1800.0,
    score_threshold: float = 0.3,
    case_id: str = "blackbox_detector",
) -> dict[str, Any]:
    """The black-box pipeline against a detector: change one object's texture so that ``hide_class`` disappears.

    The attacker knows the geometry of ``scene_objects`` (world space; e.g. the indoor scene's desk, chair and bunny)
    but not the camera or lights. (1-2) The camera and lights are estimated from the Mitsuba photo (mask and shading
    of the known objects); (3) a texture attack on the merged known objects, composited over the photo's background
    (the hidden world without them), with jitter; only the attacked object's colours are kept; (4) the adversarial
    object is re-rendered by Mitsuba under the hidden parameters and the detector is run.

    Args:
        scene_objects: ``meshadv.mesh.Mesh`` objects in world space.
        object_index: which of them is perturbed (it is the object of ``hidden.spec``; the others must be part of
            ``hidden`` through its base scene or ``extra_objects``).
        hidden: the hidden world.
        victim: a detector victim.
        hide_class: the class to hide (a name of ``victim.class_names``, e.g. ``"chair"``).
        background_exclude: base-scene shapes to drop for the background render (the known objects).
        attack_kwargs: keyword arguments of :class:`meshadv.attacks.TextureAttack`.
        jitter: per-step jitter (default :data:`DEFAULT_JITTER`).
        num_lights: directional lights to estimate.
        camera_steps: camera estimation steps.
        light_steps: light estimation steps.
        variant: Mitsuba variant.
        timeout: seconds per Mitsuba call.
        score_threshold: detection score above which ``hide_class`` counts as detected.
        case_id: identifier of the result row.

    Returns:
        A result row with estimation errors, the best ``hide_class`` score of the benign and adversarial Mitsuba
        renders and ``success_mitsuba`` (no ``hide_class`` detection above the threshold).

    Raises:
        ValueError: ``object_index`` out of range.
    """
    from meshadv.attacks import Disappearance

    objects = list(scene_objects)
    if not 0 <= object_index < len(objects):
        raise ValueError(f"object_index {object_index} out of range for {len(objects)} objects")
    target_obj = objects[object_index]
    merged = _merge_meshes(objects)
    est = estimate_parameters(target_obj, hidden, known=merged, num_lights=num_lights, camera_steps=camera_steps,
                              light_steps=light_steps, variant=variant, timeout=timeout)
    kwargs = dict(attack_kwargs or {})
    kwargs.setdefault("image_size", hidden.image_size)
    kwargs.setdefault("jitter", DEFAULT_JITTER if jitter is None else jitter)
    kwargs.setdefault("background", _background_image(hidden, background_exclude, variant, timeout))
    start = sum(int(o.faces.shape[0]) for o in objects[:object_index])
    stop = start + int(target_obj.faces.shape[0])
    face_mask = torch.zeros(int(merged.faces.shape[0]), dtype=torch.bool)
    face_mask[start:stop] = True
    attack = object_texture_attack(face_mask, **kwargs)
    result = attack(merged, est.views, victim, Disappearance(hide_class))
    adversarial = target_obj.with_face_colors(result.mesh.face_colors.detach()[start:stop].clone())
    images = render_scenes([hidden.spec(target_obj), hidden.spec(adversarial)], variant=variant, timeout=timeout)
    scores = detection_scores(victim, _images_tensor(images), hide_class)
    row: dict[str, Any] = {
        "case_id": case_id,
        "victim": getattr(victim, "name", type(victim).__name__),
        "true_class": hide_class,
        "target": "",
        "attack_type": "texture",
        "view": 0,
        "success_meshadv": bool(result.succeeded[0]),
        "success_mitsuba": scores[1] < score_threshold,
        "benign_correct_mitsuba": scores[0] >= score_threshold,
        "hide_score_benign_mitsuba": scores[0],
        "hide_score_adversarial_mitsuba": scores[1],
        "variant": images[0].variant,
    }
    row.update({k: float(v) for k, v in est.errors.items()})
    row["_images"] = images
    row["_adversarial_mesh"] = adversarial
    return row


def object_texture_attack(face_mask: torch.Tensor, **kwargs: Any) -> Any:
    """A :class:`meshadv.attacks.TextureAttack` that changes only the faces in ``face_mask`` (one object of a scene).

    Args:
        face_mask: bool (M,) faces whose colours may change.
        **kwargs: the attack's hyper-parameters.

    Raises:
        ValueError: ``face_mask`` is not a non-empty 1-D bool tensor.
    """
    from meshadv.attacks import TextureAttack
    from meshadv.attacks.distances import color_rmse

    if not isinstance(face_mask, torch.Tensor) or face_mask.dtype != torch.bool or face_mask.dim() != 1:
        raise ValueError("face_mask must be a 1-D bool tensor")
    if not bool(face_mask.any()):
        raise ValueError("face_mask selects no face")

    class _ObjectTextureAttack(TextureAttack):
        def _apply(self, params: torch.Tensor, mesh: Any) -> tuple[torch.Tensor, torch.Tensor]:
            verts, colors = super()._apply(params, mesh)
            fixed = mesh.face_colors.unsqueeze(0).expand_as(colors)
            return verts, torch.where(face_mask[None, :, None], colors, fixed)

        def _distance(self, params: torch.Tensor, mesh: Any, edges: torch.Tensor) -> torch.Tensor:
            colors = torch.sigmoid(params)[:, face_mask]
            return color_rmse(colors, mesh.face_colors[face_mask])

    return _ObjectTextureAttack(**kwargs)


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


def public_row(row: dict[str, Any]) -> dict[str, Any]:
    """``row`` without the private (non-JSON) entries whose keys start with ``_``; NaN floats become None."""
    out = {}
    for k, v in row.items():
        if k.startswith("_"):
            continue
        out[k] = None if isinstance(v, float) and math.isnan(v) else v
    return out


__all__ = [
    "DEFAULT_JITTER",
    "Estimation",
    "HiddenScene",
    "TransferCase",
    "blackbox_classifier",
    "blackbox_detector",
    "cases_from_store",
    "controlled_transfer",
    "detection_scores",
    "object_texture_attack",
    "estimate_parameters",
    "evaluate_case",
    "mitsuba_specs_for_case",
    "public_row",
    "save_images",
]
