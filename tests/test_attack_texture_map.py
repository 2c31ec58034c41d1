"""The texture-image attack: texels as the perturbation, rendered through render_surface, on generated textured meshes
(no downloads) with the stand-in victims; its parameters, distances, save/load round trip and the CLI path."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest
import torch
from stand_in_victims import PooledLinearClassifier
from surface_assets import box_textured

from meshadv.attacks import TargetedMisclassification
from meshadv.attacks.families import make_attack, perturbations
from meshadv.attacks.texture_map import (TextureMapAttack, params_to_texture, texture_distances, texture_to_params,
                                         texture_tv)
from meshadv.mesh import builtin_mesh, vertex_edges
from meshadv.mesh.surface_mesh import SurfaceMesh, load_surface_mesh, save_surface_mesh
from meshadv.render import RenderSetup, ViewSet, native_available

needs_native = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")

SETUP = RenderSetup(image_size=32)


def _views(n: int = 2) -> Any:
    return ViewSet.orbit([30.0 + 40.0 * i for i in range(n)], elevation=20.0, distance=3.0)


def _textured_cube(side: int = 12) -> SurfaceMesh:
    """The built-in cube, box-projected UVs and a random 8-bit ``side x side`` texture."""
    return box_textured("cube", side)


def test_params_round_trip_the_texture() -> None:
    texture = torch.rand(5, 7, 3) * 0.98 + 0.01
    params = texture_to_params(texture)
    assert params.shape == (35, 3)
    torch.testing.assert_close(params_to_texture(params, 5, 7), texture, rtol=0, atol=1e-6)
    attack = TextureMapAttack(steps=1)
    mesh = _textured_cube()
    p = attack.initial_params(mesh, 2)
    assert p.shape == (2, 144, 3)
    # the texels are clamped into [1e-4, 1 - 1e-4] first
    torch.testing.assert_close(attack.textures(p, mesh)[1], mesh.texture, rtol=0, atol=1.5e-4)
    with pytest.raises(ValueError, match="params"):
        params_to_texture(params, 6, 7)


def test_distances_match_hand_computed_cases() -> None:
    base = torch.zeros(2, 3, 3)
    uniform = base + 0.1  # a uniform change: RMSE sqrt(3 * 0.01), no variation
    d = texture_distances(base, uniform)
    assert math.isclose(d["texel_rmse"], math.sqrt(0.03), rel_tol=1e-6)
    assert d["texture_tv"] == pytest.approx(0.0, abs=1e-7)
    one = base.clone()
    one[0, 0, 0] = 0.6  # one texel, one channel: RMSE sqrt(0.36 / 6); TV: 2 neighbours differ by 0.6, over 3*2*3
    d = texture_distances(base, one)
    assert math.isclose(d["texel_rmse"], math.sqrt(0.36 / 6), rel_tol=1e-6)
    assert math.isclose(d["texture_tv"], 2 * 0.6 / 18, rel_tol=1e-6)
    stripes = torch.zeros(1, 4, 1).expand(1, 4, 3).clone()
    stripes[0, 1::2] = 1.0  # alternating columns: 3 jumps of 1 in each channel, over 3*1*4
    assert float(texture_tv(stripes)) == pytest.approx(9 / 12)
    with pytest.raises(ValueError, match="texture_adv"):
        texture_distances(base, torch.zeros(3, 2, 3))


def test_the_family_is_registered_and_refuses_an_untextured_mesh() -> None:
    assert "texture-map" in perturbations()
    attack = make_attack("texture-map", steps=2)
    assert isinstance(attack, TextureMapAttack) and attack.config()["perturbation"] == "texture-map"
    with pytest.raises(ValueError, match="texture"):
        attack(builtin_mesh("cube"), _views(1), PooledLinearClassifier(), TargetedMisclassification(728),
               setup=SETUP)


@needs_native
@pytest.mark.parametrize("method", ["adam", "ddn"])
def test_a_short_attack_changes_the_texture_and_round_trips(tmp_path: Path, method: str) -> None:
    mesh, victim = _textured_cube(), PooledLinearClassifier()
    source = tmp_path / "cube.obj"
    save_surface_mesh(mesh, source)
    loaded = load_surface_mesh(source)
    torch.testing.assert_close(loaded.texture, mesh.texture, rtol=0, atol=1e-6)
    options = {"lr": 0.5} if method == "adam" else {}
    attack = TextureMapAttack(steps=6, method=method, **options)
    result = attack(loaded, _views(), victim, TargetedMisclassification(728), setup=SETUP)
    adversarial = result.adversarial[0]
    assert adversarial.texture.shape == loaded.texture.shape
    change = (adversarial.texture - loaded.texture).abs().max()
    assert float(change) > 1e-3
    assert float(adversarial.texture.min()) >= 0.0 and float(adversarial.texture.max()) <= 1.0
    d = result.distances[0]
    expect = texture_distances(loaded.texture, adversarial.texture)
    assert d["texel_rmse"] == pytest.approx(expect["texel_rmse"]) and d["texel_rmse"] > 0
    assert d["texture_tv"] == pytest.approx(expect["texture_tv"]) and d["texture_tv"] > 0
    assert "texel_rmse=" in result.summary() and "texture_tv=" in result.summary()
    # the renders of the result are those of the adversarial texture, not of its mean face colours
    assert not torch.allclose(result.images[0], result.original_images, atol=1e-4)
    out = tmp_path / "out"
    record = json.loads(result.save(out).read_text())
    assert record["distances"][0]["texel_rmse"] == pytest.approx(d["texel_rmse"])
    assert {"adversarial.obj", "adversarial.mtl", "adversarial_texture.png", "adversarial.glb"} <= set(record["files"])
    for name in ("adversarial.obj", "adversarial.glb"):
        again = load_surface_mesh(out / name)
        assert again.texture.shape == adversarial.texture.shape
        # the PNG is 8-bit: the loaded texture is the adversarial one to half a grey level
        torch.testing.assert_close(again.texture, adversarial.texture, rtol=0, atol=0.5 / 255 + 1e-6)


@needs_native
def test_the_ddn_budget_bounds_the_texel_rmse() -> None:
    mesh, victim = _textured_cube(), PooledLinearClassifier()
    attack = TextureMapAttack(steps=4, method="ddn", method_options={"init_budget": 0.01, "gamma": 0.01})
    result = attack(mesh, _views(1), victim, TargetedMisclassification(728), setup=SETUP)
    # the budget grows by at most (1 + gamma) per step; the PNG-free result holds the exact texels
    assert 0.0 < result.distances[0]["texel_rmse"] <= 0.01 * 1.01**4 + 1e-5


@needs_native
def test_the_cli_attacks_a_generated_textured_obj(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from typer.testing import CliRunner

    import meshadv.victims as victims
    from meshadv.cli import app

    source = tmp_path / "cube.obj"
    save_surface_mesh(_textured_cube(16), source)
    monkeypatch.setattr(victims, "load_victim", lambda *args, **kwargs: PooledLinearClassifier())
    out = tmp_path / "out"
    run = CliRunner().invoke(app, ["attack", str(source), "--perturbation", "texture-map", "--target", "728",
                                   "--steps", "3", "--views", "1", "--image-size", "32", "--quiet", "--method",
                                   "adam", "--lr", "0.5", "-o", str(out)])
    assert run.exit_code == 0, run.output
    assert "attacked as loaded" in run.output and "resampled uniformly" not in run.output
    assert "texel_rmse=" in run.output
    record = json.loads((out / "result.json").read_text())
    assert record["perturbation"] == "texture-map" and record["distances"][0]["texel_rmse"] > 0
    png = load_surface_mesh(out / "adversarial.obj").texture
    assert png.shape == (16, 16, 3)
    assert (out / "adversarial_texture.png").is_file()


@needs_native
def test_a_shape_attack_on_a_textured_mesh_keeps_and_renders_its_texture(tmp_path: Path) -> None:
    from meshadv.attacks import ShapeAttack

    mesh, victim = _textured_cube(), PooledLinearClassifier()
    result = ShapeAttack(steps=3, lr=0.02)(mesh, _views(1), victim, TargetedMisclassification(728), setup=SETUP)
    adversarial = result.adversarial[0]
    torch.testing.assert_close(adversarial.texture, mesh.texture, rtol=0, atol=0)
    flow = 0.05 * torch.randn(1, *mesh.vertices.shape, generator=torch.Generator().manual_seed(0))
    moved = ShapeAttack(steps=1).result_meshes(flow, mesh, vertex_edges(mesh.faces))[0]
    torch.testing.assert_close(moved.vertices, mesh.vertices + flow[0])
    torch.testing.assert_close(moved.texture, mesh.texture, rtol=0, atol=0)
    # the renders are the texture's: the same mesh drawn with its per-face mean colours looks different
    flat, _ = SETUP.render(mesh.vertices[None], mesh.faces, mesh.face_colors, _views(1))
    assert not torch.allclose(result.original_images[0], flat[0], atol=1e-3)
    record = json.loads(result.save(tmp_path).read_text())
    assert "adversarial_texture.png" in record["files"]
    torch.testing.assert_close(load_surface_mesh(tmp_path / "adversarial.obj").texture, mesh.texture, rtol=0,
                               atol=1e-6)
