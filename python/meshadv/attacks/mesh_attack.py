"""The base class of the mesh attacks: hyper-parameters, the family methods and the attack call.

:class:`MeshAttack` holds only hyper-parameters (keyword-only, validated at construction); a family
(:class:`~meshadv.attacks.ShapeAttack`, :class:`~meshadv.attacks.TextureAttack`, ...) says what is optimised through
its methods: the initial parameters (:meth:`~MeshAttack.initial_params`), how parameters become vertices and colours
(:meth:`~MeshAttack.apply`), the perceptual loss and the distortion (:meth:`~MeshAttack.perceptual`,
:meth:`~MeshAttack.distance`), and the space a budget rule steps in (:meth:`~MeshAttack.budget_space`). Calling an
attack validates the mesh, views, victim and criteria and runs the one optimisation loop (:mod:`meshadv.attacks.loop`);
the per-target bookkeeping lives in :mod:`meshadv.attacks.targets`, the update rules (``method=``) in
:mod:`meshadv.attacks.update`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, Callable, Dict, Optional, Sequence, Tuple, Union

import torch
from torch import Tensor

from meshadv import _validate
from meshadv.attacks.distances import mesh_distances
from meshadv.attacks.criteria import CLASSIFIER_LOSSES, Criterion, as_criteria
from meshadv.attacks.eot import TransformationsLike, as_transformations
from meshadv.attacks.history import StepInfo
from meshadv.attacks.loop import AttackCall, run_attack
from meshadv.attacks.result import AttackResult
from meshadv.attacks.targets import StopRule
from meshadv.attacks.update import make_update_rule, update_rules
from meshadv.mesh.adjacency import vertex_edges
from meshadv.perceptibility.cap import as_cap
from meshadv.render.setup import RenderSetup
from meshadv.render.surface_reflectance import SurfaceReflectance
from meshadv.render.views import ViewSet

__all__ = ["MeshAttack"]

_JITTER_KEYS = ("azimuth", "elevation", "distance", "tilt", "light_direction", "light_intensity")


def _check_jitter(jitter: Any) -> Optional[Dict[str, float]]:
    """``None`` or a dict of known ``ViewSet.jitter`` keys to finite amounts ``>= 0``.

    Raises:
        TypeError: not a dict (e.g. ``[]``), or an amount that is not a real number.
        ValueError: unknown keys, or an amount that is negative or not finite.
    """
    if jitter is None:
        return None
    if not isinstance(jitter, dict):
        raise TypeError(f"jitter must be None or a dict of {_JITTER_KEYS}, got {type(jitter).__name__} {jitter!r}")
    unknown = set(jitter) - set(_JITTER_KEYS)
    if unknown:
        raise ValueError(f"jitter has unknown keys {sorted(map(str, unknown))}; known: {_JITTER_KEYS}")
    return {k: _validate.finite_float(f"jitter[{k!r}]", v, low=0.0) for k, v in jitter.items()}


class MeshAttack(ABC):
    """Base class of mesh attacks: holds hyper-parameters only (keyword-only); the mesh, views, victim and criterion
    are passed per call.

    Args:
        steps: maximum Adam steps per binary-search round (paper: 1000).
        lr: Adam learning rate.
        lambda_perceptual: initial weight ``lambda`` of the perceptual loss.
        binary_search_steps: rounds of the ``lambda`` search (paper: 5; 1 = a single run at ``lambda_perceptual``).
        loss: classifier loss, ``"ce"`` (targeted / untargeted cross-entropy) or ``"cw"`` (C&W margin).
        kappa: C&W confidence (``loss="cw"`` only).
        early_stop: stop a target once its criterion has held with ``early_stop_margin`` on every view for this
            many consecutive steps (``None``: run every step, as the paper).
        early_stop_margin: margin required by early stopping (logit units for classifiers, score units for
            detectors).
        max_distortion: distortion budget (shape: the Eq. 4 Laplacian sum of the flow, i.e. the per-pair mean times
            ``2E``; texture: colour RMSE): a target stops, failed unless it already succeeded within the budget, once
            it exceeds it.
        success_fraction: fraction of the victim views that must be adversarial (1.0 = all).
        jitter: random view / light jitter at every step, keys of ``ViewSet.jitter`` (``azimuth``, ``elevation``,
            ``distance``, ``tilt``, ``light_direction``, ``light_intensity``); ``None`` for none.
        seed: seed of the jitter generator and of the EOT draws (the attack is otherwise deterministic).
        eot: expectation over transformations (:mod:`meshadv.attacks.eot`): ``None`` (default) optimises the given
            views; a sample count ``N``, a dict of :class:`~meshadv.attacks.eot.Transformations` fields or a
            ``Transformations`` draws ``N`` fresh views from the whole range of the given views at every step
            (sub-pixel shifts, lights, antialias, image size, blur and noise too), keeps the least distorted
            parameters that hold on fresh check views, and measures the result's success on fresh evaluation views
            (``success`` and ``view_records`` are theirs; ``eval_views``, if given, are scored as well).
        method: the update rule (:mod:`meshadv.attacks.update`): ``"adam"`` (default) is the paper's Adam on
            ``L_adv + lambda * L_perceptual`` with the ``lambda`` binary search; others are registered there.
        method_options: extra keyword options of the update rule (JSON-able), ``None`` for none.
        perceptibility_cap: ceilings on what a person sees (:class:`meshadv.perceptibility.PerceptibilityCap`, a
            dict of its ceilings, or a string such as ``"default"`` or ``"max_displacement=0.02"``); ``None`` (the
            paper's protocol): none. A step counts as a success only inside the cap, a target that never succeeds
            inside it keeps its closest step inside it (or the pristine mesh), and a final mesh outside it is
            reported as failed. :func:`meshadv.perceptibility.recommended_cap` gives the cap of the command line.
            Under a ``max_displacement`` ceiling every update is followed by a projection of the flow into it
            (:mod:`meshadv.attacks.move_limit`), so no step moves a vertex farther than it allows.
        held_out_fraction: ``None`` or ``0`` (default): a target's verdict is that of the attack views (and the cap).
            A fraction in ``(0, 1]``: a target succeeds only when it also holds on at least this fraction of the
            held-out views, ``eval_views`` of the call or, when it gives none,
            :func:`meshadv.perceptibility.held_out_views` of its views (between and around them). Held-out views
            are never optimised on and never pick the kept result; they only judge it.

    Raises:
        TypeError: a hyper-parameter of the wrong type (``lr="0.1"``, ``steps=1.9``, ``steps=None``, ``jitter=[]``),
            naming it; floats are never truncated to integers.
        ValueError: a hyper-parameter out of range or not finite (``steps=0``, ``lr=inf``, ``seed=2**70``), naming
            it.
    """

    perturbation: str = ""

    def __init__(
        self,
        *,
        steps: int = 1000,
        lr: float = 0.01,
        lambda_perceptual: float = 1.0,
        binary_search_steps: int = 1,
        loss: str = "ce",
        kappa: float = 0.0,
        early_stop: Optional[int] = None,
        early_stop_margin: float = 0.0,
        max_distortion: Optional[float] = None,
        success_fraction: float = 1.0,
        jitter: Optional[Dict[str, float]] = None,
        seed: int = 0,
        method: str = "adam",
        method_options: Optional[Dict[str, Any]] = None,
        eot: TransformationsLike = None,
        perceptibility_cap: Any = None,
        held_out_fraction: Optional[float] = None,
    ) -> None:
        self.steps = _validate.positive_int("steps", steps)
        self.lr = _validate.positive_float("lr", lr)
        self.lambda_perceptual = _validate.finite_float("lambda_perceptual", lambda_perceptual, low=0.0)
        self.binary_search_steps = _validate.positive_int("binary_search_steps", binary_search_steps)
        self.loss = _validate.choice("loss", loss, CLASSIFIER_LOSSES)
        self.kappa = _validate.finite_float("kappa", kappa, low=0.0)
        self.early_stop = None if early_stop is None else _validate.positive_int("early_stop", early_stop)
        self.early_stop_margin = _validate.finite_float("early_stop_margin", early_stop_margin)
        self.max_distortion = (None if max_distortion is None
                               else _validate.positive_float("max_distortion", max_distortion))
        self.success_fraction = _validate.finite_float("success_fraction", success_fraction, low=0.0, high=1.0,
                                                       low_open=True)
        self.jitter = _check_jitter(jitter)
        self.seed = _validate.seed("seed", seed)
        self.method = _validate.choice("method", method, update_rules())
        if method_options is not None and not isinstance(method_options, dict):
            raise TypeError(f"method_options must be a dict or None, got {type(method_options).__name__}")
        self.method_options = dict(method_options or {})
        self.eot = as_transformations(eot)
        if self.eot is not None and self.jitter:
            raise ValueError("jitter and eot exclude each other: eot draws its own cameras and lights at every step")
        self.perceptibility_cap = as_cap(perceptibility_cap)
        held = None if held_out_fraction is None else _validate.finite_float("held_out_fraction", held_out_fraction,
                                                                              low=0.0, high=1.0)
        self.held_out_fraction = held if held else None

    # ------------------------------------------------------------------ the family's parametrisation
    @abstractmethod
    def initial_params(self, mesh: Any, num_targets: int) -> Tensor:
        """Initial parameters ``(T, ...)`` (the pristine mesh)."""

    @abstractmethod
    def apply(self, params: Tensor, mesh: Any, edges: Tensor) -> Tuple[Tensor, Tensor]:
        """``(vertices (K,N,3), face_colors (M,3) or (K,M,3))`` for parameters ``(K, ...)`` (``edges`` of ``mesh``)."""

    @abstractmethod
    def perceptual(self, params: Tensor, mesh: Any, edges: Tensor, images: Tensor, alpha: Tensor,
                   num_views: int) -> Tensor:
        """Perceptual loss per target ``(K,)``."""

    @abstractmethod
    def distance(self, params: Tensor, mesh: Any, edges: Tensor) -> Tensor:
        """Distortion per target ``(K,)`` (the budget / best-result measure)."""

    def terms(self, params: Tensor, mesh: Any, edges: Tensor, images: Tensor, alpha: Tensor,
              num_views: int) -> Tuple[Tensor, Tensor]:
        """``(perceptual, distance)`` per target, each ``(K,)``; a family whose two terms share work overrides it."""
        return (self.perceptual(params, mesh, edges, images, alpha, num_views),
                self.distance(params, mesh, edges))

    def result_meshes(self, params: Tensor, mesh: Any, edges: Tensor) -> Tuple[Any, ...]:
        """The ``T`` adversarial meshes of parameters ``(T, ...)`` (float32, contiguous, detached copies of
        :meth:`apply`'s vertices and face colours; a ``mesh`` rendered with its texture keeps it on the new vertices); a
        family whose meshes carry more overrides it."""
        from meshadv.mesh import Mesh

        num_t = params.shape[0]
        with torch.no_grad():
            verts, colors = self.apply(params, mesh, edges)
            if isinstance(colors, SurfaceReflectance):
                return tuple(mesh.with_vertices(verts[t].clone().contiguous()) for t in range(num_t))
            if colors.dim() == 2:
                colors = colors.unsqueeze(0).expand(num_t, -1, -1)
        return tuple(Mesh(verts[t].detach().clone().float().contiguous(), mesh.faces,
                          colors[t].detach().clone().float().contiguous()) for t in range(num_t))

    def result_distances(self, mesh: Any, adversarial: Any, edges: Tensor) -> Dict[str, float]:
        """Every distance between ``mesh`` and one adversarial mesh of :meth:`result_meshes`
        (:func:`~meshadv.attacks.distances.mesh_distances`); a family with its own measures adds them."""
        return mesh_distances(mesh.vertices, mesh.face_colors, adversarial.vertices, adversarial.face_colors, edges)

    def stop_rule(self) -> StopRule:
        """The thresholds of a target's success and stop (:mod:`meshadv.attacks.targets`)."""
        return StopRule(success_fraction=self.success_fraction, max_distortion=self.max_distortion,
                        early_stop=self.early_stop, early_stop_margin=self.early_stop_margin,
                        cap=self.perceptibility_cap)

    def check_mesh(self, mesh: Any) -> None:
        """Raise ``ValueError`` when the attack's masks do not fit ``mesh`` (the default accepts every mesh)."""

    def limit_moves(self, params: Tensor, idx: Tensor, edges: Tensor, radius: float) -> bool:
        """Pull the rows ``idx`` of ``params`` (in place) so that no vertex of their meshes moves farther than
        ``radius`` (scene units) from its pristine place, leaving rows already inside unchanged; ``True`` when a row
        changed. The attack loop calls it after every update under a cap with a ``max_displacement`` ceiling. The
        default, for families that move no vertex, changes nothing."""
        return False

    def budget_space(self, **options: Any) -> Any:
        """The space a distortion-budget rule (``method="ddn"``) steps this family's parameters in: a
        :class:`~meshadv.attacks.norms.FlowSpace` or :class:`~meshadv.attacks.norms.ColorSpace` (built for a mesh by
        its ``prepare(mesh, edges)``), made with ``options`` (the space's own options, see
        :meth:`budget_defaults`).

        Raises:
            ValueError: the family's parametrisation cannot be stepped that way, or a bad option.
        """
        raise ValueError(f"method='ddn' cannot step the parametrisation of {type(self).__name__}")

    @classmethod
    def budget_defaults(cls) -> Dict[str, Any]:
        """The default options of a distortion-budget rule on this family, in its space's norm units (budgets and
        step lengths, and the space's own options).

        Raises:
            ValueError: the family has no budget space.
        """
        raise ValueError(f"method='ddn' supports the shape and texture attacks, not {cls.__name__}")

    # ------------------------------------------------------------------ public
    def config(self) -> Dict[str, Any]:
        """The hyper-parameters as a JSON-able dict; ``method_options`` are the effective options of the update rule
        (the rule's ``config()`` over the options passed, so defaults the rule fills in are shown).

        Raises:
            ValueError: ``method_options`` the update rule rejects (as the attack call would), naming them.
        """
        rule = make_update_rule(self.method, attack=self, num_targets=1, **self.method_options)
        robust = {} if self.eot is None else {"eot": self.eot.config()}
        if self.held_out_fraction is not None:
            robust["held_out_fraction"] = self.held_out_fraction
        return {
            "perturbation": self.perturbation, "steps": self.steps, "lr": self.lr,
            "lambda_perceptual": self.lambda_perceptual, "binary_search_steps": self.binary_search_steps,
            "loss": self.loss, "kappa": self.kappa, "early_stop": self.early_stop,
            "early_stop_margin": self.early_stop_margin, "max_distortion": self.max_distortion,
            "success_fraction": self.success_fraction, "jitter": self.jitter, "seed": self.seed, "method": self.method,
            "method_options": {**self.method_options, **rule.config()}, **robust,
            "perceptibility_cap": None if self.perceptibility_cap is None else self.perceptibility_cap.to_record(),
        }

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.config().items() if k != "perturbation")
        return f"{type(self).__name__}({args})"

    def __call__(
        self,
        mesh: Any,
        views: Any,
        victim: Any,
        criterion: Union[Criterion, Sequence[Criterion]],
        *,
        setup: Optional[RenderSetup] = None,
        eval_views: Any = None,
        callback: Optional[Callable[[StepInfo], None]] = None,
    ) -> AttackResult:
        """Attack ``mesh`` seen from ``views`` against ``victim`` towards ``criterion``.

        Args:
            mesh: the pristine ``meshadv.mesh.Mesh``.
            views: a ``meshadv.render.ViewSet`` of the ``V`` victim views optimised over.
            victim: a classifier or detector victim (``meshadv.victims``).
            criterion: one criterion, or a sequence of ``T`` criteria attacked together as a batch.
            setup: how the mesh is rendered (:class:`~meshadv.render.setup.RenderSetup`: image size, background
                colour or photo, supersampling, static scene objects); default ``RenderSetup()`` (224 px, white).
            eval_views: optional held-out ``ViewSet`` on which the final meshes are also evaluated.
            callback: called after every step with a :class:`StepInfo`; raising ``KeyboardInterrupt`` from it stops
                the attack like Ctrl-C.

        Returns:
            An :class:`~meshadv.attacks.result.AttackResult`.

        Raises:
            ValueError: bad mesh or criterion, or a criterion that does not suit the victim.
            TypeError: ``views`` or ``eval_views`` is not a ViewSet, or ``setup`` not a RenderSetup.
        """
        criteria = as_criteria(criterion)
        if not all(hasattr(mesh, name) for name in ("vertices", "faces", "face_colors")):
            raise ValueError(f"mesh must be a meshadv.mesh.Mesh, got {type(mesh).__name__}")
        views = ViewSet.require(views)
        if eval_views is not None:
            eval_views = ViewSet.require(eval_views, "eval_views")
        if setup is None:
            setup = RenderSetup()
        elif not isinstance(setup, RenderSetup):
            raise TypeError(f"setup must be a meshadv.render.RenderSetup or None, got {type(setup).__name__}")
        self.check_mesh(mesh)
        bound = [c.bind(victim) for c in criteria]
        call = AttackCall(mesh, views.detach(), victim, setup, vertex_edges(mesh.faces).long())
        return run_attack(self, call, bound, eval_views, callback)
