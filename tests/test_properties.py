"""Property-based tests (Hypothesis) over the public API's argument types and values.

The contract checked everywhere: a call either succeeds with a sane (finite, correctly shaped) result or raises
exactly the documented exception type — ``TypeError`` for a wrong type, ``ValueError`` for a bad value, ``IndexError``
for an index, ``MeshLoadError`` (a ``ValueError``) for a bad file — never anything else, never a crash. The example
budget comes from the ``ci`` profile registered in ``tests/conftest.py`` (``HYPOTHESIS_PROFILE=fuzz`` for more).
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path
from typing import Any

import pytest
import torch

hypothesis = pytest.importorskip("hypothesis", reason="hypothesis is a test dependency (requirements.txt)")
from hypothesis import assume, given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from meshadv import _validate  # noqa: E402
from meshadv.mesh import MeshLoadError, builtin_mesh, load_mesh  # noqa: E402
from meshadv.mesh.normalize import normalize_mesh  # noqa: E402
from meshadv.render import Camera, Lights  # noqa: E402
from meshadv.render.rasterize import native_available, parse_image_size, rasterize  # noqa: E402

ANYTHING = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.complex_numbers(),
    st.text(max_size=5),
    st.lists(st.integers(-5, 5), max_size=3),
)
FLOAT32_SAFE = st.floats(min_value=-1e30, max_value=1e30, allow_nan=False, allow_infinity=False)


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


@given(ANYTHING)
def test_positive_int_returns_or_raises_the_documented_type(value: Any) -> None:
    if not _is_int(value):
        with pytest.raises(TypeError, match="^n must be an integer"):
            _validate.positive_int("n", value)
    elif value < 1:
        with pytest.raises(ValueError, match="^n must be an integer >= 1"):
            _validate.positive_int("n", value)
    else:
        assert _validate.positive_int("n", value) == value


@given(ANYTHING)
def test_finite_float_returns_or_raises_the_documented_type(value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        with pytest.raises(TypeError, match="^x must be a real number"):
            _validate.finite_float("x", value)
    elif not math.isfinite(float(value)):
        with pytest.raises(ValueError, match="^x must be finite"):
            _validate.finite_float("x", value)
    else:
        assert _validate.finite_float("x", value) == float(value)


@given(st.lists(st.text(min_size=1, max_size=8), min_size=1, max_size=6, unique=True), st.data())
def test_choice_accepts_every_option_and_refuses_anything_else(options: list, data: st.DataObject) -> None:
    pick = data.draw(st.sampled_from(options))
    assert _validate.choice("kind", pick, options) == pick
    other = data.draw(st.text(max_size=8))
    assume(other not in options)
    with pytest.raises(ValueError, match="^kind must be one of"):
        _validate.choice("kind", other, options)


@given(ANYTHING)
def test_image_size_is_a_pair_or_a_documented_error(value: Any) -> None:
    try:
        h, w = parse_image_size(value)
    except (TypeError, ValueError) as exc:
        assert str(exc).startswith("image_size")
        expected = TypeError if not (_is_int(value) or isinstance(value, list)) else None
        if expected is not None:
            assert isinstance(exc, expected)
    else:
        assert 1 <= h <= 16384 and 1 <= w <= 16384


@given(st.tuples(FLOAT32_SAFE, FLOAT32_SAFE, FLOAT32_SAFE), st.tuples(FLOAT32_SAFE, FLOAT32_SAFE, FLOAT32_SAFE))
def test_look_at_gives_an_orthonormal_rotation_or_a_value_error(eye: tuple, up: tuple) -> None:
    try:
        cam = Camera.look_at(eye, at=(0.0, 0.0, 0.0), up=up)
    except ValueError as exc:
        assert any(word in str(exc) for word in ("eye and at", "up must", "overflows"))
        return
    rot = cam.rotation()[0].double()
    assert torch.isfinite(rot).all()
    torch.testing.assert_close(rot @ rot.T, torch.eye(3, dtype=torch.float64), atol=1e-4, rtol=0)


@given(st.floats(allow_nan=True, allow_infinity=True), st.floats(allow_nan=True, allow_infinity=True))
def test_spherical_camera_is_finite_or_a_value_error(distance: float, azimuth: float) -> None:
    try:
        cam = Camera.spherical(distance, azimuth=azimuth, elevation=10.0)
    except ValueError as exc:
        assert "distance" in str(exc) or "azimuth" in str(exc)
        dist32, az32 = (float(torch.tensor(v, dtype=torch.float32)) for v in (distance, azimuth))
        assert not (math.isfinite(dist32) and math.isfinite(az32) and dist32 > 0)
        return
    assert torch.isfinite(cam.rotation()).all() and torch.isfinite(cam.eye()).all()


@given(st.one_of(st.lists(st.integers(-4, 4), max_size=4), st.integers(-4, 4), st.lists(st.floats(), max_size=2)))
def test_light_indexing_selects_or_raises_the_documented_type(index: Any) -> None:
    lights = Lights.default(Camera.spherical(2.0, azimuth=[0.0, 90.0, 180.0]))
    if isinstance(index, list) and any(isinstance(i, float) for i in index):
        with pytest.raises(TypeError, match="^lights index"):
            lights[index]
        return
    items = index if isinstance(index, list) else [index]
    if not items:
        with pytest.raises(ValueError, match="selects no items"):
            lights[index]
    elif any(not -3 <= i < 3 for i in items):
        with pytest.raises(IndexError, match="out of range"):
            lights[index]
    else:
        assert len(lights[index]) == len(items)


@given(st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-3, 3), st.text(max_size=3)))
def test_normalize_mesh_extent_gives_finite_vertices_or_a_documented_error(extent: Any) -> None:
    cube = builtin_mesh("cube")
    try:
        mesh, _ = normalize_mesh(cube, extent=extent)
    except TypeError as exc:
        assert isinstance(extent, str) and str(exc).startswith("extent must be"), exc
        return
    except ValueError as exc:
        assert not (isinstance(extent, (int, float)) and math.isfinite(extent) and 0 < extent <= 1e30)
        assert str(exc).startswith("extent must be"), exc
        return
    assert torch.isfinite(mesh.vertices).all()
    assert float(mesh.vertices.abs().max()) == pytest.approx(float(extent), rel=1e-5)


@pytest.mark.skipif(not native_available(), reason="native module not built")
@given(ANYTHING)
def test_rasterize_thread_count_is_validated_before_the_native_call(num_threads: Any) -> None:
    verts = torch.tensor([[[-0.9, -0.9, 1.0], [0.9, -0.9, 1.0], [0.0, 0.9, 1.0]]])
    faces, attrs = torch.tensor([[0, 2, 1]]), torch.ones(1, 1, 1)
    if not _is_int(num_threads):
        with pytest.raises(TypeError, match="^num_threads"):
            rasterize(verts, faces, attrs, 4, num_threads=num_threads)
    elif not 0 <= num_threads <= 4:  # keep the pools small: large valid counts are tested elsewhere
        if num_threads < 0 or num_threads > _validate.MAX_THREADS:
            with pytest.raises(ValueError, match="^num_threads"):
                rasterize(verts, faces, attrs, 4, num_threads=num_threads)
    else:
        assert rasterize(verts, faces, attrs, 4, num_threads=num_threads).image.shape == (1, 4, 4, 1)


MESH_LINES = st.sampled_from(
    [
        "v 0 0 0", "v 1 0 0", "v 0 1 0", "v 0 1", "v nan 0 0", "f 1 2 3", "f 0 1 2", "f 1 2 9", "f -1 -2 -3",
        "OFF", "3 1 0", "4 1 0", "3 0 1 2", "3 0 1 18446744073709551615", "18446744073709551615 0 1 2", "0 0 0",
        "1 0 0", "0 1 0", "ply", "format ascii 1.0", "element vertex 3", "element face 1", "property float x",
        "property float y", "property float z", "property list uchar int vertex_indices", "end_header", "",
        "# comment", "mtllib missing.mtl", "usemtl a",
    ]
)  # fmt: skip


@given(st.lists(MESH_LINES, max_size=14), st.sampled_from([".obj", ".off", ".ply"]))
def test_mesh_files_load_or_raise_mesh_load_error(lines: list, suffix: str) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"m{suffix}"
        path.write_text("\n".join(lines) + "\n")
        try:
            mesh = load_mesh(path)
        except MeshLoadError as exc:
            assert str(path) in str(exc)
            return
    assert mesh.num_faces >= 1 and torch.isfinite(mesh.vertices).all()
    assert int(mesh.faces.min()) >= 0 and int(mesh.faces.max()) < mesh.num_vertices
