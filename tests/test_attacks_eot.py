"""Expectation over transformations in the attack engine: seeded draws, the transformations, fresh-view success.

Stand-in victims and built-in meshes only (no weights, no data).
"""

from __future__ import annotations

from typing import Any

import pytest
import torch
from stand_in_victims import PooledLinearClassifier

from meshadv.attacks import ShapeAttack, TargetedMisclassification, TextureAttack, evaluate
from meshadv.attacks.eot import (
    EOTSampler,
    Transformations,
    ViewRange,
    _shifted,
    as_transformations,
    transform_images,
)
from meshadv.attacks.flow import smooth_flow
from meshadv.attacks.lowpass import lowpass_gradient
from meshadv.mesh import builtin_mesh
from meshadv.mesh.adjacency import face_adjacency
from meshadv.render import RenderSetup, ViewSet, native_available

needs_native = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")

SETUP = RenderSetup(image_size=32)


def _views() -> ViewSet:
    return ViewSet.orbit([40.0, 70.0], elevation=20.0, distance=2.6)


def _records(draw: Any) -> Any:
    return (draw.views.to_records(), draw.setup.config(), draw.blur.tolist(), draw.noise.tolist(), draw.noise_seed)


# ------------------------------------------------------------------ the transformations and their draws
@pytest.mark.parametrize("kwargs, error, match", [
    ({"samples": 0}, ValueError, "samples"),
    ({"samples": 2.0}, TypeError, "samples"),
    ({"antialias": ()}, ValueError, "antialias"),
    ({"antialias": (0,)}, ValueError, r"antialias\[0\]"),
    ({"image_scale": (0.0, 1.0)}, ValueError, "image_scale"),
    ({"elevation": (-95.0, 10.0)}, ValueError, "elevation"),
    ({"azimuth": (10.0, 0.0)}, ValueError, "azimuth"),
    ({"azimuth": "0:10"}, TypeError, "azimuth"),
    ({"distance": (0.0, 2.0)}, ValueError, "distance"),
    ({"noise": -0.1}, ValueError, "noise"),
    ({"light_intensity": 1.0}, ValueError, "light_intensity"),
])
def test_bad_transformations_are_refused_naming_the_field(kwargs: dict, error: type, match: str) -> None:
    with pytest.raises(error, match=match):
        Transformations(**kwargs)


def test_as_transformations_reads_counts_dicts_and_configs() -> None:
    assert as_transformations(None) is None
    assert as_transformations(6).samples == 6
    custom = Transformations(samples=2, azimuth=(0.0, 30.0), antialias=(1, 3))
    assert as_transformations(custom.config()) == custom
    with pytest.raises(ValueError, match="zoom"):
        as_transformations({"zoom": 2})
    with pytest.raises(TypeError, match="eot"):
        as_transformations(True)


def test_the_range_is_the_views_widened_or_given() -> None:
    views = ViewSet.orbit([150.0, 180.0, 210.0], elevation=10.0, distance=2.0)
    r = ViewRange.of(views, Transformations())
    assert r.azimuth == (140.0, 220.0) and r.elevation == pytest.approx((5.0, 15.0))
    assert r.distance == pytest.approx((1.8, 2.2)) and r.viewing_angle == pytest.approx(30.0)
    given = ViewRange.of(views, Transformations(azimuth=(0.0, 360.0), distance=(2.5, 3.0)))
    assert given.azimuth == (0.0, 360.0) and given.distance == (2.5, 3.0)
    with pytest.raises(ValueError, match="spherical"):
        ViewRange.of(_shifted(views, torch.zeros(3, 2), 32), Transformations())


def test_draws_are_seeded_reproducible_fresh_and_inside_the_range() -> None:
    eot = Transformations(samples=5, antialias=(1, 2, 3), noise=0.05, blur=1.0)
    sampler = EOTSampler(eot, _views(), RenderSetup(image_size=64))
    gen_a, gen_b = torch.Generator().manual_seed(3), torch.Generator().manual_seed(3)
    first_a, first_b = sampler.draw_step(gen_a), sampler.draw_step(gen_b)
    assert _records(first_a) == _records(first_b)
    second = sampler.draw_step(gen_a)
    assert _records(second) != _records(first_a)  # a new draw every step
    other = sampler.draw_step(torch.Generator().manual_seed(4))
    assert _records(other) != _records(first_a)
    assert len(first_a.views) == 5 and first_a.setup.antialias in (1, 2, 3)
    h, _ = first_a.setup.image_size
    assert round(64 * 0.875) <= h <= round(64 * 1.125)
    plain = sampler.plain_views(torch.Generator().manual_seed(0), 200).to_records()
    az = [rec["azimuth"] for rec in plain]
    el = [rec["elevation"] for rec in plain]
    assert 30.0 <= min(az) < 33.0 and 77.0 < max(az) <= 80.0  # the views' 40..70 widened by 10 on both sides
    assert 15.0 <= min(el) and max(el) <= 25.0
    assert all(0.0 <= b <= 1.0 for b in first_a.blur.tolist()) and all(0 <= n <= 0.05 for n in first_a.noise.tolist())


def test_a_photo_background_keeps_the_image_size() -> None:
    photo = torch.rand(3, 32, 32)
    sampler = EOTSampler(Transformations(image_scale=(0.5, 0.6)), _views(), RenderSetup(image_size=32,
                                                                                          background=photo))
    assert sampler.draw_step(torch.Generator().manual_seed(0)).setup.image_size == (32, 32)


@needs_native
def test_a_camera_shift_of_whole_pixels_translates_the_render() -> None:
    mesh = builtin_mesh("chair")
    views = ViewSet.orbit([30.0], elevation=15.0, distance=3.0)
    setup = RenderSetup(image_size=48)
    base, _ = setup.render(mesh.vertices[None], mesh.faces, mesh.face_colors, views)
    moved, _ = setup.render(mesh.vertices[None], mesh.faces, mesh.face_colors,
                            _shifted(views, torch.tensor([[2.0, 0.0]]), 48))
    inner = (slice(None), slice(None), slice(4, -4), slice(4, -4))
    errors = {dx: float((torch.roll(base, dx, dims=3)[inner] - moved[inner]).abs().mean()) for dx in (-2, 0, 2)}
    best = min(errors, key=errors.get)
    assert best != 0 and errors[best] < 0.25 * errors[0], errors


def test_transform_images_blur_noise_and_gradients() -> None:
    gen = torch.Generator().manual_seed(0)
    images = torch.rand(2, 3, 9, 9, dtype=torch.float64) * 0.6 + 0.2
    zero = torch.zeros(2, dtype=torch.float64)
    assert torch.equal(transform_images(images, zero, zero, gen), images)
    flat = torch.full((1, 3, 9, 9), 0.4, dtype=torch.float64)
    blurred = transform_images(flat, torch.tensor([1.5], dtype=torch.float64), torch.zeros(1, dtype=torch.float64),
                               gen)
    torch.testing.assert_close(blurred, flat)  # a blur keeps a constant image
    spike = torch.zeros(1, 1, 9, 9, dtype=torch.float64)
    spike[0, 0, 4, 4] = 1.0
    spread = transform_images(spike, torch.tensor([1.0], dtype=torch.float64), torch.zeros(1, dtype=torch.float64),
                              gen)
    assert float(spread.sum()) == pytest.approx(1.0) and float(spread[0, 0, 4, 4]) < 0.2
    noisy_a = transform_images(images, zero, zero + 0.05, torch.Generator().manual_seed(1))
    noisy_b = transform_images(images, zero, zero + 0.05, torch.Generator().manual_seed(1))
    assert torch.equal(noisy_a, noisy_b) and float((noisy_a - images).std()) == pytest.approx(0.05, rel=0.2)
    x = images[:, :1, :5, :5].clone().requires_grad_(True)
    sigma = torch.tensor([0.6, 1.2], dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda t: transform_images(t, sigma, zero, gen), (x,))


def test_lowpass_gradient_is_the_identity_forward_and_smooths_backward() -> None:
    faces = builtin_mesh("chair").faces
    edges = face_adjacency(faces)
    x = torch.rand(2, faces.shape[0], 3, requires_grad=True)
    weight = torch.randn(2, faces.shape[0], 3)
    y = lowpass_gradient(x, edges, 3)
    assert torch.equal(y, x)
    (y * weight).sum().backward()
    torch.testing.assert_close(x.grad, smooth_flow(weight, edges, 3))
    assert lowpass_gradient(x, edges, 0) is x
    with pytest.raises(ValueError, match="rounds"):
        lowpass_gradient(x, edges, -1)


# ------------------------------------------------------------------ the attack
@needs_native
@pytest.mark.parametrize("family, kwargs", [
    (ShapeAttack, {"lr": 0.02}),
    (ShapeAttack, {"method": "ddn"}),
    (TextureAttack, {"gradient_smoothing": 2}),
    (TextureAttack, {"method": "ddn", "gradient_smoothing": 2}),
])
def test_an_eot_attack_is_reproducible_and_judged_on_fresh_views(family: type, kwargs: dict) -> None:
    mesh, victim = builtin_mesh("chair"), PooledLinearClassifier()
    crit = TargetedMisclassification(728)
    eot = Transformations(samples=2, check_every=3, eval_views=6)
    run = family(steps=8, eot=eot, **kwargs)
    first = run(mesh, _views(), victim, crit, setup=SETUP)
    again = family(steps=8, eot=eot, **kwargs)(mesh, _views(), victim, crit, setup=SETUP)
    assert torch.equal(first.mesh.vertices, again.mesh.vertices)
    assert torch.equal(first.mesh.face_colors, again.mesh.face_colors)
    assert first.view_records == again.view_records
    other = family(steps=8, eot=eot, seed=1, **kwargs)(mesh, _views(), victim, crit, setup=SETUP)
    assert other.view_records != first.view_records
    # success is that of fresh views of the range, neither the given views nor the optimised ones
    assert first.success.shape == (1, 6) and first.config["eot"]["samples"] == 2
    fresh = ViewSet.from_records(first.view_records)
    assert not set(rec["azimuth"] for rec in first.view_records) & {40.0, 70.0}
    assert all(30.0 <= rec["azimuth"] <= 80.0 for rec in first.view_records)
    scored = evaluate(first.adversarial, fresh, victim, crit, setup=SETUP)
    assert torch.equal(scored.success, first.success)
    assert len(first.loss_history) == 8 and len(first.loss_history[0]["margin"]) == 1


@needs_native
def test_eval_views_are_scored_beside_the_fresh_ones() -> None:
    held_out = ViewSet.orbit([55.0], elevation=20.0, distance=2.6)
    result = ShapeAttack(steps=3, lr=0.02, eot=2)(builtin_mesh("chair"), _views(), PooledLinearClassifier(),
                                                  TargetedMisclassification(728), setup=SETUP, eval_views=held_out)
    assert result.eval_success is not None and result.eval_success.shape == (1, 1)
    assert result.success.shape == (1, Transformations().eval_views)


def test_eot_refuses_jitter_and_look_at_views() -> None:
    with pytest.raises(ValueError, match="jitter and eot"):
        ShapeAttack(eot=2, jitter={"azimuth": 5.0})
    with pytest.raises(TypeError, match="eot"):
        ShapeAttack(eot="4")
    shifted = _shifted(_views(), torch.zeros(2, 2), 32)
    with pytest.raises(ValueError, match="spherical"):
        ShapeAttack(steps=2, eot=2)(builtin_mesh("chair"), shifted, PooledLinearClassifier(),
                                    TargetedMisclassification(728), setup=SETUP)


@needs_native
def test_gradient_smoothing_makes_the_colour_change_smoother() -> None:
    mesh, victim = builtin_mesh("sofa"), PooledLinearClassifier()
    edges = face_adjacency(mesh.faces)

    def roughness(smoothing: int) -> float:
        attack = TextureAttack(steps=15, method="ddn", gradient_smoothing=smoothing)
        delta = attack(mesh, _views(), victim, TargetedMisclassification(728), setup=SETUP).mesh.face_colors
        delta = delta - mesh.face_colors
        jump = (delta[edges[:, 0]] - delta[edges[:, 1]]).pow(2).sum(1).mean()
        return float(jump / delta.pow(2).sum(1).mean().clamp(min=1e-12))

    assert roughness(8) < 0.5 * roughness(0)


@needs_native
def test_meshadv_attack_eot_runs_the_robust_attack(tmp_path: Any) -> None:
    import json

    from typer.testing import CliRunner

    from meshadv.cli import app

    out = tmp_path / "robust"
    result = CliRunner().invoke(app, ["attack", "builtin:chair", "--target", "sofa", "--perturbation", "texture",
                                      "--eot", "2", "--steps", "2", "--image-size", "32", "--quiet", "-o", str(out)])
    assert result.exit_code == 0, result.output
    record = json.loads((out / "result.json").read_text())
    assert record["config"]["eot"]["samples"] == 2 and record["config"]["gradient_smoothing"] == 8
    assert len(record["views"]) == Transformations().eval_views
    assert "fresh views" in result.output
    refused = CliRunner().invoke(app, ["attack", "builtin:chair", "--target", "sofa", "--eot", "2", "--jitter",
                                       "--steps", "2", "-o", str(tmp_path / "both")])
    assert refused.exit_code != 0 and "jitter and eot" in refused.output


def test_a_sweep_file_reaches_the_robust_attack() -> None:
    from sweep_fixtures import tiny_builtin_config

    from meshadv.experiments.config import expand_jobs, parse_config
    from meshadv.experiments.jobs import _make_job_attack

    config = tiny_builtin_config("robust", steps=2)
    config["attack"]["shape"].update(eot=3, method="ddn", method_options={"smoothness": 10.0})
    config["attack"]["texture"].update(eot={"samples": 2, "eval_views": 4}, gradient_smoothing=8)
    jobs = expand_jobs(parse_config(config))
    attacks = {job["perturbation"]: _make_job_attack(job, dict(job["attack"])) for job in jobs}
    assert attacks["shape"].eot.samples == 3 and attacks["shape"].config()["method_options"]["smoothness"] == 10.0
    assert attacks["texture"].eot == Transformations(samples=2, eval_views=4)
    assert attacks["texture"].gradient_smoothing == 8
    config["attack"]["shape"]["eot"] = {"zoom": 2}
    with pytest.raises(ValueError, match="zoom"):
        [_make_job_attack(job, dict(job["attack"])) for job in expand_jobs(parse_config(config))]
