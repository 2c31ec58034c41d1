"""MeshAdv attacks (Xiao et al., CVPR 2019): adversarial shape and texture perturbations of meshes.

Attack objects hold hyper-parameters only; the mesh, views, victim and criterion are passed per call and the call
returns an :class:`AttackResult`:

    >>> from meshadv.attacks import ShapeAttack, TargetedMisclassification
    >>> result = ShapeAttack(steps=300)(mesh, views, victim, TargetedMisclassification("bicycle"))  # doctest: +SKIP
    >>> result.succeeded, result.distances[0]["laplacian_pair_mean"]                                 # doctest: +SKIP

Several targets are attacked together as a batch by passing a list of criteria. ``eot=N`` (or
``**robust_options(perturbation, method)``) optimises over views drawn afresh at every step and judges success on
fresh views (:mod:`meshadv.attacks.eot`, :mod:`meshadv.attacks.robust_settings`).
"""

from __future__ import annotations

from meshadv.attacks.mesh_attack import MeshAttack
from meshadv.attacks.evaluation import Evaluation, evaluate
from meshadv.attacks.history import StepInfo
from meshadv.attacks.criteria import (
    Criterion,
    Disappearance,
    Misclassification,
    TargetedMisclassification,
    WithMargin,
)
from meshadv.attacks.distances import (
    PAPER_COMPARABLE,
    color_rmse,
    displacement_stats,
    laplacian_distance,
    laplacian_pair_mean,
    mesh_distances,
    read_distance,
)
from meshadv.attacks.eot import Transformations
from meshadv.attacks.flow import smooth_flow
from meshadv.attacks.losses import (
    cw_targeted_margin,
    cw_untargeted_margin,
    disappearance_loss,
    image_smoothness_loss,
    laplacian_flow_loss,
    targeted_cross_entropy,
    untargeted_cross_entropy,
)
from meshadv.attacks.result import AttackResult, load_result_record
from meshadv.attacks.search import LambdaSearch
from meshadv.attacks.budget import DDNRule  # noqa: F401  (registers method="ddn")
from meshadv.attacks.families import PERTURBATIONS, attack_class, make_attack, perturbations
from meshadv.attacks.robust_settings import robust_options
from meshadv.attacks.shape import ShapeAttack
from meshadv.attacks.smooth_texture import SmoothTextureAttack
from meshadv.attacks.texture import TextureAttack
from meshadv.attacks.update import AdamLambdaRule, UpdateRule, register_update_rule, update_rules

__all__ = [
    "MeshAttack",
    "ShapeAttack",
    "TextureAttack",
    "SmoothTextureAttack",
    "StepInfo",
    "Evaluation",
    "evaluate",
    "PERTURBATIONS",
    "perturbations",
    "attack_class",
    "make_attack",
    "UpdateRule",
    "AdamLambdaRule",
    "register_update_rule",
    "update_rules",
    "Criterion",
    "TargetedMisclassification",
    "Misclassification",
    "Disappearance",
    "WithMargin",
    "AttackResult",
    "load_result_record",
    "LambdaSearch",
    "laplacian_flow_loss",
    "image_smoothness_loss",
    "targeted_cross_entropy",
    "untargeted_cross_entropy",
    "cw_targeted_margin",
    "cw_untargeted_margin",
    "disappearance_loss",
    "laplacian_distance",
    "laplacian_pair_mean",
    "read_distance",
    "PAPER_COMPARABLE",
    "color_rmse",
    "displacement_stats",
    "mesh_distances",
    "smooth_flow",
    "Transformations",
    "robust_options",
]
