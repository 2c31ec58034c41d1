"""meshadv.transfer: bad input fails early with a Python exception naming the argument (TypeError for a wrong type,
ValueError for a bad value), before any Mitsuba render or optimisation; edge cases behave as documented.

Fast: no Mitsuba render runs here (a render would mean a check came too late, and a spy makes that a failure).
"""

from __future__ import annotations

import math
from typing import Any

import pytest
import torch

from meshadv.mesh import builtin_mesh
from meshadv.render import Camera, Lights, native_available, render, render_silhouette

needs_native = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")


@pytest.fixture()
def no_render(monkeypatch: pytest.MonkeyPatch) -> list[Any]:
    """Make every Mitsuba render a test failure (the checks must come first); returns the calls seen."""
    from meshadv.transfer import mitsuba_process as render_module

    calls: list[Any] = []

    def spy(*args: Any, **kwargs: Any) -> None:
        calls.append(args)
        raise AssertionError("a Mitsuba render ran before the bad argument was reported")

    monkeypatch.setattr(render_module, "_run_worker", spy)
    return calls


def _chair_case() -> tuple[Any, Camera, torch.Tensor, torch.Tensor]:
    """The builtin chair, a camera, its silhouette (32 x 32) and its render under one light."""
    chair = builtin_mesh("chair")
    camera = Camera.spherical(3.0, 40.0, 25.0)
    with torch.no_grad():
        mask = render_silhouette(chair.vertices, chair.faces, camera, 32)[0, 0]
        lights = Lights(torch.tensor([[0.3, 0.8, -0.5]]), torch.tensor([[0.6, 0.6, 0.6]]), torch.tensor([0.3] * 3))
        image = render(chair.vertices, chair.faces, chair.face_colors, camera, lights, 32).image[0]
    return chair, camera, mask, image


# ----------------------------------------------------------------------------------------------------------------------
# Camera and light estimation
# ----------------------------------------------------------------------------------------------------------------------


@needs_native
@pytest.mark.parametrize(
    "kwargs,error,name",
    [
        ({"steps": -1}, ValueError, "steps"),
        ({"steps": 2.5}, TypeError, "steps"),
        ({"refine": 0}, ValueError, "refine"),
        ({"refine": True}, TypeError, "refine"),
        ({"coarse_size": 4}, ValueError, "coarse_size"),
        ({"coarse_size": 16.0}, TypeError, "coarse_size"),
        ({"blur": -0.1}, ValueError, "blur"),
        ({"lr": 0.0}, ValueError, "lr"),
        ({"antialias": 0}, ValueError, "antialias"),
        ({"viewing_angle": 180.0}, ValueError, "viewing_angle"),
        ({"viewing_angle": "wide"}, TypeError, "viewing_angle"),
        ({"reference_distance": -1.0}, ValueError, "reference_distance"),
        ({"azimuths": (0.0, math.nan)}, ValueError, "azimuths\\[1\\]"),
        ({"elevations": ("up",)}, TypeError, "elevations\\[0\\]"),
    ],
)
def test_estimate_camera_names_a_bad_argument(kwargs: dict[str, Any], error: type, name: str) -> None:
    from meshadv.transfer.estimation import estimate_camera

    chair, _, mask, _ = _chair_case()
    with pytest.raises(error, match=f"^{name}"):
        estimate_camera(mask, chair.vertices, chair.faces, **kwargs)


@needs_native
def test_estimate_camera_and_lights_check_the_mesh_shape() -> None:
    from meshadv.transfer.estimation import estimate_camera
    from meshadv.transfer.estimation import estimate_lights

    chair, camera, mask, image = _chair_case()
    with pytest.raises(ValueError, match="^vertices must have shape"):
        estimate_camera(mask, chair.vertices[:, :2], chair.faces)
    with pytest.raises(ValueError, match="^faces must have shape"):
        estimate_lights(image, mask, chair.vertices, chair.faces[:0], chair.face_colors, camera)


@needs_native
@pytest.mark.parametrize(
    "kwargs,error,name",
    [
        ({"num_lights": -1}, ValueError, "num_lights"),
        ({"num_lights": 2.0}, TypeError, "num_lights"),
        ({"steps": -3}, ValueError, "steps"),
        ({"lr": -0.1}, ValueError, "lr"),
        ({"seed": -1}, ValueError, "seed"),
        ({"seed": "zero"}, TypeError, "seed"),
    ],
)
def test_estimate_lights_names_a_bad_argument(kwargs: dict[str, Any], error: type, name: str) -> None:
    from meshadv.transfer.estimation import estimate_lights

    chair, camera, mask, image = _chair_case()
    with pytest.raises(error, match=f"^{name}"):
        estimate_lights(image, mask, chair.vertices, chair.faces, chair.face_colors, camera, **kwargs)
    with pytest.raises(TypeError, match="^camera must be a meshadv.render.Camera"):
        estimate_lights(image, mask, chair.vertices, chair.faces, chair.face_colors, {"distance": 3.0})


@needs_native
def test_estimate_lights_with_no_directional_light_fits_the_ambient_only() -> None:
    """``num_lights = 0`` is documented as allowed: the fit has no directional light, only the ambient."""
    from meshadv.transfer.estimation import estimate_lights

    chair, camera, mask, image = _chair_case()
    est = estimate_lights(image, mask, chair.vertices, chair.faces, chair.face_colors, camera, num_lights=0, steps=5)
    assert tuple(est.lights.directions.shape) == (1, 0, 3) and tuple(est.lights.colors.shape) == (1, 0, 3)
    assert float(est.lights.ambient.min()) > 0.0 and math.isfinite(est.loss)
    one = estimate_lights(image, mask, chair.vertices, chair.faces, chair.face_colors, camera, num_lights=1, steps=5)
    assert tuple(one.lights.directions.shape) == (1, 1, 3)


# ----------------------------------------------------------------------------------------------------------------------
# The photo's estimation and the black-box pipelines: every argument before the first Mitsuba render
# ----------------------------------------------------------------------------------------------------------------------


def _hidden() -> Any:
    from meshadv.transfer.setups import HiddenScene
    from meshadv.transfer.mitsuba_spec import MitsubaLights

    lights = MitsubaLights([[0.3, 0.8, -0.5]], [[0.5, 0.5, 0.5]], [0.4, 0.4, 0.4])
    return HiddenScene(camera={"distance": 3.2, "azimuth": 50.0, "elevation": 20.0}, lights=lights, image_size=32,
                       spp=4, max_depth=2)


@pytest.mark.parametrize(
    "kwargs,error,name",
    [
        ({"num_lights": -1}, ValueError, "num_lights"),
        ({"camera_steps": 1.5}, TypeError, "camera_steps"),
        ({"light_steps": -2}, ValueError, "light_steps"),
    ],
)
def test_estimate_parameters_checks_the_step_counts_before_the_photo(no_render: list[Any], kwargs: dict[str, Any],
                                                                     error: type, name: str) -> None:
    from meshadv.transfer.photos import estimate_parameters

    with pytest.raises(error, match=f"^{name}"):
        estimate_parameters(builtin_mesh("chair"), _hidden(), **kwargs)
    assert no_render == []


def _classifier_victim() -> Any:
    from stand_in_victims import PooledLinearClassifier

    return PooledLinearClassifier()


def _detector_victim() -> Any:
    from stand_in_victims import DarkBlobDetector

    return DarkBlobDetector()


@pytest.mark.parametrize(
    "kwargs,error,match",
    [
        ({"hidden": {"distance": 3.0}}, TypeError, "^hidden must be a HiddenScene"),
        ({"victim": 42}, TypeError, "^victim must be a callable"),
        ({"victim": "detector"}, ValueError, "needs a classifier"),
        ({"true_class": "no such class"}, ValueError, "^true_class 'no such class'"),
        ({"target": "no such class"}, ValueError, "no such class"),
        ({"robustness": {"eot": 2}}, TypeError, "^robustness must be a Robustness"),
        ({"attack_kwargs": [("steps", 2)]}, TypeError, "^attack_kwargs must be a dict"),
        ({"attack_kwargs": {"stepz": 2}}, TypeError, "stepz"),
        ({"attack_kwargs": {"antialias": 0}}, ValueError, "^antialias"),
        ({"jitter": 0.5}, TypeError, "^jitter must be a dict"),
        ({"num_lights": -1}, ValueError, "^num_lights"),
        ({"camera_steps": 1.5}, TypeError, "^camera_steps"),
        ({"light_steps": True}, TypeError, "^light_steps"),
        ({"timeout": 0}, ValueError, "^timeout"),
        ({"case_id": ""}, ValueError, "^case_id"),
        ({"case_id": 7}, TypeError, "^case_id"),
        ({"perturbation": "paint"}, ValueError, "perturbation"),
    ],
)
def test_blackbox_classifier_names_a_bad_argument_before_any_render(no_render: list[Any], kwargs: dict[str, Any],
                                                                    error: type, match: str) -> None:
    from meshadv.transfer.blackbox import blackbox_classifier

    args: dict[str, Any] = {"hidden": _hidden(), "victim": _classifier_victim(), "true_class": "chair",
                            "attack_kwargs": {"steps": 1}, **kwargs}
    if args["victim"] == "detector":
        args["victim"] = _detector_victim()
    with pytest.raises(error, match=match):
        blackbox_classifier(builtin_mesh("chair"), args.pop("hidden"), **args)
    assert no_render == []


@pytest.mark.parametrize(
    "kwargs,error,match",
    [
        ({"scene_objects": "cube"}, TypeError, "^scene_objects\\[0\\] must be a meshadv.mesh.Mesh"),
        ({"object_index": 1.0}, TypeError, "^object_index must be an integer"),
        ({"object_index": 2}, ValueError, "^object_index 2 out of range"),
        ({"score_threshold": "high"}, TypeError, "^score_threshold"),
        ({"score_threshold": 1.5}, ValueError, "^score_threshold must be in"),
        ({"background_exclude": "desk"}, TypeError, "^background_exclude"),
        ({"hide_class": "chair"}, ValueError, "'chair' is not a class of dark_blob"),
        ({"victim": "classifier"}, ValueError, "needs a detector"),
        ({"context": "room"}, ValueError, "^context"),
        ({"light_fit": "all"}, ValueError, "^light_fit"),
        ({"attack_kwargs": {"stepz": 2}}, TypeError, "stepz"),
        ({"hidden": None}, TypeError, "^hidden must be a HiddenScene"),
        ({"robustness": 3}, TypeError, "^robustness"),
        ({"timeout": -1.0}, ValueError, "^timeout"),
    ],
)
def test_blackbox_detector_names_a_bad_argument_before_any_render(no_render: list[Any], kwargs: dict[str, Any],
                                                                  error: type, match: str) -> None:
    from meshadv.transfer.blackbox import blackbox_detector

    cube = builtin_mesh("cube", color=(0.1, 0.1, 0.1))
    sphere = builtin_mesh("sphere", color=(0.8, 0.8, 0.8))
    args: dict[str, Any] = {"scene_objects": [cube, sphere], "object_index": 1, "hidden": _hidden(),
                            "victim": _detector_victim(), "hide_class": "blob", "attack_kwargs": {"steps": 1},
                            **kwargs}
    if args["victim"] == "classifier":
        args["victim"] = _classifier_victim()
    with pytest.raises(error, match=match):
        blackbox_detector(args.pop("scene_objects"), args.pop("object_index"), args.pop("hidden"), **args)
    assert no_render == []


# ----------------------------------------------------------------------------------------------------------------------
# Scene values, the hidden world, the controlled transfer and the sweep reader
# ----------------------------------------------------------------------------------------------------------------------


def _record() -> dict[str, Any]:
    from meshadv.render import ViewSet

    return ViewSet.orbit([30.0], elevation=15.0, distance=3.0).to_records()[0]


@pytest.mark.parametrize(
    "kwargs,error,match",
    [
        ({"spp": 1.5}, TypeError, "^spp must be an integer"),
        ({"spp": 0}, ValueError, "^spp must be an integer >= 1"),
        ({"max_depth": 2.0}, TypeError, "^max_depth"),
        ({"max_depth": 0}, ValueError, "^max_depth"),
        ({"seed": -1}, ValueError, "^seed"),
        ({"image_size": 32.5}, TypeError, "^image_size"),
        ({"image_size": (32, 32, 3)}, ValueError, "^image_size"),
        ({"image_size": (32, 48)}, ValueError, "^image_size must be positive and square"),
        ({"environment_scale": math.inf}, ValueError, "^environment_scale"),
        ({"objects": ("mesh",)}, TypeError, "^objects\\[0\\] must be a MeshObject"),
        ({"camera": {"distance": 3.0}}, TypeError, "^camera must be a MitsubaCamera"),
        ({"lights": [1.0]}, TypeError, "^lights must be a MitsubaLights"),
    ],
)
def test_scene_spec_names_a_bad_field(kwargs: dict[str, Any], error: type, match: str) -> None:
    from meshadv.transfer.mitsuba_spec import MeshObject, MitsubaCamera, SceneSpec

    fields: dict[str, Any] = {"objects": (MeshObject.from_mesh(builtin_mesh("cube")),),
                              "camera": MitsubaCamera.from_record(_record()), "image_size": 32, **kwargs}
    with pytest.raises(error, match=match):
        SceneSpec(**fields)


def test_scene_spec_accepts_numpy_integers_and_keeps_the_size_square() -> None:
    import numpy as np

    from meshadv.transfer.mitsuba_spec import MeshObject, MitsubaCamera, SceneSpec

    spec = SceneSpec((MeshObject.from_mesh(builtin_mesh("cube")),), MitsubaCamera.from_record(_record()),
                     image_size=(np.int64(16), 16), spp=np.int32(4), max_depth=-1)
    assert spec.image_size == (16, 16) and spec.spp == 4


@pytest.mark.parametrize(
    "kwargs,error,match",
    [
        ({"eye": (0.0, 0.0)}, ValueError, "^eye must be 3 numbers"),
        ({"up": (0.0, math.nan, 0.0)}, ValueError, "^up\\[1\\]"),
        ({"target": (0.0, "x", 0.0)}, TypeError, "^target\\[1\\]"),
        ({"viewing_angle": "30"}, TypeError, "^viewing_angle"),
        ({"near": None}, TypeError, "^near"),
    ],
)
def test_mitsuba_camera_names_a_bad_field(kwargs: dict[str, Any], error: type, match: str) -> None:
    from meshadv.transfer.mitsuba_spec import MitsubaCamera

    with pytest.raises(error, match=match):
        MitsubaCamera(**{"eye": (0.0, 0.0, -3.0), **kwargs})


@pytest.mark.parametrize(
    "kwargs,error,match",
    [
        ({"camera": [3.0, 10.0, 5.0]}, TypeError, "^camera must be a dict"),
        ({"extra_objects": ("cube",)}, TypeError, "^extra_objects\\[0\\]"),
        ({"spp": 0}, ValueError, "^spp"),
        ({"image_size": (32, 64)}, ValueError, "^image_size must be positive and square"),
        ({"max_depth": "deep"}, TypeError, "^max_depth"),
        ({"viewing_angle": 200.0}, ValueError, "^viewing_angle"),
        ({"lights": {"ambient": [0.1] * 3}}, TypeError, "^lights"),
        ({"base_scene": "/no/such/scene.xml"}, FileNotFoundError, "base_scene"),
    ],
)
def test_hidden_scene_checks_its_settings_when_built(kwargs: dict[str, Any], error: type, match: str) -> None:
    """Not at the first render, minutes later, inside a pipeline."""
    from meshadv.transfer.setups import HiddenScene

    fields: dict[str, Any] = {"camera": {"distance": 3.0, "azimuth": 10.0, "elevation": 5.0}, **kwargs}
    with pytest.raises(error, match=match):
        HiddenScene(**fields)


def _case() -> Any:
    from meshadv.transfer.controlled import TransferCase

    return TransferCase("c0", builtin_mesh("cube"), (_record(),), "stand-in", "bottle", image_size=16)


@pytest.mark.parametrize(
    "kwargs,error,match",
    [
        ({"cases": ["c0"]}, TypeError, "^cases\\[0\\] must be a TransferCase"),
        ({"spp": 0}, ValueError, "^spp"),
        ({"spp": 2.5}, TypeError, "^spp"),
        ({"max_depth": 0}, ValueError, "^max_depth"),
        ({"timeout": 0.0}, ValueError, "^timeout"),
        ({"victim_loader": "efficientnet_lite0"}, TypeError, "^victim_loader"),
        ({"on_error": "ignore"}, ValueError, "^on_error"),
    ],
)
def test_controlled_transfer_names_a_bad_argument_before_any_render(no_render: list[Any], kwargs: dict[str, Any],
                                                                    error: type, match: str) -> None:
    from meshadv.transfer.controlled import controlled_transfer

    args: dict[str, Any] = {"cases": [_case()], "victim_loader": lambda name: pytest.fail("no victim is needed"),
                            **kwargs}
    with pytest.raises(error, match=match):
        controlled_transfer(args.pop("cases"), **args)
    assert no_render == []


def test_cases_from_store_rejects_a_limit_below_one_and_a_string_skip(tmp_path: Any) -> None:
    """``limit=0`` is refused instead of returning a case, and so is a string ``skip``."""
    from meshadv.experiments import ResultStore
    from meshadv.transfer.controlled import cases_from_store

    db = tmp_path / "results.db"
    with ResultStore(db):
        pass
    assert cases_from_store(db, limit=3) == []
    with pytest.raises(ValueError, match="^limit"):
        cases_from_store(db, limit=0)
    with pytest.raises(TypeError, match="^limit"):
        cases_from_store(db, limit=2.0)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="^skip"):
        cases_from_store(db, skip="4bdd3c57")


# ----------------------------------------------------------------------------------------------------------------------
# Robustness tools: a wrong type is a TypeError (it was a ValueError before the project's rule reached them)
# ----------------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"eot": 2.0}, "^eot must be an integer"),
        ({"eot": True}, "^eot must be an integer"),
        ({"verify_samples": "16"}, "^verify_samples"),
        ({"seed": 0.5}, "^seed"),
        ({"margin": "1"}, "^margin"),
        ({"pixel_noise": None}, "^pixel_noise"),
    ],
)
def test_robustness_wrong_types_are_type_errors(kwargs: dict[str, Any], match: str) -> None:
    from meshadv.transfer.robust import Robustness

    with pytest.raises(TypeError, match=match):
        Robustness(**kwargs)


def test_robustness_keeps_json_able_ints_from_numpy_integers() -> None:
    import json

    import numpy as np

    from meshadv.transfer.robust import Robustness

    record = Robustness(eot=np.int64(3), verify_samples=np.int32(2), seed=np.int64(5)).to_record()
    assert (record["eot"], record["verify_samples"], record["robust_seed"]) == (3, 2, 5)
    json.dumps(record)


def test_robust_tools_wrong_types_are_type_errors() -> None:
    from meshadv.render import ViewSet
    from meshadv.transfer.robust import check_smoothing
    from meshadv.transfer.robust import NoisyVictim, Occluded, eot_views

    victim = _classifier_victim()
    views = ViewSet.orbit([10.0], elevation=5.0, distance=3.0)
    for bad in (1.5, True):
        with pytest.raises(TypeError, match="^samples"):
            eot_views(views, bad)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="^views"):
        eot_views(views.to_records(), 2)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="^std"):
        NoisyVictim(victim, True)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="^victim"):
        NoisyVictim("efficientnet_lite0", 0.1)
    with pytest.raises(TypeError, match="^background"):
        NoisyVictim(victim, 0.1, background=[[0.5] * 8] * 3)
    with pytest.raises(TypeError, match="^photo must be a tensor"):
        Occluded(victim, [[0.0]], torch.zeros(1, 1))  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="^mask must be a tensor"):
        Occluded(victim, torch.zeros(3, 4, 4), [[0.0] * 4] * 4)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="^texture_smoothing"):
        check_smoothing(2.0, "texture")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="^texture_smoothing"):
        check_smoothing(-1, "texture")


# ----------------------------------------------------------------------------------------------------------------------
# Rendering entry points, the setups and the results database
# ----------------------------------------------------------------------------------------------------------------------


def test_render_scenes_names_a_bad_argument_before_starting_mitsuba(no_render: list[Any]) -> None:
    from meshadv.transfer.mitsuba_process import render_scenes
    from meshadv.transfer.mitsuba_spec import scene_spec

    spec = scene_spec(builtin_mesh("cube"), _record(), image_size=8, spp=1)
    with pytest.raises(TypeError, match="^specs\\[1\\] must be a SceneSpec"):
        render_scenes([spec, "spec"])  # type: ignore[list-item]
    with pytest.raises(ValueError, match="^timeout"):
        render_scenes([spec], timeout=-5.0)
    with pytest.raises(TypeError, match="^timeout"):
        render_scenes([spec], timeout="60")  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="^variant"):
        render_scenes([spec], variant="")
    assert no_render == []


def test_environment_and_setups_name_a_bad_argument() -> None:
    from meshadv.transfer.mitsuba_scene import outdoor_environment
    from meshadv.transfer.setups import indoor_detector_setup, scale_on_base

    with pytest.raises(TypeError, match="^height"):
        outdoor_environment(height=16.0)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="^height"):
        outdoor_environment(height=3)
    cube = builtin_mesh("cube")
    with pytest.raises(TypeError, match="^scale"):
        scale_on_base(cube, "2")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="^scale"):
        scale_on_base(cube, -1.0)
    with pytest.raises(TypeError, match="^object_scale"):
        indoor_detector_setup(object_scale=None)  # type: ignore[arg-type]


def test_results_database_names_a_bad_kind_or_experiment(tmp_path: Any) -> None:
    from meshadv.transfer.results import load_transfer_rows, save_transfer_rows

    db = tmp_path / "results.db"
    row = {"case_id": "a", "victim": "v", "true_class": "chair", "target": "", "perturbation": "shape", "view": 0,
           "success_meshadv": True, "success_mitsuba": False}
    assert save_transfer_rows(db, [row], experiment="e") == 1
    with pytest.raises(ValueError, match="^kind must be one of 'controlled', 'blackbox', got 'blackbx'"):
        save_transfer_rows(db, [row], kind="blackbx")
    with pytest.raises(TypeError, match="experiment"):
        save_transfer_rows(db, [row], experiment=None)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="^experiment"):
        save_transfer_rows(db, [row], experiment="")
    with pytest.raises(ValueError, match="^kind"):
        load_transfer_rows(db, kind="controled")  # a misspelt kind is refused, not an empty list
    with pytest.raises(TypeError, match="^experiment"):
        load_transfer_rows(db, experiment=1)  # type: ignore[arg-type]
    assert [r["case_id"] for r in load_transfer_rows(db, experiment="e", kind="controlled")] == ["a"]


@needs_native
def test_coverage_mask_is_rendered_by_the_fallback_variant_too() -> None:
    """``scalar_rgb`` (the fallback when the fast variant fails) renders a true mask too, although its path tracer
    leaves the alpha empty at ``max_depth = 1``: the mask must match meshadv's coverage in either variant."""
    pytest.importorskip("mitsuba")
    from meshadv.transfer.mitsuba_check import mask_iou
    from meshadv.transfer.mitsuba_process import render_mask
    from meshadv.transfer.mitsuba_spec import MitsubaCamera
    from meshadv.transfer.mitsuba_process import probe_variant

    chair = builtin_mesh("chair")
    camera = Camera.spherical(3.2, 50.0, 20.0)
    with torch.no_grad():
        ours = render_silhouette(chair.vertices, chair.faces, camera, 32)[0, 0].numpy()
    for variant in ("scalar_rgb", "llvm_ad_rgb"):
        if not probe_variant(variant):
            continue
        theirs = render_mask(chair, MitsubaCamera.from_camera(camera), 32, variant=variant, fallback=False)
        assert theirs.sum() > 100, variant
        assert mask_iou(ours, theirs) > 0.95, variant
