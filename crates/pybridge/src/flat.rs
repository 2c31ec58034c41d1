//! Bindings of the flat render (`meshadv_raster::flat`): projection, Lambert shading, rasterization and box filter
//! in one forward call, and their adjoint in one backward call.

use meshadv_raster::flat::{
    render_flat, render_flat_backward, FlatBackwardInputs, FlatCamera, FlatLights, FlatScene,
};
use meshadv_raster::{Projection, RasterParams};
use numpy::ndarray::{s, Ix4};
use numpy::{PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use super::{
    array, expect_dim, image_size, output, run, threads, view, view_exact, visibility, PyArr,
    PyRasterError,
};

/// The scene's input arrays, borrowed read-only from Python.
struct SceneArrays<'py> {
    verts: PyReadonlyArrayDyn<'py, f32>,
    faces: PyReadonlyArrayDyn<'py, i32>,
    face_colors: PyReadonlyArrayDyn<'py, f32>,
    rotation: PyReadonlyArrayDyn<'py, f32>,
    eye: PyReadonlyArrayDyn<'py, f32>,
    scale: PyReadonlyArrayDyn<'py, f32>,
    light_directions: PyReadonlyArrayDyn<'py, f32>,
    light_colors: PyReadonlyArrayDyn<'py, f32>,
    ambient: PyReadonlyArrayDyn<'py, f32>,
    background: PyReadonlyArrayDyn<'py, f32>,
}

/// The scalar settings of a flat render.
#[derive(Clone, Copy)]
struct Settings {
    batch: usize,
    k: usize,
    params: RasterParams,
    background: [f32; 3],
}

impl<'py> SceneArrays<'py> {
    #[allow(clippy::too_many_arguments)]
    fn extract(
        verts: &Bound<'py, PyAny>,
        faces: &Bound<'py, PyAny>,
        face_colors: &Bound<'py, PyAny>,
        rotation: &Bound<'py, PyAny>,
        eye: &Bound<'py, PyAny>,
        scale: &Bound<'py, PyAny>,
        light_directions: &Bound<'py, PyAny>,
        light_colors: &Bound<'py, PyAny>,
        ambient: &Bound<'py, PyAny>,
        background: &Bound<'py, PyAny>,
    ) -> PyResult<Self> {
        Ok(SceneArrays {
            verts: array::<f32>("verts", "float32", verts)?,
            faces: array::<i32>("faces", "int32", faces)?,
            face_colors: array::<f32>("face_colors", "float32", face_colors)?,
            rotation: array::<f32>("rotation", "float32", rotation)?,
            eye: array::<f32>("eye", "float32", eye)?,
            scale: array::<f32>("scale", "float32", scale)?,
            light_directions: array::<f32>("light_directions", "float32", light_directions)?,
            light_colors: array::<f32>("light_colors", "float32", light_colors)?,
            ambient: array::<f32>("ambient", "float32", ambient)?,
            background: array::<f32>("background", "float32", background)?,
        })
    }

    /// Checks ranks and trailing dimensions, and returns the core's scene and the settings.
    #[allow(clippy::too_many_arguments)]
    fn scene(
        &self,
        batch: i64,
        height: i64,
        width: i64,
        k: i64,
        near: f64,
        far: f64,
        fill_back: bool,
        orthographic: bool,
    ) -> PyResult<(FlatScene<'_>, Settings)> {
        let (vs, vd) = view("verts", &self.verts, 3)?;
        expect_dim("verts", &vs, 2, 3, "x, y, z")?;
        let (fs, fd) = view("faces", &self.faces, 2)?;
        expect_dim("faces", &fs, 1, 3, "triangles")?;
        let (cs, cd) = view("face_colors", &self.face_colors, 3)?;
        expect_dim("face_colors", &cs, 1, fs[0], "number of faces")?;
        expect_dim("face_colors", &cs, 2, 3, "RGB")?;
        let (rs, rd) = view("rotation", &self.rotation, 3)?;
        expect_dim("rotation", &rs, 1, 3, "view axes")?;
        expect_dim("rotation", &rs, 2, 3, "x, y, z")?;
        let (es, ed) = view("eye", &self.eye, 2)?;
        expect_dim("eye", &es, 0, rs[0], "batch size of rotation")?;
        expect_dim("eye", &es, 1, 3, "x, y, z")?;
        let (ss, sd) = view("scale", &self.scale, 1)?;
        expect_dim("scale", &ss, 0, rs[0], "batch size of rotation")?;
        let (ds, dd) = view("light_directions", &self.light_directions, 3)?;
        expect_dim("light_directions", &ds, 2, 3, "x, y, z")?;
        let lc = view_exact("light_colors", &self.light_colors, &ds)?;
        let (as_, ad) = view("ambient", &self.ambient, 2)?;
        expect_dim("ambient", &as_, 0, ds[0], "batch size of light_directions")?;
        expect_dim("ambient", &as_, 1, 3, "RGB")?;
        let bg = view_exact("background", &self.background, &[3])?;
        let batch = usize::try_from(batch)
            .ok()
            .filter(|&b| b >= 1)
            .ok_or_else(|| PyValueError::new_err(format!("batch: must be >= 1, got {batch}")))?;
        let k = usize::try_from(k)
            .ok()
            .filter(|&k| k >= 1)
            .ok_or_else(|| PyValueError::new_err(format!("k: must be >= 1, got {k}")))?;
        let side = |arg: &'static str, v: i64| image_size(arg, v.saturating_mul(k as i64));
        let params = RasterParams {
            height: side("height", height)?,
            width: side("width", width)?,
            near,
            far,
            cull_backfaces: !fill_back,
            projection: if orthographic {
                Projection::Orthographic
            } else {
                Projection::Perspective
            },
        };
        let scene = FlatScene {
            verts: vd,
            num_verts: vs[1],
            faces: fd,
            colors: cd,
            camera: FlatCamera {
                rotation: rd,
                eye: ed,
                scale: sd,
                orthographic,
            },
            lights: FlatLights {
                directions: dd,
                colors: lc,
                ambient: ad,
                count: ds[1],
            },
            batch,
            two_sided: fill_back,
        };
        scene.validate().map_err(PyRasterError)?;
        let settings = Settings {
            batch,
            k,
            params,
            background: [bg[0], bg[1], bg[2]],
        };
        Ok((scene, settings))
    }
}

/// The flat render: `(image f32[B,H,W,4], full_image f32[B,kH,kW,4] or None (k = 1: it is image),
/// face_index i32[B,kH,kW], depth f32[B,kH,kW], verts_screen f32[B,N,3], attrs f32[B,M,4])`.
///
/// Inputs (each batch 1 or `batch`): world `verts [Bv,N,3]`, `faces [M,3]`, reflectances `face_colors [Bc,M,3]`,
/// the cameras' world-to-view `rotation [Bk,3,3]`, `eye [Bk,3]` and `scale [Bk]` (`tan(fov / 2)` or the
/// orthographic half extent), unit `light_directions [Bl,K,3]`, `light_colors [Bl,K,3]`, `ambient [Bl,3]`, the RGB
/// `background [3]`; `height x width` is the output size, rendered at `k` times it and box-filtered. `fill_back`:
/// two-sided (normals flipped toward the camera), else back faces are culled. See `meshadv_raster::flat`.
#[pyfunction]
#[pyo3(signature = (verts, faces, face_colors, rotation, eye, scale, light_directions, light_colors, ambient,
                    background, batch, height, width, k, near, far, fill_back, orthographic, num_threads = 0))]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
pub fn flat_render_forward<'py>(
    py: Python<'py>,
    verts: &Bound<'py, PyAny>,
    faces: &Bound<'py, PyAny>,
    face_colors: &Bound<'py, PyAny>,
    rotation: &Bound<'py, PyAny>,
    eye: &Bound<'py, PyAny>,
    scale: &Bound<'py, PyAny>,
    light_directions: &Bound<'py, PyAny>,
    light_colors: &Bound<'py, PyAny>,
    ambient: &Bound<'py, PyAny>,
    background: &Bound<'py, PyAny>,
    batch: i64,
    height: i64,
    width: i64,
    k: i64,
    near: f64,
    far: f64,
    fill_back: bool,
    orthographic: bool,
    num_threads: i64,
) -> PyResult<(
    PyArr<'py, f32>,
    Option<PyArr<'py, f32>>,
    PyArr<'py, i32>,
    PyArr<'py, f32>,
    PyArr<'py, f32>,
    PyArr<'py, f32>,
)> {
    let nt = threads(num_threads)?;
    let arrays = SceneArrays::extract(
        verts,
        faces,
        face_colors,
        rotation,
        eye,
        scale,
        light_directions,
        light_colors,
        ambient,
        background,
    )?;
    let (scene, st) = arrays.scene(batch, height, width, k, near, far, fill_back, orthographic)?;
    let out = run(py, nt, || {
        render_flat(&scene, &st.params, st.background, st.k)
    })?;
    let (b, n, m) = (st.batch, scene.num_verts, scene.num_faces());
    let (fh, fw) = (st.params.height, st.params.width);
    let full = if st.k == 1 {
        None
    } else {
        Some(output(py, out.full_image, &[b, fh, fw, 4])?)
    };
    Ok((
        output(py, out.image, &[b, fh / st.k, fw / st.k, 4])?,
        full,
        output(py, out.face_index, &[b, fh, fw])?,
        output(py, out.depth, &[b, fh, fw])?,
        output(py, out.verts_screen, &[b, n, 3])?,
        output(py, out.attrs, &[b, m, 4])?,
    ))
}

/// The `(B, H, W, 4)` cotangent of the filtered image from those of its RGB `(B, 3, H, W)` and coverage
/// `(B, 1, H, W)` views (any strides; a missing one is zero).
fn cotangent(
    grad_rgb: Option<&PyReadonlyArrayDyn<'_, f32>>,
    grad_alpha: Option<&PyReadonlyArrayDyn<'_, f32>>,
    dims: [usize; 3],
) -> PyResult<Vec<f32>> {
    let [b, h, w] = dims;
    let mut cot = vec![0f32; b * h * w * 4];
    for (arg, grad, first) in [
        ("grad_image", grad_rgb, 0usize),
        ("grad_alpha", grad_alpha, 3),
    ] {
        let Some(grad) = grad else { continue };
        let channels = if first == 0 { 3 } else { 1 };
        let want = [b, channels, h, w];
        if grad.shape() != want {
            return Err(PyValueError::new_err(format!(
                "{arg}: expected shape {want:?}, got {:?}",
                grad.shape()
            )));
        }
        let src = grad
            .as_array()
            .into_dimensionality::<Ix4>()
            .map_err(|e| PyValueError::new_err(format!("{arg}: {e}")))?;
        // Row by row: each source row (any stride) fills one channel of a row of pixels.
        for ((bi, ch, y), _) in src.slice(s![.., .., .., 0usize]).indexed_iter() {
            let (bi, ch, y): (usize, usize, usize) = (bi, ch, y);
            let row = src.slice(s![bi, ch, y, ..]);
            let dst = &mut cot[((bi * h + y) * w) * 4..((bi * h + y + 1) * w) * 4];
            match row.as_slice() {
                Some(values) => {
                    for (px, &g) in dst.chunks_exact_mut(4).zip(values) {
                        px[first + ch] = g;
                    }
                }
                None => {
                    for (px, &g) in dst.chunks_exact_mut(4).zip(row.iter()) {
                        px[first + ch] = g;
                    }
                }
            }
        }
    }
    Ok(cot)
}

/// Backward of `flat_render_forward` (the same scene arguments, then its `verts_screen`, `attrs`, `face_index`,
/// `image` (its `full_image`, or `image` when `k = 1`) and the cotangents `grad_image [B,3,H,W]` and `grad_alpha
/// [B,1,H,W]` (either may be None)): the gradients `(verts, face_colors, rotation, eye, scale, light_directions,
/// light_colors, ambient)`, each shaped as its input. `edge_weight` scales the rasterization gradient of the screen
/// vertices; with `need_verts=False` the vertex and camera gradients are zero (the vertex sweep is skipped);
/// `sweep_radius` as in `rasterize_backward`.
#[pyfunction]
#[pyo3(signature = (verts, faces, face_colors, rotation, eye, scale, light_directions, light_colors, ambient,
                    background, batch, height, width, k, near, far, fill_back, orthographic, verts_screen, attrs,
                    face_index, image, grad_image, grad_alpha, edge_weight = 1.0, need_verts = true,
                    sweep_radius = None, num_threads = 0))]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
pub fn flat_render_backward<'py>(
    py: Python<'py>,
    verts: &Bound<'py, PyAny>,
    faces: &Bound<'py, PyAny>,
    face_colors: &Bound<'py, PyAny>,
    rotation: &Bound<'py, PyAny>,
    eye: &Bound<'py, PyAny>,
    scale: &Bound<'py, PyAny>,
    light_directions: &Bound<'py, PyAny>,
    light_colors: &Bound<'py, PyAny>,
    ambient: &Bound<'py, PyAny>,
    background: &Bound<'py, PyAny>,
    batch: i64,
    height: i64,
    width: i64,
    k: i64,
    near: f64,
    far: f64,
    fill_back: bool,
    orthographic: bool,
    verts_screen: &Bound<'py, PyAny>,
    attrs: &Bound<'py, PyAny>,
    face_index: &Bound<'py, PyAny>,
    image: &Bound<'py, PyAny>,
    grad_image: Option<&Bound<'py, PyAny>>,
    grad_alpha: Option<&Bound<'py, PyAny>>,
    edge_weight: f64,
    need_verts: bool,
    sweep_radius: Option<i64>,
    num_threads: i64,
) -> PyResult<(
    PyArr<'py, f32>,
    PyArr<'py, f32>,
    PyArr<'py, f32>,
    PyArr<'py, f32>,
    PyArr<'py, f32>,
    PyArr<'py, f32>,
    PyArr<'py, f32>,
    PyArr<'py, f32>,
)> {
    let nt = threads(num_threads)?;
    let visibility = visibility(sweep_radius)?;
    if !(edge_weight.is_finite() && edge_weight >= 0.0) {
        return Err(PyValueError::new_err(format!(
            "edge_weight: must be finite and >= 0, got {edge_weight}"
        )));
    }
    let arrays = SceneArrays::extract(
        verts,
        faces,
        face_colors,
        rotation,
        eye,
        scale,
        light_directions,
        light_colors,
        ambient,
        background,
    )?;
    let (scene, st) = arrays.scene(batch, height, width, k, near, far, fill_back, orthographic)?;
    let (b, n, m) = (st.batch, scene.num_verts, scene.num_faces());
    let (fh, fw) = (st.params.height, st.params.width);
    let verts_screen = array::<f32>("verts_screen", "float32", verts_screen)?;
    let attrs = array::<f32>("attrs", "float32", attrs)?;
    let face_index = array::<i32>("face_index", "int32", face_index)?;
    let image = array::<f32>("image", "float32", image)?;
    let grad_image = grad_image
        .map(|g| array::<f32>("grad_image", "float32", g))
        .transpose()?;
    let grad_alpha = grad_alpha
        .map(|g| array::<f32>("grad_alpha", "float32", g))
        .transpose()?;
    let cot = cotangent(
        grad_image.as_ref(),
        grad_alpha.as_ref(),
        [b, fh / st.k, fw / st.k],
    )?;
    let inputs = FlatBackwardInputs {
        verts_screen: view_exact("verts_screen", &verts_screen, &[b, n, 3])?,
        attrs: view_exact("attrs", &attrs, &[b, m, 4])?,
        face_index: view_exact("face_index", &face_index, &[b, fh, fw])?,
        image: view_exact("image", &image, &[b, fh, fw, 4])?,
        grad_image: &cot,
        edge_weight: edge_weight as f32,
        need_verts,
        visibility,
    };
    let g = run(py, nt, || {
        render_flat_backward(&scene, &st.params, st.background, st.k, &inputs)
    })?;
    let shape_of = |a: &PyReadonlyArrayDyn<'_, f32>| a.shape().to_vec();
    Ok((
        output(py, g.verts, &shape_of(&arrays.verts))?,
        output(py, g.colors, &shape_of(&arrays.face_colors))?,
        output(py, g.rotation, &shape_of(&arrays.rotation))?,
        output(py, g.eye, &shape_of(&arrays.eye))?,
        output(py, g.scale, &shape_of(&arrays.scale))?,
        output(py, g.light_directions, &shape_of(&arrays.light_directions))?,
        output(py, g.light_colors, &shape_of(&arrays.light_colors))?,
        output(py, g.ambient, &shape_of(&arrays.ambient))?,
    ))
}
