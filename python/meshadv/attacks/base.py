"""The optimisation loop shared by the shape and texture attacks.

An attack minimises ``L_adv + lambda * L_perceptual`` with Adam over a per-target parameter tensor ``(T, ...)``:
the ``T`` targets are a batch dimension, so one call renders ``T x V`` images (``V`` victim views) and evaluates the
victim once. Because Adam is element-wise and the total loss is a sum of per-target terms, the targets are optimised
exactly as if they ran one at a time. A target stops being rendered once it is finished (early stopping or budget).

Per step, for the parameters *before* the update, the loop records the per-view margins of the criterion; a target
whose views are adversarial (at least ``success_fraction`` of them) within the distortion budget keeps those
parameters when their distortion is the least seen so far. ``lambda`` is searched per target over
``binary_search_steps`` rounds (:class:`~meshadv.attacks.search.LambdaSearch`), each round restarting from the
pristine mesh with the same seed. How losses become updates is the attack's update rule (``method=``,
:mod:`meshadv.attacks.update`); the loop above is the paper's rule, ``"adam"``, and the only loop.

The result's success and scores are measured on the final meshes re-rendered from scratch (without jitter), never on
the optimiser's last images. Ctrl-C (``KeyboardInterrupt``) inside the loop stops the attack and returns the best
result so far with ``interrupted=True``.
"""

from __future__ import annotations

import math
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple, Union

import torch
from torch import Tensor

from meshadv import _validate
from meshadv.attacks.criteria import CLASSIFIER_LOSSES, Criterion
from meshadv.attacks.distances import mesh_distances
from meshadv.attacks.evaluation import Evaluation, evaluate
from meshadv.attacks.outputs import cat_outputs, output_tensors, rebuild_output, slice_output
from meshadv.attacks.pipeline import StepWorkers, split_images
from meshadv.attacks.result import AttackResult, enough_views
from meshadv.attacks.targets import StopRule, TargetState
from meshadv.attacks.update import make_update_rule, update_rules
from meshadv.mesh.adjacency import vertex_edges
from meshadv.render.setup import RenderSetup

#: ``Evaluation``, ``evaluate`` (:mod:`meshadv.attacks.evaluation`) and ``slice_output``
#: (:mod:`meshadv.attacks.outputs`) are re-exported from their old home.
__all__ = ["MeshAttack", "StepInfo", "Evaluation", "evaluate", "slice_output"]

#: Largest accepted ``step_workers``.
_MAX_STEP_WORKERS = 64


_JITTER_KEYS = ("azimuth", "elevation", "distance", "tilt", "light_direction", "light_intensity")


@dataclass(frozen=True)
class StepInfo:
    """Progress of one optimiser step, passed to the ``callback`` of an attack call.

    Attributes:
        round: binary-search round (0-based); ``rounds`` the number of rounds.
        step: step within the round (0-based); ``steps`` the maximum steps per round.
        total_step: steps done over all rounds before this one.
        lambdas: current ``lambda`` per target.
        loss: total loss per target (``None`` for finished targets).
        distance: current distortion per target (Laplacian for shape, colour RMSE for texture), or ``None``.
        margin: worst-view criterion margin per target, or ``None``.
        top1: top-1 class of the first view per target (classifiers), or ``None``.
        best_distance: least distortion of a success so far per target (``None`` before any success).
        active: number of targets still being optimised.
    """

    round: int
    rounds: int
    step: int
    steps: int
    total_step: int
    lambdas: Tuple[float, ...]
    loss: Tuple[Optional[float], ...]
    distance: Tuple[Optional[float], ...]
    margin: Tuple[Optional[float], ...]
    top1: Tuple[Optional[int], ...]
    best_distance: Tuple[Optional[float], ...]
    active: int


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


@dataclass(frozen=True)
class _RunInfo:
    """What the loop hands to the final evaluation besides the chosen parameters."""

    history: Tuple[Dict[str, Any], ...]
    steps: int
    wall_time: float
    interrupted: bool
    config: Dict[str, Any]


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
                        early_stop=self.early_stop, early_stop_margin=self.early_stop_margin)

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
            ValueError: bad mesh, views or criterion, or a criterion that does not suit the victim.
        """
        criteria = [criterion] if isinstance(criterion, Criterion) else list(criterion)
        if not criteria or not all(isinstance(c, Criterion) for c in criteria):
            raise ValueError("criterion must be a Criterion or a non-empty sequence of Criterion objects")
        for name, value in (("mesh", mesh), ):
            if not hasattr(value, "vertices") or not hasattr(value, "faces") or not hasattr(value, "face_colors"):
                raise ValueError(f"{name} must be a meshadv.mesh.Mesh, got {type(value).__name__}")
        if not hasattr(views, "camera") or len(views) < 1:
            raise ValueError("views must be a non-empty meshadv.render.ViewSet")
        if eval_views is not None and (not hasattr(eval_views, "camera") or len(eval_views) < 1):
            raise ValueError("eval_views must be None or a non-empty meshadv.render.ViewSet")
        if setup is None:
            setup = RenderSetup()
        elif not isinstance(setup, RenderSetup):
            raise TypeError(f"setup must be a meshadv.render.RenderSetup or None, got {type(setup).__name__}")
        self._check_mesh(mesh)
        bound = [c.bind(victim) for c in criteria]
        return self._run(_Call(mesh, views.detach(), victim, setup, vertex_edges(mesh.faces).long()), bound,
                         eval_views, callback)

    def _check_mesh(self, mesh: Any) -> None:
        """Family hook: raise ``ValueError`` when the attack's masks do not fit ``mesh``."""

    # ------------------------------------------------------------------ loop
    def _forward(self, params: Tensor, call: "_Call", views: Any) -> Tuple[Tensor, Tensor, Any]:
        verts, colors = self._apply(params, call.mesh, call.edges)
        images, alpha = call.setup.render(verts, call.mesh.faces, colors, views)
        return images, alpha, call.victim(images)

    def _adv(self, output: Any, criteria: List[Criterion], num_v: int) -> Tuple[Tensor, Tensor]:
        """Per-target adversarial loss ``(K,)`` (differentiable) and per-view margins ``(K, V)`` (detached)."""
        parts = [slice_output(output, a * num_v, (a + 1) * num_v) for a in range(len(criteria))]
        adv = torch.stack([c.loss(o, loss=self.loss, kappa=self.kappa).mean() for c, o in zip(criteria, parts)])
        with torch.no_grad():
            margins = torch.stack([c.margin(o).detach() for c, o in zip(criteria, parts)])
        return adv, margins

    def _serial_step(self, p: Tensor, idx: Tensor, criteria: List[Criterion], call: "_Call", views: Any,
                     rule: Any) -> Tuple[Tensor, Tensor, Tensor, Any, Tensor]:
        """One step in the calling thread: forward, objective, ``backward()`` into the parameters' ``.grad``.
        Returns ``(adv, perceptual, distance, output, margins)``."""
        images, alpha, output = self._forward(p, call, views)
        adv, margins = self._adv(output, criteria, len(views))
        perc, dist = self._terms(p, call.mesh, call.edges, images, alpha, len(views))
        rule.objective(adv, perc, dist, idx).backward()
        return adv, perc, dist, output, margins

    def _pipelined_step(self, params: Tensor, idx: Tensor, criteria: List[Criterion], call: "_Call", views: Any,
                        rule: Any, workers: StepWorkers) -> Tuple[Tensor, Tensor, Tensor, Any, Tensor]:
        """The step of :meth:`_serial_step` with the images split over ``workers``
        (:mod:`meshadv.attacks.pipeline`); same returns, the parameters' ``.grad`` filled the same way."""
        num_v = len(views)
        chunks = split_images(len(criteria), num_v, workers.workers)
        rows = [(blocks[0][0], blocks[-1][1]) for blocks in chunks]  # the targets each chunk renders
        leaves = [params[idx[a:b]].detach().requires_grad_(True) for a, b in rows]

        def forward(c: int) -> Tuple[Tensor, Tensor, Tensor, Any]:
            verts, colors = self._apply(leaves[c], call.mesh, call.edges)
            first = rows[c][0]
            parts = [call.setup.render(verts[k0 - first:k1 - first], call.mesh.faces,
                                       colors if colors.dim() == 2 else colors[k0 - first:k1 - first],
                                       views if (v0, v1) == (0, num_v) else views[v0:v1])
                     for k0, k1, v0, v1 in chunks[c]]
            images = parts[0][0] if len(parts) == 1 else torch.cat([im for im, _ in parts])
            alpha = parts[0][1] if len(parts) == 1 else torch.cat([al for _, al in parts])
            x = images.detach().requires_grad_(True)
            return images, alpha, x, call.victim(x)

        fwd = workers.map(forward, list(range(len(chunks))))
        # cut at the victim's output and at alpha: their cotangents come from the objective below
        outs = [[None if t is None else t.detach().requires_grad_(t.requires_grad) for t in output_tensors(f[3])]
                for f in fwd]
        alphas = [f[1].detach().requires_grad_(f[1].requires_grad) for f in fwd]
        output = cat_outputs([rebuild_output(f[3], o) for f, o in zip(fwd, outs)])
        adv, margins = self._adv(output, criteria, num_v)
        p = params[idx]
        perc, dist = self._terms(p, call.mesh, call.edges, torch.cat([f[2] for f in fwd]), torch.cat(alphas), num_v)
        rule.objective(adv, perc, dist, idx).backward()

        def backward(c: int) -> Optional[Tensor]:
            images, alpha, x, out = fwd[c]
            pairs = [(t, cut.grad) for t, cut in zip(output_tensors(out), outs[c]) if cut is not None
                     and cut.grad is not None]
            if pairs:
                torch.autograd.backward([t for t, _ in pairs], [g for _, g in pairs])
            pairs = [(t, g) for t, g in ((images, x.grad), (alpha, alphas[c].grad)) if g is not None
                     and t.requires_grad]
            if pairs:
                torch.autograd.backward([t for t, _ in pairs], [g for _, g in pairs])
            return leaves[c].grad

        grads = workers.map(backward, list(range(len(chunks))))
        with torch.no_grad():
            for (a, b), grad in zip(rows, grads):
                if grad is None:
                    continue
                if params.grad is None:
                    params.grad = torch.zeros_like(params)
                params.grad.index_put_((idx[a:b],), grad, accumulate=True)
        return adv, perc, dist, output.detach() if isinstance(output, Tensor) else output, margins

    def _run(self, call: "_Call", criteria: List[Criterion], eval_views: Any,
             callback: Optional[Callable[[StepInfo], None]]) -> AttackResult:
        t_start = time.perf_counter()
        mesh, views, edges = call.mesh, call.views, call.edges
        num_t, num_v = len(criteria), len(views)
        config = self.config()  # the hyper-parameters the run starts with, for the result
        rule = make_update_rule(self.method, attack=self, num_targets=num_t, **self.method_options)
        rule.prepare(mesh, edges)
        targets = [TargetState(c) for c in criteria]
        stop = self._stop_rule()
        history: List[Dict[str, Any]] = []
        total_steps = 0
        interrupted = False
        classifier = getattr(call.victim, "kind", "") == "classifier"
        most = self.workers_for(num_t * num_v)
        workers = StepWorkers(most, max(1, torch.get_num_threads() // most)) if most > 1 else None

        try:
            for rnd in range(rule.rounds):
                generator = torch.Generator().manual_seed(self.seed)
                params = self._init_params(mesh, num_t).detach().clone().requires_grad_(True)
                rule.start_round(params)
                lambdas = rule.lambdas
                for target in targets:
                    target.start_round()
                for step in range(self.steps):
                    act = [t for t in range(num_t) if targets[t].active]
                    if not act:
                        break
                    try:
                        step_views = views.jitter(generator, **self.jitter) if self.jitter else views
                        idx = torch.tensor(act, dtype=torch.long)
                        p = params[idx]
                        crits = [targets[t].criterion for t in act]
                        if workers is not None and self.workers_for(len(act) * num_v) > 1:
                            adv, perc, dist, output, margins = self._pipelined_step(
                                params, idx, crits, call, step_views, rule, workers)
                        else:
                            adv, perc, dist, output, margins = self._serial_step(p, idx, crits, call, step_views,
                                                                                 rule)
                        with torch.no_grad():
                            fractions = (margins > 0).float().mean(dim=1)
                            is_adv = enough_views(fractions, self.success_fraction)
                        rule.step(params, idx, is_adv)
                    except KeyboardInterrupt:
                        interrupted = True
                        break
                    total_steps += 1
                    with torch.no_grad():
                        adv, perc, dist = adv.detach(), perc.detach(), dist.detach()
                        total = adv + lambdas[idx] * perc
                        top = output.detach().argmax(dim=1).view(len(act), num_v)[:, 0] if classifier else None
                    row: Dict[str, Any] = {"round": rnd, "step": step, "loss": [None] * num_t, "adv": [None] * num_t,
                                           "perceptual": [None] * num_t, "distance": [None] * num_t,
                                           "margin": [None] * num_t, "lambda": lambdas.tolist()}
                    top1: List[Optional[int]] = [None] * num_t
                    for a, t in enumerate(act):
                        d = float(dist[a])
                        targets[t].observe(p[a], d, float(fractions[a]), margins[a], float(lambdas[t]), stop,
                                           total_steps, time.perf_counter() - t_start)
                        row["loss"][t] = float(total[a])
                        row["adv"][t] = float(adv[a])
                        row["perceptual"][t] = float(perc[a])
                        row["distance"][t] = d
                        row["margin"][t] = float(margins[a].min())
                        if top is not None:
                            top1[t] = int(top[a])
                    history.append(row)
                    if callback is not None:
                        info = StepInfo(
                            round=rnd, rounds=rule.rounds, step=step, steps=self.steps,
                            total_step=total_steps, lambdas=tuple(lambdas.tolist()), loss=tuple(row["loss"]),
                            distance=tuple(row["distance"]), margin=tuple(row["margin"]), top1=tuple(top1),
                            best_distance=tuple(None if math.isinf(tg.best_distance) else tg.best_distance
                                                for tg in targets),
                            active=sum(tg.active for tg in targets),
                        )
                        try:
                            callback(info)
                        except KeyboardInterrupt:
                            interrupted = True
                            break
                if interrupted:
                    break
                rule.end_round([tg.round_success for tg in targets])

        except KeyboardInterrupt:  # Ctrl-C between steps: keep what we have
            interrupted = True
        finally:
            if workers is not None:
                workers.close()

        pristine = self._init_params(mesh, 1)[0].detach()
        chosen = torch.stack([tg.chosen(pristine) for tg in targets])
        run = _RunInfo(history=tuple(history), steps=total_steps, wall_time=time.perf_counter() - t_start,
                       interrupted=interrupted, config=config)
        return self._finish(call, targets, eval_views, chosen, run)

    # ------------------------------------------------------------------ final evaluation
    def _finish(self, call: "_Call", targets: List[TargetState], eval_views: Any, params: Tensor,
                run: _RunInfo) -> AttackResult:
        from meshadv.mesh import Mesh

        mesh, views, victim = call.mesh, call.views, call.victim
        num_t = params.shape[0]
        with torch.no_grad():
            verts, colors = self._apply(params, mesh, call.edges)
            if colors.dim() == 2:
                colors = colors.unsqueeze(0).expand(num_t, -1, -1)
        adversarial = tuple(
            Mesh(verts[t].detach().clone().float().contiguous(), mesh.faces,
                 colors[t].detach().clone().float().contiguous())
            for t in range(num_t)
        )
        criteria = [tg.criterion for tg in targets]
        after = evaluate(adversarial, views, victim, criteria, setup=call.setup)
        before = evaluate([mesh], views, victim, criteria, setup=call.setup)
        eval_success = eval_scores = None
        if eval_views is not None:
            held_out = evaluate(adversarial, eval_views.detach(), victim, criteria, setup=call.setup)
            eval_success, eval_scores = held_out.success, held_out.scores
        distances = tuple(
            mesh_distances(mesh.vertices, mesh.face_colors, m.vertices, m.face_colors, call.edges) for m in adversarial
        )
        return AttackResult(
            original=mesh,
            adversarial=adversarial,
            perturbation=self.perturbation,
            criteria=tuple(c.to_record() for c in criteria),
            success=after.success,
            scores=after.scores,
            original_scores=before.scores,
            margins=after.margins,
            top1=after.top1,
            original_top1=None if before.top1 is None else before.top1[0],
            eval_success=eval_success,
            eval_scores=eval_scores,
            distances=distances,
            lambdas=tuple(tg.best_lambda for tg in targets),
            loss_history=run.history,
            steps=run.steps,
            steps_to_success=tuple(tg.first_step for tg in targets),
            time_to_success=tuple(tg.first_time for tg in targets),
            wall_time=run.wall_time,
            interrupted=run.interrupted,
            success_fraction=self.success_fraction,
            original_images=before.images[0],
            images=after.images,
            view_records=tuple(views.to_records()),
            eval_view_records=None if eval_views is None else tuple(eval_views.to_records()),
            config={**run.config, **call.setup.config()},
            victim=str(getattr(victim, "name", type(victim).__name__)),
            class_names=tuple(getattr(victim, "class_names", ()) or ()),
        )


@dataclass(frozen=True)
class _Call:
    """What one attack call works on: the mesh, the views, the victim, the render setup and the mesh's edges."""

    mesh: Any
    views: Any
    victim: Any
    setup: RenderSetup
    edges: Tensor
