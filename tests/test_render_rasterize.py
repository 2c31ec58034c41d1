"""The Python <-> Rust bridge contract of ``meshadv.render.rasterize``: dtypes, shapes, errors, autograd plumbing."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from meshadv.render import native_available, rasterize
from meshadv.render.rasterize import _to_numpy_f32, _to_numpy_i32

pytestmark = pytest.mark.skipif(not native_available(), reason="meshadv._raster is not built (maturin develop)")


def scene(batch: int = 1, dtype: torch.dtype = torch.float32) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    verts = torch.tensor(
        [[-0.8, -0.7, 2.0], [0.7, -0.6, 2.5], [0.0, 0.8, 3.0], [0.5, 0.5, 1.5], [-0.9, 0.2, 1.2]], dtype=dtype
    )
    faces = torch.tensor([[0, 2, 1], [1, 3, 4], [0, 4, 3]])
    attrs = torch.rand(batch, 3, 4, generator=torch.Generator().manual_seed(0), dtype=dtype)
    return verts.expand(batch, -1, -1).clone(), faces, attrs


def test_shapes_dtypes_and_values() -> None:
    verts, faces, attrs = scene(batch=2)
    out = rasterize(verts, faces, attrs, (12, 17), background=[0.1, 0.2, 0.3, 0.0])
    assert out.image.shape == (2, 12, 17, 4) and out.image.dtype == torch.float32
    assert out.face_index.shape == (2, 12, 17) and out.face_index.dtype == torch.int64
    assert out.depth.shape == (2, 12, 17) and out.depth.dtype == torch.float32
    empty = out.face_index < 0
    assert empty.any() and (~empty).any()
    torch.testing.assert_close(out.image[empty], torch.tensor([0.1, 0.2, 0.3, 0.0]).expand(int(empty.sum()), 4))
    torch.testing.assert_close(out.depth[empty], torch.full((int(empty.sum()),), 100.0))
    idx = out.face_index.clamp_min(0)
    drawn = torch.gather(attrs, 1, idx.reshape(2, -1, 1).expand(-1, -1, 4)).reshape(2, 12, 17, 4)
    torch.testing.assert_close(out.image[~empty], drawn[~empty])
    assert ((out.depth[~empty] >= 1.2 - 1e-5) & (out.depth[~empty] <= 3.0 + 1e-5)).all()


def test_unbatched_inputs_and_int32_faces_and_float64() -> None:
    verts, faces, attrs = scene(dtype=torch.float64)
    out = rasterize(verts[0], faces.int(), attrs[0], 10)
    assert out.image.shape == (1, 10, 10, 4) and out.image.dtype == torch.float64
    v = verts.clone().requires_grad_(True)
    a = attrs.clone().requires_grad_(True)
    res = rasterize(v, faces, a, 10)
    (res.image * torch.randn_like(res.image)).sum().backward()
    assert v.grad.dtype == torch.float64 and a.grad.dtype == torch.float64
    assert torch.all(v.grad[..., 2] == 0) and v.grad.abs().sum() > 0


def test_attrs_broadcast_over_batch() -> None:
    verts, faces, attrs = scene(batch=3)
    a = attrs[:1].clone().requires_grad_(True)
    out = rasterize(verts, faces, a, 9)
    out.image.sum().backward()
    single = rasterize(verts[:1], faces, attrs[:1], 9)
    torch.testing.assert_close(out.image[2], single.image[0])
    assert a.grad.shape == (1, 3, 4)


def test_attribute_gradient_counts_pixels() -> None:
    verts, faces, attrs = scene()
    a = attrs.clone().requires_grad_(True)
    out = rasterize(verts, faces, a, 16)
    out.image.sum().backward()
    counts = torch.bincount(out.face_index[out.face_index >= 0], minlength=3).float()
    torch.testing.assert_close(a.grad[0], counts[:, None].expand(3, 4))


def test_no_grad_requested_returns_none() -> None:
    verts, faces, attrs = scene()
    a = attrs.clone().requires_grad_(True)
    out = rasterize(verts, faces, a, 8)
    out.image.sum().backward()
    assert verts.grad is None and a.grad is not None
    v = verts.clone().requires_grad_(True)
    out2 = rasterize(v, faces, attrs, 8)
    out2.image.sum().backward()
    assert v.grad is not None and attrs.grad is None
    assert not out2.face_index.requires_grad and not out2.depth.requires_grad


def test_results_do_not_depend_on_thread_count() -> None:
    verts, faces, attrs = scene(batch=2)
    cot = torch.randn(2, 23, 31, 4, generator=torch.Generator().manual_seed(1))
    grads = []
    for threads in (1, 2, 0):
        v = verts.clone().requires_grad_(True)
        out = rasterize(v, faces, attrs, (23, 31), num_threads=threads)
        (out.image * cot).sum().backward()
        grads.append((out.image.detach(), out.face_index, v.grad))
    for other in grads[1:]:
        for x, y in zip(grads[0], other):
            assert torch.equal(x, y)


def test_cull_backfaces_drops_counter_clockwise() -> None:
    # NDC counter-clockwise (positive signed area) = back-facing under NMR conventions (ARCHITECTURE.md).
    ccw = torch.tensor([[[-0.8, -0.8, 2.0], [0.8, -0.8, 2.0], [0.0, 0.8, 2.0]]])
    cw = ccw[:, [0, 2, 1]]
    face = torch.tensor([[0, 1, 2]])
    one = torch.ones(1, 1, 1)
    assert (rasterize(ccw, face, one, 8).face_index >= 0).any()
    assert (rasterize(ccw, face, one, 8, cull_backfaces=True).face_index < 0).all()
    assert (rasterize(cw, face, one, 8, cull_backfaces=True).face_index >= 0).any()


def test_contiguous_cpu_inputs_are_not_copied() -> None:
    t = torch.rand(2, 5, 3)
    assert _to_numpy_f32(t).__array_interface__["data"][0] == t.data_ptr()
    faces = torch.zeros(4, 3, dtype=torch.int32)
    assert _to_numpy_i32(faces).__array_interface__["data"][0] == faces.data_ptr()
    # A non-contiguous or float64 tensor is converted (one copy), never mutated.
    t64 = torch.rand(5, 3, dtype=torch.float64)
    arr = _to_numpy_f32(t64.T)
    assert arr.flags["C_CONTIGUOUS"] and arr.dtype == np.float32


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_cuda_tensors_round_trip() -> None:
    verts, faces, attrs = scene()
    out = rasterize(verts.cuda(), faces.cuda(), attrs.cuda(), 8)
    assert out.image.is_cuda and out.face_index.is_cuda


NAN = float("nan")


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"verts_screen": torch.zeros(1, 5, 2)}, "verts_screen"),
        ({"verts_screen": torch.zeros(1, 5, 3, dtype=torch.int64)}, "verts_screen"),
        ({"verts_screen": torch.full((1, 5, 3), NAN)}, "verts_screen"),
        ({"verts_screen": torch.zeros(1, 0, 3)}, "verts_screen"),
        ({"faces": torch.tensor([[0, 1, 5]])}, "faces"),
        ({"faces": torch.tensor([[0, -1, 2]])}, "faces"),
        ({"faces": torch.zeros(0, 3, dtype=torch.int64)}, "faces"),
        ({"faces": torch.zeros(2, 4, dtype=torch.int64)}, "faces"),
        ({"faces": torch.zeros(3, 3)}, "faces"),
        ({"face_attrs": torch.zeros(1, 2, 4)}, "face_attrs"),
        ({"face_attrs": torch.zeros(1, 3, 0)}, "face_attrs"),
        ({"face_attrs": torch.full((1, 3, 4), float("inf"))}, "face_attrs"),
        ({"face_attrs": torch.zeros(2, 3, 4)}, "face_attrs"),
        ({"image_size": 0}, "image_size"),
        ({"image_size": 100_000}, "image_size"),
        ({"image_size": (8, 8, 8)}, "image_size"),
        ({"background": [0.0, 0.0]}, "background"),
        ({"background": [NAN] * 4}, "background"),
        ({"near": -1.0}, "near"),
        ({"near": 5.0, "far": 1.0}, "far"),
        ({"far": float("inf")}, "far"),
        ({"num_threads": -1}, "num_threads"),
    ],
)
def test_bad_input_raises_value_error_naming_argument(change: dict, match: str) -> None:
    verts, faces, attrs = scene()
    kwargs = {"verts_screen": verts, "faces": faces, "face_attrs": attrs, "image_size": 8}
    kwargs.update(change)
    with pytest.raises(ValueError, match=match):
        rasterize(**kwargs)


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"verts_screen": [[0.0, 0.0, 1.0]]}, "verts_screen"),
        ({"num_threads": "1"}, "num_threads"),
        ({"num_threads": 1.5}, "num_threads"),
        ({"num_threads": True}, "num_threads"),
        ({"image_size": 8.0}, "image_size"),
        ({"near": "0.1"}, "near"),
        ({"background": "white"}, "background"),
    ],
)
def test_wrong_types_raise_type_error_naming_argument(change: dict, match: str) -> None:
    verts, faces, attrs = scene()
    kwargs = {"verts_screen": verts, "faces": faces, "face_attrs": attrs, "image_size": 8}
    kwargs.update(change)
    with pytest.raises(TypeError, match=match):
        rasterize(**kwargs)


def test_native_module_rejects_bad_input_without_panicking() -> None:
    import meshadv._raster as native

    v = np.zeros((1, 3, 3), np.float32)
    v[0, :, 2] = 1.0
    f = np.array([[0, 1, 2]], np.int32)
    a = np.ones((1, 1, 1), np.float32)
    bg = np.zeros(1, np.float32)
    native.rasterize_forward(v, f, a, bg, 4, 4, 0.1, 10.0, False)
    bad_calls = [
        ((v, np.array([[0, 1, 7]], np.int32), a, bg, 4, 4, 0.1, 10.0, False), IndexError, "^faces: "),
        ((v, f, a, bg, 0, 4, 0.1, 10.0, False), ValueError, "^height: "),
        ((v, f, a, bg, 4, 4, 1.0, 0.5, False), ValueError, "^near/far: "),
        ((v, f, np.ones((1, 2, 1), np.float32), bg, 4, 4, 0.1, 10.0, False), ValueError, "^face_attrs: "),
        ((np.full((1, 3, 3), np.nan, np.float32), f, a, bg, 4, 4, 0.1, 10.0, False), ValueError, "^verts_screen: "),
    ]
    for args, error, match in bad_calls:
        with pytest.raises(error, match=match):
            native.rasterize_forward(*args)
    with pytest.raises(TypeError, match="^verts_screen: expected a numpy.ndarray of float32"):
        native.rasterize_forward(v.astype(np.float64), f, a, bg, 4, 4, 0.1, 10.0, False)


def test_attribute_only_backward_matches_full_backward() -> None:
    # With vertices not requiring grad the native backward may skip the vertex sweep; attribute grads must not change.
    verts, faces, attrs = scene(batch=2)
    cot = torch.randn(2, 14, 15, 4, generator=torch.Generator().manual_seed(3))
    grads = []
    for need_v in (True, False):
        v = verts.clone().requires_grad_(need_v)
        a = attrs.clone().requires_grad_(True)
        (rasterize(v, faces, a, (14, 15)).image * cot).sum().backward()
        grads.append(a.grad)
    assert torch.equal(grads[0], grads[1])


def test_huge_thread_count_is_a_value_error() -> None:
    verts, faces, attrs = scene()
    with pytest.raises(ValueError, match="num_threads"):
        rasterize(verts, faces, attrs, 8, num_threads=2**64)


def test_attributes_near_float32_max_raise_a_clear_error_instead_of_inf_gradients() -> None:
    verts, faces, attrs = scene()
    verts = verts.clone().requires_grad_(True)
    signs = torch.tensor([[1.0, -1.0, 1.0, -1.0], [-1.0, 1.0, -1.0, 1.0], [0.5, 1.0, -0.5, 1.0]])
    big = (signs * 3e38).unsqueeze(0).requires_grad_(True)
    out = rasterize(verts, faces, big, 16)
    with pytest.raises(ValueError, match="face_attrs: the vertex gradient overflows float32"):
        (out.image * torch.randn_like(out.image)).sum().backward()
    with pytest.raises(ValueError, match="beyond float32's range"):
        rasterize(verts, faces, attrs.double() * 1e300, 16)
