"""Camera conventions (NMR), projection, batching, validation and gradients."""

from __future__ import annotations

import math

import pytest
import torch

from meshadv.render import Camera


def nmr_eye(distance: float, azimuth: float, elevation: float) -> torch.Tensor:
    """NMR get_points_from_angles, written out independently."""
    az, el = math.radians(azimuth), math.radians(elevation)
    return torch.tensor(
        [distance * math.cos(el) * math.sin(az), distance * math.sin(el), -distance * math.cos(el) * math.cos(az)],
        dtype=torch.float64,
    )


def nmr_look_at(verts: torch.Tensor, eye: torch.Tensor, at: torch.Tensor, up: torch.Tensor) -> torch.Tensor:
    """NMR look_at, written out independently (normalise, cross(up, z), cross(z, x))."""
    z = (at - eye) / (at - eye).norm()
    x = torch.linalg.cross(up, z)
    x = x / x.norm()
    y = torch.linalg.cross(z, x)
    y = y / y.norm()
    return (verts - eye) @ torch.stack([x, y, z]).T


@pytest.mark.parametrize(("az", "el"), [(0.0, 0.0), (90.0, 0.0), (37.0, 25.0), (-120.0, -40.0), (200.0, 80.0)])
def test_spherical_eye_and_view_match_nmr(az: float, el: float) -> None:
    cam = Camera.spherical(torch.tensor(2.5, dtype=torch.float64), az, el)
    torch.testing.assert_close(cam.eye()[0], nmr_eye(2.5, az, el))
    pts = torch.randn(7, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    expected = nmr_look_at(
        pts,
        nmr_eye(2.5, az, el),
        torch.zeros(3, dtype=torch.float64),
        torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64),
    )
    torch.testing.assert_close(cam.world_to_view(pts)[0], expected)


def test_past_the_pole_matches_nmr_flip() -> None:
    # elevation 120: cos(el) < 0 so NMR's normalize(cross(up, z)) flips x; the closed form must follow.
    cam = Camera.spherical(torch.tensor(3.0, dtype=torch.float64), 30.0, 120.0)
    pts = torch.randn(5, 3, dtype=torch.float64)
    expected = nmr_look_at(
        pts,
        nmr_eye(3.0, 30.0, 120.0),
        torch.zeros(3, dtype=torch.float64),
        torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64),
    )
    torch.testing.assert_close(cam.world_to_view(pts)[0], expected)


def test_image_orientation_conventions() -> None:
    cam = Camera.spherical(3.0, 0.0, 0.0)
    pts = torch.tensor([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.5, 0.0]])
    s = cam.project(pts)[0]
    assert s[0, 0].abs() < 1e-6 and s[0, 1].abs() < 1e-6 and abs(float(s[0, 2]) - 3.0) < 1e-6
    assert s[1, 0] > 0.1 and s[1, 1].abs() < 1e-6  # world +x is to the right at azimuth 0
    assert s[2, 1] > 0.1 and s[2, 0].abs() < 1e-6  # world +y is up
    width = math.tan(math.radians(15.0))
    assert abs(float(s[1, 0]) - 0.5 / (3.0 * width)) < 1e-5


def test_tilt_rotates_up_counter_clockwise() -> None:
    pts = torch.tensor([[0.0, 0.5, 0.0]])
    s = Camera.spherical(3.0, 0.0, 0.0, tilt=90.0).project(pts)[0, 0]
    # The up vector turns counter-clockwise (to the left), so the scene turns clockwise: world-up goes right.
    assert s[0] > 0.1 and abs(float(s[1])) < 1e-5
    s30 = Camera.spherical(3.0, 0.0, 0.0, tilt=30.0).project(pts)[0, 0]
    assert abs(math.degrees(math.atan2(float(s30[0]), float(s30[1]))) - 30.0) < 1e-3


def test_look_at_matches_spherical_and_tilt() -> None:
    az, el, d = torch.tensor([10.0, 140.0]), torch.tensor([20.0, -35.0]), torch.tensor([2.0, 4.0])
    sph = Camera.spherical(d, az, el, tilt=torch.tensor([0.0, 25.0]))
    la = Camera.look_at(sph.eye(), torch.zeros(3), torch.tensor([0.0, 1.0, 0.0]), tilt=torch.tensor([0.0, 25.0]))
    pts = torch.randn(2, 9, 3)
    torch.testing.assert_close(sph.project(pts), la.project(pts), atol=1e-5, rtol=1e-5)
    params = la.spherical_params()
    torch.testing.assert_close(params["azimuth"], az, atol=1e-4, rtol=0)
    torch.testing.assert_close(params["elevation"], el, atol=1e-4, rtol=0)


def test_front_facing_face_has_negative_ndc_area() -> None:
    # The contract in ARCHITECTURE.md: normal toward the camera <=> NDC signed area < 0 (left-handed view space).
    gen = torch.Generator().manual_seed(3)
    for _ in range(10):
        az, el = float(torch.rand(1, generator=gen)) * 360, float(torch.rand(1, generator=gen)) * 140 - 70
        cam = Camera.spherical(4.0, az, el)
        tri = torch.randn(3, 3, generator=gen) * 0.5
        normal = torch.linalg.cross(tri[1] - tri[0], tri[2] - tri[0])
        facing = float(normal @ (cam.eye()[0] - tri.mean(0)))
        s = cam.project(tri)[0]
        area = float((s[1, 0] - s[0, 0]) * (s[2, 1] - s[0, 1]) - (s[2, 0] - s[0, 0]) * (s[1, 1] - s[0, 1]))
        assert (facing > 0) == (area < 0)


def test_orthographic_projection() -> None:
    cam = Camera.spherical(5.0, 0.0, 0.0, orthographic=True, ortho_scale=2.0)
    s = cam.project(torch.tensor([[1.0, 0.5, 0.3]]))[0, 0]
    torch.testing.assert_close(s, torch.tensor([0.5, 0.25, 5.3]))


def test_batching_and_indexing() -> None:
    cam = Camera.spherical(2.0, torch.tensor([0.0, 90.0, 180.0]), 10.0)
    assert len(cam) == 3 and cam.eye().shape == (3, 3)
    assert cam.project(torch.randn(4, 3)).shape == (3, 4, 3)
    assert cam.project(torch.randn(3, 4, 3)).shape == (3, 4, 3)
    assert len(cam[1]) == 1 and len(cam[1:]) == 2 and len(cam[[0, 2]]) == 2
    torch.testing.assert_close(cam[2].eye(), cam.eye()[2:3])
    both = Camera.cat([cam, cam[0]])
    assert len(both) == 4
    with pytest.raises(ValueError, match="batch size"):
        cam.project(torch.randn(2, 4, 3))
    with pytest.raises(IndexError, match="^camera index 3 is out of range"):
        cam[3]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"distance": 0.0}, "distance"),
        ({"distance": float("nan")}, "distance"),
        ({"distance": 2.0, "near": 0.0}, "near"),
        ({"distance": 2.0, "near": 5.0, "far": 1.0}, "far"),
        ({"distance": 2.0, "viewing_angle": 180.0}, "viewing_angle"),
        ({"distance": [2.0, 3.0], "azimuth": [0.0, 1.0, 2.0]}, "batch"),
        ({"distance": [[2.0]]}, "distance"),
    ],
)
def test_spherical_rejects_bad_input(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        Camera.spherical(**kwargs)


def test_look_at_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="eye"):
        Camera.look_at(torch.zeros(3), torch.zeros(3))
    with pytest.raises(ValueError, match="up"):
        Camera.look_at(torch.ones(3), torch.zeros(3), torch.zeros(3))
    with pytest.raises(ValueError, match="eye"):
        Camera.look_at(torch.ones(4), torch.zeros(3))
    with pytest.raises(ValueError, match="verts_world"):
        Camera.spherical(2.0).project(torch.ones(3, 2))


def test_gradcheck_spherical_projection() -> None:
    pts = torch.randn(6, 3, dtype=torch.float64) * 0.5
    params = [
        torch.tensor(v, dtype=torch.float64, requires_grad=True)
        for v in ([2.5, 3.0], [20.0, -50.0], [15.0, 60.0], [5.0, -30.0], [30.0, 45.0])
    ]

    def fn(d: torch.Tensor, az: torch.Tensor, el: torch.Tensor, tilt: torch.Tensor, fov: torch.Tensor) -> torch.Tensor:
        return Camera.spherical(d, az, el, tilt=tilt, viewing_angle=fov).project(pts)

    assert torch.autograd.gradcheck(fn, params)


def test_gradcheck_look_at_projection() -> None:
    pts = torch.randn(5, 3, dtype=torch.float64) * 0.5
    eye = torch.tensor([[0.5, 1.0, -3.0]], dtype=torch.float64, requires_grad=True)
    at = torch.tensor([[0.1, -0.1, 0.2]], dtype=torch.float64, requires_grad=True)
    up = torch.tensor([[0.1, 1.0, 0.0]], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda e, a, u: Camera.look_at(e, a, u).project(pts), [eye, at, up])


def test_pole_is_stable_and_continuous() -> None:
    pts = torch.randn(5, 3, dtype=torch.float64)
    az = torch.tensor([33.0], dtype=torch.float64, requires_grad=True)
    el = torch.tensor([90.0], dtype=torch.float64, requires_grad=True)
    out = Camera.spherical(torch.tensor(3.0, dtype=torch.float64), az, el).project(pts)
    near_pole = Camera.spherical(torch.tensor(3.0, dtype=torch.float64), 33.0, 90.0 - 1e-6).project(pts)
    torch.testing.assert_close(out.detach(), near_pole, atol=1e-6, rtol=1e-6)
    out.sum().backward()
    assert torch.isfinite(az.grad).all() and torch.isfinite(el.grad).all() and az.grad.abs().sum() > 0
    assert torch.autograd.gradcheck(
        lambda a, e: Camera.spherical(torch.tensor(3.0, dtype=torch.float64), a, e).project(pts),
        [az.detach().requires_grad_(), torch.tensor([89.0], dtype=torch.float64, requires_grad=True)],
    )


def test_look_at_degenerate_up_is_finite() -> None:
    eye = torch.tensor([0.0, 3.0, 0.0], requires_grad=True)
    out = Camera.look_at(eye, torch.zeros(3), torch.tensor([0.0, 1.0, 0.0])).project(torch.randn(4, 3))
    out.sum().backward()
    assert torch.isfinite(out).all() and torch.isfinite(eye.grad).all()
    rot = Camera.look_at(eye.detach(), torch.zeros(3), torch.tensor([0.0, 1.0, 0.0])).rotation()[0]
    torch.testing.assert_close(rot @ rot.T, torch.eye(3), atol=1e-6, rtol=0)


@pytest.mark.parametrize("value", ["far", None, 2.0 + 1.0j, torch.tensor([2.0 + 1.0j])])
def test_camera_refuses_wrong_types_with_type_error(value: object) -> None:
    with pytest.raises(TypeError, match="^distance must be"):
        Camera.spherical(value)
    with pytest.raises(TypeError, match="^eye must be"):
        Camera.look_at([value, 0.0, 1.0] if not isinstance(value, torch.Tensor) else value.expand(3))


def test_look_at_with_huge_finite_vectors_keeps_an_orthonormal_rotation() -> None:
    # float32 squares of 1e20 overflow: normalising naively gave zero rotation rows and an empty image.
    for cam in (Camera.look_at([0.0, 0.0, -2.7], up=[0.0, 1e20, 0.0]), Camera.look_at([0.0, 0.0, -2e19])):
        rot = cam.rotation()[0]
        torch.testing.assert_close(rot @ rot.T, torch.eye(3))
    with pytest.raises(ValueError, match="at - eye overflows"):
        Camera.look_at([0.0, 0.0, -3e38], at=[0.0, 0.0, 3e38])


def test_a_camera_of_zero_views_is_refused() -> None:
    with pytest.raises(ValueError, match="eye must hold at least one view"):
        Camera.look_at(torch.ones(0, 3))
    with pytest.raises(ValueError, match="at least one view"):
        Camera.spherical(torch.ones(0))
