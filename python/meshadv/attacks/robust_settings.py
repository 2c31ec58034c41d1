"""The robust attack's settings: expectation over transformations with a low-frequency perturbation.

:func:`robust_options` gives the hyper-parameters that make an attack of a perturbation and update rule change the
object rather than the shading of single facets or the pixels of a few views, for ``meshadv attack --eot N``, sweep
files and the Python API alike: ``eot`` samples per step (:mod:`meshadv.attacks.eot`) and a low-pass on the
perturbation:

* shape, ``method="ddn"``: the rule's Laplacian preconditioner ``(L + I / smoothness)^-1`` at ``smoothness``
  :data:`ROBUST_DDN_SMOOTHNESS` (its default, 0.1, is nearly the raw per-vertex gradient);
* shape, ``method="adam"``: the smoothed flow ``dv = S^k p`` with ``k =`` :data:`ROBUST_SHAPE_SMOOTHING` and the
  larger learning rate it needs (:data:`ROBUST_SHAPE_LR`);
* texture, either rule: ``gradient_smoothing`` :data:`ROBUST_TEXTURE_SMOOTHING` (face-neighbour low-pass of the
  colour gradient, :mod:`meshadv.attacks.lowpass`).

Example:
    >>> robust_options("shape", "ddn", samples=4)["method_options"]
    {'smoothness': 10.0}
    >>> from meshadv.attacks import make_attack
    >>> make_attack("texture", steps=100, method="ddn", **robust_options("texture", "ddn")).gradient_smoothing
    8
"""

from __future__ import annotations

from typing import Any, Dict

from meshadv import _validate
from meshadv.attacks.families import check_perturbation

__all__ = ["robust_options", "ROBUST_SAMPLES", "ROBUST_DDN_SMOOTHNESS", "ROBUST_SHAPE_SMOOTHING", "ROBUST_SHAPE_LR",
           "ROBUST_TEXTURE_SMOOTHING"]

#: Views drawn per step by default.
ROBUST_SAMPLES = 4
#: ``method="ddn"``'s shape preconditioner strength of the robust attack.
ROBUST_DDN_SMOOTHNESS = 10.0
#: Rounds of neighbour averaging of the Adam shape flow of the robust attack, and its learning rate.
ROBUST_SHAPE_SMOOTHING = 8
ROBUST_SHAPE_LR = 1e-2
#: Rounds of face-neighbour averaging of the colour gradient of the robust texture attack.
ROBUST_TEXTURE_SMOOTHING = 8


def robust_options(perturbation: str, method: str, samples: int = ROBUST_SAMPLES) -> Dict[str, Any]:
    """Hyper-parameters of the robust attack for ``perturbation`` and ``method`` (keyword arguments of the attack
    class: ``eot`` and the low-pass options above; merge user options over them).

    Raises:
        ValueError: unknown ``perturbation``, a ``method`` other than ``"ddn"`` / ``"adam"``, or ``samples < 1``.
        TypeError: ``samples`` is not an integer.
    """
    check_perturbation(perturbation)
    method = _validate.choice("method", method, ("adam", "ddn"))
    options: Dict[str, Any] = {"eot": _validate.positive_int("samples", samples, high=4096)}
    if perturbation == "texture":
        options["gradient_smoothing"] = ROBUST_TEXTURE_SMOOTHING
    elif method == "ddn":
        options["method_options"] = {"smoothness": ROBUST_DDN_SMOOTHNESS}
    else:
        options.update(smoothing=ROBUST_SHAPE_SMOOTHING, lr=ROBUST_SHAPE_LR)
    return options
