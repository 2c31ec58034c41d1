"""meshadv.transfer: Mitsuba's renders agree with meshadv's (masks, and colours of a convex shape)."""

from __future__ import annotations

from pathlib import Path
import numpy as np
import pytest
import torch

from meshadv.mesh import Mesh
from meshadv.render import Camera, Lights, ViewSet, native_available, render_silhouette
from meshadv.transfer import MitsubaCamera, SceneSpec, render_mask, render_scene, scene_spec
from meshadv.transfer.mitsuba_check import conversion_check, mask_iou

pytest.importorskip("mitsuba", reason="mitsuba is not installed (pip install 'meshadv[transfer]')")
pytestmark = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")


def _record(distance: float, azimuth: float, elevation: float, tilt: float = 0.0) -> dict:
    camera = Camera.spherical(distance, azimuth, elevation, tilt=tilt, viewing_angle=30.0)
    lights = Lights([[0.3, 0.8, -0.5], [-0.6, 0.2, 0.4]], [[0.45, 0.4, 0.35], [0.2, 0.25, 0.3]], [0.35, 0.35, 0.4])
    return ViewSet(camera, lights).to_records()[0]


@pytest.fixture(scope="module")
def chair() -> Mesh:
    from meshadv.mesh import builtin_mesh

    return builtin_mesh("chair")


@pytest.mark.parametrize("az,el,tilt", [(30.0, 20.0, 0.0), (200.0, -15.0, 25.0), (100.0, 55.0, -10.0)])
def test_mask_iou_builtin_chair(chair: Mesh, az: float, el: float, tilt: float) -> None:
    cam = Camera.spherical(3.2, az, el, tilt=tilt, viewing_angle=30.0)
    ours = render_silhouette(chair.vertices, chair.faces, cam, 80)[0, 0].numpy()
    theirs = render_mask(chair, MitsubaCamera.from_camera(cam), 80)
    assert ours.sum() > 200  # the object is well inside the image
    assert mask_iou(ours, theirs) > 0.98
    # A mirrored or transposed Mitsuba image would not match: the check is sensitive to orientation.
    assert mask_iou(ours, theirs[:, ::-1]) < 0.95 or mask_iou(ours, theirs.T) < 0.95


def test_mask_iou_pascal3d_mesh(shared_data: Path) -> None:
    from meshadv.mesh import load_mesh, normalize_mesh

    mesh, _ = normalize_mesh(load_mesh(shared_data / "pascal3d/aeroplane/01.ply"), z_up=True)
    record = _record(2.7, 140.0, 25.0)
    views = ViewSet.from_records([record])
    ours = render_silhouette(mesh.vertices, mesh.faces, views.camera, 96)[0, 0].numpy()
    theirs = render_mask(mesh, MitsubaCamera.from_record(record), 96)
    assert mask_iou(ours, theirs) > 0.98


def test_conversion_colors_agree_on_convex_shape() -> None:
    from meshadv.mesh import builtin_mesh

    sphere = builtin_mesh("sphere")
    gen = torch.Generator().manual_seed(0)
    sphere = sphere.with_face_colors(0.3 + 0.6 * torch.rand(sphere.faces.shape[0], 3, generator=gen))
    check = conversion_check(sphere, _record(3.0, 40.0, 25.0), image_size=64, spp=256)
    assert check.mask_iou > 0.98
    assert check.interior_pixels > 500
    assert check.mean_abs_difference < 0.03
    assert check.p95_abs_difference < 0.08


def test_mismatched_lighting_is_detected() -> None:
    """The colour check is not vacuous: doubling Mitsuba's light colours gives a clear difference."""
    from meshadv.mesh import builtin_mesh

    sphere = builtin_mesh("sphere")
    record = _record(3.0, 40.0, 25.0)
    brighter = dict(record, light_colors=(np.asarray(record["light_colors"]) * 2).tolist())
    ours = conversion_check(sphere, record, image_size=48, spp=64)
    views = ViewSet.from_records([record])
    from meshadv.render import render

    with torch.no_grad():
        reference = render(sphere.vertices, sphere.faces, sphere.face_colors, views.camera, views.lights, 48)
    bright = render_scene(scene_spec(sphere, brighter, image_size=48, spp=64, max_depth=2))
    inside = (reference.alpha[0, 0].numpy() > 0.5) & (bright.alpha > 0.999)
    bright_diff = np.abs(reference.image[0].permute(1, 2, 0).numpy() - bright.image).mean(axis=-1)[inside].mean()
    assert bright_diff > 3 * ours.mean_abs_difference


def test_shadows_and_interreflection_only_in_mitsuba(chair: Mesh) -> None:
    """Deeper paths add light (interreflection) on a concave object; direct-only does not."""
    record = _record(3.2, 30.0, 20.0)
    direct = render_scene(scene_spec(chair, record, image_size=48, spp=64, max_depth=2, seed=1))
    bounce = render_scene(scene_spec(chair, record, image_size=48, spp=64, max_depth=6, seed=1))
    inside = (direct.alpha > 0.999) & (bounce.alpha > 0.999)
    assert (bounce.image - direct.image).mean(axis=-1)[inside].mean() > 0.002


def test_scene_spec_from_record_keeps_views(chair: Mesh) -> None:
    record = _record(3.0, 10.0, 5.0)
    spec = scene_spec(chair, record, image_size=32)
    assert isinstance(spec, SceneSpec)
    np.testing.assert_allclose(spec.lights.colors, np.asarray(record["light_colors"]), atol=1e-6)
    assert spec.camera.viewing_angle == pytest.approx(30.0)
