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

``anneal`` sets when ``alpha_k`` falls: ``"cosine"`` (the default) over the whole run from step 0, the same for every
target; ``"after_success"`` per target, ``alpha_k = step_size`` until the target first holds (at step ``k0``), then
cosine from ``step_size`` at ``k0`` to ``final_step_size`` at the last step, so a target that has not held by step
~100 does not crawl at a fraction of the first step. Measured on the 8 targets the benchmark's default runs miss, it
reached 1 of them (far above the paper's distance) and left 7 of 8 more distorted (pair mean up to 11x): the step
length is not what stops them (benchmarks/RESULTS.md, "ddn: the targets it misses"), so ``"cosine"`` stays the default.

Two options change the step itself (both off by default):

* ``momentum`` ``beta`` in ``[0, 1)``: the step goes along the normalised running sum ``v <- beta v + d`` of the unit
  directions ``d`` (MI-FGSM's accumulation, as DDN's authors suggest for noisy gradients), to damp the step-to-step
  swings of NMR's surrogate gradient.
* ``stall_steps`` ``N`` (0: off) and ``stall_factor`` ``f`` in ``(0, 1]``: a target whose adversarial loss has not
  fallen below its lowest value for ``N`` steps, and that does not hold, is put back at its lowest-loss
  perturbation, its momentum cleared and its step length multiplied by ``f`` (a local restart with smaller steps).

Measured on the benchmark's hardest instance the default reaches (sofa/0, 6 targets batched), neither helped:
``momentum`` 0.9 lost two targets the default reaches by step 57 and reached two others only at step ~285, far more
distorted; ``stall_steps`` 20 with ``stall_factor`` 0.5 gave the same 5 of 6. So both stay off (same section).

A third changes the direction of a target that has not held yet in the round (off by default):

* ``reach`` ``"budget"`` (the default) or ``"adam"``: with ``"adam"`` such a target steps along Adam's
  per-coordinate normalised direction ``-m_hat / (sqrt(v_hat) + 1e-8)`` of its gradients (moments with torch's
  decays 0.9 and 0.999, advanced only while the target is unheld), made unit in the budget's norm, so every vertex
  (every colour) moves, as Adam moves them; from its first success on it steps along the budget direction. Measured
  on the three instances holding the default's bicycle misses (aeroplane/1, bottle/1, diningtable/1, 6 targets
  batched): 12 of 18 targets within 300 steps against 15 of 18 for the default, the bicycles still missed; plain
  Adam (lr 1e-3 or 3e-3, 300 steps) held 3 and 2 of bottle/1's 6 (benchmarks/RESULTS.md, "ddn: reaching the bicycle
  targets (seventh session)"). So it stays off.

The gradient a shape step follows (shape only):

* ``edge_gradient`` ``w >= 0`` (default 0.1): the weight of NMR's rasterization gradient -- the sweep that credits
  each edge with the pixels it could cover, docs/NMR_GRADIENT.md -- beside the exact shading gradient (face normals
  under the lights) in the vertex gradient the rule steps along (:func:`meshadv.render.render`'s
  ``edge_gradient``; the images are the same). NMR's surrogate is what left the hard targets on a plateau where the
  rendered loss rose along its own descent direction; with ``w = 0.1`` the convergence benchmark's 14 instances held
  84 of 84 shape targets within 300 steps (every instance all 6; median pair mean 3.3e-6), against 80 of 84 (10 of
  14; 1.0e-5) with NMR's full gradient (``w = 1``), including diningtable/1 -> bicycle, which no method had held
  before; ``w = 0`` (shading alone) stalled far from it (benchmarks/RESULTS.md, "ddn: NMR's rasterization gradient
  down-weighted"). ``w = 1`` is NMR's definition, and the value of every ddn run recorded before the option
  existed (:data:`DDN_ADDED_OPTIONS`).
* ``visibility_gradient`` ``"nmr"`` (default) or ``"local"``: which rasterization gradient that weight applies to,
  NMR's (sweeps to the image border) or the local one (NMR's sweeps cut to 2 output pixels of each edge,
  docs/LOCAL_GRADIENT.md; cheaper to compute; :func:`meshadv.render.render`'s ``visibility_gradient``).

``eps`` never goes below ``min_budget`` (> 0), so it is never negative. The engine keeps the least distorted step
where the target held, so a run returns its best success, not its last step.

Norms (budgets, steps and ``min_budget`` are in these units):

* shape -- ``sqrt(laplacian_pair_mean(dv))``: the root of the Eq. 4 Laplacian of the flow divided by its ``2E``
  (vertex, neighbour) pairs, i.e. the RMS change of an edge vector. It is the square root of the paper-comparable
  distance, so one setting suits meshes of any resolution. The descent direction of a gradient ``g`` is the steepest
  one in the metric ``L + I / smoothness`` (``L`` the mesh graph Laplacian): ``(L + I / smoothness)^-1 g``, the
  preconditioner of Nicolet et al. (SIGGRAPH Asia 2021, "Large Steps in Inverse Rendering of Geometry",
  ``(I + smoothness L)^-1`` up to scale), which turns NMR's noisy per-vertex gradient into smooth patches instead
  of moving every vertex by about ``lr`` like Adam. The default ``smoothness`` 0.1 (``(I + 0.1 L)^-1``: nearly the
  raw per-vertex gradient, lightly mixed with its neighbours') replaced 1.0 after the benchmark: on its 14 instances
  it held 80 of 84 shape targets within 300 steps instead of 76 (median pair mean 1.0e-5 instead of 1.3e-5; one
  target 1.0 reached, aeroplane/1 -> bicycle, it misses); 10 (smoother, more global steps) held none of bottle/1's
  three misses
  (benchmarks/RESULTS.md, "ddn: smoothness 0.1, momentum, a margin loss and stall restarts"). ``L`` is blind to
  translations: a rigid shift of any connected component costs nothing under the Laplacian distance. Steps and the
  perturbation are therefore kept free of them (every connected component's mean displacement is removed), so the
  budget bounds the whole perturbation and no part of the mesh drifts away for free.
* texture -- the face-colour RMSE ``sqrt(1/m sum_i ||t_i^adv - t_i||^2)`` (the paper's measure); the direction is
  the colour gradient (steepest for the RMSE), and colours are clipped into ``[0, 1]`` after every step. The rule
  works on colours; the attack's logit parameters are written from them.

Why not Adam: Adam normalises each coordinate, so every vertex moves by about ``lr`` per step whatever its gradient,
and after the first success the cross-entropy keeps pushing, so the distortion never shrinks (issue 14). Measured
on one rendering-set aeroplane: the linearised loss of a full gradient step holds only within a Laplacian distance
of about 1e-2 (sum), far below the distances at success, so steps are small and of fixed length, not a fraction of
the budget (benchmarks/RESULTS.md, "Minimal-distortion attacks").

Example:
    >>> from meshadv.attacks import ShapeAttack
    >>> attack = ShapeAttack(method="ddn", steps=300)                                  # defaults below
    >>> attack = ShapeAttack(method="ddn", steps=300, method_options={"smoothness": 3.0})
"""

from __future__ import annotations

import math
from typing import Any, Dict, Mapping, Optional, Tuple

import torch
from torch import Tensor

from meshadv.attacks.budget_modifiers import AdamReach, Momentum, StallRestarts
from meshadv.attacks.norms import TINY, ColorNorm, LaplacianNorm, per_row, positive_option
from meshadv.attacks.shape import ShapeAttack
from meshadv.attacks.texture import COLOR_EPS, TextureAttack
from meshadv.attacks.update import UpdateRule, register_update_rule
from meshadv.render.visibility import check_visibility_gradient

#: ``LaplacianNorm`` and ``ColorNorm`` live in :mod:`meshadv.attacks.norms` and are re-exported here.
__all__ = ["LaplacianNorm", "ColorNorm", "BudgetState", "DDNRule", "DDN_DEFAULTS", "DDN_ADDED_OPTIONS", "ANNEAL_MODES",
           "REACH_MODES", "DDN_REFERENCE_DIAGONAL", "DDN_LENGTH_OPTIONS", "recorded_options", "shape_options_for"]

#: Default options of ``method="ddn"`` per perturbation (norm units, see the module docstring).
DDN_DEFAULTS: Dict[str, Dict[str, Any]] = {
    "shape": {"init_budget": 1e-3, "gamma": 0.05, "step_size": 1e-3, "final_step_size": 1e-4, "min_budget": 1e-7,
              "smoothness": 0.1, "anneal": "cosine", "momentum": 0.0, "stall_steps": 0, "stall_factor": 0.5,
              "reach": "budget", "edge_gradient": 0.1, "visibility_gradient": "nmr"},
    "texture": {"init_budget": 5e-3, "gamma": 0.1, "step_size": 5e-3, "final_step_size": 5e-4, "min_budget": 1e-6,
                "anneal": "cosine", "momentum": 0.0, "stall_steps": 0, "stall_factor": 0.5, "reach": "budget"},
}

#: Options the rule gained after its first recorded runs, per perturbation, each at the value the rule behaved with
#: before it existed: a recorded (complete) options dict without one of them ran with that value
#: (:func:`recorded_options`).
DDN_ADDED_OPTIONS: Dict[str, Dict[str, Any]] = {"shape": {"edge_gradient": 1.0, "visibility_gradient": "nmr"},
                                                 "texture": {}}


#: The shape lengths of :data:`DDN_DEFAULTS` (budgets and steps, in the Laplacian norm) were tuned on PASCAL3D+ meshes
#: normalised to ``[-1, 1]`` (bounding-box diagonals 2.2-2.8); an object of another size gets them times its own
#: diagonal over this one (:func:`shape_options_for`), as Adam's learning rate is given in units of the diagonal.
#: Measured on the indoor scene (the 35k-vertex bunny, diagonal 0.41; dining table, threshold 0.2, width 160, 60
#: steps; benchmarks/RESULTS.md, "Scene attacks on ddn"): the unscaled lengths hid the table at a Laplacian sum of
#: 0.15 (max displacement 8.4% of the diagonal), Adam (lr 5e-4, smoothing 8) at 1.8e-3 (0.62%), the scaled ones at
#: 1.2e-4 (0.50%).
DDN_REFERENCE_DIAGONAL = 2.5
#: The ddn shape options that are lengths in the rule's norm (scaled by :func:`shape_options_for`).
DDN_LENGTH_OPTIONS = ("init_budget", "step_size", "final_step_size", "min_budget")


def shape_options_for(mesh: Any) -> Dict[str, float]:
    """``method_options`` of a ddn shape attack on ``mesh`` of any size: the rule's default lengths
    (:data:`DDN_LENGTH_OPTIONS`) times its bounding-box diagonal over :data:`DDN_REFERENCE_DIAGONAL`."""
    scale = float(mesh.bbox_diagonal()) / DDN_REFERENCE_DIAGONAL
    return {k: DDN_DEFAULTS["shape"][k] * scale for k in DDN_LENGTH_OPTIONS}


def recorded_options(kind: str, options: Mapping[str, Any]) -> Dict[str, Any]:
    """The effective ddn options of a run recorded with the complete ``options`` of its day (a record's
    ``attack_config``, a sweep's pinned defaults) for perturbation ``kind``: each option added since
    (:data:`DDN_ADDED_OPTIONS`) that they lack, at the value the rule had before it existed, so that today's default
    of a new option never changes how an old run is resumed or regenerated."""
    return {**DDN_ADDED_OPTIONS.get(kind, {}), **options}


#: Options of :class:`DDNRule` that are not :class:`BudgetState`'s.
_RULE_OPTIONS = ("smoothness", "momentum", "stall_steps", "stall_factor", "reach", "edge_gradient",
                 "visibility_gradient")

#: Values of the ``reach`` option: the step direction of a target that has not held yet (see the module docstring).
REACH_MODES = ("budget", "adam")

#: Values of the ``anneal`` option: when the step length falls (see the module docstring).
ANNEAL_MODES = ("cosine", "after_success")

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
        anneal: ``"cosine"`` (one schedule from step 0) or ``"after_success"`` (per target, from its first success).

    Raises:
        ValueError: a hyper-parameter out of range, naming it.
    """

    def __init__(self, num_targets: int, steps: int, *, init_budget: float, gamma: float, step_size: float,
                 final_step_size: float, min_budget: float, cap: Optional[float] = None,
                 anneal: str = "cosine") -> None:
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
        if not isinstance(anneal, str) or anneal not in ANNEAL_MODES:
            raise ValueError(f"anneal must be one of {ANNEAL_MODES}, got {anneal!r}")
        self.anneal = anneal
        self.steps = int(steps)
        self.num_targets = int(num_targets)
        self.budgets = torch.empty(0, dtype=torch.float64)
        self.first_held = torch.empty(0, dtype=torch.long)
        self.reset()

    def reset(self) -> None:
        """Every budget back to ``init_budget`` (capped); no target has held yet."""
        start = self.init_budget if self.cap is None else min(self.init_budget, self.cap)
        self.budgets = torch.full((self.num_targets,), start, dtype=torch.float64)
        self.first_held = torch.full((self.num_targets,), -1, dtype=torch.long)

    def step_length(self, step: int) -> float:
        """``alpha_step``: cosine from ``step_size`` (step 0) to ``final_step_size`` (the last step)."""
        frac = min(max(step, 0), self.steps - 1) / max(self.steps - 1, 1)
        lo, hi = self.final_step_size, self.step_size
        return lo + 0.5 * (hi - lo) * (1.0 + math.cos(math.pi * frac))

    def step_lengths(self, index: Tensor, step: int) -> Tensor:
        """``alpha_step`` of the targets ``index``, ``(K,)`` float64: :meth:`step_length` for every target with
        ``anneal="cosine"``; with ``"after_success"``, ``step_size`` for a target that has not held yet, else the
        cosine from ``step_size`` at its first success to ``final_step_size`` at the last step."""
        idx = index.cpu().long()
        if self.anneal == "cosine":
            return torch.full((len(idx),), self.step_length(step), dtype=torch.float64)
        first = self.first_held[idx]
        last = self.steps - 1
        span = (last - first).clamp(min=1).double()
        frac = ((min(max(step, 0), last) - first).double() / span).clamp(0.0, 1.0)
        lo, hi = self.final_step_size, self.step_size
        cosine = lo + 0.5 * (hi - lo) * (1.0 + torch.cos(math.pi * frac))
        return torch.where(first < 0, torch.full_like(cosine, hi), cosine)

    def update(self, index: Tensor, adversarial: Tensor, norms: Tensor, step: int = 0) -> Tensor:
        """New budgets of the targets ``index`` given whether they held and their current norms; returned ``(K,)``.

        ``step`` (the step whose render ``adversarial`` judged) is recorded as a target's first success."""
        eps = self.budgets[index]
        held = adversarial.detach().cpu().bool()
        idx = index.cpu().long()
        fresh = held & (self.first_held[idx] < 0)
        self.first_held[idx[fresh]] = int(step)
        cur = norms.detach().cpu().double()
        shrunk = (1.0 - self.gamma) * torch.minimum(eps, cur)
        grown = (1.0 + self.gamma) * eps
        if self.cap is not None:
            grown = grown.clamp(max=self.cap)
        new = torch.where(held, shrunk, grown).clamp(min=self.min_budget)
        self.budgets[index] = new
        return new

    def move(self, delta: Tensor, direction: Tensor, budgets: Tensor, step: int, norm: Any,
             index: Optional[Tensor] = None) -> Tensor:
        """``delta + alpha_step * direction``, projected, then pulled into ``||.|| <= budgets``; ``(K, ...)``.

        ``index``: the targets of the rows (needed for ``anneal="after_success"``; by default ``0..K-1``)."""
        if self.anneal == "cosine":
            moved = norm.project(delta + self.step_length(step) * direction)
        else:
            rows = torch.arange(delta.shape[0]) if index is None else index
            alpha = self.step_lengths(rows, step).to(direction.dtype).to(direction.device)
            moved = norm.project(delta + per_row(alpha, direction) * direction)
        size = norm.norm(moved).double().cpu()
        scale = torch.where(size > budgets, budgets / size.clamp(min=TINY), torch.ones_like(size))
        return moved * per_row(scale.to(moved.dtype).to(moved.device), moved)


def _ddn_perturbation(attack: Any, options: Dict[str, Any]) -> str:
    """The perturbation of ``attack`` when ``method="ddn"`` can step it with ``options``.

    Raises:
        ValueError: another attack family or parametrisation, an option unknown for the perturbation, a ``lambda``
            search (``binary_search_steps != 1``), a smoothed or clamped shape flow.
    """
    kind = getattr(attack, "perturbation", None)
    if kind not in DDN_DEFAULTS:
        raise ValueError(f"method='ddn' supports the shape and texture attacks, not {type(attack).__name__}")
    unknown = set(options) - set(DDN_DEFAULTS[kind])
    if unknown:
        raise ValueError(f"method_options has unknown keys {sorted(unknown)} for method='ddn' on {kind}; "
                         f"known: {sorted(DDN_DEFAULTS[kind])}")
    if getattr(attack, "binary_search_steps", 1) != 1:
        raise ValueError(f"binary_search_steps must be 1 with method='ddn' (it searches no lambda), got "
                         f"{attack.binary_search_steps}")
    if kind == "shape":
        if not isinstance(attack, ShapeAttack) or type(attack).displacement is not ShapeAttack.displacement:
            raise ValueError(f"method='ddn' cannot step the parametrisation of {type(attack).__name__}")
        if attack.smoothing != 0:
            raise ValueError(f"smoothing must be 0 with method='ddn' (its preconditioner smooths the steps), "
                             f"got {attack.smoothing}")
        if attack.max_step is not None:
            raise ValueError(f"max_step must be None with method='ddn', got {attack.max_step}")
    else:
        same = [getattr(type(attack), n, None) is getattr(TextureAttack, n, None) for n in ("_apply", "_colors")]
        if not isinstance(attack, TextureAttack) or not all(same):
            raise ValueError(f"method='ddn' cannot step the parametrisation of {type(attack).__name__}")
    return kind


class DDNRule(UpdateRule):
    """The distortion-budget update rule (``method="ddn"``) for :class:`~meshadv.attacks.ShapeAttack` and
    :class:`~meshadv.attacks.TextureAttack` (see the module docstring).

    Args:
        attack: the attack (its ``perturbation``, ``steps``, ``max_distortion`` and parametrisation are used).
        num_targets: ``T``.
        init_budget, gamma, step_size, final_step_size, min_budget, anneal: :class:`BudgetState` options (norm
            units); defaults per perturbation in :data:`DDN_DEFAULTS`.
        smoothness: shape only, ``s`` of the preconditioner ``(L + I/s)^-1`` (``None``: the Laplacian alone).
        momentum, stall_steps, stall_factor: the step's momentum and stall restarts (see the module docstring).
        reach: ``"budget"`` or ``"adam"``, the direction of a target that has not held yet (module docstring).
        edge_gradient: shape only, the weight of NMR's rasterization gradient in the vertex gradient (module
            docstring); 1 is NMR's definition.
        visibility_gradient: shape only, ``"nmr"`` or ``"local"``: which rasterization gradient (module
            docstring).

    Attributes:
        restarts: int64 ``(T,)``, stall restarts per target in the current round.

    Raises:
        ValueError: an option out of range or not known for the perturbation, ``binary_search_steps != 1``, or an
            attack whose parametrisation the rule cannot step (a smoothed or clamped flow, another colour mapping).
    """

    rounds = 1
    # the per-round step state (:meth:`_reset_round_state`); a modifier is None while its option is off
    _delta: Optional[Tensor]
    _momentum: Optional[Momentum]
    _stall: Optional[StallRestarts]
    _adam: Optional[AdamReach]
    _last_loss: Optional[Tensor]

    def __init__(self, *, attack: Any, num_targets: int, **options: Any) -> None:
        kind = _ddn_perturbation(attack, options)
        self.kind = kind
        self.options = {**DDN_DEFAULTS[kind], **options}
        opts = {k: v for k, v in self.options.items() if k not in _RULE_OPTIONS}
        self._read_rule_options()
        self._attack = attack
        self._budget_options = opts
        BudgetState(num_targets, attack.steps, **opts)  # validate every option now
        self.num_targets = int(num_targets)
        self.state: Optional[BudgetState] = None
        self.norm: Any = None
        self._origin: Optional[Tensor] = None
        self._reset_round_state(None)

    def _read_rule_options(self) -> None:
        """Validate and keep the options that are the rule's own (not :class:`BudgetState`'s)."""
        smoothness = self.options.get("smoothness")
        if smoothness is not None:
            positive_option("smoothness", smoothness)
        self.smoothness = smoothness
        momentum = self.options["momentum"]
        if isinstance(momentum, bool) or not isinstance(momentum, (int, float)) or not 0 <= momentum < 1:
            raise ValueError(f"momentum must be a number in [0, 1), got {momentum!r}")
        self.momentum = float(momentum)
        stall_steps = self.options["stall_steps"]
        if isinstance(stall_steps, bool) or not isinstance(stall_steps, int) or stall_steps < 0:
            raise ValueError(f"stall_steps must be an integer >= 0 (0: off), got {stall_steps!r}")
        self.stall_steps = int(stall_steps)
        self.stall_factor = positive_option("stall_factor", self.options["stall_factor"])
        if self.stall_factor > 1:
            raise ValueError(f"stall_factor must be in (0, 1], got {self.stall_factor!r}")
        reach = self.options["reach"]
        if not isinstance(reach, str) or reach not in REACH_MODES:
            raise ValueError(f"reach must be one of {REACH_MODES}, got {reach!r}")
        self.reach = reach
        if "edge_gradient" in self.options:  # shape only: a texture attack moves no vertex
            weight = self.options["edge_gradient"]
            if isinstance(weight, bool) or not isinstance(weight, (int, float)) or not 0 <= weight < float("inf"):
                raise ValueError(f"edge_gradient must be a finite number >= 0, got {weight!r}")
            self.edge_gradient = float(weight)
        if "visibility_gradient" in self.options:  # shape only, as edge_gradient
            self.visibility_gradient = check_visibility_gradient(self.options["visibility_gradient"])

    def _reset_round_state(self, delta: Optional[Tensor]) -> None:
        """The per-round step state: the perturbation ``delta`` (``None`` before the first round), the step modifiers
        whose options are on (:mod:`meshadv.attacks.budget_modifiers`), the step lengths' scales and the step count."""
        self._delta = delta
        on = delta is not None
        self._momentum = Momentum(self.momentum, delta) if on and self.momentum > 0 else None
        self._stall = StallRestarts(self.stall_steps, delta) if on and self.stall_steps > 0 else None
        self._adam = AdamReach(delta) if on and self.reach == "adam" else None
        self._scale = torch.ones(self.num_targets, dtype=torch.float64)
        self.restarts = torch.zeros(self.num_targets, dtype=torch.long)
        self._last_loss = None
        self._step = 0

    @property
    def lambdas(self) -> Tensor:
        """No perceptual weight: zeros ``(T,)``."""
        return torch.zeros(self.num_targets, dtype=torch.float32)

    def prepare(self, mesh: Any, edges: Tensor) -> None:
        """Build the norm of the mesh (Laplacian and components, or the colour mask) and the budgets."""
        attack = self._attack
        if self.kind == "shape":
            self.norm = LaplacianNorm(edges, mesh.vertices.shape[0], self.smoothness,
                                      getattr(attack, "vertex_mask", None))
            self._origin = torch.zeros_like(mesh.vertices)
        else:
            self.norm = ColorNorm(getattr(attack, "face_mask", None))
            self._origin = mesh.face_colors.detach().clamp(COLOR_EPS, 1 - COLOR_EPS)
        # a hair inside max_distortion, so float rounding never pushes a target past it (the loop would stop it)
        cap = None if attack.max_distortion is None else self.norm.from_distance(attack.max_distortion) * (1 - 1e-6)
        self.state = BudgetState(self.num_targets, attack.steps, cap=cap, **self._budget_options)

    def start_round(self, params: Tensor) -> None:
        """Budgets back to ``init_budget``, ``delta = 0``."""
        if self.state is None or self._origin is None:
            raise RuntimeError("DDNRule.prepare(mesh, edges) must be called before start_round")
        self.state.reset()
        self._reset_round_state(torch.zeros((params.shape[0], *self._origin.shape), dtype=params.dtype))
        params.grad = None

    def objective(self, adv: Tensor, perceptual: Tensor, distance: Tensor, active: Tensor) -> Tensor:
        """The adversarial loss alone, summed over the targets (the distortion is the budget)."""
        self._last_loss = adv.detach().double().cpu()
        return adv.sum()

    def _restart_stalled(self, idx: Tensor, delta: Tensor, held: Tensor) -> Tuple[Tensor, Tensor]:
        """Stall handling (``stall_steps > 0``): every target of ``idx`` that has stalled (:class:`StallRestarts`)
        is put back at its lowest-loss point (this step's gradient, taken elsewhere, is not used for it); its step
        length is multiplied by ``stall_factor`` and its momentum cleared. Returns the new ``delta`` and the
        restarted rows (bool ``(K,)``)."""
        none = torch.zeros(len(idx), dtype=torch.bool)
        if self._stall is None or self._last_loss is None or len(self._last_loss) != len(idx):
            return delta, none
        delta, stalled = self._stall.check(idx, delta, self._last_loss, held)
        if bool(stalled.any()):
            rows = idx[stalled]
            self._scale[rows] *= self.stall_factor
            self.restarts[rows] += 1
            if self._momentum is not None:
                self._momentum.clear(rows)
        return delta, stalled

    def _heading(self, idx: Tensor, grad: Tensor) -> Tensor:
        """The unit step direction of the targets ``idx``: the budget norm's direction of ``grad``, through the
        momentum when it is on, and Adam's direction for the targets not held yet with ``reach="adam"``."""
        heading = self.norm.direction(grad)
        if self._momentum is not None:
            heading = self._momentum.heading(idx, heading, self.norm)
        if self._adam is not None and self.state is not None:
            heading = self._adam.heading(idx, self.state.first_held[idx] < 0, grad, heading, self.norm)
        return heading

    def step(self, params: Tensor, active: Tensor, is_adversarial: Tensor) -> None:
        """Budget update, one step of fixed length in the budget's norm, projection into the budget ball."""
        if self._delta is None or self.state is None or self._origin is None:
            raise RuntimeError("DDNRule.start_round must be called before step")
        idx = active.cpu().long()
        with torch.no_grad():
            grad = self._gradient(params, idx)
            delta = self._delta[idx]
            budgets = self.state.update(idx, is_adversarial, self.norm.norm(delta), self._step)
            delta, restarted = self._restart_stalled(idx, delta, is_adversarial.detach().cpu().bool())
            heading = self._heading(idx, grad)
            if self._momentum is not None and bool(restarted.any()):
                self._momentum.clear(idx[restarted])
            scale = torch.where(restarted, torch.zeros_like(self._scale[idx]), self._scale[idx])
            heading = heading * scale.to(heading.dtype).to(heading.device).view((-1,) + (1,) * (heading.dim() - 1))
            moved = self.state.move(delta, heading, budgets, self._step, self.norm, idx)
            self._delta[idx] = self._write_params(params, idx, moved, self._origin)
        params.grad = None
        self._step += 1

    def _gradient(self, params: Tensor, idx: Tensor) -> Tensor:
        """The gradient of the rows ``idx`` with respect to what the rule steps: the flow (shape) or the colours
        (texture: ``d loss / d colour = d loss / d logit / (c (1 - c))``); zeros when there is none."""
        grad = params.grad
        grad = torch.zeros_like(params[idx]) if grad is None else grad[idx].detach()
        if self.kind == "texture":
            colors = torch.sigmoid(params[idx].detach())
            grad = grad / (colors * (1 - colors)).clamp(min=TINY)
        return grad

    def _write_params(self, params: Tensor, idx: Tensor, moved: Tensor, origin: Tensor) -> Tensor:
        """Write the perturbation ``moved`` of the rows ``idx`` into the attack's parameters (texture: the colours
        ``origin + moved`` clipped into ``[0, 1]``, projected again and written as logits) and return the perturbation
        kept."""
        if self.kind == "texture":
            moved = (origin + moved).clamp(0.0, 1.0) - origin
            moved = self.norm.project(moved)
            params[idx] = torch.logit((origin + moved).clamp(COLOR_EPS, 1 - COLOR_EPS)).to(params.dtype)
        else:
            params[idx] = moved.to(params.dtype)
        return moved

    def config(self) -> Dict[str, Any]:
        """The effective options (defaults filled in)."""
        return dict(self.options)


def _ddn(*, attack: Any, num_targets: int, **options: Any) -> UpdateRule:
    return DDNRule(attack=attack, num_targets=num_targets, **options)


register_update_rule("ddn", _ddn)
