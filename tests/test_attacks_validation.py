"""Attack hyper-parameters are checked at construction: wrong types raise TypeError, bad values ValueError, each
naming the argument; masks, the update rule and the perturbation registry likewise."""

from __future__ import annotations

import math
from typing import Any, Dict

import pytest
import torch

from meshadv.attacks import ShapeAttack, SmoothTextureAttack, TextureAttack, make_attack, perturbations

BAD: Dict[str, Any] = {
    "lr='0.1'": ({"lr": "0.1"}, TypeError, "lr"),
    "steps=None": ({"steps": None}, TypeError, "steps"),
    "steps=inf": ({"steps": math.inf}, TypeError, "steps"),
    "steps=1.9": ({"steps": 1.9}, TypeError, "steps"),
    "steps=2.0": ({"steps": 2.0}, TypeError, "steps"),
    "steps='10'": ({"steps": "10"}, TypeError, "steps"),
    "steps=True": ({"steps": True}, TypeError, "steps"),
    "steps=0": ({"steps": 0}, ValueError, "steps"),
    "lr=inf": ({"lr": math.inf}, ValueError, "lr"),
    "lr=nan": ({"lr": math.nan}, ValueError, "lr"),
    "lr=0": ({"lr": 0.0}, ValueError, "lr"),
    "jitter=[]": ({"jitter": []}, TypeError, "jitter"),
    "jitter={'zoom': 1}": ({"jitter": {"zoom": 1.0}}, ValueError, "jitter"),
    "jitter={'azimuth': -1}": ({"jitter": {"azimuth": -1.0}}, ValueError, "jitter"),
    "seed=2**70": ({"seed": 2**70}, ValueError, "seed"),
    "seed=-1": ({"seed": -1}, ValueError, "seed"),
    "seed=0.5": ({"seed": 0.5}, TypeError, "seed"),
    "binary_search_steps=1.5": ({"binary_search_steps": 1.5}, TypeError, "binary_search_steps"),
    "lambda_perceptual=-1": ({"lambda_perceptual": -1.0}, ValueError, "lambda_perceptual"),
    "success_fraction=0": ({"success_fraction": 0.0}, ValueError, "success_fraction"),
    "success_fraction=1.5": ({"success_fraction": 1.5}, ValueError, "success_fraction"),
    "early_stop=0": ({"early_stop": 0}, ValueError, "early_stop"),
    "max_distortion=-1": ({"max_distortion": -1.0}, ValueError, "max_distortion"),
    "loss='hinge'": ({"loss": "hinge"}, ValueError, "loss"),
    "method='sgd'": ({"method": "sgd"}, ValueError, "method"),
    "method_options=[]": ({"method_options": []}, TypeError, "method_options"),
}


@pytest.mark.parametrize("cls", [ShapeAttack, TextureAttack, SmoothTextureAttack])
@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_hyper_parameters_raise_at_construction_naming_the_argument(cls: Any, case: str) -> None:
    kwargs, error, name = BAD[case]
    with pytest.raises(error, match=name):
        cls(**kwargs)


def test_shape_only_hyper_parameters_and_masks() -> None:
    with pytest.raises(TypeError, match="smoothing"):
        ShapeAttack(smoothing=1.5)
    with pytest.raises(ValueError, match="max_step"):
        ShapeAttack(max_step=math.inf)
    with pytest.raises(TypeError, match="vertex_mask"):
        ShapeAttack(vertex_mask=[True, False])
    with pytest.raises(ValueError, match="face_mask selects no face"):
        TextureAttack(face_mask=torch.zeros(4, dtype=torch.bool))


def test_masks_and_method_are_shown_in_config() -> None:
    mask = torch.tensor([False, True, True, False])
    config = TextureAttack(face_mask=mask).config()
    assert config["face_mask"] == {"size": 4, "indices": [1, 2]}
    assert config["method"] == "adam" and config["method_options"] == {}
    assert ShapeAttack().config()["vertex_mask"] is None


def test_valid_values_are_kept_with_python_types() -> None:
    attack = ShapeAttack(steps=torch.tensor(5), lr=torch.tensor(0.5), seed=2**63 - 1, jitter={"azimuth": 2})
    assert attack.steps == 5 and isinstance(attack.steps, int)
    assert attack.lr == 0.5 and isinstance(attack.lr, float)
    assert attack.jitter == {"azimuth": 2.0}


def test_perturbation_registry() -> None:
    assert perturbations() == ["shape", "texture"]
    assert isinstance(make_attack("shape", steps=3), ShapeAttack)
    with pytest.raises(ValueError, match="perturbation"):
        make_attack("colour")


def test_bad_call_and_helper_arguments_raise_naming_them() -> None:
    """evaluate, the criteria, the lambda search and the rule registry check their arguments by name."""
    from stand_in_victims import PooledLinearClassifier

    from meshadv.attacks import Disappearance, LambdaSearch, Misclassification, evaluate, register_update_rule
    from meshadv.mesh import builtin_mesh
    from meshadv.render import ViewSet

    victim, mesh = PooledLinearClassifier(), builtin_mesh("cube")
    views = ViewSet.orbit([40.0], elevation=20.0, distance=2.6)
    with pytest.raises(ValueError, match="meshes must be a Mesh or a non-empty sequence"):
        evaluate([], views, victim, Misclassification(1))
    for bad in ([], 5, [Misclassification(1), "boat"]):
        with pytest.raises(ValueError, match="criterion must be a Criterion"):
            evaluate(mesh, views, victim, bad)
        with pytest.raises(ValueError, match="criterion must be a Criterion"):
            TextureAttack(steps=1)(mesh, views, victim, bad)
    with pytest.raises(TypeError, match="threshold"):
        Disappearance("blob", threshold="high")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="threshold"):
        Disappearance("blob", threshold=math.nan)
    with pytest.raises(TypeError, match="factory must be callable"):
        register_update_rule("not-a-rule", "adam")  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="initial"):
        LambdaSearch("1")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="initial"):
        LambdaSearch(-1.0)
    with pytest.raises(TypeError, match="num_targets"):
        LambdaSearch(1.0, 1.5)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="factor"):
        LambdaSearch(1.0, factor=1.0)


def test_views_and_victims_that_are_not_meshadv_objects_are_named() -> None:
    """A list of azimuths for ``views``, a bare ``nn.Module`` for ``victim``: errors that say what to pass instead."""
    from stand_in_victims import PooledLinearClassifier

    from meshadv.attacks import TargetedMisclassification
    from meshadv.mesh import builtin_mesh
    from meshadv.render import RenderSetup, ViewSet

    victim, mesh = PooledLinearClassifier(), builtin_mesh("cube")
    views = ViewSet.orbit([40.0], elevation=20.0, distance=2.6)
    attack, target = TextureAttack(steps=1), TargetedMisclassification(3)
    with pytest.raises(TypeError, match=r"^views must be a meshadv.render.ViewSet .*got list"):
        attack(mesh, [40.0], victim, target)
    with pytest.raises(TypeError, match=r"^eval_views must be a meshadv.render.ViewSet .*got str"):
        attack(mesh, views, victim, target, eval_views="front")
    with pytest.raises(TypeError, match=r"^views must be a meshadv.render.ViewSet .*got tuple"):
        RenderSetup(image_size=16).render(mesh.vertices[None], mesh.faces, mesh.face_colors, (views,))
    with pytest.raises(ValueError, match=r"^victim must be a meshadv victim .*ClassifierVictim.*got Linear"):
        attack(mesh, views, torch.nn.Linear(3, 1000), target)
