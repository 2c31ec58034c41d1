"""Attack a detector through one object of a scene: perturb only that object's shape or texture.

The paper's detector experiments: the Stanford Bunny sits on a desk and a barely visible change of the bunny makes
the detector miss the table (or every object); inserted into a real photo, a changed object hides the dog or the
bicycle. The objective is the disappearance loss ``max_{z,b} score_{y'}(z, b)`` plus ``lambda`` times the shape
(Laplacian flow) or texture (image 4-neighbour smoothness) perceptual loss, minimised with Adam. The attack stops
early once the hidden class's best score stays ``margin`` below the threshold for ``patience`` steps; success is
measured on a fresh render of the final object, not on the optimiser's last image.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional

import torch

from meshadv.attacks.criteria import Disappearance
from meshadv.attacks.distances import mesh_distances
from meshadv.attacks.flow import smooth_flow
from meshadv.attacks.losses import image_smoothness_loss, laplacian_flow_loss
from meshadv.mesh import Mesh, vertex_edges
from meshadv.render import Lights
from meshadv.scenes.composite import composite_over_photo
from meshadv.scenes.scene import Scene, SceneCamera
from meshadv.victims.base import Detections, DetectorVictim

PERTURBATIONS = ("shape", "texture")


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


@dataclass
class SceneAttackResult:
    """Outcome of a scene attack.

    Attributes:
        success: the hidden class's best score is below the threshold on a fresh render of the final object.
        object_mesh: the object's adversarial mesh (model space).
        image_before: (1, 3, H, W) the pristine scene image; image_after: the adversarial one.
        detections_before / detections_after: the victim's NMS-filtered detections on those images.
        score_before / score_after: best score of the hidden class(es).
        distances: ``attacks.distances.mesh_distances`` (``laplacian_sum``, ``laplacian_pair_mean``,
            ``color_rmse``, ...).
        loss_history: total loss per step; steps: steps taken; wall_time: seconds.
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

    def to_record(self) -> dict:
        """JSON-able summary (detections, scores, distances, steps, time)."""
        return {
            "success": self.success,
            "score_before": self.score_before,
            "score_after": self.score_after,
            "detections_before": self.detections_before.to_records(),
            "detections_after": self.detections_after.to_records(),
            "distances": self.distances,
            "steps": self.steps,
            "wall_time": self.wall_time,
            "loss_history": self.loss_history,
        }


@dataclass(frozen=True)
class SceneAttack:
    """Disappearance attack through one object of a scene (hyper-parameters only; keyword-only).

    Args:
        perturb: ``"shape"`` (vertex displacement) or ``"texture"`` (per-face colours kept in [0, 1] by a sigmoid).
        steps: maximum Adam steps.
        lr: Adam learning rate: for shape in units of the object's bounding-box diagonal (the displacement is
            ``diagonal * smooth(p)``), for texture in logit units.
        smoothing: shape only: iterations of neighbour averaging ``p <- p + 0.5 * L p`` applied to the optimised
            per-vertex parameters before they become displacements (0 = the paper's plain per-vertex flow;
            :func:`meshadv.attacks.flow.smooth_flow`, shared with :class:`~meshadv.attacks.ShapeAttack`). NMR's
            rasterization gradients are sparse and heavy-tailed and Adam moves every vertex that receives any
            gradient by about ``lr`` per step, which roughens a dense mesh such as the bunny; smoothing the
            parametrisation (in the spirit of Nicolet et al., "Large Steps in Inverse Rendering", 2021) spreads
            each step over a neighbourhood and keeps the perturbation smooth.
        lambda_perceptual: weight of the perceptual loss.
        margin: stop once the best hidden score is ``threshold - margin`` or lower ...
        patience: ... for this many consecutive steps.
        seed: seeds the (tiny) initial noise that breaks symmetry.

    Example:
        >>> attack = SceneAttack(perturb="shape", steps=200)                           # doctest: +SKIP
        >>> result = attack(setup, victim, Disappearance("dining table"))              # doctest: +SKIP
    """

    perturb: str = "shape"
    steps: int = 300
    lr: float = 5e-4
    lambda_perceptual: float = 1.0
    smoothing: int = 8
    margin: float = 0.05
    patience: int = 5
    seed: int = 0

    def __post_init__(self) -> None:
        if self.perturb not in PERTURBATIONS:
            raise ValueError(f"perturb must be one of {PERTURBATIONS}, got {self.perturb!r}")
        if self.steps < 1:
            raise ValueError(f"steps must be >= 1, got {self.steps}")
        if self.lr <= 0:
            raise ValueError(f"lr must be > 0, got {self.lr}")
        if self.lambda_perceptual < 0:
            raise ValueError(f"lambda_perceptual must be >= 0, got {self.lambda_perceptual}")
        if self.patience < 1:
            raise ValueError(f"patience must be >= 1, got {self.patience}")
        if self.smoothing < 0:
            raise ValueError(f"smoothing must be >= 0, got {self.smoothing}")

    def __call__(
        self,
        setup: SceneSetup,
        victim: DetectorVictim,
        criterion: Disappearance,
        *,
        progress: Optional[Callable[[int, float, float], None]] = None,
    ) -> SceneAttackResult:
        """Run the attack.

        Args:
            setup: the scene, the object to perturb, camera, lights and background.
            victim: a detector victim.
            criterion: which class(es) to hide and the detection threshold.
            progress: optional callback ``(step, loss, hidden_score)``.

        Returns:
            A ``SceneAttackResult``; an interrupted run (Ctrl-C) returns the best result so far.
        """
        if getattr(victim, "kind", None) != "detector":
            raise ValueError(f"victim must be a detector, got kind {getattr(victim, 'kind', None)!r}")
        bound = criterion.bind(victim)
        start = time.perf_counter()
        obj = setup.scene[setup.object_name]
        mesh = obj.mesh
        edges = vertex_edges(mesh.faces)
        generator = torch.Generator().manual_seed(self.seed)

        diagonal = float((mesh.vertices.max(0).values - mesh.vertices.min(0).values).norm())

        def displacement(p: torch.Tensor) -> torch.Tensor:
            return diagonal * smooth_flow(p, edges, self.smoothing)

        if self.perturb == "shape":
            param = (1e-6 * torch.randn(mesh.vertices.shape, generator=generator)).requires_grad_(True)
        else:
            base = mesh.face_colors.clamp(1e-3, 1 - 1e-3)
            param = torch.logit(base).clone().requires_grad_(True)
        optimizer = torch.optim.Adam([param], lr=self.lr)

        def parameters_to_mesh(p: torch.Tensor) -> Mesh:
            if self.perturb == "shape":
                return mesh.with_vertices((mesh.vertices + displacement(p)).detach())
            return mesh.with_face_colors(torch.sigmoid(p).detach())

        with torch.no_grad():
            image_before = setup.image()
            score_before = float(bound.score(victim(image_before))[0])
        best_param = param.detach().clone()
        best_score = score_before
        history: List[float] = []
        held = 0
        step = 0
        try:
            for step in range(1, self.steps + 1):
                optimizer.zero_grad()
                if self.perturb == "shape":
                    flow = displacement(param)
                    image = setup.image(vertices=mesh.vertices + flow)
                    perceptual = laplacian_flow_loss(flow, edges)
                else:
                    image = setup.image(face_colors=torch.sigmoid(param))
                    perceptual = image_smoothness_loss(image)[0] / image[0, 0].numel()
                hidden = bound.loss(victim(image))[0]
                loss = hidden + self.lambda_perceptual * perceptual
                hidden_value = float(hidden.detach())
                if hidden_value < best_score:
                    best_score = hidden_value
                    best_param = param.detach().clone()
                history.append(float(loss.detach()))
                if progress is not None:
                    progress(step, history[-1], hidden_value)
                held = held + 1 if hidden_value <= bound.threshold - self.margin else 0
                if held >= self.patience:
                    break
                loss.backward()
                optimizer.step()
        except KeyboardInterrupt:
            pass

        adversarial = parameters_to_mesh(best_param)
        with torch.no_grad():
            image_after = setup.image(vertices=adversarial.vertices, face_colors=adversarial.face_colors)
            score_after = float(bound.score(victim(image_after))[0])
            detections = victim.detect(torch.cat([image_before, image_after]), score_threshold=bound.threshold)
        return SceneAttackResult(
            success=score_after < bound.threshold,
            object_mesh=adversarial,
            image_before=image_before,
            image_after=image_after,
            detections_before=detections[0],
            detections_after=detections[1],
            score_before=score_before,
            score_after=score_after,
            distances=mesh_distances(
                mesh.vertices, mesh.face_colors, adversarial.vertices, adversarial.face_colors, edges
            ),
            loss_history=history,
            steps=step,
            wall_time=time.perf_counter() - start,
        )
