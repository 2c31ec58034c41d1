//! Bindings of the per-pixel surface ops: perspective-correct weights, per-corner attribute interpolation, the UV
//! texture sampled at each pixel (one pass) and the vertex gradient of images with per-pixel colours (see
//! `meshadv_raster::surface`, `meshadv_raster::textured` and `meshadv_raster::backward::image_vertex_backward`).

use meshadv_raster::backward::image_vertex_backward as core_image_vertex_backward;
use meshadv_raster::backward::Isa;
use meshadv_raster::surface::{self, CornerAttrs};
use meshadv_raster::texture::{Texture, Wrap};
use meshadv_raster::textured;
use meshadv_raster::{Projection, RasterParams, ScreenMesh};
use numpy::PyReadonlyArrayDyn;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use super::{array, expect_dim, output, run, threads, view, view_exact, PyArr, PyRasterError};

/// The screen mesh, its face-index map and the raster parameters the map was drawn with.
struct Fragments<'py> {
    verts_screen: PyReadonlyArrayDyn<'py, f32>,
    faces: PyReadonlyArrayDyn<'py, i32>,
    face_index: PyReadonlyArrayDyn<'py, i32>,
}

/// Checked views of [`Fragments`].
struct FragmentViews<'a> {
    mesh: ScreenMesh<'a>,
    face_index: &'a [i32],
    params: RasterParams,
}

impl<'py> Fragments<'py> {
    fn extract(
        verts_screen: &Bound<'py, PyAny>,
        faces: &Bound<'py, PyAny>,
        face_index: &Bound<'py, PyAny>,
    ) -> PyResult<Self> {
        Ok(Fragments {
            verts_screen: array::<f32>("verts_screen", "float32", verts_screen)?,
            faces: array::<i32>("faces", "int32", faces)?,
            face_index: array::<i32>("face_index", "int32", face_index)?,
        })
    }

    fn views(&self, near: f64, far: f64, orthographic: bool) -> PyResult<FragmentViews<'_>> {
        let (vs, vd) = view("verts_screen", &self.verts_screen, 3)?;
        expect_dim("verts_screen", &vs, 2, 3, "x_ndc, y_ndc, z_view")?;
        let (fs, fd) = view("faces", &self.faces, 2)?;
        expect_dim("faces", &fs, 1, 3, "triangles")?;
        let (is, id) = view("face_index", &self.face_index, 3)?;
        expect_dim("face_index", &is, 0, vs[0], "batch size of verts_screen")?;
        let params = RasterParams {
            height: is[1],
            width: is[2],
            near,
            far,
            cull_backfaces: false,
            projection: if orthographic {
                Projection::Orthographic
            } else {
                Projection::Perspective
            },
        };
        let mesh = ScreenMesh::new(vd, fd, vs[0], vs[1]).map_err(PyRasterError)?;
        params.validate().map_err(PyRasterError)?;
        Ok(FragmentViews {
            mesh,
            face_index: id,
            params,
        })
    }
}

/// `(B, H, W)` of a fragment map.
fn dims(v: &FragmentViews<'_>) -> [usize; 3] {
    [v.mesh.batch, v.params.height, v.params.width]
}

/// Perspective-correct barycentric weights `f32[B,H,W,3]` of the face drawn at each pixel (0 on background).
#[pyfunction]
#[pyo3(signature = (verts_screen, faces, face_index, near, far, orthographic = false, num_threads = 0))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn pixel_weights<'py>(
    py: Python<'py>,
    verts_screen: &Bound<'py, PyAny>,
    faces: &Bound<'py, PyAny>,
    face_index: &Bound<'py, PyAny>,
    near: f64,
    far: f64,
    orthographic: bool,
    num_threads: i64,
) -> PyResult<PyArr<'py, f32>> {
    let nt = threads(num_threads)?;
    let arrays = Fragments::extract(verts_screen, faces, face_index)?;
    let v = arrays.views(near, far, orthographic)?;
    let [b, h, w] = dims(&v);
    let out = run(py, nt, || {
        surface::pixel_weights(&v.mesh, &v.params, v.face_index)
    })?;
    output(py, out, &[b, h, w, 3])
}

/// Backward of `pixel_weights`: `f32[B,N,3]`, the gradient with respect to `verts_screen` (x, y and z).
#[pyfunction]
#[pyo3(signature = (verts_screen, faces, face_index, grad_weights, near, far, orthographic = false, num_threads = 0))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn pixel_weights_backward<'py>(
    py: Python<'py>,
    verts_screen: &Bound<'py, PyAny>,
    faces: &Bound<'py, PyAny>,
    face_index: &Bound<'py, PyAny>,
    grad_weights: &Bound<'py, PyAny>,
    near: f64,
    far: f64,
    orthographic: bool,
    num_threads: i64,
) -> PyResult<PyArr<'py, f32>> {
    let nt = threads(num_threads)?;
    let arrays = Fragments::extract(verts_screen, faces, face_index)?;
    let gw = array::<f32>("grad_weights", "float32", grad_weights)?;
    let v = arrays.views(near, far, orthographic)?;
    let [b, h, w] = dims(&v);
    let gw = view_exact("grad_weights", &gw, &[b, h, w, 3])?;
    let n = v.mesh.num_verts;
    let out = run(py, nt, || {
        surface::pixel_weights_backward(&v.mesh, &v.params, v.face_index, gw)
    })?;
    output(py, out, &[b, n, 3])
}

/// Per-corner attributes `values f32[Bv,A,K]` with their rows `corners i32[M,3]`.
fn corner_attrs<'a>(
    arg: &'static str,
    values: &'a PyReadonlyArrayDyn<'_, f32>,
    corners: &'a PyReadonlyArrayDyn<'_, i32>,
) -> PyResult<CornerAttrs<'a>> {
    let (vs, vd) = view(arg, values, 3)?;
    let (cs, cd) = view("corners", corners, 2)?;
    expect_dim("corners", &cs, 1, 3, "one row per face corner")?;
    Ok(CornerAttrs {
        values: vd,
        corners: cd,
        batch: vs[0],
        rows: vs[1],
        channels: vs[2],
        arg,
    })
}

/// Interpolates per-corner attributes at every pixel: `f32[B,H,W,K]`, 0 on background.
#[pyfunction]
#[pyo3(signature = (verts_screen, faces, face_index, weights, corners, values, num_threads = 0))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn interpolate<'py>(
    py: Python<'py>,
    verts_screen: &Bound<'py, PyAny>,
    faces: &Bound<'py, PyAny>,
    face_index: &Bound<'py, PyAny>,
    weights: &Bound<'py, PyAny>,
    corners: &Bound<'py, PyAny>,
    values: &Bound<'py, PyAny>,
    num_threads: i64,
) -> PyResult<PyArr<'py, f32>> {
    let nt = threads(num_threads)?;
    let arrays = Fragments::extract(verts_screen, faces, face_index)?;
    let weights = array::<f32>("weights", "float32", weights)?;
    let corners = array::<i32>("corners", "int32", corners)?;
    let values = array::<f32>("values", "float32", values)?;
    let v = arrays.views(0.0, 1.0, false)?;
    let [b, h, w] = dims(&v);
    let weights = view_exact("weights", &weights, &[b, h, w, 3])?;
    let attrs = corner_attrs("values", &values, &corners)?;
    let k = attrs.channels;
    let out = run(py, nt, || {
        surface::interpolate(&v.mesh, &v.params, v.face_index, weights, &attrs)
    })?;
    output(py, out, &[b, h, w, k])
}

/// Backward of `interpolate`: `(grad_values f32[Bv,A,K], grad_weights f32[B,H,W,3])`.
#[pyfunction]
#[pyo3(signature = (verts_screen, faces, face_index, weights, corners, values, grad, num_threads = 0))]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
pub(crate) fn interpolate_backward<'py>(
    py: Python<'py>,
    verts_screen: &Bound<'py, PyAny>,
    faces: &Bound<'py, PyAny>,
    face_index: &Bound<'py, PyAny>,
    weights: &Bound<'py, PyAny>,
    corners: &Bound<'py, PyAny>,
    values: &Bound<'py, PyAny>,
    grad: &Bound<'py, PyAny>,
    num_threads: i64,
) -> PyResult<(PyArr<'py, f32>, PyArr<'py, f32>)> {
    let nt = threads(num_threads)?;
    let arrays = Fragments::extract(verts_screen, faces, face_index)?;
    let weights = array::<f32>("weights", "float32", weights)?;
    let corners = array::<i32>("corners", "int32", corners)?;
    let values = array::<f32>("values", "float32", values)?;
    let grad = array::<f32>("grad", "float32", grad)?;
    let v = arrays.views(0.0, 1.0, false)?;
    let [b, h, w] = dims(&v);
    let weights = view_exact("weights", &weights, &[b, h, w, 3])?;
    let attrs = corner_attrs("values", &values, &corners)?;
    let grad = view_exact("grad", &grad, &[b, h, w, attrs.channels])?;
    let g = run(py, nt, || {
        surface::interpolate_backward(&v.mesh, &v.params, v.face_index, weights, &attrs, grad)
    })?;
    Ok((
        output(
            py,
            g.grad_values,
            &[attrs.batch, attrs.rows, attrs.channels],
        )?,
        output(py, g.grad_weights, &[b, h, w, 3])?,
    ))
}

/// `"repeat"` or `"clamp"`.
fn wrap_mode(wrap: &str) -> PyResult<Wrap> {
    match wrap {
        "repeat" => Ok(Wrap::Repeat),
        "clamp" => Ok(Wrap::Clamp),
        other => Err(PyValueError::new_err(format!(
            "wrap: expected 'repeat' or 'clamp', got {other:?}"
        ))),
    }
}

/// A texture `f32[Bt,Ht,Wt,C]`.
fn texture_view<'a>(a: &'a PyReadonlyArrayDyn<'_, f32>, wrap: &str) -> PyResult<Texture<'a>> {
    let (ts, td) = view("texture", a, 4)?;
    Ok(Texture {
        texels: td,
        batch: ts[0],
        height: ts[1],
        width: ts[2],
        channels: ts[3],
        wrap: wrap_mode(wrap)?,
    })
}

/// The drawn faces' UV planes of one `sample_uv_texture` call, for its backward (opaque; built once from the
/// forward's checked inputs, see `meshadv_raster::textured::UvTexturePlanes`).
#[pyclass(frozen, module = "meshadv._raster", name = "UvTexturePlanes")]
pub(crate) struct UvTexturePlanes(textured::UvTexturePlanes);

/// The texture `f32[Bt,Ht,Wt,C]` sampled (bilinear) at each pixel's perspective-correct UV: `(f32[B,H,W,C], 0 on
/// background; the UV planes for `sample_uv_texture_backward`)`; `uvs f32[Bv,T,2]` with their rows `corners
/// i32[M,3]`; `wrap` is `"repeat"` or `"clamp"`.
#[pyfunction]
#[pyo3(signature = (verts_screen, faces, face_index, corners, uvs, texture, near, far, orthographic = false,
                    wrap = "repeat", num_threads = 0))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn sample_uv_texture<'py>(
    py: Python<'py>,
    verts_screen: &Bound<'py, PyAny>,
    faces: &Bound<'py, PyAny>,
    face_index: &Bound<'py, PyAny>,
    corners: &Bound<'py, PyAny>,
    uvs: &Bound<'py, PyAny>,
    texture: &Bound<'py, PyAny>,
    near: f64,
    far: f64,
    orthographic: bool,
    wrap: &str,
    num_threads: i64,
) -> PyResult<(PyArr<'py, f32>, UvTexturePlanes)> {
    let nt = threads(num_threads)?;
    let arrays = Fragments::extract(verts_screen, faces, face_index)?;
    let corners = array::<i32>("corners", "int32", corners)?;
    let uvs = array::<f32>("uvs", "float32", uvs)?;
    let texture = array::<f32>("texture", "float32", texture)?;
    let v = arrays.views(near, far, orthographic)?;
    let [b, h, w] = dims(&v);
    let attrs = corner_attrs("uvs", &uvs, &corners)?;
    let tex = texture_view(&texture, wrap)?;
    let (out, planes) = run(py, nt, || {
        let planes =
            textured::UvTexturePlanes::new(&v.mesh, &v.params, v.face_index, &attrs, &tex)?;
        Ok((planes.sample(Isa::detect(), v.face_index, &tex)?, planes))
    })?;
    Ok((
        output(py, out, &[b, h, w, tex.channels])?,
        UvTexturePlanes(planes),
    ))
}

/// Backward of `sample_uv_texture` with the `planes` it returned and its `face_index` and `texture` (and `wrap`):
/// `(grad_texture f32[Bt,Ht,Wt,C], grad_uvs f32[Bv,T,2], grad_verts_screen f32[B,N,3])`, the last at fixed face
/// assignment (the UVs moving with the vertices).
#[pyfunction]
#[pyo3(signature = (planes, face_index, texture, grad, wrap = "repeat", num_threads = 0))]
#[allow(clippy::type_complexity)]
pub(crate) fn sample_uv_texture_backward<'py>(
    py: Python<'py>,
    planes: &Bound<'py, UvTexturePlanes>,
    face_index: &Bound<'py, PyAny>,
    texture: &Bound<'py, PyAny>,
    grad: &Bound<'py, PyAny>,
    wrap: &str,
    num_threads: i64,
) -> PyResult<(PyArr<'py, f32>, PyArr<'py, f32>, PyArr<'py, f32>)> {
    let nt = threads(num_threads)?;
    let planes = &planes.get().0;
    let face_index = array::<i32>("face_index", "int32", face_index)?;
    let texture = array::<f32>("texture", "float32", texture)?;
    let grad = array::<f32>("grad", "float32", grad)?;
    let (is, fi) = view("face_index", &face_index, 3)?;
    let tex = texture_view(&texture, wrap)?;
    let grad = view_exact("grad", &grad, &[is[0], is[1], is[2], tex.channels])?;
    let g = run(py, nt, || planes.backward(Isa::detect(), fi, &tex, grad))?;
    let [uv_batch, uv_rows] = planes.uv_shape();
    Ok((
        output(
            py,
            g.grad_texels,
            &[tex.batch, tex.height, tex.width, tex.channels],
        )?,
        output(py, g.grad_uvs, &[uv_batch, uv_rows, 2])?,
        output(py, g.grad_verts_screen, &[is[0], planes.num_verts(), 3])?,
    ))
}

/// NMR's vertex gradient `f32[B,N,3]` (z = 0) of an image with per-pixel colours `image f32[B,H,W,C]` drawn with
/// the fragments `face_index`, for its cotangent `grad_image`; `sweep_radius` as in `rasterize_backward` (`None`:
/// NMR's sweeps, `r >= 1`: the local gradient).
#[pyfunction]
#[pyo3(signature = (verts_screen, faces, face_index, image, grad_image, near, far, cull_backfaces,
                    orthographic = false, num_threads = 0, sweep_radius = None))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn image_vertex_backward<'py>(
    py: Python<'py>,
    verts_screen: &Bound<'py, PyAny>,
    faces: &Bound<'py, PyAny>,
    face_index: &Bound<'py, PyAny>,
    image: &Bound<'py, PyAny>,
    grad_image: &Bound<'py, PyAny>,
    near: f64,
    far: f64,
    cull_backfaces: bool,
    orthographic: bool,
    num_threads: i64,
    sweep_radius: Option<i64>,
) -> PyResult<PyArr<'py, f32>> {
    let nt = threads(num_threads)?;
    let visibility = super::visibility(sweep_radius)?;
    let arrays = Fragments::extract(verts_screen, faces, face_index)?;
    let image = array::<f32>("image", "float32", image)?;
    let grad_image = array::<f32>("grad_image", "float32", grad_image)?;
    let mut v = arrays.views(near, far, orthographic)?;
    v.params.cull_backfaces = cull_backfaces;
    let [b, h, w] = dims(&v);
    let (ims, _) = view("image", &image, 4)?;
    let c = ims[3];
    let image = view_exact("image", &image, &[b, h, w, c])?;
    let grad_image = view_exact("grad_image", &grad_image, &[b, h, w, c])?;
    let n = v.mesh.num_verts;
    let out = run(py, nt, || {
        core_image_vertex_backward(
            &v.mesh,
            &v.params,
            v.face_index,
            image,
            grad_image,
            c,
            visibility,
        )
    })?;
    output(py, out, &[b, n, 3])
}
