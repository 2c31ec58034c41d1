"""Attack a detector through one object of a scene: perturb only that object's shape or texture.

The paper's detector experiments: the Stanford Bunny sits on a desk and a barely visible change of the bunny makes
the detector miss the table (or every object); inserted into a real photo, a changed object hides the dog or the
bicycle. There is no scene-specific attack: a :class:`SceneSetup` turns the scene into the attacked object's mesh,
one view and a :class:`~meshadv.render.setup.RenderSetup` whose static objects are the rest of the scene (rendered
with it, with occlusion) and whose background is the photo if any; :func:`attack_scene` runs an ordinary
:class:`~meshadv.attacks.ShapeAttack` / :class:`~meshadv.attacks.TextureAttack` with a
:class:`~meshadv.attacks.Disappearance` criterion on them and reports detections before and after.

Example:
    >>> attack = ShapeAttack(steps=200, smoothing=8, early_stop=5, early_stop_margin=0.05)   # doctest: +SKIP
    >>> result = attack_scene(attack, setup, victim, Disappearance("dining table"))          # doctest: +SKIP
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Optional

import torch

from meshadv.attacks.mesh_attack import MeshAttack, StepInfo
from meshadv.attacks.criteria import Disappearance
from meshadv.attacks.evaluation import evaluate
from meshadv.attacks.result import enough_views, held_out_sentence, held_out_verdict
from meshadv.mesh import Mesh
from meshadv.render import Lights, ViewSet
from meshadv.render.setup import RenderSetup, static_objects
from meshadv.scenes.composite import composite_over_photo
from meshadv.scenes.held_out import SceneHeldOut, scene_held_out_views
from meshadv.scenes.scene import Scene, SceneCamera
from meshadv.victims.victim import Detections

__all__ = ["SceneSetup", "SceneAttackResult", "attack_scene", "scene_held_out_verdict"]


@dataclass(frozen=True)
class SceneSetup:
    """Everything fixed about an attacked scene: the scene, the object to perturb, camera, lights, background.

    Attributes:
        scene: the scene.
        object_name: name of the only object whose parameters change.
        camera: the scene camera.
        lights: lights of batch 1.
        photo: optional (1, 3, H, W) background photograph; the render is alpha-composited over it.
        background: RGB background colour when there is no photo.
    """

    scene: Scene
    object_name: str
    camera: SceneCamera
    lights: Lights
    photo: Optional[torch.Tensor] = None
    background: tuple = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        self.scene.index_of(self.object_name)
        if self.photo is not None and tuple(self.photo.shape) != (1, 3, self.camera.height, self.camera.width):
            raise ValueError(
                f"photo must have shape (1, 3, {self.camera.height}, {self.camera.width}) to match the camera, "
                f"got {tuple(self.photo.shape)}"
            )

    def image(
        self, vertices: Optional[torch.Tensor] = None, face_colors: Optional[torch.Tensor] = None
    ) -> torch.Tensor:
        """Render the scene with the object's vertices / colours replaced, composited over the photo if any.

        Returns:
            (1, 3, H, W) image in [0, 1].
        """
        overrides_v = {} if vertices is None else {self.object_name: vertices}
        overrides_c = {} if face_colors is None else {self.object_name: face_colors}
        out = self.scene.render(
            self.camera, self.lights, vertices=overrides_v, face_colors=overrides_c, background=self.background
        )
        if self.photo is None:
            return out.image
        return composite_over_photo(out.image, out.alpha, self.photo)

    @property
    def mesh(self) -> Mesh:
        """The attacked object's mesh (model space)."""
        return self.scene[self.object_name].mesh

    def views(self) -> ViewSet:
        """The one view of the scene camera under the scene's lights."""
        return ViewSet(self.camera.to_camera(), self.lights)

    def render_setup(self, antialias: int = 1) -> RenderSetup:
        """The attack's render setup: the other objects static, the object's transform, the camera's crop and the
        photo (or the background colour)."""
        index = self.scene.index_of(self.object_name)
        others = [o for i, o in enumerate(self.scene.objects) if i != index]
        background: Any = self.background if self.photo is None else self.photo[0]
        return RenderSetup(image_size=self.camera.width, background=background, antialias=antialias,
                           static=static_objects(others), transform=self.scene.objects[index].transform,
                           crop_rows=(self.camera.crop_rows().start, self.camera.crop_rows().stop))


@dataclass
class SceneAttackResult:
    """Outcome of a scene attack.

    Attributes:
        success: the hidden class's best score is below the threshold on a fresh render of the final object from
            the scene camera, on at least ``held_out_fraction`` of the counted held-out views (when the attack asks
            for a held-out verdict; :func:`scene_held_out_verdict`), and the object lies inside the attack's
            perceptibility cap (when it has one).
        object_mesh: the object's adversarial mesh (model space).
        image_before: (1, 3, H, W) the pristine scene image; image_after: the adversarial one.
        detections_before / detections_after: the victim's NMS-filtered detections on those images.
        score_before / score_after: best score of the hidden class(es).
        distances: ``attacks.distances.mesh_distances`` (``laplacian_sum``, ``laplacian_pair_mean``,
            ``color_rmse``, ...).
        loss_history: total loss per step; steps: steps taken; wall_time: seconds.
        config: the attack's hyper-parameters and render setup.
        interrupted: the attack was stopped early by Ctrl-C / SIGTERM (the result is the best so far).
        views_success: the class is hidden on the scene camera's view (the view optimised on).
        held_out_success: per held-out view (:mod:`meshadv.scenes.held_out`, never optimised on), the class is
            hidden there too; ``None`` without held-out views. ``held_out_scores``: the hidden class's best score
            on each; ``held_out_scores_before``: on the pristine scene from the same views.
        held_out_counted: per held-out view, the pristine scene shows the class there (the detector finds it
            above the threshold); only those views count towards ``held_out_rate`` and the verdict (a view on which
            the class is missed before the attack shows nothing hidden).
        held_out_fraction: ``None`` (the scene camera's verdict alone) or the fraction of held-out views the class
            must be hidden on for ``success``.
        held_out: the record of the held-out views (``SceneHeldOut.to_record``: kind, moves, views), or ``None``.
    """

    success: bool
    object_mesh: Mesh
    image_before: torch.Tensor
    image_after: torch.Tensor
    detections_before: Detections
    detections_after: Detections
    score_before: float
    score_after: float
    distances: Dict[str, float]
    loss_history: List[float] = field(default_factory=list)
    steps: int = 0
    wall_time: float = 0.0
    config: Dict[str, Any] = field(default_factory=dict)
    interrupted: bool = False
    views_success: bool = False
    held_out_success: Optional[List[bool]] = None
    held_out_scores: Optional[List[float]] = None
    held_out_scores_before: Optional[List[float]] = None
    held_out_counted: Optional[List[bool]] = None
    held_out_fraction: Optional[float] = None
    held_out: Optional[Dict[str, Any]] = None

    def _counted(self) -> List[bool]:
        """The held-out views' success on the counted views only."""
        success = self.held_out_success or []
        counted = self.held_out_counted if self.held_out_counted is not None else [True] * len(success)
        return [s for s, c in zip(success, counted) if c]

    @property
    def held_out_rate(self) -> Optional[float]:
        """Fraction of the counted held-out views on which the class is hidden (``None`` without any)."""
        counted = self._counted()
        return sum(counted) / len(counted) if counted else None

    def held_out_line(self) -> Optional[str]:
        """The held-out verdict in words (``attacks.result.held_out_sentence``), ``None`` without held-out views."""
        if self.held_out_success is None:
            return None
        counted = self._counted()
        line = held_out_sentence(sum(counted), len(counted), self.held_out_fraction)
        left_out = len(self.held_out_success) - len(counted)
        if left_out:
            line += f" ({left_out} held-out view(s) left out: the pristine scene shows no such detection there)"
        return line

    def to_record(self) -> dict:
        """JSON-able summary (verdict, detections, scores, distances, held-out views, steps, time)."""
        return {
            "success": self.success,
            "views_success": self.views_success,
            "held_out_success": self.held_out_success,
            "held_out_scores": self.held_out_scores,
            "held_out_scores_before": self.held_out_scores_before,
            "held_out_counted": self.held_out_counted,
            "held_out_rate": self.held_out_rate,
            "held_out_fraction": self.held_out_fraction,
            "held_out": self.held_out,
            "score_before": self.score_before,
            "score_after": self.score_after,
            "detections_before": self.detections_before.to_records(),
            "detections_after": self.detections_after.to_records(),
            "distances": self.distances,
            "steps": self.steps,
            "interrupted": self.interrupted,
            "wall_time": self.wall_time,
            "loss_history": self.loss_history,
            "attack": self.config,
        }


def scene_held_out_verdict(held_out_success: List[bool], counted: List[bool], fraction: Optional[float]) -> bool:
    """The held-out part of a scene attack's verdict: the class is hidden on at least ``fraction`` of the held-out
    views whose pristine scene shows it (``counted``), by the rule of
    :func:`~meshadv.attacks.result.held_out_verdict` (``fraction`` ``None``: true; no counted view: false).

    Example:
        >>> scene_held_out_verdict([True, True, False, True], [True, True, False, True], 0.8)
        True
    """
    if len(counted) != len(held_out_success):
        raise ValueError(f"counted ({len(counted)}) and held_out_success ({len(held_out_success)}) must have one "
                         "entry per held-out view")
    kept = torch.tensor([[s for s, c in zip(held_out_success, counted) if c]], dtype=torch.bool).reshape(1, -1)
    return bool(held_out_verdict(kept, fraction, 1)[0])


def attack_scene(attack: MeshAttack, setup: SceneSetup, victim: Any, criterion: Disappearance, *,
                 antialias: int = 1, callback: Optional[Callable[[StepInfo], None]] = None,
                 held_out: Optional[SceneHeldOut] = None) -> SceneAttackResult:
    """Run ``attack`` on the object of ``setup`` against a detector and report detections before and after.

    Args:
        attack: a shape or texture attack (hyper-parameters only); its ``held_out_fraction`` (``None``: the scene
            camera's verdict alone) is the fraction of held-out views the class must also be hidden on.
        setup: the scene, the object to perturb, camera, lights and background.
        victim: a detector victim.
        criterion: which class(es) to hide and the detection threshold.
        antialias: supersampling factor of the renders.
        callback: called after every step (see :class:`~meshadv.attacks.StepInfo`).
        held_out: the held-out views that judge the result (never optimised on, never used to pick it); ``None``:
            :func:`~meshadv.scenes.held_out.scene_held_out_views` of ``setup`` with the attack's seed when the attack
            asks for a held-out verdict, else none.

    Returns:
        A :class:`SceneAttackResult`; success is measured on fresh renders of the final object.

    Raises:
        ValueError: ``victim`` is not a detector.
    """
    if getattr(victim, "kind", None) != "detector":
        raise ValueError(f"victim must be a detector, got kind {getattr(victim, 'kind', None)!r}")
    if held_out is None and getattr(attack, "held_out_fraction", None):
        held_out = scene_held_out_views(setup, seed=attack.seed)
    result = attack(setup.mesh, setup.views(), victim, criterion, setup=setup.render_setup(antialias),
                    callback=callback, eval_views=None if held_out is None else held_out.views)
    image_before = result.original_images[0][None]
    image_after = result.images[0, 0][None]
    bound = criterion.bind(victim)
    with torch.no_grad():
        detections = victim.detect(torch.cat([image_before, image_after]), score_threshold=bound.threshold)
    success = bool(result.succeeded[0])
    before = counted = held_out_success = None
    if held_out is not None:  # the pristine scene from the held-out views: what the attack had to hide there
        pristine = evaluate(setup.mesh, held_out.views, victim, bound, setup=setup.render_setup(antialias))
        before = [float(s) for s in pristine.scores[0].tolist()]
        counted = [not bool(s) for s in pristine.success[0].tolist()]
        held_out_success = [bool(s) for s in result.eval_success[0].tolist()]
        views_hold = bool(enough_views(result.success_rate[0], result.success_fraction))
        success = views_hold and bool(result.inside_cap[0]) and scene_held_out_verdict(
            held_out_success, counted, result.held_out_fraction)
    return SceneAttackResult(
        success=success,
        object_mesh=result.mesh,
        image_before=image_before,
        image_after=image_after,
        detections_before=detections[0],
        detections_after=detections[1],
        score_before=float(result.original_scores[0, 0]),
        score_after=float(result.scores[0, 0]),
        distances=dict(result.distances[0]),
        loss_history=[row["loss"][0] for row in result.loss_history],
        steps=result.steps,
        wall_time=result.wall_time,
        config=dict(result.config),
        interrupted=bool(getattr(result, "interrupted", False)),
        views_success=bool(enough_views(result.success_rate[0], result.success_fraction)),
        held_out_success=held_out_success,
        held_out_scores=None if result.eval_scores is None else [float(s) for s in result.eval_scores[0].tolist()],
        held_out_scores_before=before,
        held_out_counted=counted,
        held_out_fraction=result.held_out_fraction,
        held_out=None if held_out is None else held_out.to_record(),
    )
