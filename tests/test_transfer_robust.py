"""meshadv.transfer.robust and the black-box options built on it: margin criterion, EOT views, pixel noise,
Robustness, estimated-view render, object shape attack, scaled bunny, black-box report and CLI checks.

Fast: stand-in victims (a 'red' classifier and a 'dark blob' detector) on tiny renders; Mitsuba only where needed.
"""

from __future__ import annotations

import json
import math

import pytest
import torch
import torch.nn.functional as F
from stand_in_victims import DarkBlobDetector

from meshadv.attacks import Criterion, Disappearance, Misclassification, TextureAttack
from meshadv.render import native_available
from meshadv.transfer.robust import NoisyVictim, eot_views
from meshadv.attacks.criteria import WithMargin
from meshadv.victims.victim import ClassifierVictim

needs_native = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")


class RedClassifier(ClassifierVictim):
    """Stand-in classifier: logit 0 ("tench") is 2, logit 1 is ``scale * mean(red - green)``, the rest 0.

    A grey object is class 0; making it red raises logit 1 until it wins (untargeted margin ``max(z1, 0) - 2``).
    """

    def __init__(self, scale: float = 60.0) -> None:
        super().__init__("red", (32, 32))
        self.scale = scale

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        x = self.resize(images)
        logits = torch.zeros(images.shape[0], 1000, dtype=images.dtype)
        logits[:, 0] = 2.0
        logits[:, 1] = self.scale * (x[:, 0] - x[:, 1]).mean(dim=(1, 2))
        return logits


def _logits(z0: float, z1: float) -> torch.Tensor:
    out = torch.zeros(1, 1000)
    out[0, 0], out[0, 1] = z0, z1
    return out


# ----------------------------------------------------------------------------------------------------------------
# WithMargin
# ----------------------------------------------------------------------------------------------------------------


def test_with_margin_shifts_the_margin_and_keeps_loss_and_score() -> None:
    victim = RedClassifier()
    base = Misclassification(0).bind(victim)
    crit = WithMargin(Misclassification(0), 3.0).bind(victim)
    out = _logits(2.0, 4.0)  # base margin 2: adversarial, but not with margin 3
    assert float(base.margin(out)[0]) == pytest.approx(2.0)
    assert float(crit.margin(out)[0]) == pytest.approx(-1.0)
    assert not bool(crit.is_adversarial(out)[0]) and bool(base.is_adversarial(out)[0])
    assert bool(crit.is_adversarial(_logits(2.0, 5.5))[0])
    assert torch.equal(crit.loss(out), base.loss(out)) and torch.equal(crit.score(out), base.score(out))
    assert torch.equal(crit.loss(out, loss="cw", kappa=3.0), base.loss(out, loss="cw", kappa=3.0))
    assert crit.label == "untargeted(true=tench)+margin3"
    record = crit.to_record()
    assert record["required_margin"] == 3.0 and record["criterion"] == "WithMargin(Misclassification)"
    assert record["indices"] == [0]


def test_with_margin_checks_its_arguments_and_the_victim_kind() -> None:
    with pytest.raises(ValueError, match="required"):
        WithMargin(Misclassification(0), -1.0)
    with pytest.raises(ValueError, match="required"):
        WithMargin(Misclassification(0), math.nan)
    with pytest.raises(ValueError, match="base"):
        WithMargin("not a criterion", 1.0)  # type: ignore[arg-type]
    assert WithMargin(Disappearance("blob"), 0.1).victim_kind == "detector"
    with pytest.raises(ValueError, match="classifier"):  # a detector criterion on a classifier victim
        WithMargin(Disappearance("blob"), 0.1).bind(RedClassifier())
    with pytest.raises(ValueError, match="^criterion is not bound"):
        WithMargin(Misclassification(0), 1.0).margin(_logits(2.0, 0.0))


def test_with_margin_detector_margin_is_in_score_units() -> None:
    detector = DarkBlobDetector()
    crit = WithMargin(Disappearance("blob", threshold=0.3), 0.1).bind(detector)
    base = Disappearance("blob", threshold=0.3).bind(detector)
    images = torch.full((1, 3, 64, 64), 0.75)  # darkness 0.25: blob score sigmoid(-1) = 0.27 < 0.3
    score = float(base.score(detector(images))[0])
    assert score == pytest.approx(1 / (1 + math.e), rel=1e-4)
    assert bool(base.is_adversarial(detector(images))[0])
    assert float(crit.margin(detector(images))[0]) == pytest.approx(0.3 - score - 0.1, abs=1e-6)
    assert not bool(crit.is_adversarial(detector(images))[0])


@needs_native
def test_attack_with_margin_keeps_a_step_that_holds_the_margin() -> None:
    """The attacks keep the least distorted success: a borderline one, unless the criterion asks for a margin."""
    from meshadv.mesh import builtin_mesh
    from meshadv.render import RenderSetup, ViewSet, render_views

    mesh = builtin_mesh("sphere", color=(0.5, 0.5, 0.5))
    views = ViewSet.orbit([30.0], elevation=10.0, distance=3.0)
    victim = RedClassifier()
    attack = TextureAttack(steps=60, lr=0.05, lambda_perceptual=0.0)
    base = Misclassification(0).bind(victim)

    def final_margin(criterion: Criterion) -> float:
        result = attack(mesh, views, victim, criterion, setup=RenderSetup(image_size=32))
        adv = result.mesh
        with torch.no_grad():
            images, _ = render_views(adv.vertices[None], adv.faces, adv.face_colors[None], views,
                                     RenderSetup(image_size=32))
            return float(base.margin(victim(images))[0])

    plain = final_margin(Misclassification(0))
    strong = final_margin(WithMargin(Misclassification(0), 3.0))
    assert 0.0 < plain < 1.0  # the first success, barely adversarial
    assert strong >= 3.0


@needs_native
def test_blackbox_attack_step_with_ddn_holds_the_required_margin() -> None:
    """The black-box pipelines' attack step (:func:`~meshadv.transfer.robust.attack_estimated`: EOT samples,
    jitter, pixel noise, the required margin) with ``method="ddn"``: the least distorted success sits on the
    boundary of the noisy jittered samples, so without a margin the clean re-render is barely adversarial, and the
    required margin is what it keeps (at a larger distortion)."""
    from meshadv.mesh import builtin_mesh
    from meshadv.render import RenderSetup, ViewSet, render_views
    from meshadv.transfer.robust import attack_estimated
    from meshadv.transfer.robust import Robustness

    mesh = builtin_mesh("sphere", color=(0.5, 0.5, 0.5))
    views = ViewSet.orbit([30.0], elevation=10.0, distance=3.0)
    victim = RedClassifier()
    setup = RenderSetup(image_size=32)
    base = Misclassification(0).bind(victim)
    attack = TextureAttack(method="ddn", steps=60, jitter={"azimuth": 5.0, "light_intensity": 0.2})

    def run(margin: float) -> tuple:
        robustness = Robustness(eot=2, margin=margin, pixel_noise=0.02, seed=0)
        result = attack_estimated(attack, mesh, views, victim, Misclassification(0), robustness, setup)
        assert result.config["method"] == "ddn" and result.steps_to_success[0] is not None
        adv = result.mesh
        with torch.no_grad():
            images, _ = render_views(adv.vertices[None], adv.faces, adv.face_colors[None], views, setup)
        return float(base.margin(victim(images))[0]), result.distances[0]["color_rmse"]

    plain, plain_rmse = run(0.0)
    strong, strong_rmse = run(3.0)
    assert 0.0 < plain < 1.0  # the clean re-render of the least distorted success: barely adversarial
    assert strong >= 2.5  # the margin held on noisy jittered samples carries over to the clean view
    assert 0 < plain_rmse < strong_rmse


# ----------------------------------------------------------------------------------------------------------------
# EOT views, pixel noise, Robustness
# ----------------------------------------------------------------------------------------------------------------


def test_eot_views_copies_then_jitter_draws_independent_samples() -> None:
    from meshadv.render import ViewSet

    views = ViewSet.orbit([10.0, 50.0], elevation=5.0, distance=3.0)
    copies = eot_views(views, 3)
    assert len(copies) == 6
    assert [r["azimuth"] for r in copies.to_records()] == pytest.approx([10.0, 50.0] * 3)
    assert eot_views(views, 1) is views
    jittered = copies.jitter(torch.Generator().manual_seed(0), azimuth=5.0).to_records()
    azimuths = [r["azimuth"] for r in jittered]
    assert len({round(a, 6) for a in azimuths[0::2]}) == 3  # three different samples of the first view
    assert all(abs(a - b) <= 5.0 for a, b in zip(azimuths, [10.0, 50.0] * 3))
    for bad in (0, -2):  # wrong types (1.5, True): test_transfer_inputs.py
        with pytest.raises(ValueError, match="samples"):
            eot_views(views, bad)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="views"):
        eot_views([1, 2], 2)


class _Identity(ClassifierVictim):
    def __init__(self) -> None:
        super().__init__("identity", (8, 8))

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return images


def test_noisy_victim_adds_reproducible_noise_and_passes_attributes_and_gradients() -> None:
    inner = _Identity()
    noisy = NoisyVictim(inner, 0.05, seed=3)
    assert noisy.kind == "classifier" and noisy.name == "identity" and noisy.input_size == (8, 8)
    images = torch.full((4, 3, 32, 32), 0.5, requires_grad=True)
    out = noisy(images)
    noise = (out - images).detach()
    assert noise.std().item() == pytest.approx(0.05, rel=0.1) and abs(noise.mean().item()) < 0.01
    assert not torch.equal(noisy(images), out)  # fresh noise at every call
    assert torch.equal(NoisyVictim(inner, 0.05, seed=3)(images), out)  # same seed, same sequence
    out.sum().backward()
    assert torch.allclose(images.grad, torch.ones_like(images))
    assert float(NoisyVictim(inner, 0.5)(torch.ones(1, 3, 8, 8)).max()) <= 1.0  # clamped like a render
    for bad in (0.0, -0.1, math.inf):  # wrong types (True): test_transfer_inputs.py
        with pytest.raises(ValueError, match="std"):
            NoisyVictim(inner, bad)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="victim"):
        NoisyVictim(42, 0.1)


def test_noisy_victim_with_a_background_adds_noise_only_on_the_rendered_pixels() -> None:
    background = torch.rand(3, 16, 16, generator=torch.Generator().manual_seed(1))
    images = background.expand(2, 3, 16, 16).clone()
    images[:, :, 4:8, 4:12] = 0.5  # the 'object' meshadv rendered over the photo
    noisy = NoisyVictim(_Identity(), 0.05, background=background)
    out = noisy(images)
    changed = (out != images).any(dim=1)
    assert bool(changed[:, 4:8, 4:12].all())
    changed[:, 4:8, 4:12] = False
    assert not bool(changed.any())  # the photo is left as it is
    assert "rendered pixels" in repr(noisy)
    with pytest.raises(ValueError, match="background"):
        NoisyVictim(_Identity(), 0.05, background=torch.zeros(16, 16))
    with pytest.raises(ValueError, match="must match the background"):
        noisy(torch.zeros(1, 3, 8, 8))


def test_robustness_validates_its_fields() -> None:
    from meshadv.transfer.robust import Robustness

    r = Robustness(eot=4, margin=2.5, pixel_noise=0.01)
    assert r.to_record() == {"eot": 4, "required_margin": 2.5, "pixel_noise": 0.01, "verify_samples": 16,
                             "robust_seed": 0}
    for kwargs, name in (({"eot": 0}, "eot"), ({"margin": -1.0}, "margin"),
                         ({"pixel_noise": math.nan}, "pixel_noise"), ({"verify_samples": -1}, "verify_samples")):
        with pytest.raises(ValueError, match=name):
            Robustness(**kwargs)


# ----------------------------------------------------------------------------------------------------------------
# Estimated-view render, compositing, object shape attack, scaled bunny
# ----------------------------------------------------------------------------------------------------------------


def test_composite_puts_the_background_where_alpha_is_zero() -> None:
    import numpy as np

    from meshadv.transfer.photos import composite
    from meshadv.transfer.mitsuba_process import MitsubaImage

    image = np.zeros((4, 4, 3), np.float32)
    image[:2] = 0.6  # premultiplied: the top half is covered
    alpha = np.zeros((4, 4), np.float32)
    alpha[:2] = 1.0
    background = torch.full((3, 4, 4), 0.25)
    out = composite(MitsubaImage(image, alpha, "scalar_rgb"), background)
    assert torch.allclose(out[:, :2], torch.full((3, 2, 4), 0.6))
    assert torch.allclose(out[:, 2:], torch.full((3, 2, 4), 0.25))
    with pytest.raises(ValueError, match="background"):
        composite(MitsubaImage(image, alpha, "scalar_rgb"), torch.zeros(3, 5, 5))
    with pytest.raises(TypeError, match="background"):
        composite(MitsubaImage(image, alpha, "scalar_rgb"), np.full((3, 4, 4), 0.25))  # type: ignore[arg-type]


def test_hidden_scene_and_estimate_parameters_name_a_bad_argument() -> None:
    """Bad input fails at once, naming the argument, before any Mitsuba render."""
    from meshadv.mesh import builtin_mesh
    from meshadv.transfer.setups import HiddenScene
    from meshadv.transfer.photos import estimate_parameters

    with pytest.raises(ValueError, match="camera.*missing \\['elevation'\\]"):
        HiddenScene(camera={"distance": 3.0, "azimuth": 10.0})
    for bad in ("far", "3.0", None, True):  # the wrong type: TypeError, like every other entry point
        with pytest.raises(TypeError, match="camera\\['distance'\\] must be a real number"):
            HiddenScene(camera={"distance": bad, "azimuth": 10.0, "elevation": 5.0})
    with pytest.raises(ValueError, match="camera\\['distance'\\] must be finite"):
        HiddenScene(camera={"distance": math.nan, "azimuth": 10.0, "elevation": 5.0})
    with pytest.raises(ValueError, match="camera\\['tilt'\\] must be finite"):
        HiddenScene(camera={"distance": 3.0, "azimuth": 10.0, "elevation": 5.0, "tilt": math.inf})
    hidden = HiddenScene(camera={"distance": 3.0, "azimuth": 10.0, "elevation": 5.0, "tilt": 2})
    assert hidden.mitsuba_camera().viewing_angle == 30.0
    cube = builtin_mesh("cube")
    with pytest.raises(TypeError, match="hidden must be a HiddenScene"):
        estimate_parameters(cube, {"distance": 3.0, "azimuth": 10.0, "elevation": 5.0})  # type: ignore[arg-type]
    for bad_size in (4, 64.0):
        with pytest.raises(ValueError, match="camera_size"):
            estimate_parameters(cube, hidden, camera_size=bad_size)  # type: ignore[arg-type]


def test_estimated_view_spec_is_the_attack_view_with_direct_light_only() -> None:
    import numpy as np

    from meshadv.mesh import builtin_mesh
    from meshadv.render import Camera, Lights, ViewSet
    from meshadv.transfer.setups import HiddenScene
    from meshadv.transfer.photos import estimated_view_spec

    camera = Camera.spherical(3.0, 40.0, 10.0, viewing_angle=30.0)
    lights = Lights([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]], [[0.4] * 3, [0.2] * 3], [0.3] * 3)
    record = ViewSet(camera, lights).to_records()[0]
    hidden = HiddenScene(camera={"distance": 3.1, "azimuth": 41.0, "elevation": 9.0}, image_size=(48, 48), spp=32)
    spec = estimated_view_spec(builtin_mesh("cube"), record, hidden, seed=5)
    assert spec.max_depth == 2 and spec.spp == 32 and spec.image_size == (48, 48) and spec.seed == 5
    assert spec.background == (0.0, 0.0, 0.0) and spec.environment is None and spec.base_scene is None
    np.testing.assert_allclose(spec.camera.eye, camera.eye()[0].numpy(), atol=1e-5)  # estimated, not hidden
    np.testing.assert_allclose(spec.lights.colors, [[0.4] * 3, [0.2] * 3])
    np.testing.assert_allclose(spec.lights.ambient, [0.3] * 3)


def _side_by_side(name: str, color: tuple, *, scale: float, half_gap: float) -> tuple:
    """Two copies of a builtin mesh, scaled and centred at x = -half_gap and +half_gap, and their merged mesh."""
    from meshadv.mesh import builtin_mesh
    from meshadv.transfer.setups import merge_meshes

    left = builtin_mesh(name, color=color)
    left = left.with_vertices(left.vertices * scale + torch.tensor([-half_gap, 0.0, 0.0]))
    right = left.with_vertices(left.vertices + torch.tensor([2 * half_gap, 0.0, 0.0]))
    return left, right, merge_meshes([left, right])


@needs_native
def test_object_shape_attack_moves_only_the_masked_object() -> None:
    from meshadv.attacks import ShapeAttack
    from meshadv.render import RenderSetup, ViewSet

    left, right, merged = _side_by_side("cube", (0.15, 0.15, 0.15), scale=0.4, half_gap=0.6)
    mask = torch.zeros(merged.num_vertices, dtype=torch.bool)
    mask[8:] = True  # the right cube
    attack = ShapeAttack(vertex_mask=mask, steps=15, lr=0.02, lambda_perceptual=0.0)
    views = ViewSet.orbit([10.0], elevation=10.0, distance=4.0)
    result = attack(merged, views, DarkBlobDetector(), Disappearance("blob", threshold=0.5),
                    setup=RenderSetup(image_size=64))
    moved = (result.mesh.vertices - merged.vertices).abs().amax(dim=1)
    assert float(moved[:8].max()) == 0.0
    assert float(moved[8:].max()) > 1e-3
    for bad in (torch.zeros(16, dtype=torch.bool), torch.ones(16), torch.ones(2, 8, dtype=torch.bool)):
        with pytest.raises(ValueError, match="vertex_mask"):
            ShapeAttack(vertex_mask=bad, steps=1)


def test_scale_on_base_keeps_the_base_centre() -> None:
    from meshadv.mesh import builtin_mesh
    from meshadv.transfer.setups import scale_on_base

    cube = builtin_mesh("cube")
    cube = cube.with_vertices(cube.vertices * 0.1 + torch.tensor([0.3, 0.75 + 0.1, -0.2]))
    big = scale_on_base(cube, 3.0)
    lo, hi = cube.bounds()
    lo3, hi3 = big.bounds()
    assert float(lo3[1]) == pytest.approx(float(lo[1]))  # still standing on y = 0.75
    assert torch.allclose((lo3 + hi3)[[0, 2]] / 2, (lo + hi)[[0, 2]] / 2, atol=1e-6)
    assert torch.allclose(hi3 - lo3, 3.0 * (hi - lo), atol=1e-5)
    for bad in (0.0, -1.0, math.inf):
        with pytest.raises(ValueError, match="scale"):
            scale_on_base(cube, bad)


@needs_native
@pytest.mark.parametrize("context,perturbation", [("photo", "shape"), ("render", "texture")])
def test_blackbox_detector_tiny_run(context: str, perturbation: str) -> None:
    """Two known objects (a dark cube 'table' and a sphere); the sphere is attacked so that 'blob' disappears."""
    pytest.importorskip("mitsuba")
    from meshadv.mesh import builtin_mesh
    from meshadv.transfer.setups import HiddenScene
    from meshadv.transfer.blackbox import blackbox_detector
    from meshadv.transfer.robust import Robustness
    from meshadv.transfer.mitsuba_spec import MeshObject, MitsubaLights

    cube = builtin_mesh("cube", color=(0.1, 0.1, 0.1))
    cube = cube.with_vertices(cube.vertices * 0.5 + torch.tensor([-0.4, 0.0, 0.0]))
    sphere = builtin_mesh("sphere", color=(0.8, 0.8, 0.8))
    sphere = sphere.with_vertices(sphere.vertices * 0.3 + torch.tensor([0.5, 0.0, 0.0]))
    lights = MitsubaLights([[0.3, 0.8, -0.5]], [[0.5, 0.5, 0.5]], [0.4, 0.4, 0.4])
    hidden = HiddenScene(camera={"distance": 3.5, "azimuth": 20.0, "elevation": 15.0}, lights=lights,
                         extra_objects=(MeshObject.from_mesh(cube),), image_size=64, spp=8, max_depth=2)
    row = blackbox_detector([cube, sphere], 1, hidden, victim=DarkBlobDetector(), hide_class="blob",
                            perturbation=perturbation, context=context, attack_kwargs={"steps": 2},
                            robustness=Robustness(eot=2, margin=0.05, verify_samples=2),
                            camera_steps=20, light_steps=20, score_threshold=0.5)
    public = row.to_record()
    json.dumps(public)  # JSON-able
    assert public["perturbation"] == perturbation and public["score_threshold"] == 0.5
    assert public["context"] == context
    assert public["occluded_pixels"] == (0 if context == "photo" else None)  # side by side: nothing in front
    for key in ("hide_score_meshadv", "hide_score_mitsuba_estimated", "hide_score_benign_mitsuba",
                "hide_score_adversarial_mitsuba"):
        assert 0.0 <= public[key] <= 1.0, key
    assert public["success_mitsuba"] == (public["hide_score_adversarial_mitsuba"] < 0.5)
    assert public["success_meshadv"] == (public["hide_score_meshadv"] < 0.5)
    adversarial = row.adversarial_mesh
    assert adversarial.vertices.shape == sphere.vertices.shape  # only the attacked object comes back
    if perturbation == "shape":
        assert torch.equal(adversarial.face_colors, sphere.face_colors)
    else:
        assert torch.equal(adversarial.vertices, sphere.vertices)
    # Outside the sphere (benign or adversarial silhouette, one pixel wider), the detector's meshadv image is the
    # Mitsuba photo itself in the "photo" context (rendered again with the same seed: identical), and meshadv's own
    # render of the cube over the empty world in the "render" context.
    from meshadv.render import Camera, render_silhouette

    cam = Camera.spherical(public["estimated_distance"], public["estimated_azimuth"], public["estimated_elevation"],
                           viewing_angle=30.0)
    sil = torch.maximum(render_silhouette(adversarial.vertices, adversarial.faces, cam, 64),
                        render_silhouette(sphere.vertices, sphere.faces, cam, 64))
    outside = F.max_pool2d(sil, 3, stride=1, padding=1)[0, 0] == 0
    seen = torch.from_numpy(row.images["adversarial_meshadv"]).permute(2, 0, 1)
    photo = torch.from_numpy(row.images["benign_mitsuba"]).permute(2, 0, 1)
    diff = (seen - photo).abs().amax(dim=0)[outside]
    assert int(outside.sum()) > 2000
    if context == "photo":
        assert float(diff.max()) < 1e-6
    else:
        assert float(diff.max()) > 0.05
    with pytest.raises(ValueError, match="perturbation"):
        blackbox_detector([cube, sphere], 1, hidden, victim=DarkBlobDetector(), hide_class="blob",
                          perturbation="paint")
    with pytest.raises(ValueError, match="context"):
        blackbox_detector([cube, sphere], 1, hidden, victim=DarkBlobDetector(), hide_class="blob",
                          context="room")
    with pytest.raises(ValueError, match="score_threshold"):
        blackbox_detector([cube, sphere], 1, hidden, victim=DarkBlobDetector(), hide_class="blob",
                          score_threshold=0.0)


# ----------------------------------------------------------------------------------------------------------------
# Report and CLI
# ----------------------------------------------------------------------------------------------------------------


def test_blackbox_report_shows_each_section_with_the_columns_some_row_has() -> None:
    from meshadv.transfer.results import blackbox_report, transfer_report

    old = {"case_id": "old", "victim": "v", "true_class": "aeroplane", "target": "", "perturbation": "texture",
           "view": 0, "success_meshadv": True, "success_mitsuba": False, "azimuth_error": 0.2, "kind": "blackbox"}
    new = dict(old, case_id="new", success_mitsuba=True, success_mitsuba_estimated=True, margin_meshadv=7.5,
               margin_mitsuba=1.25, eot=8, required_margin=10.0)
    text = blackbox_report([old, new])
    assert "#### Outcome" in text and "#### Estimation errors" in text and "#### Attack settings" in text
    # Columns no row has (robust_rate_meshadv, benign_correct_mitsuba, ...) are left out; missing values are "–".
    assert "| old | v | aeroplane |  | texture | True | – | False |" in text
    assert "| new | v | aeroplane |  | texture | True | True | True |" in text
    assert "| case_id | margin_meshadv | margin_mitsuba |" in text
    assert "| old | – | – |" in text and "| new | 7.50 | 1.25 |" in text
    detector = dict(old, case_id="det", true_class="dining table", hide_score_meshadv=0.125,
                    hide_score_adversarial_mitsuba=0.75, score_threshold=0.3, lambda_perceptual=1e-05)
    text = blackbox_report([old, new, detector])
    assert "| case_id | hide_score_meshadv | hide_score_adversarial_mitsuba | score_threshold |" in text
    assert "| det | 0.12 | 0.75 | 0.30 |" in text
    margins = text.split("#### Classifier margins")[1].split("####")[0]
    assert "| new |" in margins and "| det |" not in margins  # the detector has its own score table
    assert "| det | – | – | 1e-05 |" in text  # settings: eot, required_margin, then a small weight kept readable
    only_outcome = blackbox_report([old])
    assert "#### Margins" not in only_outcome and "#### Attack settings" not in only_outcome
    assert "Black-box pipeline" in transfer_report([new])


def test_cli_blackbox_rejects_bad_options_before_any_work() -> None:
    from typer.testing import CliRunner

    from meshadv.cli import build_app

    app = build_app({"transfer": "transfer:transfer"})
    runner = CliRunner()
    for args, hint in ((["--eot", "0"], "--eot"), (["--margin", "-1"], "--margin"),
                       (["--pixel-noise", "-0.1"], "--pixel-noise"), (["--antialias", "0"], "--antialias"),
                       (["--loss", "hinge"], "--loss"), (["--early-stop", "0"], "--early-stop"),
                       (["--light-jitter", "-1"], "--light-jitter"), (["--jitter", "-1"], "--jitter")):
        result = runner.invoke(app, ["transfer", "blackbox-classifier", "aeroplane", *args])
        assert result.exit_code == 2, (args, result.output)
        assert hint in result.output
    result = runner.invoke(app, ["transfer", "blackbox-detector", "--object-scale", "0"])
    assert result.exit_code == 2 and "--object-scale" in result.output
    result = runner.invoke(app, ["transfer", "blackbox-detector", "--light-fit", "sky"])
    assert result.exit_code == 2 and "--light-fit" in result.output
    result = runner.invoke(app, ["transfer", "blackbox-detector", "--context", "room"])
    assert result.exit_code == 2 and "--context" in result.output
    result = runner.invoke(app, ["transfer", "blackbox-detector", "--perturbation", "shape",
                                 "--texture-smoothing", "4"])
    assert result.exit_code == 2 and "--texture-smoothing" in result.output
    result = runner.invoke(app, ["transfer", "blackbox-detector", "--progress", "-1"])
    assert result.exit_code == 2 and "--progress" in result.output
    result = runner.invoke(app, ["transfer", "blackbox-detector", "--perturbation", "paint"])
    assert result.exit_code == 2 and "--perturb" in result.output


def test_occluded_puts_the_photo_back_where_the_mask_is_one() -> None:
    from meshadv.transfer.robust import Occluded

    inner = _Identity()
    photo = torch.full((3, 8, 8), 0.9)
    mask = torch.zeros(8, 8)
    mask[:, :3] = 1.0
    wrapped = Occluded(inner, photo, mask)
    assert wrapped.kind == "classifier" and wrapped.name == "identity"
    images = torch.full((2, 3, 8, 8), 0.2, requires_grad=True)
    out = wrapped(images)
    assert torch.allclose(out[:, :, :, :3], torch.full((2, 3, 8, 3), 0.9))
    assert torch.allclose(out[:, :, :, 3:], torch.full((2, 3, 8, 5), 0.2))
    out.sum().backward()
    assert float(images.grad[:, :, :, :3].abs().max()) == 0.0 and float(images.grad[:, :, :, 3:].min()) == 1.0
    noisy = NoisyVictim(wrapped, 0.01)  # wrappers compose
    assert noisy.kind == "classifier" and noisy(images).shape == images.shape
    with pytest.raises(ValueError, match="match the occlusion mask"):
        wrapped(torch.zeros(1, 3, 4, 4))
    with pytest.raises(ValueError, match="mask"):
        Occluded(inner, photo, torch.zeros(4, 4))
    with pytest.raises(ValueError, match="mask values"):
        Occluded(inner, photo, torch.full((8, 8), 2.0))
    with pytest.raises(ValueError, match="photo"):
        Occluded(inner, torch.zeros(8, 8), mask)


@needs_native
def test_occlusion_mask_marks_what_is_behind_another_object() -> None:
    from meshadv.mesh import builtin_mesh
    from meshadv.render import ViewSet
    from meshadv.transfer.setups import occlusion_mask

    back = builtin_mesh("sphere")
    back = back.with_vertices(back.vertices * 0.5)
    front = builtin_mesh("cube")  # between the camera (azimuth 0: on -Z) and the sphere, covering its left part
    front = front.with_vertices(front.vertices * 0.3 + torch.tensor([0.35, 0.0, -1.2]))
    views = ViewSet.orbit([0.0], elevation=0.0, distance=4.0)
    occluded = occlusion_mask([front, back], 1, views, 48)
    assert occluded.shape == (48, 48)
    assert 20 < int(occluded.sum()) < 300
    assert int(occlusion_mask([front, back], 0, views, 48).sum()) == 0  # nothing is in front of the cube
    far = front.with_vertices(front.vertices + torch.tensor([3.0, 0.0, 0.0]))
    assert int(occlusion_mask([far, back], 1, views, 48).sum()) == 0
    with pytest.raises(ValueError, match="index"):
        occlusion_mask([front, back], 2, views, 48)


# ----------------------------------------------------------------------------------------------------------------
# SmoothTextureAttack
# ----------------------------------------------------------------------------------------------------------------


def test_smooth_texture_starts_at_the_original_colours_and_spreads_a_vertex_offset() -> None:
    from meshadv.mesh import builtin_mesh, vertex_edges
    from meshadv.attacks import SmoothTextureAttack

    mesh = builtin_mesh("sphere")
    gen = torch.Generator().manual_seed(0)
    mesh = mesh.with_face_colors(0.2 + 0.6 * torch.rand(mesh.num_faces, 3, generator=gen))
    edges = vertex_edges(mesh.faces)
    sharp, smooth = SmoothTextureAttack(smoothing=0), SmoothTextureAttack(smoothing=16)
    zero = smooth.initial_params(mesh, 2)
    assert zero.shape == (2, mesh.num_vertices, 3)
    assert torch.allclose(smooth.colors(zero, mesh, edges), mesh.face_colors.expand(2, -1, -1), atol=1e-5)
    assert float(smooth.distance(zero, mesh, edges).max()) < 1e-5
    bump = zero[:1].clone()
    bump[0, 0] = 5.0  # one vertex
    changed_sharp = ((sharp.colors(bump, mesh, edges) - mesh.face_colors).abs().amax(-1) > 1e-4).sum()
    changed_smooth = ((smooth.colors(bump, mesh, edges) - mesh.face_colors).abs().amax(-1) > 1e-4).sum()
    faces_of_vertex = int((mesh.faces == 0).any(dim=1).sum())
    assert int(changed_sharp) == faces_of_vertex  # unsmoothed: only the faces around the vertex
    assert int(changed_smooth) > 10 * faces_of_vertex  # smoothed: a patch around it
    colors = smooth.colors(bump * 100, mesh, edges)
    assert float(colors.min()) >= 0.0 and float(colors.max()) <= 1.0  # always valid reflectances
    assert smooth.config()["smoothing"] == 16 and smooth.config()["face_mask"] is None
    with pytest.raises(ValueError, match="smoothing"):
        SmoothTextureAttack(smoothing=-1)
    for bad in (1.5, True, "16"):
        with pytest.raises(TypeError, match="smoothing"):
            SmoothTextureAttack(smoothing=bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="face_mask"):
        SmoothTextureAttack(face_mask=torch.zeros(3, dtype=torch.bool))
    with pytest.raises(ValueError, match="face_mask"):
        SmoothTextureAttack(face_mask=torch.ones(3))
    with pytest.raises(ValueError, match="face_mask has 3 entries"):
        SmoothTextureAttack(face_mask=torch.ones(3, dtype=torch.bool)).check_mesh(mesh)


@needs_native
def test_smooth_texture_attack_with_a_face_mask_changes_only_those_faces() -> None:
    from meshadv.attacks import SmoothTextureAttack
    from meshadv.render import RenderSetup, ViewSet

    left, right, merged = _side_by_side("sphere", (0.5, 0.5, 0.5), scale=0.45, half_gap=0.5)
    mask = torch.zeros(merged.num_faces, dtype=torch.bool)
    mask[left.num_faces:] = True
    views = ViewSet.orbit([0.0], elevation=10.0, distance=3.5)
    attack = SmoothTextureAttack(smoothing=4, face_mask=mask, steps=30, lr=0.1, lambda_perceptual=0.0)
    result = attack(merged, views, RedClassifier(), Misclassification(0), setup=RenderSetup(image_size=32))
    change = (result.mesh.face_colors - merged.face_colors).abs().amax(dim=1)
    assert float(change[:left.num_faces].max()) == 0.0
    assert float(change[left.num_faces:].max()) > 0.05
    assert bool(result.succeeded[0])
    # the distortion the attack minimises is measured on the attacked faces only
    from meshadv.mesh import vertex_edges

    edges = vertex_edges(merged.faces)
    params = torch.zeros(1, merged.num_vertices, 3)
    params[0, left.num_vertices:] = 1.0
    colors = attack.colors(params, merged, edges)[0]
    rmse = (colors[mask] - merged.face_colors[mask]).pow(2).sum(-1).mean().sqrt()
    assert float(attack.distance(params, merged, edges)[0]) == pytest.approx(float(rmse), rel=1e-5)
    assert float(rmse) > 0.1


@needs_native
def test_estimate_parameters_can_fit_the_lights_on_one_object() -> None:
    """Two objects under different light: the object-local fit matches the attacked object's brightness better."""
    pytest.importorskip("mitsuba")
    from meshadv.mesh import builtin_mesh
    from meshadv.render import render
    from meshadv.transfer.setups import HiddenScene
    from meshadv.transfer.photos import estimate_parameters
    from meshadv.transfer.setups import merge_meshes
    from meshadv.transfer.mitsuba_spec import MeshObject, MitsubaLights

    cube = builtin_mesh("cube", color=(0.6, 0.6, 0.6))
    cube = cube.with_vertices(cube.vertices * 0.4 + torch.tensor([-0.5, 0.0, 0.0]))
    sphere = builtin_mesh("sphere", color=(0.6, 0.6, 0.6))
    sphere = sphere.with_vertices(sphere.vertices * 0.35 + torch.tensor([0.5, 0.0, 0.0]))
    lights = MitsubaLights([[0.2, 0.9, -0.4]], [[0.6, 0.6, 0.6]], [0.3, 0.3, 0.3])
    # the sphere is brighter than the light explains: it is a light-grey sphere the attacker believes 0.6
    bright = MeshObject(sphere.vertices, sphere.faces, torch.full((sphere.num_faces, 3), 0.95))
    hidden = HiddenScene(camera={"distance": 3.5, "azimuth": 15.0, "elevation": 10.0}, lights=lights,
                         extra_objects=(MeshObject.from_mesh(cube),), image_size=64, spp=16, max_depth=2)
    merged = merge_meshes([cube, sphere])
    faces = (cube.num_faces, cube.num_faces + sphere.num_faces)
    results = {}
    for name, light_faces in (("known", None), ("object", faces)):
        est = estimate_parameters(bright, hidden, known=merged, light_faces=light_faces, camera_steps=20,
                                  light_steps=60)
        with torch.no_grad():
            out = render(merged.vertices, merged.faces, merged.face_colors, est.views.camera, est.views.lights, 64)
        on_sphere = (out.face_index[0] >= faces[0]) & (est.mask > 0.5)
        error = (out.image[0][:, on_sphere] - est.photo[:, on_sphere]).abs().mean()
        results[name] = (float(error), est.errors["light_fit_pixels"])
    assert results["object"][1] < 0.7 * results["known"][1]  # fitted on the sphere's pixels only
    assert results["object"][0] < 0.7 * results["known"][0]  # and the sphere's brightness is matched better
    with pytest.raises(ValueError, match="light_faces"):
        estimate_parameters(bright, hidden, known=merged, light_faces=(5, 5), camera_steps=1, light_steps=1)


def test_cli_light_jitter_scales_only_the_light_entries() -> None:
    from meshadv.transfer.robust import DEFAULT_JITTER
    from meshadv.transfer.robust import scaled_jitter as _jitter

    both = _jitter(2.0)
    assert both == {k: 2.0 * v for k, v in DEFAULT_JITTER.items()}
    split = _jitter(1.0, 3.0)
    assert split["azimuth"] == DEFAULT_JITTER["azimuth"] and split["distance"] == DEFAULT_JITTER["distance"]
    assert split["light_direction"] == pytest.approx(3.0 * DEFAULT_JITTER["light_direction"])
    assert split["light_intensity"] == pytest.approx(3.0 * DEFAULT_JITTER["light_intensity"])
    assert _jitter(0.0, 1.0)["elevation"] == 0.0 and _jitter(0.0, 1.0)["light_intensity"] > 0


def test_blackbox_case_ids_name_every_non_default_setting_including_the_seed() -> None:
    from meshadv.transfer.blackbox import settings_suffix as _settings_suffix

    assert _settings_suffix(1.0, 1, 0.0, 0.0, 1, 100, 100) == ""
    assert _settings_suffix(1.0, 4, 0.29, 0.0, 2, 300, 100, None, 1) == "_eot4_margin0.29_aa2_steps300_seed1"
    assert _settings_suffix(0.5, 1, 0.0, 0.02, 1, 100, 100, 2.0) == "_jitter0.5_lightjitter2_noise0.02"
