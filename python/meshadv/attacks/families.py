"""The registry of attack families: one name per kind of perturbation, used by the CLI, sweeps and transfer.

The concept is called the *perturbation* everywhere (the paper's word): ``"shape"`` (vertex flow), ``"texture"``
(face colours) or ``"texture-map"`` (the texels of a UV texture image). Code that must build an attack for a
perturbation named in a config, a command-line option or a database row asks this registry instead of writing
``if perturbation == "shape"`` chains.

Example:
    >>> make_attack("texture", steps=10).perturbation
    'texture'
    >>> perturbations()
    ['shape', 'texture', 'texture-map']
"""

from __future__ import annotations

from typing import Any, Dict, List, Type

from meshadv.attacks.mesh_attack import MeshAttack
from meshadv.attacks.shape import ShapeAttack
from meshadv.attacks.texture import TextureAttack
from meshadv.attacks.texture_map import TextureMapAttack

__all__ = ["PERTURBATIONS", "MESH_PERTURBATIONS", "perturbations", "attack_class", "make_attack", "check_perturbation"]

#: Attack class per perturbation name.
PERTURBATIONS: Dict[str, Type[MeshAttack]] = {"shape": ShapeAttack, "texture": TextureAttack,
                                               "texture-map": TextureMapAttack}
#: The perturbations every mesh takes (``texture-map`` needs a UV texture image): what a sweep runs by default.
MESH_PERTURBATIONS: List[str] = ["shape", "texture"]


def perturbations() -> List[str]:
    """The registered perturbation names, sorted."""
    return sorted(PERTURBATIONS)


def check_perturbation(name: Any, argument: str = "perturbation") -> str:
    """Return ``name`` when it is a registered perturbation.

    Raises:
        ValueError: unknown name (the message names ``argument`` and lists the known ones).
    """
    if not isinstance(name, str) or name not in PERTURBATIONS:
        raise ValueError(f"{argument} must be one of {perturbations()}, got {name!r}")
    return name


def attack_class(perturbation: str) -> Type[MeshAttack]:
    """The attack class of ``perturbation`` (``ValueError`` when unknown)."""
    return PERTURBATIONS[check_perturbation(perturbation)]


def make_attack(perturbation: str, **hyper_parameters: Any) -> MeshAttack:
    """An attack of ``perturbation`` with the given keyword-only hyper-parameters."""
    return attack_class(perturbation)(**hyper_parameters)
