//! `meshadv._raster`: thin PyO3 bindings of the `meshadv-raster` core.
//!
//! Arrays come in read-only and zero-copy (C-contiguous float32 / int32 required), are validated while holding the
//! GIL, and the work runs with the GIL released. Results are moved into new NumPy arrays without copying. Core errors
//! become `ValueError` / `IndexError` naming the argument; a panic (a bug) becomes `RuntimeError`.

use std::panic::{catch_unwind, AssertUnwindSafe};

mod flat;
mod surface;

use meshadv_raster::backward::Visibility;
use meshadv_raster::boxfilter::{self, BoxShape};
use meshadv_raster::camera::SphericalCamera;
use meshadv_raster::pipeline::{render, Lights, RenderSettings};
use meshadv_raster::raycast::{raycast as core_raycast, RayCamera};
use meshadv_raster::{
    rasterize, rasterize_backward as core_backward, with_threads, BackwardInputs, ErrorKind,
    FaceAttrs, Projection, RasterError, RasterParams, ScreenMesh,
};
use numpy::ndarray::{Array, IxDyn};
use numpy::{
    Element, IntoPyArray, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyIndexError, PyMemoryError, PyRuntimeError, PyTypeError, PyValueError};
use pyo3::prelude::*;

/// Local newtype so the core error converts into precise Python exceptions.
struct PyRasterError(RasterError);

impl From<PyRasterError> for PyErr {
    fn from(e: PyRasterError) -> PyErr {
        let msg = e.0.to_string();
        match e.0.kind() {
            ErrorKind::Index => PyIndexError::new_err(msg),
            ErrorKind::Value => PyValueError::new_err(msg),
            ErrorKind::Memory => PyMemoryError::new_err(msg),
        }
    }
}

impl From<RasterError> for PyRasterError {
    fn from(e: RasterError) -> Self {
        PyRasterError(e)
    }
}

type PyArr<'py, T> = Bound<'py, PyArrayDyn<T>>;

/// Casts `obj` to a read-only NumPy array of `T` (no copy), or raises `TypeError` naming the argument.
fn array<'py, T: Element>(
    arg: &str,
    dtype: &str,
    obj: &Bound<'py, PyAny>,
) -> PyResult<PyReadonlyArrayDyn<'py, T>> {
    let a = obj.cast::<PyArrayDyn<T>>().map_err(|_| {
        let got = match obj.getattr("dtype") {
            Ok(d) => format!("an array of {d}"),
            Err(_) => obj
                .get_type()
                .name()
                .map(|n| n.to_string())
                .unwrap_or_else(|_| "another type".into()),
        };
        PyTypeError::new_err(format!(
            "{arg}: expected a numpy.ndarray of {dtype}, got {got}"
        ))
    })?;
    a.try_readonly()
        .map_err(|e| PyValueError::new_err(format!("{arg}: cannot borrow the array: {e}")))
}

/// Borrowed view of an input array: its shape and its contiguous data.
fn view<'a, T: Element>(
    arg: &str,
    a: &'a PyReadonlyArrayDyn<'_, T>,
    ndim: usize,
) -> PyResult<(Vec<usize>, &'a [T])> {
    let shape = a.shape().to_vec();
    if shape.len() != ndim {
        return Err(PyValueError::new_err(format!(
            "{arg}: expected {ndim} dimensions, got shape {shape:?}"
        )));
    }
    let data = a.as_slice().map_err(|_| {
        PyValueError::new_err(format!(
            "{arg}: array must be C-contiguous (use np.ascontiguousarray)"
        ))
    })?;
    Ok((shape, data))
}

/// A C-contiguous view whose shape must equal `expected` exactly (e.g. a forward output fed back to backward).
fn view_exact<'a, T: Element>(
    arg: &str,
    a: &'a PyReadonlyArrayDyn<'_, T>,
    expected: &[usize],
) -> PyResult<&'a [T]> {
    let (shape, data) = view(arg, a, expected.len())?;
    if shape != expected {
        let want: Vec<String> = expected.iter().map(|d| d.to_string()).collect();
        return Err(PyValueError::new_err(format!(
            "{arg}: expected shape ({}), got {shape:?}",
            want.join(", ")
        )));
    }
    Ok(data)
}

fn expect_dim(arg: &str, shape: &[usize], axis: usize, want: usize, what: &str) -> PyResult<()> {
    if shape[axis] != want {
        return Err(PyValueError::new_err(format!(
            "{arg}: dimension {axis} must be {want} ({what}), got shape {shape:?}"
        )));
    }
    Ok(())
}

fn image_size(arg: &'static str, v: i64) -> PyResult<usize> {
    Ok(meshadv_raster::input::check_image_size(arg, v).map_err(PyRasterError)?)
}

fn threads(num_threads: i64) -> PyResult<usize> {
    if num_threads < 0 {
        return Err(PyValueError::new_err(format!(
            "num_threads: must be >= 0 (0 = default), got {num_threads}"
        )));
    }
    Ok(num_threads as usize)
}

fn output<'py, T: Element>(
    py: Python<'py>,
    data: Vec<T>,
    shape: &[usize],
) -> PyResult<Bound<'py, PyArrayDyn<T>>> {
    let arr = Array::from_shape_vec(IxDyn(shape), data).map_err(|e| {
        PyRuntimeError::new_err(format!("internal error: output shape {shape:?}: {e}"))
    })?;
    Ok(arr.into_pyarray(py))
}

/// Runs `f` without the GIL, on `num_threads` threads, turning panics into `RuntimeError`.
fn run<R: Send>(
    py: Python<'_>,
    num_threads: usize,
    f: impl FnOnce() -> Result<R, RasterError> + Send,
) -> PyResult<R> {
    let res = py.detach(|| catch_unwind(AssertUnwindSafe(|| with_threads(num_threads, f))));
    match res {
        Ok(Ok(Ok(r))) => Ok(r),
        Ok(Ok(Err(e))) | Ok(Err(e)) => Err(PyRasterError(e).into()),
        Err(_) => Err(PyRuntimeError::new_err(
            "meshadv._raster: internal error (panic) in the raster core",
        )),
    }
}

/// Checked views of the arguments shared by the forward and backward op.
struct OpArgs<'a> {
    mesh: ScreenMesh<'a>,
    attrs: FaceAttrs<'a>,
    params: RasterParams,
}

impl OpArgs<'_> {
    /// `(batch, height, width, channels)` of the op's image.
    fn dims(&self) -> (usize, usize, usize, usize) {
        (
            self.mesh.batch,
            self.params.height,
            self.params.width,
            self.attrs.channels,
        )
    }
}

/// The four input arrays shared by the forward and backward op, borrowed read-only from Python.
struct OpArrays<'py> {
    verts_screen: PyReadonlyArrayDyn<'py, f32>,
    faces: PyReadonlyArrayDyn<'py, i32>,
    face_attrs: PyReadonlyArrayDyn<'py, f32>,
    background: PyReadonlyArrayDyn<'py, f32>,
}

impl<'py> OpArrays<'py> {
    /// Casts the Python arguments (no copy), raising `TypeError` naming the first wrong one.
    fn extract(
        verts_screen: &Bound<'py, PyAny>,
        faces: &Bound<'py, PyAny>,
        face_attrs: &Bound<'py, PyAny>,
        background: &Bound<'py, PyAny>,
    ) -> PyResult<Self> {
        Ok(OpArrays {
            verts_screen: array::<f32>("verts_screen", "float32", verts_screen)?,
            faces: array::<i32>("faces", "int32", faces)?,
            face_attrs: array::<f32>("face_attrs", "float32", face_attrs)?,
            background: array::<f32>("background", "float32", background)?,
        })
    }

    /// Checks shapes and scalar parameters and returns the core's views of the arrays.
    fn args(
        &self,
        height: i64,
        width: i64,
        near: f64,
        far: f64,
        cull_backfaces: bool,
        orthographic: bool,
    ) -> PyResult<OpArgs<'_>> {
        let OpArrays {
            verts_screen,
            faces,
            face_attrs,
            background,
        } = self;
        let (vs, vd) = view("verts_screen", verts_screen, 3)?;
        expect_dim("verts_screen", &vs, 2, 3, "x_ndc, y_ndc, z_view")?;
        let (fs, fd) = view("faces", faces, 2)?;
        expect_dim("faces", &fs, 1, 3, "triangles")?;
        let (as_, ad) = view("face_attrs", face_attrs, 3)?;
        expect_dim("face_attrs", &as_, 0, vs[0], "batch size of verts_screen")?;
        expect_dim("face_attrs", &as_, 1, fs[0], "number of faces")?;
        let (bs, bd) = view("background", background, 1)?;
        expect_dim("background", &bs, 0, as_[2], "channels of face_attrs")?;
        let params = RasterParams {
            height: image_size("height", height)?,
            width: image_size("width", width)?,
            near,
            far,
            cull_backfaces,
            projection: if orthographic {
                Projection::Orthographic
            } else {
                Projection::Perspective
            },
        };
        let mesh = ScreenMesh::new(vd, fd, vs[0], vs[1]).map_err(PyRasterError)?;
        let attrs = FaceAttrs {
            values: ad,
            background: bd,
            channels: as_[2],
        };
        mesh.validate().map_err(PyRasterError)?;
        params.validate().map_err(PyRasterError)?;
        attrs.validate(&mesh).map_err(PyRasterError)?;
        Ok(OpArgs {
            mesh,
            attrs,
            params,
        })
    }
}

/// The vertex gradient named by the bindings' `sweep_radius`: `None` NMR's, `r >= 1` the local one.
fn visibility(sweep_radius: Option<i64>) -> PyResult<Visibility> {
    match sweep_radius {
        None => Ok(Visibility::Nmr),
        Some(r) if r >= 1 => Ok(Visibility::Local {
            radius: usize::try_from(r).unwrap_or(usize::MAX),
        }),
        Some(r) => Err(PyValueError::new_err(format!(
            "sweep_radius: must be None (NMR's gradient) or an int >= 1, got {r}"
        ))),
    }
}

/// Rasterizes screen-space triangles with per-face attributes (see docs/ARCHITECTURE.md, "The native op").
///
/// Returns `(image f32[B,H,W,C], face_index i32[B,H,W], depth f32[B,H,W])`.
#[pyfunction]
#[pyo3(signature = (verts_screen, faces, face_attrs, background, height, width, near, far, cull_backfaces,
                    num_threads = 0, orthographic = false))]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
fn rasterize_forward<'py>(
    py: Python<'py>,
    verts_screen: &Bound<'py, PyAny>,
    faces: &Bound<'py, PyAny>,
    face_attrs: &Bound<'py, PyAny>,
    background: &Bound<'py, PyAny>,
    height: i64,
    width: i64,
    near: f64,
    far: f64,
    cull_backfaces: bool,
    num_threads: i64,
    orthographic: bool,
) -> PyResult<(PyArr<'py, f32>, PyArr<'py, i32>, PyArr<'py, f32>)> {
    let nt = threads(num_threads)?;
    let arrays = OpArrays::extract(verts_screen, faces, face_attrs, background)?;
    let a = arrays.args(height, width, near, far, cull_backfaces, orthographic)?;
    let (b, h, w, c) = a.dims();
    let out = run(py, nt, || rasterize(&a.mesh, &a.attrs, &a.params))?;
    Ok((
        output(py, out.image, &[b, h, w, c])?,
        output(py, out.face_index, &[b, h, w])?,
        output(py, out.depth, &[b, h, w])?,
    ))
}

/// Backward of `rasterize_forward`: `(grad_verts_screen f32[B,N,3] (z = 0), grad_face_attrs f32[B,M,C])`.
///
/// The vertex gradient is NMR's approximate rasterization gradient, defined in docs/NMR_GRADIENT.md, or with
/// `sweep_radius=r` (an int >= 1) the local gradient of docs/LOCAL_GRADIENT.md, NMR's sweeps truncated to the `r`
/// pixels nearest each edge; with `vertex_grad=False` it is skipped (returned as zeros), which makes texture-only
/// backward passes cheap.
#[pyfunction]
#[pyo3(signature = (verts_screen, faces, face_attrs, background, height, width, near, far, cull_backfaces,
                    face_index, image, grad_image, num_threads = 0, orthographic = false, vertex_grad = true,
                    sweep_radius = None))]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
fn rasterize_backward<'py>(
    py: Python<'py>,
    verts_screen: &Bound<'py, PyAny>,
    faces: &Bound<'py, PyAny>,
    face_attrs: &Bound<'py, PyAny>,
    background: &Bound<'py, PyAny>,
    height: i64,
    width: i64,
    near: f64,
    far: f64,
    cull_backfaces: bool,
    face_index: &Bound<'py, PyAny>,
    image: &Bound<'py, PyAny>,
    grad_image: &Bound<'py, PyAny>,
    num_threads: i64,
    orthographic: bool,
    vertex_grad: bool,
    sweep_radius: Option<i64>,
) -> PyResult<(PyArr<'py, f32>, PyArr<'py, f32>)> {
    let nt = threads(num_threads)?;
    let visibility = visibility(sweep_radius)?;
    let arrays = OpArrays::extract(verts_screen, faces, face_attrs, background)?;
    let face_index = array::<i32>("face_index", "int32", face_index)?;
    let image = array::<f32>("image", "float32", image)?;
    let grad_image = array::<f32>("grad_image", "float32", grad_image)?;
    let a = arrays.args(height, width, near, far, cull_backfaces, orthographic)?;
    let (b, h, w, c) = a.dims();
    let inputs = BackwardInputs {
        face_index: view_exact("face_index", &face_index, &[b, h, w])?,
        image: view_exact("image", &image, &[b, h, w, c])?,
        grad_image: view_exact("grad_image", &grad_image, &[b, h, w, c])?,
        vertex_grad,
        visibility,
    };
    let n = a.mesh.num_verts;
    let m = a.mesh.num_faces();
    let g = run(py, nt, || {
        core_backward(&a.mesh, &a.attrs, &a.params, &inputs)
    })?;
    Ok((
        output(py, g.grad_verts_screen, &[b, n, 3])?,
        output(py, g.grad_face_attrs, &[b, m, c])?,
    ))
}

/// The `k x k` block averages of a supersampled image `f32[B, kH, kW, C]`: `f32[B, H, W, C]`, the bits of torch's
/// `avg_pool2d(x, k, k)` (see `meshadv_raster::boxfilter`).
#[pyfunction]
#[pyo3(signature = (image, k, num_threads = 0))]
fn box_downsample<'py>(
    py: Python<'py>,
    image: &Bound<'py, PyAny>,
    k: i64,
    num_threads: i64,
) -> PyResult<PyArr<'py, f32>> {
    let nt = threads(num_threads)?;
    let image = array::<f32>("image", "float32", image)?;
    let (dims, data) = view("image", &image, 4)?;
    let shape = BoxShape::of_full("image", dims4(&dims), block_side(k)?).map_err(PyRasterError)?;
    let out = run(py, nt, || boxfilter::box_downsample(data, &shape))?;
    output(py, out, &shape.filtered_dims())
}

/// The adjoint of `box_downsample`: the cotangent `f32[B, H, W, C]` of the filtered image, each value divided by
/// `k * k` and given to every sample of its block: `f32[B, kH, kW, C]` (the bits of `avg_pool2d`'s backward).
#[pyfunction]
#[pyo3(signature = (grad, k, num_threads = 0))]
fn box_spread<'py>(
    py: Python<'py>,
    grad: &Bound<'py, PyAny>,
    k: i64,
    num_threads: i64,
) -> PyResult<PyArr<'py, f32>> {
    let nt = threads(num_threads)?;
    let grad = array::<f32>("grad", "float32", grad)?;
    let (dims, data) = view("grad", &grad, 4)?;
    let shape =
        BoxShape::of_filtered("grad", dims4(&dims), block_side(k)?).map_err(PyRasterError)?;
    let out = run(py, nt, || boxfilter::box_spread(data, &shape))?;
    output(py, out, &shape.full_dims())
}

/// The box filter's block side `k` as a count (a negative one is the same error the core gives out of range).
fn block_side(k: i64) -> PyResult<usize> {
    usize::try_from(k).map_err(|_| {
        PyValueError::new_err(format!(
            "k: the block side must be in [1, {}], got {k}",
            boxfilter::MAX_BLOCK
        ))
    })
}

/// The shape of a 4-dimensional array (checked by `view`) as an array.
fn dims4(dims: &[usize]) -> [usize; 4] {
    [dims[0], dims[1], dims[2], dims[3]]
}

/// Exact BVH ray cast of view-space triangles: one primary ray through each pixel centre.
///
/// Returns `(face_index i32[B,H,W], depth f32[B,H,W])`, equal to the rasterizer's output for the same camera except
/// at exact ties and pixel centres within rounding of an edge.
#[pyfunction]
#[pyo3(signature = (verts_view, faces, height, width, viewing_angle = 30.0, near = 0.1, far = 100.0,
                    orthographic = false, ortho_scale = 1.0, cull_backfaces = false, num_threads = 0))]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
fn raycast<'py>(
    py: Python<'py>,
    verts_view: &Bound<'py, PyAny>,
    faces: &Bound<'py, PyAny>,
    height: i64,
    width: i64,
    viewing_angle: f64,
    near: f64,
    far: f64,
    orthographic: bool,
    ortho_scale: f64,
    cull_backfaces: bool,
    num_threads: i64,
) -> PyResult<(PyArr<'py, i32>, PyArr<'py, f32>)> {
    let nt = threads(num_threads)?;
    let verts_view = array::<f32>("verts_view", "float32", verts_view)?;
    let faces = array::<i32>("faces", "int32", faces)?;
    let (vs, vd) = view("verts_view", &verts_view, 3)?;
    expect_dim("verts_view", &vs, 2, 3, "x, y, z in view space")?;
    let (fs, fd) = view("faces", &faces, 2)?;
    expect_dim("faces", &fs, 1, 3, "triangles")?;
    let mesh = ScreenMesh::new(vd, fd, vs[0], vs[1]).map_err(PyRasterError)?;
    let params = RasterParams {
        height: image_size("height", height)?,
        width: image_size("width", width)?,
        near,
        far,
        cull_backfaces,
        projection: if orthographic {
            Projection::Orthographic
        } else {
            Projection::Perspective
        },
    };
    let cam = RayCamera {
        viewing_angle,
        orthographic,
        ortho_scale,
    };
    let (b, h, w) = (vs[0], params.height, params.width);
    let out = run(py, nt, || core_raycast(&mesh, &cam, &params))?;
    Ok((
        output(py, out.face_index, &[b, h, w])?,
        output(py, out.depth, &[b, h, w])?,
    ))
}

/// Full forward render of one view in the core (camera + Lambert shading + raster), for cross-checks.
///
/// Returns `(image f32[H,W,3], alpha f32[H,W], depth f32[H,W], face_index i32[H,W])`.
#[pyfunction]
#[pyo3(signature = (verts_world, faces, face_colors, height, width, distance, azimuth, elevation, tilt = 0.0,
                    viewing_angle = 30.0, near = 0.1, far = 100.0, orthographic = false, ortho_scale = 1.0,
                    light_directions = None, light_colors = None, ambient = None, background = None,
                    fill_back = true, num_threads = 0))]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
fn render_full<'py>(
    py: Python<'py>,
    verts_world: &Bound<'py, PyAny>,
    faces: &Bound<'py, PyAny>,
    face_colors: &Bound<'py, PyAny>,
    height: i64,
    width: i64,
    distance: f64,
    azimuth: f64,
    elevation: f64,
    tilt: f64,
    viewing_angle: f64,
    near: f64,
    far: f64,
    orthographic: bool,
    ortho_scale: f64,
    light_directions: Option<&Bound<'py, PyAny>>,
    light_colors: Option<&Bound<'py, PyAny>>,
    ambient: Option<&Bound<'py, PyAny>>,
    background: Option<&Bound<'py, PyAny>>,
    fill_back: bool,
    num_threads: i64,
) -> PyResult<(
    PyArr<'py, f32>,
    PyArr<'py, f32>,
    PyArr<'py, f32>,
    PyArr<'py, i32>,
)> {
    let nt = threads(num_threads)?;
    let verts_world = array::<f32>("verts_world", "float32", verts_world)?;
    let faces = array::<i32>("faces", "int32", faces)?;
    let face_colors = array::<f32>("face_colors", "float32", face_colors)?;
    let light_directions = light_directions
        .map(|o| array::<f32>("light_directions", "float32", o))
        .transpose()?;
    let light_colors = light_colors
        .map(|o| array::<f32>("light_colors", "float32", o))
        .transpose()?;
    let ambient = ambient
        .map(|o| array::<f32>("ambient", "float32", o))
        .transpose()?;
    let background = background
        .map(|o| array::<f32>("background", "float32", o))
        .transpose()?;
    let (vs, vd) = view("verts_world", &verts_world, 2)?;
    expect_dim("verts_world", &vs, 1, 3, "x, y, z")?;
    let (fs, fd) = view("faces", &faces, 2)?;
    expect_dim("faces", &fs, 1, 3, "triangles")?;
    let (cs, cd) = view("face_colors", &face_colors, 2)?;
    if cs != [fs[0], 3] {
        return Err(PyValueError::new_err(format!(
            "face_colors: expected shape ({}, 3), got {cs:?}",
            fs[0]
        )));
    }
    let mut lights = Lights::default();
    match (&light_directions, &light_colors) {
        (Some(d), Some(c)) => {
            let (ds, dd) = view("light_directions", d, 2)?;
            expect_dim("light_directions", &ds, 1, 3, "x, y, z")?;
            let (lcs, lcd) = view("light_colors", c, 2)?;
            if lcs != ds {
                return Err(PyValueError::new_err(format!(
                    "light_colors: expected shape {ds:?} (as light_directions), got {lcs:?}"
                )));
            }
            lights.directions = dd.chunks_exact(3).map(|v| [v[0], v[1], v[2]]).collect();
            lights.colors = lcd.chunks_exact(3).map(|v| [v[0], v[1], v[2]]).collect();
        }
        (None, None) => {}
        _ => {
            return Err(PyValueError::new_err(
                "light_directions/light_colors: give both or neither".to_string(),
            ))
        }
    }
    if let Some(a) = &ambient {
        let (s, d) = view("ambient", a, 1)?;
        expect_dim("ambient", &s, 0, 3, "RGB")?;
        lights.ambient = [d[0], d[1], d[2]];
    }
    let mut settings = RenderSettings {
        height: image_size("height", height)?,
        width: image_size("width", width)?,
        fill_back,
        ..RenderSettings::default()
    };
    if let Some(bg) = &background {
        let (s, d) = view("background", bg, 1)?;
        expect_dim("background", &s, 0, 3, "RGB")?;
        settings.background = [d[0], d[1], d[2]];
    }
    let camera = SphericalCamera {
        distance,
        azimuth,
        elevation,
        tilt,
        viewing_angle,
        near,
        far,
        orthographic,
        ortho_scale,
    };
    let (h, w) = (settings.height, settings.width);
    let out = run(py, nt, || render(vd, fd, cd, &camera, &lights, &settings))?;
    Ok((
        output(py, out.image, &[h, w, 3])?,
        output(py, out.alpha, &[h, w])?,
        output(py, out.depth, &[h, w])?,
        output(py, out.face_index, &[h, w])?,
    ))
}

/// The native module `meshadv._raster`.
#[pymodule]
fn _raster(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(rasterize_forward, m)?)?;
    m.add_function(wrap_pyfunction!(rasterize_backward, m)?)?;
    m.add_function(wrap_pyfunction!(flat::flat_render_forward, m)?)?;
    m.add_function(wrap_pyfunction!(flat::flat_render_backward, m)?)?;
    m.add_function(wrap_pyfunction!(box_downsample, m)?)?;
    m.add_function(wrap_pyfunction!(box_spread, m)?)?;
    m.add_function(wrap_pyfunction!(raycast, m)?)?;
    m.add_function(wrap_pyfunction!(render_full, m)?)?;
    m.add_function(wrap_pyfunction!(surface::pixel_weights, m)?)?;
    m.add_function(wrap_pyfunction!(surface::pixel_weights_backward, m)?)?;
    m.add_function(wrap_pyfunction!(surface::interpolate, m)?)?;
    m.add_function(wrap_pyfunction!(surface::interpolate_backward, m)?)?;
    m.add_function(wrap_pyfunction!(surface::sample_uv_texture, m)?)?;
    m.add_function(wrap_pyfunction!(surface::sample_uv_texture_backward, m)?)?;
    m.add_class::<surface::UvTexturePlanes>()?;
    m.add_function(wrap_pyfunction!(surface::image_vertex_backward, m)?)?;
    m.add("MAX_IMAGE_SIZE", meshadv_raster::MAX_IMAGE_SIZE)?;
    m.add("MAX_CACHED_POOLS", meshadv_raster::MAX_CACHED_POOLS)?;
    m.add("MAX_MESH_FILE_BYTES", meshadv_raster::MAX_MESH_FILE_BYTES)?;
    m.add("MIN_VIEWING_ANGLE", meshadv_raster::MIN_VIEWING_ANGLE)?;
    m.add("MIN_LIGHT_DIRECTION", meshadv_raster::MIN_LIGHT_DIRECTION)?;
    Ok(())
}
