"""glTF files with a base-colour texture and ``COLOR_0`` vertex colours (written here byte by byte): both load, render
multiplied (a pixel checked by hand), save and reload, draw multiplied in Mitsuba; bad ``COLOR_0`` accessors are
errors naming the file and field."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch
from gltf_assets import write_glb

from meshadv.mesh import MeshLoadError
from meshadv.mesh.surface_mesh import SurfaceMesh, load_surface_mesh, save_surface_mesh
from meshadv.render import Camera, Lights, native_available, render_surface

#: A unit quad in the z = 0 plane: two triangles, UVs over the whole image.
QUAD = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=np.float64)
QUAD_FACES = np.array([[0, 1, 2], [0, 2, 3]])
QUAD_UVS = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64)
#: Its vertex colours, one per corner, all different.
COLORS = np.array([[1.0, 0.2, 0.6], [0.4, 1.0, 0.8], [0.6, 0.4, 1.0], [0.8, 0.6, 0.2]])


def _block_texture() -> np.ndarray:
    """8 x 8 texels in four 4 x 4 blocks of different colours (uint8)."""
    tex = np.zeros((8, 8, 3), np.uint8)
    tex[:4, :4], tex[:4, 4:], tex[4:, :4], tex[4:, 4:] = (200, 40, 120), (20, 220, 60), (90, 30, 250), (250, 250, 10)
    return tex


def _painted_quad(tmp_path: Path, colors: np.ndarray) -> Path:
    return write_glb(tmp_path / "quad.glb", QUAD, QUAD_FACES, uvs=QUAD_UVS, texture=_block_texture(), colors=colors)


@pytest.mark.parametrize("dtype", ["uint8", "uint16", "float32"])
def test_a_texture_and_color_0_both_load_per_welded_vertex(tmp_path: Path, dtype: str) -> None:
    scale = {"uint8": 255, "uint16": 65535, "float32": 1}[dtype]
    stored = np.concatenate([COLORS, np.ones((4, 1))], 1) * scale
    stored = (stored.round() if scale > 1 else stored).astype(dtype)
    surface = load_surface_mesh(_painted_quad(tmp_path, stored))
    assert surface.texture is not None and surface.vertex_colors is not None
    np.testing.assert_allclose(surface.texture.numpy(), _block_texture() / 255.0, atol=1e-6)
    by_position = {tuple(p): c for p, c in zip(surface.vertices.numpy().round(6), surface.vertex_colors.numpy())}
    for position, color in zip(QUAD, COLORS):
        np.testing.assert_allclose(by_position[tuple(position)], color, atol=0.5 / scale + 1e-7)
    # the per-face colours (the flat path's) are the texel at the UV centroid times the mean corner colour
    centroid = QUAD_UVS[QUAD_FACES[0]].mean(0)  # (2/3, 1/3): texel row 5, column 5, the bottom-right block
    expected = _block_texture()[5, 5] / 255.0 * COLORS[QUAD_FACES[0]].mean(0)
    assert np.floor(centroid * 8).tolist() == [5.0, 2.0]
    np.testing.assert_allclose(surface.face_colors[0].numpy(), expected, atol=1e-3)


def test_texture_and_colours_survive_load_save_load_as_glb_and_obj(tmp_path: Path) -> None:
    stored = (np.concatenate([COLORS, np.ones((4, 1))], 1) * 255).round().astype(np.uint8)
    first = load_surface_mesh(_painted_quad(tmp_path, stored))
    for name in ("again.glb", "again.obj"):
        save_surface_mesh(first, tmp_path / name)
        back = load_surface_mesh(tmp_path / name)
        assert back.texture is not None and back.vertex_colors is not None, name
        torch.testing.assert_close(back.texture, first.texture, atol=0.6 / 255, rtol=0)
        # welded vertices come back in the same order: compare the colours row by row
        torch.testing.assert_close(back.vertices, first.vertices, atol=1e-6, rtol=0)
        torch.testing.assert_close(back.vertex_colors, first.vertex_colors, atol=0.6 / 255, rtol=0)
        torch.testing.assert_close(back.uvs[back.uv_faces], first.uvs[first.uv_faces], atol=1e-6, rtol=0)
        torch.testing.assert_close(back.face_colors, first.face_colors, atol=1e-5, rtol=0)


def test_the_base_color_factor_multiplies_the_texture_else_the_colours(tmp_path: Path) -> None:
    factor = [0.5, 1.0, 0.25, 1.0]
    colors = COLORS.astype(np.float32)
    textured = load_surface_mesh(write_glb(tmp_path / "t.glb", QUAD, QUAD_FACES, uvs=QUAD_UVS,
                                           texture=_block_texture(), colors=colors, factor=factor))
    np.testing.assert_allclose(textured.texture.numpy(), _block_texture() / 255.0 * factor[:3], atol=1e-6)
    by_position = {tuple(p): c for p, c in zip(textured.vertices.numpy().round(6), textured.vertex_colors.numpy())}
    np.testing.assert_allclose(by_position[tuple(QUAD[1])], COLORS[1], atol=1e-6)
    painted = load_surface_mesh(write_glb(tmp_path / "c.glb", QUAD, QUAD_FACES, colors=colors, factor=factor))
    assert painted.texture is None
    by_position = {tuple(p): c for p, c in zip(painted.vertices.numpy().round(6), painted.vertex_colors.numpy())}
    for position, color in zip(QUAD, COLORS):
        np.testing.assert_allclose(by_position[tuple(position)], color * factor[:3], atol=1e-6)
    # saved with the factor folded in, the file reloads the same
    save_surface_mesh(textured, tmp_path / "again.glb")
    torch.testing.assert_close(load_surface_mesh(tmp_path / "again.glb").texture, textured.texture, atol=0.6 / 255,
                               rtol=0)
    bad = write_glb(tmp_path / "bad.glb", QUAD, QUAD_FACES, colors=colors, factor=[2.0, 1.0, 1.0, 1.0])
    with pytest.raises(MeshLoadError, match=r"bad\.glb: baseColorFactor: needs 3 or 4 numbers in \[0, 1\]"):
        load_surface_mesh(bad)


@pytest.mark.skipif(not native_available(), reason="the native module meshadv._raster is not built")
def test_a_pixel_is_the_texel_times_the_interpolated_colour_times_the_shading(tmp_path: Path) -> None:
    stored = COLORS.astype(np.float32)
    surface = load_surface_mesh(_painted_quad(tmp_path, stored))
    # A camera on the -Z axis at distance 3, 30 degrees field of view: +X right, +Y up, the quad fills the image.
    size, half = 32, 3.0 * math.tan(math.radians(15.0))
    camera = Camera.spherical(3.0, azimuth=0.0, elevation=0.0)
    light = np.array([0.0, 0.6, -0.8])  # toward the light; the quad's normal turned to the camera is -Z
    lights = Lights.single(direction=tuple(light), color=(0.5, 0.5, 0.5), ambient=(0.3, 0.3, 0.3))
    image = render_surface(surface.vertices, surface.faces, camera, lights, size, texture=surface.texture,
                           uvs=surface.uvs, uv_faces=surface.uv_faces, vertex_colors=surface.vertex_colors,
                           shading="flat").image[0]
    shading = 0.3 + 0.5 * float(light @ np.array([0.0, 0.0, -1.0]))  # 0.7
    for row, col in ((8, 9), (9, 23), (22, 7), (24, 24)):
        x, y = (2 * col + 1 - size) / size * half, (size - 1 - 2 * row) / size * half
        # the pixel's point on the quad: its UV is ((x + 1) / 2, (y + 1) / 2), a texel position well inside a block
        u, v = (x + 1) / 2, (y + 1) / 2
        texel = _block_texture()[int((1 - v) * 8), int(u * 8)] / 255.0
        tri = QUAD_FACES[0] if x > y else QUAD_FACES[1]
        a, b, c = QUAD[tri, :2]
        weights = np.linalg.solve(np.array([[a[0], b[0], c[0]], [a[1], b[1], c[1]], [1, 1, 1]]), [x, y, 1.0])
        expected = np.clip(texel * (weights @ COLORS[tri]) * shading, 0, 1)
        np.testing.assert_allclose(image[:, row, col].numpy(), expected, atol=2e-5, err_msg=f"pixel {(row, col)}")


@pytest.mark.parametrize(("field", "colors", "kind", "message"), [
    ("count", np.ones((3, 3), np.float32), None, r"COLOR_0: 3 colours for 4 vertices \(POSITION\)"),
    ("type", np.ones((4, 2), np.float32), "VEC2", "COLOR_0: type must be VEC3 or VEC4"),
    ("range", np.full((4, 3), 1.5, np.float32), None, r"COLOR_0: colours must lie in \[0, 1\]"),
    ("nan", np.full((4, 3), np.nan, np.float32), None, "COLOR_0: NaN or infinite"),
])
def test_bad_color_0_is_an_error_naming_the_file_and_field(tmp_path: Path, field: str, colors: np.ndarray,
                                                           kind: str, message: str) -> None:
    path = write_glb(tmp_path / f"{field}.glb", QUAD, QUAD_FACES, uvs=QUAD_UVS, texture=_block_texture(),
                     colors=colors, color_type=kind)
    with pytest.raises(MeshLoadError, match=rf"{field}\.glb: .*{message}"):
        load_surface_mesh(path)


def test_a_gltf_json_file_loads_and_checks_its_color_0_as_a_glb(tmp_path: Path) -> None:
    colors = COLORS.astype(np.float32)
    path = write_glb(tmp_path / "quad.gltf", QUAD, QUAD_FACES, uvs=QUAD_UVS, texture=_block_texture(), colors=colors)
    surface = load_surface_mesh(path)
    assert surface.texture is not None and surface.vertex_colors is not None
    np.testing.assert_allclose(np.sort(surface.vertex_colors.numpy(), axis=0), np.sort(COLORS, axis=0), atol=1e-6)
    short = write_glb(tmp_path / "short.gltf", QUAD, QUAD_FACES, uvs=QUAD_UVS, texture=_block_texture(),
                      colors=colors[:2])
    with pytest.raises(MeshLoadError, match=r"short\.gltf: mesh 0 primitive 0: COLOR_0: 2 colours for 4 vertices"):
        load_surface_mesh(short)


def test_a_color_0_of_an_integer_type_glTF_does_not_allow_is_an_error(tmp_path: Path) -> None:
    path = write_glb(tmp_path / "int.glb", QUAD, QUAD_FACES, uvs=QUAD_UVS, texture=_block_texture(),
                     colors=np.ones((4, 3), np.float32))
    data = path.read_bytes().replace(b'"componentType": 5126, "count": 4, "type": "VEC3"',
                                     b'"componentType": 5125, "count": 4, "type": "VEC3"')
    path.write_bytes(data)
    with pytest.raises(MeshLoadError, match=r"int\.glb: mesh 0 primitive 0: COLOR_0: componentType must be"):
        load_surface_mesh(path)


@pytest.mark.skipif(not native_available(), reason="the native module meshadv._raster is not built")
@pytest.mark.parametrize("shading", ["flat", "smooth"])
def test_mitsuba_draws_the_texture_times_the_vertex_colours(shading: str) -> None:
    pytest.importorskip("mitsuba", reason="mitsuba is not installed (pip install 'meshadv[transfer]')")
    from test_transfer_surface import _checker_sphere

    from meshadv.transfer.mitsuba_check import conversion_check, head_light_record

    textured = _checker_sphere()
    v = textured.vertices
    both = SurfaceMesh(textured.mesh, textured.uvs, textured.uv_faces, textured.texture,
                       0.5 + 0.45 * v / v.abs().max()).with_texture(textured.texture)
    light = head_light_record(3.5, 30.0, 20.0, 0.5, 0.5)
    check = conversion_check(both, light, image_size=64, spp=64, shading=shading)
    assert check.mask_iou > 0.98 and check.interior_pixels > 1500
    assert check.mean_abs_difference < 0.02 and check.p95_abs_difference < 0.06
    # Mitsuba's image is the product, not the texture alone: the texture-only mesh draws another image
    alone = conversion_check(textured, light, image_size=64, spp=64, shading=shading)
    assert np.abs(alone.mitsuba_image - check.mitsuba_image).mean() > 0.05


@pytest.mark.skipif(not native_available(), reason="the native module meshadv._raster is not built")
def test_meshadv_attack_and_transfer_keep_a_glbs_texture_and_colours(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("mitsuba", reason="mitsuba is not installed (pip install 'meshadv[transfer]')")
    from PIL import Image
    from stand_in_victims import PooledLinearClassifier
    from surface_assets import box_textured, vertex_coloured
    from typer.testing import CliRunner

    import meshadv.victims as victims
    from meshadv.cli import app
    from meshadv.transfer.controlled import case_from_attack_folder, transfer_attack_folder

    monkeypatch.setattr(victims, "load_victim", lambda *args, **kwargs: PooledLinearClassifier())
    textured = box_textured()
    both = SurfaceMesh(textured.mesh, textured.uvs, textured.uv_faces, textured.texture,
                       vertex_coloured().vertex_colors).with_texture(textured.texture)
    save_surface_mesh(both, tmp_path / "ball.glb")
    out = tmp_path / "out"
    run = CliRunner().invoke(app, [str(a) for a in (
        "attack", tmp_path / "ball.glb", "--perturbation", "shape", "--target", "728", "--steps", "2", "--views", "1",
        "--azimuths", "30:30", "--image-size", 48, "--quiet", "--method", "adam", "--lr", "0.01", "--cap", "none",
        "--benign-wrong-ok", "--resample", "0", "-o", out)])
    assert run.exit_code == 0, run.output
    for name in ("adversarial.obj", "adversarial.glb"):
        saved = load_surface_mesh(out / name)
        assert saved.texture is not None and saved.vertex_colors is not None, name
    case = case_from_attack_folder(out)
    assert case.mesh.texture is not None and case.mesh.vertex_colors is not None
    rows = transfer_attack_folder(out, spp=32, max_depth=2, victim_loader=lambda name: PooledLinearClassifier())
    ours, theirs = (np.asarray(Image.open(out / f).convert("RGB"), dtype=np.float64) / 255.0
                    for f in ("after_v0.png", "mitsuba_v0.png"))
    inside = (ours < 0.99).any(-1) & (theirs < 0.99).any(-1)
    assert np.median(np.abs(ours - theirs).mean(-1)[inside]) < 0.05
    assert rows[0].mean_abs_image_difference < 0.06
