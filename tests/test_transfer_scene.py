"""meshadv.transfer: scene conversion, variant choice and crash isolation (no native rasterizer needed)."""

from __future__ import annotations

from pathlib import Path
import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import torch

from meshadv.render import Camera
from meshadv.transfer import (
    MeshObject,
    MitsubaCamera,
    MitsubaLights,
    MitsubaRenderError,
    SceneSpec,
    best_variant,
    outdoor_environment,
    probe_variant,
    render_mask,
    render_scene,
    render_scenes,
)
from meshadv.transfer import mitsuba_process as render_module
from meshadv.transfer.mitsuba_scene import _base_scene_xml

mitsuba = pytest.importorskip("mitsuba", reason="mitsuba is not installed (pip install 'meshadv[transfer]')")


def _quad(z: float = 0.0) -> MeshObject:
    """A 2x2 quad in the plane z, lower-right triangle red, upper-left green (as seen from -Z)."""
    v = np.array([[-1, -1, z], [1, -1, z], [1, 1, z], [-1, 1, z]], np.float32)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    c = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], np.float32)
    return MeshObject(v, f, c)


@pytest.mark.parametrize("az,el,tilt", [(0.0, 0.0, 0.0), (37.0, 21.0, 0.0), (200.0, -30.0, 15.0), (95.0, 60.0, -40.0)])
def test_camera_projection_matches_meshadv(az: float, el: float, tilt: float) -> None:
    pts = torch.randn(20, 3, generator=torch.Generator().manual_seed(0)) * 0.5
    cam = Camera.spherical(3.0, az, el, tilt=tilt, viewing_angle=40.0)
    ndc = cam.project(pts)[0, :, :2].numpy()
    expected = np.stack([(ndc[:, 0] + 1) * 64 / 2, (1 - ndc[:, 1]) * 48 / 2], axis=-1)
    ours = MitsubaCamera.spherical(3.0, az, el, tilt, 40.0).project(pts.numpy(), (48, 64))
    np.testing.assert_allclose(ours, expected, atol=1e-4)
    from_cam = MitsubaCamera.from_camera(cam).project(pts.numpy(), (48, 64))
    np.testing.assert_allclose(from_cam, expected, atol=1e-4)


def test_camera_from_look_at_record() -> None:
    cam = Camera.look_at([1.0, 2.0, 3.0], [0.1, 0.2, -0.3], [0.0, 1.0, 0.0], viewing_angle=35.0, tilt=10.0)
    record = {"eye": [1.0, 2.0, 3.0], "at": [0.1, 0.2, -0.3], "up": [0.0, 1.0, 0.0], "tilt": 10.0,
              "viewing_angle": 35.0}
    pts = np.random.default_rng(1).normal(size=(10, 3)) * 0.3
    ndc = cam.project(torch.as_tensor(pts, dtype=torch.float32))[0, :, :2].numpy()
    expected = np.stack([(ndc[:, 0] + 1) * 32 / 2, (1 - ndc[:, 1]) * 32 / 2], axis=-1)
    np.testing.assert_allclose(MitsubaCamera.from_record(record).project(pts, (32, 32)), expected, atol=1e-4)


def test_bad_inputs_raise_value_error() -> None:
    with pytest.raises(ValueError, match="distance"):
        MitsubaCamera.spherical(0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="viewing_angle"):
        MitsubaCamera((0.0, 0.0, -3.0), viewing_angle=200.0)
    with pytest.raises(ValueError, match="faces"):
        MeshObject(np.zeros((3, 3)), np.array([[0, 1, 5]]), np.ones((1, 3)))
    with pytest.raises(ValueError, match="face_colors"):
        MeshObject(np.zeros((3, 3)), np.array([[0, 1, 2]]), np.ones((2, 3)))
    with pytest.raises(ValueError, match="directions"):
        MitsubaLights(np.ones((2, 3)), np.ones((1, 3)), np.ones(3))
    with pytest.raises(ValueError, match="spp"):
        SceneSpec((_quad(),), MitsubaCamera((0.0, 0.0, -3.0)), spp=0)
    with pytest.raises(FileNotFoundError, match="base_scene"):
        SceneSpec((_quad(),), MitsubaCamera((0.0, 0.0, -3.0)), base_scene="/nonexistent/scene.xml")
    with pytest.raises(TypeError, match="specs"):
        render_scenes(["not a spec"])  # type: ignore[list-item]


def test_best_variant_is_a_working_cpu_variant() -> None:
    variant = best_variant()
    assert variant in ("llvm_ad_rgb", "scalar_rgb")
    assert probe_variant(variant)
    assert not probe_variant("no_such_variant")


def test_orientation_and_face_colors() -> None:
    """Camera at azimuth 0 looks down +Z: world +X is image right (NMR), row 0 is the top; per-face colours."""
    cam = MitsubaCamera.spherical(5.0, 0.0, 0.0, viewing_angle=30.0)
    lights = MitsubaLights(np.zeros((0, 3)), np.zeros((0, 3)), np.ones(3))
    spec = SceneSpec((_quad(),), cam, lights, image_size=40, spp=16, max_depth=2)
    img = render_scene(spec)
    assert img.image.shape == (40, 40, 3)
    # Lower-right: red (face 0); upper-left: green (face 1); corners outside the quad: white background.
    lower_right, upper_left = img.image[26, 28], img.image[13, 11]
    assert lower_right[0] > 0.5 and lower_right[1] < 0.2
    assert upper_left[1] > 0.5 and upper_left[0] < 0.2
    np.testing.assert_allclose(img.image[0, 0], [1.0, 1.0, 1.0], atol=1e-6)
    # Quad half-width 1 at distance 5, tan(15 deg) * 5 = 1.34 visible: |x_ndc| <= 0.746.
    mask = render_mask(_quad(), cam, 40)
    cols = np.where(mask[20] > 0.5)[0]
    rows = np.where(mask[:, 20] > 0.5)[0]
    half = 1.0 / (5 * math.tan(math.radians(15)))
    first = math.ceil((1 - half) * 40 / 2 - 0.5)
    assert cols.min() == first and cols.max() == 39 - first
    assert rows.min() == first and rows.max() == 39 - first
    assert set(np.unique(mask)) <= {0.0, 1.0}
    with pytest.raises(ValueError, match="^image_size must be positive and square"):
        SceneSpec((_quad(),), cam, lights, image_size=(32, 40))


def test_lambert_and_ambient_match_meshadv_units() -> None:
    """A white quad facing the camera lit head-on: radiance = ambient + colour (meshadv's shading)."""
    cam = MitsubaCamera.spherical(5.0, 0.0, 0.0)
    white = MeshObject(_quad().vertices, _quad().faces, np.full((2, 3), 0.8, np.float32))
    lights = MitsubaLights(np.array([[0.0, 0.0, -1.0]]), np.array([[0.5, 0.4, 0.3]]), np.array([0.2, 0.2, 0.2]))
    img = render_scene(SceneSpec((white,), cam, lights, image_size=16, spp=256, max_depth=2))
    centre = img.image[6:10, 6:10].reshape(-1, 3).mean(axis=0)
    np.testing.assert_allclose(centre, 0.8 * np.array([0.7, 0.6, 0.5]), atol=0.02)


def test_base_scene_xml_drops_sensor_and_excluded_shapes(shared_data: Path) -> None:
    xml = _base_scene_xml(shared_data / "scenes/indoor/scene.xml", ("bunny",), keep_emitters=True)
    root = ET.fromstring(xml)
    assert root.find("sensor") is None and root.find("integrator") is None
    names = [s.get("value") for s in root.iter("string") if s.get("name") == "filename"]
    assert names and all(n.startswith("/") for n in names)
    assert not any("bunny" in n for n in names) and any("desk" in n for n in names)


def test_object_inside_indoor_scene_renders(shared_data: Path) -> None:
    cam = MitsubaCamera.spherical(3.4, 145.0, 24.0, viewing_angle=45.0)
    cube = MeshObject(np.array([[-0.1, 0.75, -0.1], [0.1, 0.75, -0.1], [0.0, 0.95, 0.0]], np.float32),
                      np.array([[0, 1, 2]]), np.array([[1.0, 0.0, 0.0]], np.float32))
    spec = SceneSpec((cube,), cam, None, image_size=24, spp=4, background=None,
                     base_scene=str(shared_data / "scenes/indoor/scene.xml"), base_exclude=("bunny",))
    img = render_scene(spec)
    assert img.image.shape == (24, 24, 3)
    assert img.alpha.mean() > 0.9  # walls and floor fill the view
    assert 0.02 < img.image.mean() < 0.98


def test_environment_map_lights_the_object() -> None:
    env = outdoor_environment(height=16, sun_strength=0.0)
    assert env.shape == (16, 32, 3) and env.min() >= 0
    cam = MitsubaCamera.spherical(5.0, 0.0, 0.0)
    spec = SceneSpec((_quad(),), cam, None, image_size=16, spp=16, environment=env, background=None)
    img = render_scene(spec)
    assert img.image[8, 8].sum() > 0.05  # lit by the sky
    assert img.image[0, 0].sum() > 0.05  # the sky is visible behind


def test_crash_in_child_becomes_python_exception(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "abort_worker.py").write_text("import os\nos.abort()\n")
    monkeypatch.setenv("PYTHONPATH", str(tmp_path))
    monkeypatch.setattr(render_module, "_WORKER_MODULE", "abort_worker")
    spec = SceneSpec((_quad(),), MitsubaCamera.spherical(5.0, 0.0, 0.0), image_size=8, spp=1)
    with pytest.raises(MitsubaRenderError, match="signal"):
        render_scenes([spec], variant="llvm_ad_rgb")  # fails, falls back to scalar_rgb, which fails too


def test_bad_variant_and_timeout_raise() -> None:
    spec = SceneSpec((_quad(),), MitsubaCamera.spherical(5.0, 0.0, 0.0), image_size=8, spp=1)
    with pytest.raises(MitsubaRenderError, match="exited"):
        render_scenes([spec], variant="no_such_variant", fallback=False)
    with pytest.raises(MitsubaRenderError, match="timed out"):
        render_scenes([spec], variant="scalar_rgb", timeout=0.01)
    # The fallback rescues a broken preferred variant.
    assert render_scenes([spec], variant="no_such_variant")[0].variant == "scalar_rgb"
