"""The distortion-budget update rule, ``method="ddn"``: minimise the distortion directly, without a ``lambda`` search.

In the manner of decoupled direction and norm attacks (Rony et al., CVPR 2019, "DDN"), every target keeps a
distortion budget ``eps`` that shrinks while the target holds and grows while it does not, and the perturbation
``delta`` moves by steps of a set length **measured in the budget's own norm**, then is pulled back into the ball
``||delta|| <= eps``. No perceptual term is weighted: the objective is the adversarial loss alone and the distortion
is the budget. Per step ``k`` of ``steps``, for each active target (``delta`` is what was rendered)::

    eps   <- (1 - gamma) * min(eps, ||delta||)      if the target held on the rendered images
    eps   <- min((1 + gamma) * eps, cap)            otherwise (cap: the attack's max_distortion)
    delta <- delta + alpha_k * direction(grad)      alpha_k: cosine from step_size to final_step_size
    delta <- delta * min(1, eps / ||delta||)

``eps`` never goes below ``min_budget`` (> 0). The loop keeps the least distorted step where the target held, so a
run returns its best success, not its last step.

The space ``delta`` lives in, its norm, its steepest direction and how it is read from and written into the
attack's parameters belong to the attack family (:meth:`~meshadv.attacks.mesh_attack.MeshAttack.budget_space`,
:mod:`meshadv.attacks.norms`), and so do the defaults in its norm units
(:meth:`~meshadv.attacks.mesh_attack.MeshAttack.budget_defaults`, :data:`DDN_DEFAULTS`):

* shape -- the flow, measured by ``sqrt(laplacian_pair_mean(dv))`` (the RMS change of an edge vector, so one
  setting suits meshes of any resolution); directions ``(L + I / smoothness)^-1 grad`` (the preconditioner of
  Nicolet et al., SIGGRAPH Asia 2021), free of every connected component's translation. ``edge_gradient`` ``w >= 0``
  weights NMR's rasterization gradient beside the exact shading gradient in the vertex gradient the rule steps along
  (:func:`meshadv.render.render`'s ``edge_gradient``; the images are the same; 1 is NMR's definition), and
  ``visibility_gradient`` (``"nmr"`` or ``"local"``: NMR's sweeps cut to 2 output pixels of each edge,
  docs/LOCAL_GRADIENT.md) chooses which rasterization gradient that is (:func:`meshadv.render.render`'s).
* texture -- the face colours, measured by their RMSE (the paper's measure); directions along the colour gradient;
  colours clipped into ``[0, 1]`` after every step and written back as logits.

Options (``method_options``): ``init_budget``, ``gamma``, ``step_size``, ``final_step_size`` and ``min_budget``
(:class:`BudgetState`), ``edge_gradient`` and ``visibility_gradient`` (the rule's), and the family space's own
(shape: ``smoothness``).

Example:
    >>> from meshadv.attacks import ShapeAttack
    >>> attack = ShapeAttack(method="ddn", steps=300)                                  # the family's defaults
    >>> attack = ShapeAttack(method="ddn", steps=300, method_options={"smoothness": 3.0})
"""

from __future__ import annotations

import math
from typing import Any, Dict, Mapping, Optional

import torch
from torch import Tensor

from meshadv.attacks.families import PERTURBATIONS
from meshadv.attacks.norms import TINY, per_row, positive_option
from meshadv.attacks.update import UpdateRule, register_update_rule
from meshadv.render.visibility import check_visibility_gradient

__all__ = ["BudgetState", "DDNRule", "DDN_DEFAULTS", "DDN_ADDED_OPTIONS", "DDN_REMOVED_OPTIONS",
           "DDN_REFERENCE_DIAGONAL", "DDN_LENGTH_OPTIONS", "recorded_options", "shape_options_for"]

#: Default options of ``method="ddn"`` per perturbation (each family's :meth:`budget_defaults`, in its norm units).
DDN_DEFAULTS: Dict[str, Dict[str, Any]] = {name: cls.budget_defaults() for name, cls in PERTURBATIONS.items()}

#: Options the rule takes that a recorded (complete) options dict may lack, per perturbation, each at the value the
#: rule behaves with when it is absent from such a record (:func:`recorded_options`).
DDN_ADDED_OPTIONS: Dict[str, Dict[str, Any]] = {"shape": {"edge_gradient": 1.0, "visibility_gradient": "nmr"},
                                                 "texture": {}}

#: Options a recorded options dict may hold that the rule does not take, each at the one value with which the run
#: behaved as the rule does without it (:func:`recorded_options` drops them).
DDN_REMOVED_OPTIONS: Dict[str, Any] = {"anneal": "cosine", "momentum": 0.0, "stall_steps": 0, "stall_factor": 0.5,
                                       "reach": "budget"}

#: The bounding-box diagonal the shape lengths of :data:`DDN_DEFAULTS` (budgets and steps, in the Laplacian norm)
#: suit: PASCAL3D+ meshes normalised to ``[-1, 1]`` (diagonals 2.2-2.8). An object of another size gets them times
#: its own diagonal over this one (:func:`shape_options_for`), as Adam's learning rate is given in units of the
#: diagonal.
DDN_REFERENCE_DIAGONAL = 2.5
#: The ddn shape options that are lengths in the rule's norm (scaled by :func:`shape_options_for`).
DDN_LENGTH_OPTIONS = ("init_budget", "step_size", "final_step_size", "min_budget")


def shape_options_for(mesh: Any) -> Dict[str, float]:
    """``method_options`` of a ddn shape attack on ``mesh`` of any size: the rule's default lengths
    (:data:`DDN_LENGTH_OPTIONS`) times its bounding-box diagonal over :data:`DDN_REFERENCE_DIAGONAL`."""
    scale = float(mesh.bbox_diagonal()) / DDN_REFERENCE_DIAGONAL
    return {k: DDN_DEFAULTS["shape"][k] * scale for k in DDN_LENGTH_OPTIONS}


def recorded_options(kind: str, options: Mapping[str, Any]) -> Dict[str, Any]:
    """The ddn options that run as a record's complete ``options`` (a record's ``attack_config``, a sweep's pinned
    defaults) did for perturbation ``kind``: each option of :data:`DDN_ADDED_OPTIONS` they lack at its value there,
    each of :data:`DDN_REMOVED_OPTIONS` left out, so that a default never changes how a recorded run is resumed or
    regenerated.

    Raises:
        ValueError: ``options`` hold an option of :data:`DDN_REMOVED_OPTIONS` at another value (a run the rule
            cannot repeat).
    """
    out = {**DDN_ADDED_OPTIONS.get(kind, {}), **options}
    for name, neutral in DDN_REMOVED_OPTIONS.items():
        if name in out:
            if out[name] != neutral:
                raise ValueError(f"method_options {name}={out[name]!r} is not an option of method='ddn' (only "
                                 f"{neutral!r}, its behaviour without the option, can be repeated)")
            del out[name]
    return out


#: Options of :class:`BudgetState`; the rule's own are :data:`_RULE_OPTIONS`, every other is the family space's.
_BUDGET_OPTIONS = ("init_budget", "gamma", "step_size", "final_step_size", "min_budget")
_RULE_OPTIONS = ("edge_gradient", "visibility_gradient")

class BudgetState:
    """Per-target budgets and the step schedule of the distortion-budget rule (see the module docstring).

    Args:
        num_targets: ``T``.
        steps: steps of the schedule (the cosine runs over them).
        init_budget: starting ``eps`` (> 0).
        gamma: relative budget change per step, in ``(0, 1)``.
        step_size: first step length (> 0).
        final_step_size: last step length, in ``(0, step_size]``.
        min_budget: floor of ``eps``, in ``(0, init_budget]``.
        cap: optional ceiling of ``eps`` (> 0).

    Raises:
        ValueError: a hyper-parameter out of range, naming it.
    """

    def __init__(self, num_targets: int, steps: int, *, init_budget: float, gamma: float, step_size: float,
                 final_step_size: float, min_budget: float, cap: Optional[float] = None) -> None:
        if isinstance(num_targets, bool) or int(num_targets) != num_targets or num_targets < 1:
            raise ValueError(f"num_targets must be an integer >= 1, got {num_targets!r}")
        if isinstance(steps, bool) or int(steps) != steps or steps < 1:
            raise ValueError(f"steps must be an integer >= 1, got {steps!r}")
        self.init_budget = positive_option("init_budget", init_budget)
        self.gamma = positive_option("gamma", gamma)
        if self.gamma >= 1:
            raise ValueError(f"gamma must be in (0, 1), got {gamma!r}")
        self.step_size = positive_option("step_size", step_size)
        self.final_step_size = positive_option("final_step_size", final_step_size)
        if self.final_step_size > self.step_size:
            raise ValueError(f"final_step_size ({final_step_size}) must be <= step_size ({step_size})")
        self.min_budget = positive_option("min_budget", min_budget)
        if self.min_budget > self.init_budget:
            raise ValueError(f"min_budget ({min_budget}) must be <= init_budget ({init_budget})")
        self.cap = None if cap is None else max(positive_option("cap", cap), self.min_budget)
        self.steps = int(steps)
        self.num_targets = int(num_targets)
        self.budgets = torch.empty(0, dtype=torch.float64)
        self.reset()

    def reset(self) -> None:
        """Every budget back to ``init_budget`` (capped)."""
        start = self.init_budget if self.cap is None else min(self.init_budget, self.cap)
        self.budgets = torch.full((self.num_targets,), start, dtype=torch.float64)

    def step_length(self, step: int) -> float:
        """``alpha_step``: cosine from ``step_size`` (step 0) to ``final_step_size`` (the last step)."""
        frac = min(max(step, 0), self.steps - 1) / max(self.steps - 1, 1)
        lo, hi = self.final_step_size, self.step_size
        return lo + 0.5 * (hi - lo) * (1.0 + math.cos(math.pi * frac))

    def update(self, index: Tensor, adversarial: Tensor, norms: Tensor) -> Tensor:
        """New budgets of the targets ``index`` given whether they held and their current norms; returned ``(K,)``."""
        eps = self.budgets[index]
        held = adversarial.detach().cpu().bool()
        cur = norms.detach().cpu().double()
        shrunk = (1.0 - self.gamma) * torch.minimum(eps, cur)
        grown = (1.0 + self.gamma) * eps
        if self.cap is not None:
            grown = grown.clamp(max=self.cap)
        new = torch.where(held, shrunk, grown).clamp(min=self.min_budget)
        self.budgets[index] = new
        return new

    def move(self, delta: Tensor, direction: Tensor, budgets: Tensor, step: int, norm: Any) -> Tensor:
        """``delta + alpha_step * direction``, projected, then pulled into ``||.|| <= budgets``; ``(K, ...)``.
        ``norm`` has the ``project`` and ``norm`` of the perturbation's space."""
        moved = norm.project(delta + self.step_length(step) * direction)
        size = norm.norm(moved).double().cpu()
        scale = torch.where(size > budgets, budgets / size.clamp(min=TINY), torch.ones_like(size))
        return moved * per_row(scale.to(moved.dtype).to(moved.device), moved)


class DDNRule(UpdateRule):
    """The distortion-budget update rule (``method="ddn"``) for the attack families that have a budget space (see
    the module docstring).

    Args:
        attack: the attack (its ``budget_defaults``, ``budget_space``, ``steps``, ``max_distortion`` and
            ``binary_search_steps`` are used).
        num_targets: ``T``.
        init_budget, gamma, step_size, final_step_size, min_budget: :class:`BudgetState` options (norm units).
        edge_gradient: the weight of NMR's rasterization gradient in the vertex gradient (module docstring).
        visibility_gradient: ``"nmr"`` or ``"local"``, which rasterization gradient (module docstring).
        **options: the options of the family's space (shape: ``smoothness``).

    Raises:
        ValueError: an option out of range or unknown for the family, ``binary_search_steps != 1``, or an attack
            whose parametrisation the rule cannot step (a smoothed or clamped flow, another colour mapping).
    """

    rounds = 1

    def __init__(self, *, attack: Any, num_targets: int, **options: Any) -> None:
        defaults = attack.budget_defaults()
        unknown = set(options) - set(defaults)
        if unknown:
            raise ValueError(f"method_options has unknown keys {sorted(unknown)} for method='ddn' on "
                             f"{attack.perturbation}; known: {sorted(defaults)}")
        if getattr(attack, "binary_search_steps", 1) != 1:
            raise ValueError(f"binary_search_steps must be 1 with method='ddn' (it searches no lambda), got "
                             f"{attack.binary_search_steps}")
        self.options = {**defaults, **options}
        if "edge_gradient" in self.options:
            weight = self.options["edge_gradient"]
            if isinstance(weight, bool) or not isinstance(weight, (int, float)) or not 0 <= weight < float("inf"):
                raise ValueError(f"edge_gradient must be a finite number >= 0, got {weight!r}")
            self.edge_gradient = float(weight)
        if "visibility_gradient" in self.options:
            self.visibility_gradient = check_visibility_gradient(self.options["visibility_gradient"])
        self._budget_options = {k: v for k, v in self.options.items() if k in _BUDGET_OPTIONS}
        space_options = {k: v for k, v in self.options.items() if k not in _BUDGET_OPTIONS + _RULE_OPTIONS}
        self.norm = attack.budget_space(**space_options)
        self._attack = attack
        BudgetState(num_targets, attack.steps, **self._budget_options)  # validate every option now
        self.num_targets = int(num_targets)
        self.state: Optional[BudgetState] = None
        self._delta: Optional[Tensor] = None
        self._step = 0

    @property
    def lambdas(self) -> Tensor:
        """No perceptual weight: zeros ``(T,)``."""
        return torch.zeros(self.num_targets, dtype=torch.float32)

    def prepare(self, mesh: Any, edges: Tensor) -> None:
        """Build the space of the mesh (:meth:`~meshadv.attacks.norms.FlowSpace.prepare`) and the budgets."""
        attack = self._attack
        self.norm.prepare(mesh, edges)
        # a hair inside max_distortion, so float rounding never pushes a target past it (the loop would stop it)
        cap = None if attack.max_distortion is None else self.norm.from_distance(attack.max_distortion) * (1 - 1e-6)
        self.state = BudgetState(self.num_targets, attack.steps, cap=cap, **self._budget_options)

    def start_round(self, params: Tensor) -> None:
        """Budgets back to ``init_budget``, ``delta = 0``."""
        if self.state is None or self.norm.origin is None:
            raise RuntimeError("DDNRule.prepare(mesh, edges) must be called before start_round")
        self.state.reset()
        self._delta = torch.zeros((params.shape[0], *self.norm.origin.shape), dtype=params.dtype)
        self._step = 0
        params.grad = None

    def objective(self, adv: Tensor, perceptual: Tensor, distance: Tensor, active: Tensor) -> Tensor:
        """The adversarial loss alone, summed over the targets (the distortion is the budget)."""
        return adv.sum()

    def step(self, params: Tensor, active: Tensor, is_adversarial: Tensor) -> None:
        """Budget update, one step of fixed length in the budget's norm, projection into the budget ball."""
        if self._delta is None or self.state is None:
            raise RuntimeError("DDNRule.start_round must be called before step")
        idx = active.cpu().long()
        with torch.no_grad():
            grad = self.norm.gradient(params, idx)
            delta = self._delta[idx]
            budgets = self.state.update(idx, is_adversarial, self.norm.norm(delta))
            heading = self.norm.direction(grad)
            moved = self.state.move(delta, heading, budgets, self._step, self.norm)
            self._delta[idx] = self.norm.write(params, idx, moved)
        params.grad = None
        self._step += 1

    def params_changed(self, params: Tensor, active: Tensor) -> None:
        """Re-read the perturbation of the rows ``active`` from ``params`` (changed by the loop's projection)."""
        if self._delta is None:
            raise RuntimeError("DDNRule.start_round must be called before params_changed")
        idx = active.cpu().long()
        with torch.no_grad():
            self._delta[idx] = self.norm.read(params, idx).to(self._delta.dtype)

    def config(self) -> Dict[str, Any]:
        """The effective options (defaults filled in)."""
        return dict(self.options)


def _ddn(*, attack: Any, num_targets: int, **options: Any) -> UpdateRule:
    return DDNRule(attack=attack, num_targets=num_targets, **options)


register_update_rule("ddn", _ddn)
