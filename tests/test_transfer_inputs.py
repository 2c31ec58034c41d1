"""meshadv.transfer: bad input fails early with a Python exception naming the argument (TypeError for a wrong type,
ValueError for a bad value), before any Mitsuba render or optimisation; edge cases that used to crash.

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
    from meshadv.transfer import render as render_module

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
    from meshadv.transfer.camera_estimate import estimate_camera

    chair, _, mask, _ = _chair_case()
    with pytest.raises(error, match=f"^{name}"):
        estimate_camera(mask, chair.vertices, chair.faces, **kwargs)


@needs_native
def test_estimate_camera_and_lights_check_the_mesh_shape() -> None:
    from meshadv.transfer.camera_estimate import estimate_camera
    from meshadv.transfer.light_estimate import estimate_lights

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
    from meshadv.transfer.light_estimate import estimate_lights

    chair, camera, mask, image = _chair_case()
    with pytest.raises(error, match=f"^{name}"):
        estimate_lights(image, mask, chair.vertices, chair.faces, chair.face_colors, camera, **kwargs)
    with pytest.raises(TypeError, match="^camera must be a meshadv.render.Camera"):
        estimate_lights(image, mask, chair.vertices, chair.faces, chair.face_colors, {"distance": 3.0})


@needs_native
def test_estimate_lights_with_no_directional_light_fits_the_ambient_only() -> None:
    """``num_lights = 0`` is documented as allowed; it used to crash (an IndexError building zero directions)."""
    from meshadv.transfer.light_estimate import estimate_lights

    chair, camera, mask, image = _chair_case()
    est = estimate_lights(image, mask, chair.vertices, chair.faces, chair.face_colors, camera, num_lights=0, steps=5)
    assert tuple(est.lights.directions.shape) == (1, 0, 3) and tuple(est.lights.colors.shape) == (1, 0, 3)
    assert float(est.lights.ambient.min()) > 0.0 and math.isfinite(est.loss)
    one = estimate_lights(image, mask, chair.vertices, chair.faces, chair.face_colors, camera, num_lights=1, steps=5)
    assert tuple(one.lights.directions.shape) == (1, 1, 3)
