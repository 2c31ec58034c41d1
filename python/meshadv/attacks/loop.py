"""The one optimisation loop of the mesh attacks: rounds of steps over the active targets, then the final result.

An attack minimises ``L_adv + lambda * L_perceptual`` over a per-target parameter tensor ``(T, ...)``: the ``T``
targets are a batch dimension, so one step renders ``T x V`` images (``V`` victim views) and evaluates the victim
once. Because the paper's Adam is element-wise and the total loss is a sum of per-target terms, the targets are
optimised exactly as if they ran one at a time. A target stops being rendered once it is finished (early stopping or
budget). How losses become updates is the attack's update rule (``method=``, :mod:`meshadv.attacks.update`); this
loop serves every rule. What is optimised is the attack family's (:class:`AttackFamily`, the public family methods of
:class:`~meshadv.attacks.mesh_attack.MeshAttack`).

Per round (``rule.rounds`` of them: for ``method="adam"`` the ``binary_search_steps`` rounds of the per-target
``lambda`` search, :class:`~meshadv.attacks.search.LambdaSearch`) the parameters restart from the pristine mesh and
the jitter generator from the attack's seed. Per step (:func:`attack_step`), the active targets' ``K x V`` images are
rendered (mesh-major), the victim runs once, and per target the adversarial loss (the criterion's loss, mean over the
views), the perceptual loss and the distortion are computed; the update rule's ``objective`` of those is
back-propagated into the parameters' ``.grad`` and the rule steps the parameters. Each target records the per-view
margins and the distortion of the parameters *before* the update (:class:`~meshadv.attacks.targets.TargetState`): a
target whose views are adversarial (at least ``success_fraction`` of them) within the distortion budget keeps those
parameters when their distortion is the least seen so far. The step's loss-history row is kept and the callback, if
any, gets a :class:`~meshadv.attacks.history.StepInfo`.

Under a perceptibility cap with a largest-move ceiling (``max_displacement``), every update is followed by a
projection of the flow into it (the family's ``limit_moves``, :mod:`meshadv.attacks.move_limit`), for every update
rule: no vertex ever moves farther than the ceiling allows, so the steps are spent on meshes the cap admits.

The result's success and scores are measured on the final meshes re-rendered from scratch (without jitter,
:func:`~meshadv.attacks.evaluation.evaluate`), never on the optimiser's last images; held-out views (``eval_views``,
or the held-out views of the attack's views when its ``held_out_fraction`` asks for a held-out verdict) only judge
the kept meshes, they never choose them. Ctrl-C (``KeyboardInterrupt``)
in a step, in the callback or between steps ends the loop; the result is then the best so far, with
``interrupted=True``.

With ``eot`` (:mod:`meshadv.attacks.eot`) every step renders a fresh draw of views and render setup, and the victim
sees the renders through the draw's blur and noise; a target observes a step (success, best result, early stopping)
only at the success checks, every ``check_every`` steps and after a round's last step, with the margins of fresh
check views (:func:`~meshadv.attacks.eot.check_margins`), and leaves at any step once it exceeds the distortion
budget; the result is measured on a fresh evaluation draw.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Any, Callable, Dict, List, NamedTuple, Optional, Protocol, Tuple

import torch
from torch import Tensor

from meshadv.attacks.criteria import Criterion
from meshadv.attacks.eot import (CHECK_STREAM, EVAL_STREAM, STEP_STREAM, EOTSampler, Transformations, check_margins,
                                 stream_seed)
from meshadv.attacks.evaluation import evaluate
from meshadv.attacks.history import StepInfo, first_view_top1, history_row, step_info
from meshadv.attacks.outputs import slice_output
from meshadv.attacks.result import AttackResult, enough_views
from meshadv.attacks.targets import StopRule, TargetState
from meshadv.attacks.update import UpdateRule, make_update_rule
from meshadv.mesh.structure import bbox_diagonal
from meshadv.perceptibility.cap import step_measures
from meshadv.perceptibility.held_out import held_out_views
from meshadv.perceptibility.measures import perceptibility_measures
from meshadv.render.setup import RenderSetup

__all__ = ["AttackCall", "AttackFamily", "StepTerms", "adversarial_terms", "attack_step", "move_radius", "run_attack"]


class AttackFamily(Protocol):
    """What the loop asks of an attack (:class:`~meshadv.attacks.mesh_attack.MeshAttack` and its families):
    hyper-parameters and the family's parametrisation."""

    perturbation: str
    steps: int
    seed: int
    jitter: Optional[Dict[str, float]]
    eot: Optional[Transformations]
    method: str
    method_options: Dict[str, Any]
    success_fraction: float
    held_out_fraction: Optional[float]
    loss: str
    kappa: float

    def config(self) -> Dict[str, Any]:
        """The hyper-parameters as a JSON-able dict."""

    def initial_params(self, mesh: Any, num_targets: int) -> Tensor:
        """Initial parameters ``(T, ...)`` (the pristine mesh)."""

    def apply(self, params: Tensor, mesh: Any, edges: Tensor) -> Tuple[Tensor, Tensor]:
        """``(vertices, face_colors)`` of parameters ``(K, ...)``."""

    def terms(self, params: Tensor, mesh: Any, edges: Tensor, images: Tensor, alpha: Tensor,
              num_views: int) -> Tuple[Tensor, Tensor]:
        """``(perceptual, distance)`` per target, each ``(K,)``."""

    def stop_rule(self) -> StopRule:
        """The thresholds of a target's success and stop."""

    def result_meshes(self, params: Tensor, mesh: Any, edges: Tensor) -> Tuple[Any, ...]:
        """The ``T`` adversarial meshes of parameters ``(T, ...)``."""

    def result_distances(self, mesh: Any, adversarial: Any, edges: Tensor) -> Dict[str, float]:
        """Every distance between the pristine mesh and one adversarial mesh."""

    def limit_moves(self, params: Tensor, idx: Tensor, edges: Tensor, radius: float) -> bool:
        """Pull the rows ``idx`` of ``params`` in place so that no vertex moves farther than ``radius``; ``True``
        when a row changed."""


@dataclass(frozen=True)
class AttackCall:
    """What one attack call works on: the mesh, the views, the victim, the render setup and the mesh's edges.

    Attributes:
        mesh: the pristine ``Mesh``.
        views: the ``ViewSet`` of the ``V`` victim views (detached).
        victim: the victim.
        setup: how the mesh is rendered.
        edges: int64 ``(E, 2)`` unique undirected edges of the mesh.
    """

    mesh: Any
    views: Any
    victim: Any
    setup: RenderSetup
    edges: Tensor


class StepTerms(NamedTuple):
    """What a step measured, per active target (``K`` of them), on the images the gradient was taken from.

    Attributes:
        adv: ``(K,)`` adversarial loss (differentiable).
        perceptual: ``(K,)`` perceptual loss (differentiable).
        distance: ``(K,)`` distortion (differentiable).
        output: the victim's output for the ``K x V`` images.
        margins: ``(K, V)`` criterion margins (detached).
    """

    adv: Tensor
    perceptual: Tensor
    distance: Tensor
    output: Any
    margins: Tensor


def adversarial_terms(attack: AttackFamily, output: Any, criteria: List[Criterion],
                      num_views: int) -> Tuple[Tensor, Tensor]:
    """Per-target adversarial loss ``(K,)`` (differentiable; the attack's ``loss`` and ``kappa``) and per-view margins
    ``(K, V)`` (detached) of a victim output of ``K x V`` images (mesh-major)."""
    parts = [slice_output(output, a * num_views, (a + 1) * num_views) for a in range(len(criteria))]
    adv = torch.stack([c.loss(o, loss=attack.loss, kappa=attack.kappa).mean() for c, o in zip(criteria, parts)])
    with torch.no_grad():
        margins = torch.stack([c.margin(o).detach() for c, o in zip(criteria, parts)])
    return adv, margins


def attack_step(attack: AttackFamily, p: Tensor, idx: Tensor, criteria: List[Criterion], call: AttackCall,
                views: Any, rule: UpdateRule) -> StepTerms:
    """One step: forward, objective, ``backward()`` into the parameters' ``.grad``.

    Args:
        attack: the attack (its parametrisation, perceptual term and loss settings).
        p: ``(K, ...)`` the active targets' rows of the parameters (``params[idx]``, still in their graph).
        idx: int64 ``(K,)`` the active targets.
        criteria: the ``K`` bound criteria.
        call: the attack call.
        views: the step's (possibly jittered) views.
        rule: the update rule, whose ``objective`` is differentiated.
    """
    verts, colors = attack.apply(p, call.mesh, call.edges)
    images, alpha = call.setup.render(verts, call.mesh.faces, colors, views, rule.edge_gradient,
                                      visibility_gradient=rule.visibility_gradient)
    output = call.victim(images)
    adv, margins = adversarial_terms(attack, output, criteria, len(views))
    perc, dist = attack.terms(p, call.mesh, call.edges, images, alpha, len(views))
    rule.objective(adv, perc, dist, idx).backward()
    return StepTerms(adv, perc, dist, output, margins)




def move_radius(cap: Any, vertices: Tensor) -> Optional[float]:
    """The largest vertex move (scene units) a ``max_displacement`` ceiling of ``cap`` allows on a mesh of pristine
    ``vertices (N, 3)``: the ceiling times their bounding-box diagonal; ``None`` without a cap or without that
    ceiling."""
    ceiling = None if cap is None else cap.max_displacement
    if ceiling is None:
        return None
    diagonal = float(bbox_diagonal(vertices))
    return ceiling * diagonal if diagonal > 0 else None


@dataclass(frozen=True)
class _RunInfo:
    """What the loop hands to the final evaluation besides the chosen parameters."""

    history: Tuple[Dict[str, Any], ...]
    steps: int
    wall_time: float
    interrupted: bool
    config: Dict[str, Any]


def run_attack(attack: AttackFamily, call: AttackCall, criteria: List[Criterion], eval_views: Any,
               callback: Optional[Callable[[StepInfo], None]]) -> AttackResult:
    """Run ``attack`` on ``call`` towards the bound ``criteria`` (one per target) and return its result.

    Args:
        attack: the attack (hyper-parameters and parametrisation).
        call: the mesh, views, victim, render setup and edges of the call (validated).
        criteria: the ``T`` bound criteria.
        eval_views: optional held-out ``ViewSet`` the final meshes are also scored on; with the attack's
            ``held_out_fraction`` and none given, :func:`~meshadv.perceptibility.held_out.held_out_views` of the
            call's views.
        callback: called with a :class:`StepInfo` after every step (``KeyboardInterrupt`` there stops the attack).
    """
    if eval_views is None and getattr(attack, "held_out_fraction", None):
        eval_views = held_out_views(call.views)
    loop = _Loop(attack, call, criteria, callback)
    try:
        loop.run_rounds()
    except KeyboardInterrupt:  # Ctrl-C between steps: keep what we have
        loop.interrupted = True
    return loop.finish(eval_views)


class _Loop:
    """The state of one attack call's loop: the update rule, the targets, the loss history and the step count."""

    def __init__(self, attack: AttackFamily, call: AttackCall, criteria: List[Criterion],
                 callback: Optional[Callable[[StepInfo], None]]) -> None:
        self.t_start = time.perf_counter()
        self.attack, self.call, self.callback = attack, call, callback
        self.num_targets, self.num_views = len(criteria), len(call.views)
        self.config = attack.config()  # the hyper-parameters the run starts with, for the result
        self.rule = make_update_rule(attack.method, attack=attack, num_targets=self.num_targets,
                                     **attack.method_options)
        self.rule.prepare(call.mesh, call.edges)
        self.targets = [TargetState(c) for c in criteria]
        self.stop = attack.stop_rule()
        self.move_radius = move_radius(self.stop.cap, call.mesh.vertices)
        self.history: List[Dict[str, Any]] = []
        self.total_steps = 0
        self.interrupted = False
        self.classifier = getattr(call.victim, "kind", "") == "classifier"
        self.sampler = None if attack.eot is None else EOTSampler(attack.eot, call.views, call.setup)
        self.check_generator = torch.Generator()
        if self.sampler is not None:
            self.num_views = self.sampler.eot.samples

    def run_rounds(self) -> None:
        """Every round, until the rule's rounds are done or the attack is interrupted."""
        for rnd in range(self.rule.rounds):
            self._run_round(rnd)
            if self.interrupted:
                break
            self.rule.end_round([tg.round_success for tg in self.targets])

    def _run_round(self, rnd: int) -> None:
        """One round from the pristine mesh: steps until every target is finished or ``steps`` are done."""
        attack = self.attack
        generator = torch.Generator().manual_seed(attack.seed if self.sampler is None
                                                  else stream_seed(attack.seed, STEP_STREAM))
        self.check_generator.manual_seed(stream_seed(attack.seed, CHECK_STREAM))
        params = attack.initial_params(self.call.mesh, self.num_targets).detach().clone().requires_grad_(True)
        self.rule.start_round(params)
        lambdas = self.rule.lambdas
        for target in self.targets:
            target.start_round()
        for step in range(attack.steps):
            active = [t for t in range(self.num_targets) if self.targets[t].active]
            if not active:
                break
            try:
                idx = torch.tensor(active, dtype=torch.long)
                p, terms, fractions = self._step(params, active, idx, generator)
            except KeyboardInterrupt:
                self.interrupted = True
                return
            self.total_steps += 1
            row, top1 = self._record(rnd, step, active, idx, p, terms, fractions, lambdas)
            if self.callback is not None and not self._report(self.callback, row, top1):
                return

    def _step(self, params: Tensor, active: List[int], idx: Tensor,
              generator: torch.Generator) -> Tuple[Tensor, StepTerms, Tensor]:
        """Render and differentiate the active targets, then let the rule update ``params``. Returns the rendered
        parameters of the active targets (before the update), the step's terms and the fraction of adversarial
        views per active target."""
        attack, call = self.attack, self.call
        p = params[idx]
        crits = [self.targets[t].criterion for t in active]
        if self.sampler is not None:
            draw = self.sampler.draw_step(generator)
            step_call = replace(call, setup=draw.setup, victim=draw.victim(call.victim))
            terms = attack_step(attack, p, idx, crits, step_call, draw.views, self.rule)
        else:
            step_views = call.views.jitter(generator, **attack.jitter) if attack.jitter else call.views
            terms = attack_step(attack, p, idx, crits, call, step_views, self.rule)
        with torch.no_grad():
            fractions = (terms.margins > 0).float().mean(dim=1)
            is_adv = enough_views(fractions, attack.success_fraction)
        self.rule.step(params, idx, is_adv)
        if self.move_radius is not None and self.attack.limit_moves(params, idx, call.edges, self.move_radius):
            self.rule.params_changed(params, idx)
        return p, terms, fractions

    def _record(self, rnd: int, step: int, active: List[int], idx: Tensor, p: Tensor, terms: StepTerms,
                fractions: Tensor, lambdas: Tensor) -> Tuple[Dict[str, Any], List[Optional[int]]]:
        """Let every active target observe the step and keep its history row; returns the row and the first-view
        top-1 classes."""
        with torch.no_grad():
            adv, perc, dist = terms.adv.detach(), terms.perceptual.detach(), terms.distance.detach()
            total = adv + lambdas[idx] * perc
            top = (terms.output.detach().argmax(dim=1).view(len(active), self.num_views)[:, 0] if self.classifier
                   else None)
        if self.sampler is None:
            self._observe(active, p, dist, fractions, terms.margins, lambdas)
        elif (step + 1) % self.sampler.eot.check_every == 0 or step == self.attack.steps - 1:
            call = self.call
            crits = [self.targets[t].criterion for t in active]
            margins = check_margins(self.attack, p, crits, call.mesh, call.edges, call.victim, call.setup,
                                    self.sampler.draw_check(self.check_generator))
            self._observe(active, p, dist, (margins > 0).float().mean(dim=1), margins, lambdas)
        elif self.stop.max_distortion is not None:
            for a, t in enumerate(active):
                if float(dist[a]) > self.stop.max_distortion:
                    self.targets[t].active = False
        row = history_row(rnd, step, self.num_targets, active, total, adv, perc, dist, terms.margins, lambdas)
        self.history.append(row)
        return row, first_view_top1(top, self.num_targets, active)

    def _observe(self, active: List[int], p: Tensor, dist: Tensor, fractions: Tensor, margins: Tensor,
                 lambdas: Tensor) -> None:
        """Every active target observes parameters ``p`` with their distortion, their views' margins and whether they
        lie inside the perceptibility cap."""
        inside = self._inside_cap(p)
        for a, t in enumerate(active):
            self.targets[t].observe(p[a], float(dist[a]), float(fractions[a]), margins[a], float(lambdas[t]),
                                    self.stop, self.total_steps, time.perf_counter() - self.t_start,
                                    inside_cap=inside[a])

    def _inside_cap(self, params: Tensor) -> List[bool]:
        """Per row of the rendered parameters ``params`` ``(K, ...)``, whether its mesh is inside the attack's
        perceptibility cap (all ``True`` without one)."""
        cap = self.stop.cap
        if cap is None:
            return [True] * params.shape[0]
        mesh = self.call.mesh
        with torch.no_grad():
            verts, colors = self.attack.apply(params.detach(), mesh, self.call.edges)
            measures = step_measures(cap, verts, colors, mesh.vertices, mesh.face_colors, mesh.faces,
                                     texture=getattr(mesh, "texture", None))
        inside = cap.admits(measures)
        if not isinstance(inside, Tensor):
            return [bool(inside)] * params.shape[0]
        return [bool(x) for x in inside.reshape(-1).tolist()]

    def _report(self, callback: Callable[[StepInfo], None], row: Dict[str, Any], top1: List[Optional[int]]) -> bool:
        """Call ``callback`` with the step's :class:`StepInfo`; ``False`` when it raised ``KeyboardInterrupt`` (the
        attack stops)."""
        info = step_info(row, top1, rounds=self.rule.rounds, steps=self.attack.steps, total_step=self.total_steps,
                         targets=self.targets)
        try:
            callback(info)
        except KeyboardInterrupt:
            self.interrupted = True
            return False
        return True

    def finish(self, eval_views: Any) -> AttackResult:
        """Every target's chosen parameters as its adversarial mesh, measured from scratch."""
        pristine = self.attack.initial_params(self.call.mesh, 1)[0].detach()
        chosen = torch.stack([tg.chosen(pristine) for tg in self.targets])
        run = _RunInfo(history=tuple(self.history), steps=self.total_steps,
                       wall_time=time.perf_counter() - self.t_start, interrupted=self.interrupted, config=self.config)
        call = self.call
        if self.sampler is not None:
            generator = torch.Generator().manual_seed(stream_seed(self.attack.seed, EVAL_STREAM))
            call = replace(call, views=self.sampler.draw_eval(generator))
        return _final_result(self.attack, call, self.targets, eval_views, chosen, run)


def _final_result(attack: AttackFamily, call: AttackCall, targets: List[TargetState], eval_views: Any,
                  params: Tensor, run: _RunInfo) -> AttackResult:
    """The result of a run: the chosen parameters' meshes scored on the views (and ``eval_views``) from scratch."""
    mesh, views, victim = call.mesh, call.views, call.victim
    adversarial = attack.result_meshes(params, mesh, call.edges)
    criteria = [tg.criterion for tg in targets]
    after = evaluate(adversarial, views, victim, criteria, setup=call.setup)
    before = evaluate([mesh], views, victim, criteria, setup=call.setup)
    eval_success = eval_scores = None
    if eval_views is not None:
        held_out = evaluate(adversarial, eval_views.detach(), victim, criteria, setup=call.setup)
        eval_success, eval_scores = held_out.success, held_out.scores
    perceptible = perceptibility_measures(mesh, adversarial, views, call.setup)
    cap = attack.stop_rule().cap
    distances = tuple(
        {**seen, **attack.result_distances(mesh, m, call.edges)}
        for m, seen in zip(adversarial, perceptible)
    )
    return AttackResult(
        original=mesh,
        adversarial=adversarial,
        perturbation=attack.perturbation,
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
        success_fraction=attack.success_fraction,
        held_out_fraction=getattr(attack, "held_out_fraction", None),
        perceptibility_cap=None if cap is None else cap.to_record(),
        original_images=before.images[0],
        images=after.images,
        view_records=tuple(views.to_records()),
        eval_view_records=None if eval_views is None else tuple(eval_views.to_records()),
        config={**run.config, **call.setup.config()},
        victim=str(getattr(victim, "name", type(victim).__name__)),
        class_names=tuple(getattr(victim, "class_names", ()) or ()),
    )
