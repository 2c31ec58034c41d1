"""The base class of the mesh attacks: hyper-parameters, the family hooks and the attack call.

:class:`MeshAttack` holds only hyper-parameters (keyword-only, validated at construction); a family
(:class:`~meshadv.attacks.ShapeAttack`, :class:`~meshadv.attacks.TextureAttack`, ...) says what is optimised through
its hooks: the initial parameters, how parameters become vertices and colours, the perceptual loss and the distortion.
Calling an attack validates the mesh, views, victim and criteria and runs the one optimisation loop
(:mod:`meshadv.attacks.loop`); one step of it lives in :mod:`meshadv.attacks.step`, the per-target bookkeeping in
:mod:`meshadv.attacks.targets`, the update rules (``method=``) in :mod:`meshadv.attacks.update`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple, Union

from torch import Tensor

from meshadv import _validate
from meshadv.attacks.criteria import CLASSIFIER_LOSSES, Criterion, as_criteria
from meshadv.attacks.evaluation import Evaluation, evaluate
from meshadv.attacks.loop import run_attack
from meshadv.attacks.outputs import slice_output
from meshadv.attacks.pipeline import StepWorkers
from meshadv.attacks.progress import StepInfo
from meshadv.attacks.result import AttackResult
from meshadv.attacks.step import AttackCall, StepTerms, pipelined_step, serial_step
from meshadv.attacks.targets import StopRule
from meshadv.attacks.update import make_update_rule, update_rules
from meshadv.mesh.adjacency import vertex_edges
from meshadv.perceptibility.cap import as_cap
from meshadv.render.setup import RenderSetup
from meshadv.render.views import ViewSet

#: ``StepInfo`` (:mod:`meshadv.attacks.progress`), ``Evaluation``, ``evaluate`` (:mod:`meshadv.attacks.evaluation`)
#: and ``slice_output`` (:mod:`meshadv.attacks.outputs`) are re-exported from their old home.
__all__ = ["MeshAttack", "StepInfo", "Evaluation", "evaluate", "slice_output"]

#: The attack call's data under its old name (tests/test_pipeline.py and benchmarks/attack_bench.py build one).
_Call = AttackCall

#: Largest accepted ``step_workers``.
_MAX_STEP_WORKERS = 64


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
        seed: seed of the jitter generator (the attack is otherwise deterministic).
        method: the update rule (:mod:`meshadv.attacks.update`): ``"adam"`` (default) is the paper's Adam on
            ``L_adv + lambda * L_perceptual`` with the ``lambda`` binary search; others are registered there.
        method_options: extra keyword options of the update rule (JSON-able), ``None`` for none.
        step_workers: threads a step's images are split over (:mod:`meshadv.attacks.pipeline`; ranges of targets,
            or of one target's views): each renders its chunk and runs the victim on it, overlapping one chunk's
            render with another's victim; the
            gradient is the one-thread step's up to the victim's float rounding at another batch size and thread
            count. ``1`` (default): one thread, the step as it always was. ``2`` was faster on a loaded 2-core
            machine (+9-15% target-steps/s, benchmarks/RESULTS.md "Pipelined attack step"); since the cheaper NMR
            backward it gains nothing for shape on a quiet one (same file, "Attack step split at HEAD on a quiet
            machine"). It runs each chunk's victim on fewer torch threads, so its float rounding differs from a
            serial run's. An execution setting like
            ``--threads``: not part of :meth:`config`.
        perceptibility_cap: ceilings on what a person sees (:class:`meshadv.perceptibility.PerceptibilityCap`, a
            dict of its ceilings, or a string such as ``"default"`` or ``"max_displacement=0.02"``); ``None`` (the
            paper's protocol): none. A step counts as a success only inside the cap, a target that never succeeds
            inside it keeps its closest step inside it (or the pristine mesh), and a final mesh outside it is
            reported as failed. :func:`meshadv.perceptibility.recommended_cap` gives the cap of the command line.

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
        step_workers: int = 1,
        perceptibility_cap: Any = None,
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
        self.step_workers = _validate.positive_int("step_workers", step_workers, high=_MAX_STEP_WORKERS)
        self.perceptibility_cap = as_cap(perceptibility_cap)

    # ------------------------------------------------------------------ family hooks
    @abstractmethod
    def _init_params(self, mesh: Any, num_targets: int) -> Tensor:
        """Initial parameters ``(T, ...)`` (the pristine mesh)."""

    @abstractmethod
    def _apply(self, params: Tensor, mesh: Any, edges: Tensor) -> Tuple[Tensor, Tensor]:
        """``(vertices (K,N,3), face_colors (M,3) or (K,M,3))`` for parameters ``(K, ...)`` (``edges`` of ``mesh``)."""

    @abstractmethod
    def _perceptual(self, params: Tensor, mesh: Any, edges: Tensor, images: Tensor, alpha: Tensor,
                    num_views: int) -> Tensor:
        """Perceptual loss per target ``(K,)``."""

    @abstractmethod
    def _distance(self, params: Tensor, mesh: Any, edges: Tensor) -> Tensor:
        """Distortion per target ``(K,)`` (the budget / best-result measure)."""

    def _terms(self, params: Tensor, mesh: Any, edges: Tensor, images: Tensor, alpha: Tensor,
               num_views: int) -> Tuple[Tensor, Tensor]:
        """``(perceptual, distance)`` per target, each ``(K,)``; a family whose two terms share work overrides it."""
        return (self._perceptual(params, mesh, edges, images, alpha, num_views),
                self._distance(params, mesh, edges))

    def _stop_rule(self) -> StopRule:
        """The thresholds of a target's success and stop (:mod:`meshadv.attacks.targets`)."""
        return StopRule(success_fraction=self.success_fraction, max_distortion=self.max_distortion,
                        early_stop=self.early_stop, early_stop_margin=self.early_stop_margin,
                        cap=self.perceptibility_cap)

    def workers_for(self, num_images: int) -> int:
        """The step workers used for a step of ``num_images`` images (active targets x views): ``step_workers``, never
        more than there are images."""
        return max(1, min(self.step_workers, num_images))

    # ------------------------------------------------------------------ public
    def config(self) -> Dict[str, Any]:
        """The hyper-parameters as a JSON-able dict; ``method_options`` are the effective options of the update rule
        (the rule's ``config()`` over the options passed, so defaults the rule fills in are shown).

        Raises:
            ValueError: ``method_options`` the update rule rejects (as the attack call would), naming them.
        """
        rule = make_update_rule(self.method, attack=self, num_targets=1, **self.method_options)
        return {
            "perturbation": self.perturbation, "steps": self.steps, "lr": self.lr,
            "lambda_perceptual": self.lambda_perceptual, "binary_search_steps": self.binary_search_steps,
            "loss": self.loss, "kappa": self.kappa, "early_stop": self.early_stop,
            "early_stop_margin": self.early_stop_margin, "max_distortion": self.max_distortion,
            "success_fraction": self.success_fraction, "jitter": self.jitter, "seed": self.seed, "method": self.method,
            "method_options": {**self.method_options, **rule.config()},
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
        self._check_mesh(mesh)
        bound = [c.bind(victim) for c in criteria]
        call = AttackCall(mesh, views.detach(), victim, setup, vertex_edges(mesh.faces).long())
        return run_attack(self, call, bound, eval_views, callback)

    def _check_mesh(self, mesh: Any) -> None:
        """Family hook: raise ``ValueError`` when the attack's masks do not fit ``mesh``."""

    # ------------------------------------------------------------------ the step (meshadv.attacks.step)
    def _serial_step(self, p: Tensor, idx: Tensor, criteria: List[Criterion], call: AttackCall, views: Any,
                     rule: Any) -> StepTerms:
        """:func:`meshadv.attacks.step.serial_step` of this attack (kept as a method for the tests and
        benchmarks/attack_bench.py, which time and compare the step)."""
        return serial_step(self, p, idx, criteria, call, views, rule)

    def _pipelined_step(self, params: Tensor, idx: Tensor, criteria: List[Criterion], call: AttackCall, views: Any,
                        rule: Any, workers: StepWorkers) -> StepTerms:
        """:func:`meshadv.attacks.step.pipelined_step` of this attack (see :meth:`_serial_step`)."""
        return pipelined_step(self, params, idx, criteria, call, views, rule, workers)
