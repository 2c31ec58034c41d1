"""Update rules: how the attack loop turns losses into parameter updates (pluggable, chosen by ``method=``).

The loop in :mod:`meshadv.attacks.loop` owns everything a rule should not care about: rendering, the victim, the
criteria, the per-target bookkeeping (best result, early stopping, budget) and the final evaluation. A rule owns the
optimisation itself. Contract, per attack call with ``T`` targets:

1. ``rule = make_update_rule(method, attack=attack, num_targets=T, **method_options)`` -- one rule object per call;
   then ``rule.prepare(mesh, edges)`` with the pristine mesh and its unique edges.
2. For ``round`` in ``range(rule.rounds)``: the loop resets the parameters to the pristine mesh
   (``params (T, ...)``, a leaf tensor with ``requires_grad``) and calls ``rule.start_round(params)``.
3. Per step, with ``idx`` the int64 indices ``(K,)`` of the targets still active, the loop renders ``params[idx]``
   and computes per-target terms, each ``(K,)`` and differentiable: ``adv`` (criterion loss, mean over the views),
   ``perceptual`` (the paper's perceptual loss of the family) and ``distance`` (the family's distortion measure, the
   one the budget and the best result use). ``rule.objective(adv, perceptual, distance, idx)`` returns the scalar to
   differentiate; the loop calls ``backward()`` on it.
4. The loop then calls ``rule.step(params, idx, is_adversarial)``: ``is_adversarial (K,) bool`` says which active
   targets met the criterion (``success_fraction`` of the views) *before* this update, measured on the images the
   objective was computed from. The rule updates ``params`` in place (an optimiser step, a projection, ...).
   Under a cap with a largest-move ceiling the loop then projects the updated rows into it and, when that changed
   them, calls ``rule.params_changed(params, idx)``.
5. After a round, ``rule.end_round(successes)`` with one flag per target (did the round reach a success within the
   distortion budget?) drives any outer search.

``rule.lambdas`` (float32 ``(T,)``) is the current perceptual weight per target, recorded in the loss history and in
the result (a rule without one returns zeros). ``rule.config()`` is the JSON-able description that the attack's
``config()`` shows under ``method_options``.

The reference rule, :class:`AdamLambdaRule` (``method="adam"``), is the paper's: minimise
``sum_k adv_k + lambda_k * perceptual_k`` with Adam (element-wise, so batched targets behave as if run one at a time),
``lambda`` searched per target over ``binary_search_steps`` rounds by :class:`~meshadv.attacks.search.LambdaSearch`.

Adding a rule: subclass :class:`UpdateRule` and register a factory with :func:`register_update_rule`; the factory
receives the attack (for its ``lr``, ``lambda_perceptual``, ``binary_search_steps``, ...) and ``num_targets`` plus
any ``method_options`` given to the attack.

Example:
    >>> rule = AdamLambdaRule(lr=0.1, lambda_perceptual=1.0, rounds=2, num_targets=1)
    >>> p = torch.zeros(1, 3, requires_grad=True); rule.start_round(p)
    >>> idx = torch.tensor([0])
    >>> rule.objective((p[idx] - 1).pow(2).sum(1), p[idx].pow(2).sum(1), p[idx].pow(2).sum(1), idx).backward()
    >>> rule.step(p, idx, torch.tensor([False])); [round(v, 3) for v in p[0].tolist()]
    [0.1, 0.1, 0.1]
"""

from __future__ import annotations

import inspect
from abc import ABC, abstractmethod
from typing import Any, Callable, Dict, List, Sequence

import torch
from torch import Tensor

from meshadv.attacks.search import LambdaSearch

__all__ = ["RECOMMENDED_METHOD", "UpdateRule", "AdamLambdaRule", "register_update_rule", "make_update_rule",
           "update_rules"]

#: The update rule that ``meshadv attack``, ``meshadv demo`` and sweep files use unless told otherwise: the
#: distortion-budget rule (:mod:`meshadv.attacks.budget`). The attack classes themselves keep ``method="adam"``, the
#: paper's reference.
RECOMMENDED_METHOD = "ddn"


class UpdateRule(ABC):
    """How one attack call optimises its parameters (see the module docstring for the contract).

    Attributes:
        rounds: number of rounds (restarts from the pristine mesh) the loop runs.
        edge_gradient: weight of NMR's rasterization gradient on the vertices in the renders the rule differentiates.
        visibility_gradient: which rasterization gradient those renders give the vertices (``"nmr"`` or
            ``"local"``, :func:`meshadv.render.render`'s ``visibility_gradient``).
    """

    rounds: int = 1
    #: Weight of NMR's rasterization gradient in the vertex gradient the rule steps along
    #: (:func:`meshadv.render.render`'s ``edge_gradient``): 1, NMR's definition, unless a rule says otherwise.
    edge_gradient: float = 1.0
    #: The rasterization gradient of the renders the rule differentiates (:func:`meshadv.render.render`'s
    #: ``visibility_gradient``): NMR's unless a rule says otherwise.
    visibility_gradient: str = "nmr"

    @property
    @abstractmethod
    def lambdas(self) -> Tensor:
        """Current perceptual weight per target, float32 ``(T,)``."""

    @abstractmethod
    def start_round(self, params: Tensor) -> None:
        """A round starts from ``params (T, ...)`` (pristine, a leaf tensor with ``requires_grad``)."""

    @abstractmethod
    def objective(self, adv: Tensor, perceptual: Tensor, distance: Tensor, active: Tensor) -> Tensor:
        """The scalar to differentiate from the per-target terms ``(K,)`` of the ``active`` targets (int64 ``(K,)``)."""

    @abstractmethod
    def step(self, params: Tensor, active: Tensor, is_adversarial: Tensor) -> None:
        """Update ``params`` in place after ``backward()``; ``is_adversarial (K,) bool`` per active target."""

    def prepare(self, mesh: Any, edges: Tensor) -> None:
        """Called once per attack call, before the first round, with the pristine mesh and its unique edges
        ``(E, 2)`` (for rules whose geometry depends on the mesh, e.g. a Laplacian). The default does nothing."""

    def params_changed(self, params: Tensor, active: Tensor) -> None:
        """The loop changed the rows ``active`` of ``params`` after :meth:`step` (a projection into the
        perceptibility cap's largest move); a rule that keeps its own copy of the perturbation re-reads it. The
        default does nothing (Adam steps ``params`` itself)."""

    def end_round(self, successes: Sequence[bool]) -> None:
        """A round ended; ``successes`` has one flag per target. The default does nothing."""

    def config(self) -> Dict[str, Any]:
        """JSON-able options of the rule (shown by the attack's ``config()``)."""
        return {}


class AdamLambdaRule(UpdateRule):
    """The paper's rule: Adam on ``adv + lambda * perceptual``, ``lambda`` binary-searched per target over rounds.

    Args:
        lr: Adam learning rate.
        lambda_perceptual: initial ``lambda``.
        rounds: binary-search rounds (1 = a single run at ``lambda_perceptual``).
        num_targets: ``T``.
    """

    def __init__(self, *, lr: float, lambda_perceptual: float, rounds: int, num_targets: int) -> None:
        self.lr = float(lr)
        self.rounds = int(rounds)
        self._search = LambdaSearch(lambda_perceptual, num_targets)
        self._lambdas = self._search.lambdas
        self._optimiser: Any = None

    @property
    def lambdas(self) -> Tensor:
        """Current ``lambda`` per target (fixed during a round)."""
        return self._lambdas

    def start_round(self, params: Tensor) -> None:
        """A fresh Adam state for the round's parameters."""
        self._lambdas = self._search.lambdas
        self._optimiser = torch.optim.Adam([params], lr=self.lr)
        self._optimiser.zero_grad(set_to_none=True)

    def objective(self, adv: Tensor, perceptual: Tensor, distance: Tensor, active: Tensor) -> Tensor:
        """``sum_k adv_k + lambda_k perceptual_k`` (``distance`` is not used)."""
        return (adv + self._lambdas[active] * perceptual).sum()

    def step(self, params: Tensor, active: Tensor, is_adversarial: Tensor) -> None:
        """One Adam step (finished targets have no gradient, so Adam leaves them alone)."""
        self._optimiser.step()
        self._optimiser.zero_grad(set_to_none=True)

    def end_round(self, successes: Sequence[bool]) -> None:
        """Move each target's ``lambda`` (:meth:`LambdaSearch.update`)."""
        self._search.update(list(successes))

    def config(self) -> Dict[str, Any]:
        """No options beyond the attack's own ``lr``, ``lambda_perceptual`` and ``binary_search_steps``."""
        return {}


RuleFactory = Callable[..., UpdateRule]
_RULES: Dict[str, RuleFactory] = {}


def register_update_rule(name: str, factory: RuleFactory) -> None:
    """Make ``method=name`` available to the attacks.

    Args:
        name: the method name.
        factory: ``factory(attack=attack, num_targets=T, **method_options) -> UpdateRule``.

    Raises:
        ValueError: ``name`` is empty or already registered.
        TypeError: ``factory`` is not callable.
    """
    if not isinstance(name, str) or not name:
        raise ValueError(f"name must be a non-empty string, got {name!r}")
    if name in _RULES:
        raise ValueError(f"update rule {name!r} is already registered")
    if not callable(factory):
        raise TypeError(f"factory must be callable, got {type(factory).__name__}")
    _RULES[name] = factory


def update_rules() -> List[str]:
    """Names of the registered update rules."""
    return sorted(_RULES)


def make_update_rule(method: str, *, attack: Any, num_targets: int, **options: Any) -> UpdateRule:
    """The rule ``method`` for one attack call.

    Raises:
        ValueError: unknown ``method``, or ``options`` (the attack's ``method_options``) the rule does not take.
    """
    if method not in _RULES:
        raise ValueError(f"method must be one of {update_rules()}, got {method!r}")
    factory = _RULES[method]
    params = inspect.signature(factory).parameters
    if not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        takes = set(params) - {"attack", "num_targets"}
        unknown = sorted(set(options) - takes)
        if unknown:
            raise ValueError(f"method_options has unknown keys {unknown} for method={method!r}; it takes "
                             f"{sorted(takes) if takes else 'none'}")
    return factory(attack=attack, num_targets=num_targets, **options)


def _adam(*, attack: Any, num_targets: int) -> UpdateRule:
    return AdamLambdaRule(lr=attack.lr, lambda_perceptual=attack.lambda_perceptual,
                          rounds=attack.binary_search_steps, num_targets=num_targets)


register_update_rule("adam", _adam)
