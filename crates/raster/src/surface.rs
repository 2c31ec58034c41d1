//! Per-pixel surface attributes: the perspective-correct barycentric weights of the face drawn at each pixel,
//! per-corner attributes (UVs, normals, colours) interpolated with them, and the exact gradients of both.
//!
//! Weights: with `w_k` the screen-space (pixel-space) barycentric weights of the pixel centre in its face (the
//! forward's edge functions over the area, [`FaceSetup::barycentric`]), the perspective-correct weights are
//! `b_k = (w_k / z_k) / sum_j (w_j / z_j)` (`z_k` the view depth of corner `k`), so that an attribute interpolated
//! with `b` is linear on the face in view (and world) space; orthographic projections use `b_k = w_k`. Background
//! pixels get weights 0.
//!
//! Attributes have their own per-corner index: `corners` `(M, 3)` names, for each face corner, a row of `values`
//! `(A, K)` (as OBJ's `f v/vt/vn`, PyTorch3D's `faces_uvs`), so a UV seam needs no split geometry.
//!
//! Gradients are exact (derivatives of the formulas above at fixed face assignment, "interior" terms); the change of
//! which face a pixel shows belongs to the visibility gradient ([`crate::backward`]). Sums over pixels run in
//! row-major order within a batch element, so results are bit-identical for any thread count.

use rayon::prelude::*;

use crate::error::{try_filled_vec, RasterError, Result};
use crate::input::{check_finite, first_bad_face, Projection, RasterParams, ScreenMesh};
use crate::setup::{ndc_to_u, ndc_to_v};

/// Checks a `(B, H, W)` face-index map against the mesh: length and entries in `-1..M`.
pub fn check_face_index(
    face_index: &[i32],
    mesh: &ScreenMesh<'_>,
    params: &RasterParams,
) -> Result<()> {
    let (b, h, w) = (mesh.batch, params.height, params.width);
    if face_index.len() != b * h * w {
        return Err(RasterError::shape(
            "face_index",
            format!("({b}, {h}, {w})"),
            format!("{} values", face_index.len()),
        ));
    }
    let m = mesh.num_faces();
    match first_bad_face(face_index, m) {
        Some(index) => Err(RasterError::FaceMapOutOfRange {
            index,
            value: face_index[index] as i64,
            num_faces: m,
        }),
        None => Ok(()),
    }
}

/// The screen-space weights of one face as planes in pixel space, and what their gradient needs.
///
/// `w_k(u, v) = A_k / A` with `A_k = cross(P_{k+1} - p, P_{k+2} - p)` and `A = cross(P_1 - P_0, P_2 - P_0)` (signed,
/// pixel space, `cross(a, b) = a.u b.v - a.v b.u`), so `w_k = (n_k0 + n_k1 u + n_k2 v) / A` with
/// `n_k = (u_{k+1} v_{k+2} - v_{k+1} u_{k+2}, v_{k+1} - v_{k+2}, u_{k+2} - u_{k+1})`. The perspective numerators are
/// `q_k = w_k / z_k` (orthographic: `q_k = w_k`).
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct FacePlanes {
    /// `w_k(u, v) = w[k][0] + w[k][1] u + w[k][2] v`.
    pub(crate) w: [[f64; 3]; 3],
    /// `1 / z_k` (perspective) or 1 (orthographic): `q_k = iz_k w_k`.
    pub(crate) iz: [f64; 3],
    /// Corner columns.
    u: [f64; 3],
    /// Corner rows.
    v: [f64; 3],
    /// `A`.
    area: f64,
    /// Orthographic projection: the weights do not depend on depth.
    pub(crate) ortho: bool,
}

/// `p[0] + p[1] u + p[2] v`.
#[inline(always)]
pub(crate) fn plane_at(p: &[f64; 3], u: f64, v: f64) -> f64 {
    p[0] + p[1] * u + p[2] * v
}

/// `a . b` of two 3-vectors.
#[inline(always)]
pub(crate) fn dot3(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

impl FacePlanes {
    /// The planes of face `f` of batch element `b` (a face the rasterizer draws: non-zero area, in front).
    pub(crate) fn new(
        mesh: &ScreenMesh<'_>,
        b: usize,
        f: usize,
        params: &RasterParams,
    ) -> FacePlanes {
        let ortho = params.projection == Projection::Orthographic;
        let mut s = FacePlanes {
            ortho,
            ..Default::default()
        };
        for (k, &vi) in mesh.face(f).iter().enumerate() {
            let p = mesh.vert(b, vi);
            s.u[k] = ndc_to_u(p[0], params.width);
            s.v[k] = ndc_to_v(p[1], params.height);
            s.iz[k] = if ortho { 1.0 } else { 1.0 / p[2] as f64 };
        }
        let (u, v) = (s.u, s.v);
        s.area = (u[1] - u[0]) * (v[2] - v[0]) - (v[1] - v[0]) * (u[2] - u[0]);
        let inv = 1.0 / s.area;
        for k in 0..3 {
            let (k1, k2) = ((k + 1) % 3, (k + 2) % 3);
            s.w[k] = [
                (u[k1] * v[k2] - v[k1] * u[k2]) * inv,
                (v[k1] - v[k2]) * inv,
                (u[k2] - u[k1]) * inv,
            ];
        }
        s
    }

    /// The perspective numerator `q_k` as a plane.
    #[inline(always)]
    pub(crate) fn numerator(&self, k: usize) -> [f64; 3] {
        self.w[k].map(|x| x * self.iz[k])
    }

    /// Screen weights `w` and perspective-correct weights `b` at pixel `(row, col)`.
    #[inline(always)]
    fn weights_at(&self, row: usize, col: usize) -> ([f64; 3], [f64; 3]) {
        let (u, v) = (col as f64, row as f64);
        let w = self.w.map(|p| plane_at(&p, u, v));
        if self.ortho {
            return (w, w);
        }
        let q = [w[0] * self.iz[0], w[1] * self.iz[1], w[2] * self.iz[2]];
        let total = q[0] + q[1] + q[2];
        (w, [q[0] / total, q[1] / total, q[2] / total])
    }

    /// The gradient `[corner][x_ndc, y_ndc, z_view]` of a loss whose gradient with respect to the coefficients of
    /// the numerator planes `q_k` is `gq[k]` (summed over the face's pixels: `sum_P dL/dq_k(P) (1, u, v)`).
    pub(crate) fn vertex_grads(&self, gq: &[[f64; 3]; 3], params: &RasterParams) -> [[f64; 3]; 3] {
        let (u, v) = (&self.u, &self.v);
        let inv_area = 1.0 / self.area;
        let (mut gu, mut gv, mut out) = ([0f64; 3], [0f64; 3], [[0f64; 3]; 3]);
        let mut g_area = 0f64;
        for k in 0..3 {
            let (k1, k2) = ((k + 1) % 3, (k + 2) % 3);
            if !self.ortho {
                // q_k = w_k / z_k: dL/dz_k = -(dL/d(1/z_k)) / z_k^2.
                out[k][2] = -self.iz[k] * self.iz[k] * dot3(&gq[k], &self.w[k]);
            }
            // w_k = n_k / A.
            let gw = gq[k].map(|x| x * self.iz[k]);
            g_area -= dot3(&gw, &self.w[k]) * inv_area;
            let gn = gw.map(|x| x * inv_area);
            gu[k1] += gn[0] * v[k2] - gn[2];
            gu[k2] += gn[2] - gn[0] * v[k1];
            gv[k1] += gn[1] - gn[0] * u[k2];
            gv[k2] += gn[0] * u[k1] - gn[1];
        }
        let (width, height) = (params.width as f64, params.height as f64);
        for k in 0..3 {
            let (k1, k2) = ((k + 1) % 3, (k + 2) % 3);
            // dA/du_k = v_{k+1} - v_{k+2}, dA/dv_k = u_{k+2} - u_{k+1}.
            let (du, dv) = (
                gu[k] + g_area * (v[k1] - v[k2]),
                gv[k] + g_area * (u[k2] - u[k1]),
            );
            // u = (x W + W - 1) / 2, v = (H - 1 - y H) / 2.
            out[k][0] = du * width / 2.0;
            out[k][1] = -dv * height / 2.0;
        }
        out
    }
}

/// The planes of the faces drawn somewhere in `face_index` (one batch element); the others are left default.
fn drawn_planes(
    mesh: &ScreenMesh<'_>,
    b: usize,
    params: &RasterParams,
    face_index: &[i32],
) -> Vec<FacePlanes> {
    let mut drawn = vec![false; mesh.num_faces()];
    for &f in face_index {
        if f >= 0 {
            drawn[f as usize] = true;
        }
    }
    drawn
        .iter()
        .enumerate()
        .map(|(f, &d)| {
            if d {
                FacePlanes::new(mesh, b, f, params)
            } else {
                FacePlanes::default()
            }
        })
        .collect()
}

/// Adds the vertex gradient `g` (`[corner][x, y, z]`) of a face with vertices `verts` to the vertex sums `sums`
/// `(N, 3)`.
#[inline]
pub(crate) fn add_to_vertices(verts: [usize; 3], g: &[[f64; 3]; 3], sums: &mut [f64]) {
    for (&vi, gk) in verts.iter().zip(g) {
        for (s, &x) in sums[vi * 3..vi * 3 + 3].iter_mut().zip(gk) {
            *s += x;
        }
    }
}

/// Perspective-correct barycentric weights `(B, H, W, 3)` of the face drawn at each pixel (0 on background), for
/// the fragments `face_index` of a forward pass with the same `mesh` and `params`.
///
/// ```
/// use meshadv_raster::{rasterize_fragments, RasterParams, ScreenMesh};
/// use meshadv_raster::surface::pixel_weights;
/// let verts = [-1.0f32, -1.0, 2.0, 1.0, -1.0, 2.0, -1.0, 1.0, 2.0];
/// let mesh = ScreenMesh::new(&verts, &[0, 1, 2], 1, 3).unwrap();
/// let params = RasterParams::new(4, 4, 0.1, 10.0);
/// let frags = rasterize_fragments(&mesh, &params).unwrap();
/// let w = pixel_weights(&mesh, &params, &frags.face_index).unwrap();
/// let p = 12 * 3; // the bottom-left pixel
/// assert!((w[p] + w[p + 1] + w[p + 2] - 1.0).abs() < 1e-6);
/// assert_eq!(&w[3 * 3..3 * 3 + 3], &[0.0, 0.0, 0.0]); // background
/// ```
pub fn pixel_weights(
    mesh: &ScreenMesh<'_>,
    params: &RasterParams,
    face_index: &[i32],
) -> Result<Vec<f32>> {
    mesh.validate()?;
    params.validate()?;
    check_face_index(face_index, mesh, params)?;
    let hw = params.pixels();
    let mut out = try_filled_vec(face_index.len() * 3, 0f32, "weights")?;
    out.par_chunks_mut(hw * 3).enumerate().for_each(|(b, dst)| {
        let fi = &face_index[b * hw..(b + 1) * hw];
        let planes = drawn_planes(mesh, b, params, fi);
        for (p, (&f, wp)) in fi.iter().zip(dst.chunks_exact_mut(3)).enumerate() {
            if f >= 0 {
                let (_, bw) = planes[f as usize].weights_at(p / params.width, p % params.width);
                for k in 0..3 {
                    wp[k] = bw[k] as f32;
                }
            }
        }
    });
    Ok(out)
}

/// Backward of [`pixel_weights`]: the gradient `(B, N, 3)` with respect to `verts_screen` (x, y and z) of
/// `sum_P sum_k grad_weights[P, k] * b_k(P)`, exact at fixed face assignment.
pub fn pixel_weights_backward(
    mesh: &ScreenMesh<'_>,
    params: &RasterParams,
    face_index: &[i32],
    grad_weights: &[f32],
) -> Result<Vec<f32>> {
    mesh.validate()?;
    params.validate()?;
    check_face_index(face_index, mesh, params)?;
    if grad_weights.len() != face_index.len() * 3 {
        return Err(RasterError::shape(
            "grad_weights",
            format!("({}, {}, {}, 3)", mesh.batch, params.height, params.width),
            format!("{} values", grad_weights.len()),
        ));
    }
    check_finite("grad_weights", grad_weights)?;
    let (hw, nv, m) = (params.pixels(), mesh.num_verts, mesh.num_faces());
    let mut grad = try_filled_vec(mesh.batch * nv * 3, 0f32, "grad_verts_screen")?;
    grad.par_chunks_mut(nv * 3)
        .enumerate()
        .try_for_each(|(b, gv)| -> Result<()> {
            let fi = &face_index[b * hw..(b + 1) * hw];
            let planes = drawn_planes(mesh, b, params, fi);
            // Per face and corner, summed over its pixels in row-major order: the numerator cotangent dL/dq_k times
            // (1, u, v), the gradient of the plane q_k's coefficients.
            let mut acc = try_filled_vec(m, [[0f64; 3]; 3], "weights backward accumulator")?;
            let gw = &grad_weights[b * hw * 3..(b + 1) * hw * 3];
            for (p, (&f, g)) in fi.iter().zip(gw.chunks_exact(3)).enumerate() {
                if f < 0 {
                    continue;
                }
                let pl = &planes[f as usize];
                let (row, col) = (p / params.width, p % params.width);
                let (w, bw) = pl.weights_at(row, col);
                let gb = [g[0] as f64, g[1] as f64, g[2] as f64];
                // Perspective division: b_k = q_k / Q, q_k = w_k / z_k.
                let gq = if pl.ortho {
                    gb
                } else {
                    let total = w[0] * pl.iz[0] + w[1] * pl.iz[1] + w[2] * pl.iz[2];
                    let dot = gb[0] * bw[0] + gb[1] * bw[1] + gb[2] * bw[2];
                    gb.map(|x| (x - dot) / total)
                };
                let (u, v) = (col as f64, row as f64);
                for (a, g) in acc[f as usize].iter_mut().zip(gq) {
                    a[0] += g;
                    a[1] += g * u;
                    a[2] += g * v;
                }
            }
            let mut sums = try_filled_vec(nv * 3, 0f64, "vertex gradient accumulator")?;
            for (f, (a, pl)) in acc.iter().zip(&planes).enumerate() {
                if a.iter().flatten().any(|&x| x != 0.0) {
                    add_to_vertices(mesh.face(f), &pl.vertex_grads(a, params), &mut sums);
                }
            }
            for (d, &s) in gv.iter_mut().zip(&sums) {
                *d = s as f32;
            }
            Ok(())
        })?;
    Ok(grad)
}

/// Per-corner attributes: `values` `(Bv, A, K)` (`Bv` is 1, shared by the batch, or the batch size) and `corners`
/// `(M, 3)`, the row of `values` at each corner of each face. `arg` names the values in errors.
#[derive(Debug, Clone, Copy)]
pub struct CornerAttrs<'a> {
    /// Flat `(Bv, A, K)` values.
    pub values: &'a [f32],
    /// Flat `(M, 3)` rows of `values`.
    pub corners: &'a [i32],
    /// `Bv`.
    pub batch: usize,
    /// Rows `A`.
    pub rows: usize,
    /// Channels `K`.
    pub channels: usize,
    /// The values' argument name (e.g. `uvs`, `normals`).
    pub arg: &'static str,
}

impl CornerAttrs<'_> {
    /// Checks shapes against the mesh (`Bv` is 1 or the mesh's batch, one corner row per face), corner indices in
    /// `0..A`, and finite values.
    pub fn validate(&self, mesh: &ScreenMesh<'_>) -> Result<()> {
        if self.channels == 0 || self.rows == 0 {
            return Err(RasterError::shape(
                self.arg,
                "(Bv, A, K) with A, K >= 1",
                "an empty array",
            ));
        }
        if self.batch != 1 && self.batch != mesh.batch {
            return Err(RasterError::shape(
                self.arg,
                format!("batch 1 or {}", mesh.batch),
                format!("batch {}", self.batch),
            ));
        }
        if self.values.len() != self.batch * self.rows * self.channels {
            return Err(RasterError::shape(
                self.arg,
                format!("({}, {}, {})", self.batch, self.rows, self.channels),
                format!("{} values", self.values.len()),
            ));
        }
        if self.corners.len() != mesh.faces.len() {
            return Err(RasterError::shape(
                "corners",
                format!("({}, 3), one row per face", mesh.num_faces()),
                format!("{} values", self.corners.len()),
            ));
        }
        if let Some(i) = self
            .corners
            .iter()
            .position(|&c| c < 0 || c as usize >= self.rows)
        {
            return Err(RasterError::Parameter {
                arg: "corners",
                message: format!(
                    "face {} corner {} refers to row {} of {}, which has {} rows",
                    i / 3,
                    i % 3,
                    self.corners[i],
                    self.arg,
                    self.rows
                ),
            });
        }
        check_finite(self.arg, self.values)
    }

    /// Row `r` of the values of batch element `b`.
    #[inline(always)]
    pub(crate) fn row(&self, b: usize, r: usize) -> &[f32] {
        let b = if self.batch == 1 { 0 } else { b };
        let o = (b * self.rows + r) * self.channels;
        &self.values[o..o + self.channels]
    }
}

/// Checks a per-pixel cotangent `grad` of `channels` values per pixel `(B, H, W, channels)`: its length and that it
/// is finite.
pub(crate) fn check_pixel_grad(
    grad: &[f32],
    channels: usize,
    batch: usize,
    params: &RasterParams,
) -> Result<()> {
    if grad.len() != batch * params.pixels() * channels {
        return Err(RasterError::shape(
            "grad",
            format!("({batch}, {}, {}, {channels})", params.height, params.width),
            format!("{} values", grad.len()),
        ));
    }
    check_finite("grad", grad)
}

/// Checks a `(B, H, W, 3)` weights array.
fn check_weights(weights: &[f32], face_index: &[i32]) -> Result<()> {
    if weights.len() != face_index.len() * 3 {
        return Err(RasterError::shape(
            "weights",
            "(B, H, W, 3) like face_index",
            format!("{} values for {} pixels", weights.len(), face_index.len()),
        ));
    }
    check_finite("weights", weights)
}

/// Interpolates `attrs` at every pixel: `out[P] = sum_k weights[P, k] * values[corners[F[P], k]]` `(B, H, W, K)`,
/// 0 on background (`F[P] = -1`). `weights` come from [`pixel_weights`] (or any `(B, H, W, 3)` weights).
pub fn interpolate(
    mesh: &ScreenMesh<'_>,
    params: &RasterParams,
    face_index: &[i32],
    weights: &[f32],
    attrs: &CornerAttrs<'_>,
) -> Result<Vec<f32>> {
    check_face_index(face_index, mesh, params)?;
    check_weights(weights, face_index)?;
    attrs.validate(mesh)?;
    let k = attrs.channels;
    let mut out = try_filled_vec(face_index.len() * k, 0f32, "interpolated attributes")?;
    out.par_chunks_mut(params.width * k)
        .enumerate()
        .for_each(|(line, dst)| {
            with_channels!(k, K => interpolate_line::<K>(attrs, face_index, weights, params, line, dst))
        });
    Ok(out)
}

/// [`interpolate`] of image line `line` into `dst`, for `K` channels (0: any count).
#[inline(always)]
fn interpolate_line<const K: usize>(
    attrs: &CornerAttrs<'_>,
    face_index: &[i32],
    weights: &[f32],
    params: &RasterParams,
    line: usize,
    dst: &mut [f32],
) {
    let k = if K == 0 { attrs.channels } else { K };
    let b = line / params.height;
    let o = line * params.width;
    for (j, px) in dst.chunks_exact_mut(k).enumerate() {
        let f = face_index[o + j];
        if f < 0 {
            continue;
        }
        let w = &weights[(o + j) * 3..(o + j) * 3 + 3];
        let c = &attrs.corners[f as usize * 3..f as usize * 3 + 3];
        let rows: [&[f32]; 3] = std::array::from_fn(|i| &attrs.row(b, c[i] as usize)[..k]);
        for ch in 0..k {
            px[ch] = (w[0] as f64 * rows[0][ch] as f64
                + w[1] as f64 * rows[1][ch] as f64
                + w[2] as f64 * rows[2][ch] as f64) as f32;
        }
    }
}

/// Gradients of [`interpolate`].
#[derive(Debug, Clone, PartialEq)]
pub struct InterpGradients {
    /// `(Bv, A, K)` gradient with respect to the attribute values.
    pub grad_values: Vec<f32>,
    /// `(B, H, W, 3)` gradient with respect to the weights.
    pub grad_weights: Vec<f32>,
}

/// [`interpolate_backward`] of batch element `b`: its weight gradient into `gw` and its value gradient added to
/// `acc`, pixels in row-major order, for `K` channels (0: any count).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn interpolate_backward_element<const K: usize>(
    attrs: &CornerAttrs<'_>,
    face_index: &[i32],
    weights: &[f32],
    grad: &[f32],
    hw: usize,
    b: usize,
    gw: &mut [f32],
    acc: &mut [f64],
) {
    let k = if K == 0 { attrs.channels } else { K };
    for p in 0..hw {
        let q = b * hw + p;
        let f = face_index[q];
        if f < 0 {
            continue;
        }
        let w = &weights[q * 3..q * 3 + 3];
        let g = &grad[q * k..(q + 1) * k];
        let c = &attrs.corners[f as usize * 3..f as usize * 3 + 3];
        for corner in 0..3 {
            let r = c[corner] as usize;
            let row = &attrs.row(b, r)[..k];
            let a = &mut acc[r * k..(r + 1) * k];
            let mut sum = 0f64;
            for ch in 0..k {
                sum += g[ch] as f64 * row[ch] as f64;
                a[ch] += w[corner] as f64 * g[ch] as f64;
            }
            gw[p * 3 + corner] = sum as f32;
        }
    }
}

/// Backward of [`interpolate`] for the cotangent `grad` `(B, H, W, K)`: exact gradients to the values (summed over
/// pixels in row-major order, batch elements in order) and to the weights.
pub fn interpolate_backward(
    mesh: &ScreenMesh<'_>,
    params: &RasterParams,
    face_index: &[i32],
    weights: &[f32],
    attrs: &CornerAttrs<'_>,
    grad: &[f32],
) -> Result<InterpGradients> {
    check_face_index(face_index, mesh, params)?;
    check_weights(weights, face_index)?;
    attrs.validate(mesh)?;
    let k = attrs.channels;
    check_pixel_grad(grad, k, mesh.batch, params)?;
    let hw = params.pixels();
    let mut grad_weights = try_filled_vec(face_index.len() * 3, 0f32, "grad_weights")?;
    // Per batch element in parallel, pixels in row-major order; shared values are summed in batch order below.
    let per_elem = attrs.rows * k;
    let partial: Vec<Vec<f64>> = grad_weights
        .par_chunks_mut(hw * 3)
        .enumerate()
        .map(|(b, gw)| {
            let mut acc = vec![0f64; per_elem];
            with_channels!(k, K => interpolate_backward_element::<K>(attrs, face_index, weights, grad, hw, b, gw, &mut acc));
            acc
        })
        .collect();
    let mut grad_values = vec![0f32; attrs.batch * per_elem];
    if attrs.batch == 1 {
        let mut sum = vec![0f64; per_elem];
        for part in &partial {
            for (s, &x) in sum.iter_mut().zip(part) {
                *s += x;
            }
        }
        for (d, s) in grad_values.iter_mut().zip(&sum) {
            *d = *s as f32;
        }
    } else {
        for (d, s) in grad_values.iter_mut().zip(partial.iter().flatten()) {
            *d = *s as f32;
        }
    }
    Ok(InterpGradients {
        grad_values,
        grad_weights,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::rasterize_fragments;
    use crate::test_rng::Rng;

    /// A few random overlapping triangles in front of the camera.
    fn scene(rng: &mut Rng, faces: usize) -> (Vec<f32>, Vec<i32>) {
        let mut v = Vec::new();
        for _ in 0..faces * 3 {
            v.extend_from_slice(&[
                (rng.next() * 1.6 - 0.8) as f32,
                (rng.next() * 1.6 - 0.8) as f32,
                (1.0 + rng.next() * 3.0) as f32,
            ]);
        }
        (v, (0..faces as i32 * 3).collect())
    }

    #[test]
    fn weights_sum_to_one_and_interpolate_depth_exactly() {
        // 1/z interpolated with the screen weights is the forward's depth; so sum_k b_k z_k = z (perspective).
        let mut rng = Rng(7);
        let (verts, faces) = scene(&mut rng, 6);
        let mesh = ScreenMesh::new(&verts, &faces, 1, verts.len() / 3).expect("mesh");
        let params = RasterParams::new(31, 37, 0.1, 10.0);
        let frags = rasterize_fragments(&mesh, &params).expect("raster");
        let w = pixel_weights(&mesh, &params, &frags.face_index).expect("weights");
        let mut drawn = 0;
        for (p, &f) in frags.face_index.iter().enumerate() {
            let wp = &w[p * 3..p * 3 + 3];
            if f < 0 {
                assert_eq!(wp, &[0.0, 0.0, 0.0]);
                continue;
            }
            drawn += 1;
            assert!((wp.iter().sum::<f32>() - 1.0).abs() < 1e-5);
            let z: f32 = (0..3)
                .map(|k| wp[k] * mesh.vert(0, faces[f as usize * 3 + k] as usize)[2])
                .sum();
            assert!(
                (z - frags.depth[p]).abs() < 1e-4 * z,
                "pixel {p}: {z} vs {}",
                frags.depth[p]
            );
        }
        assert!(drawn > 100);
    }

    #[test]
    fn the_weight_gradient_matches_finite_differences() {
        let mut rng = Rng(3);
        for ortho in [false, true] {
            let (verts, faces) = scene(&mut rng, 3);
            let mut params = RasterParams::new(21, 23, 0.1, 10.0);
            if ortho {
                params.projection = crate::input::Projection::Orthographic;
            }
            let mesh = ScreenMesh::new(&verts, &faces, 1, verts.len() / 3).expect("mesh");
            let fi = rasterize_fragments(&mesh, &params)
                .expect("raster")
                .face_index;
            let g: Vec<f32> = (0..fi.len() * 3)
                .map(|_| (rng.next() - 0.5) as f32)
                .collect();
            let loss = |v: &[f32]| -> f64 {
                let m = ScreenMesh::new(v, &faces, 1, v.len() / 3).expect("mesh");
                let w = pixel_weights(&m, &params, &fi).expect("weights");
                w.iter().zip(&g).map(|(a, b)| *a as f64 * *b as f64).sum()
            };
            let grad = pixel_weights_backward(&mesh, &params, &fi, &g).expect("backward");
            for i in 0..verts.len() {
                let h = 2.5e-4f32;
                let (mut a, mut b) = (verts.clone(), verts.clone());
                a[i] += h;
                b[i] -= h;
                let fd = (loss(&a) - loss(&b)) / (2.0 * h as f64);
                // Central differences converge as h^2 (the weights are rational in the coordinates): 1e-3 at h = 2.5e-4.
                let tol = 5e-3 * fd.abs().max(1.0);
                assert!(
                    (fd - grad[i] as f64).abs() < tol,
                    "ortho {ortho} coord {i}: fd {fd} vs {}",
                    grad[i]
                );
            }
        }
    }

    #[test]
    fn interpolation_gradients_match_finite_differences() {
        let mut rng = Rng(9);
        let (verts, faces) = scene(&mut rng, 4);
        let verts2: Vec<f32> = verts.iter().chain(verts.iter()).copied().collect();
        let mesh = ScreenMesh::new(&verts2, &faces, 2, verts.len() / 3).expect("mesh");
        let params = RasterParams::new(17, 19, 0.1, 10.0);
        let fi = rasterize_fragments(&mesh, &params)
            .expect("raster")
            .face_index;
        let w = pixel_weights(&mesh, &params, &fi).expect("weights");
        let rows = 5;
        let corners: Vec<i32> = (0..faces.len()).map(|_| rng.below(rows) as i32).collect();
        let values: Vec<f32> = (0..rows * 2).map(|_| rng.next() as f32).collect();
        let g: Vec<f32> = (0..fi.len() * 2)
            .map(|_| (rng.next() - 0.5) as f32)
            .collect();
        fn uvs<'a>(values: &'a [f32], corners: &'a [i32], rows: usize) -> CornerAttrs<'a> {
            CornerAttrs {
                values,
                corners,
                batch: 1,
                rows,
                channels: 2,
                arg: "uvs",
            }
        }

        let out =
            interpolate(&mesh, &params, &fi, &w, &uvs(&values, &corners, rows)).expect("interp");
        let grads =
            interpolate_backward(&mesh, &params, &fi, &w, &uvs(&values, &corners, rows), &g)
                .expect("bwd");
        // Linear in the values and in the weights: the gradients are the exact adjoints.
        let dot = |a: &[f32], b: &[f32]| {
            a.iter()
                .zip(b)
                .map(|(x, y)| *x as f64 * *y as f64)
                .sum::<f64>()
        };
        let probe: Vec<f32> = (0..values.len())
            .map(|_| (rng.next() - 0.5) as f32)
            .collect();
        let moved =
            interpolate(&mesh, &params, &fi, &w, &uvs(&probe, &corners, rows)).expect("interp");
        assert!((dot(&moved, &g) - dot(&probe, &grads.grad_values)).abs() < 1e-4);
        let wp: Vec<f32> = (0..w.len()).map(|_| (rng.next() - 0.5) as f32).collect();
        let moved =
            interpolate(&mesh, &params, &fi, &wp, &uvs(&values, &corners, rows)).expect("interp");
        let masked: f64 = dot(&wp, &grads.grad_weights);
        assert!((dot(&moved, &g) - masked).abs() < 1e-4);
        assert!(out.iter().any(|&x| x != 0.0));
    }

    #[test]
    fn bad_corner_rows_and_shapes_are_errors_naming_the_argument() {
        let verts = [-1.0f32, -1.0, 2.0, 1.0, -1.0, 2.0, -1.0, 1.0, 2.0];
        let mesh = ScreenMesh::new(&verts, &[0, 1, 2], 1, 3).expect("mesh");
        let params = RasterParams::new(4, 4, 0.1, 10.0);
        let fi = rasterize_fragments(&mesh, &params)
            .expect("raster")
            .face_index;
        let w = pixel_weights(&mesh, &params, &fi).expect("weights");
        let values = [0.0f32; 4];
        let bad = CornerAttrs {
            values: &values,
            corners: &[0, 1, 2],
            batch: 1,
            rows: 2,
            channels: 2,
            arg: "uvs",
        };
        let e = interpolate(&mesh, &params, &fi, &w, &bad).expect_err("row 2 of 2");
        assert!(
            e.to_string().contains("corners") && e.to_string().contains("uvs"),
            "{e}"
        );
        let nan = [f32::NAN; 6];
        let bad = CornerAttrs {
            values: &nan,
            corners: &[0, 1, 2],
            batch: 1,
            rows: 3,
            channels: 2,
            arg: "uvs",
        };
        let e = interpolate(&mesh, &params, &fi, &w, &bad).expect_err("NaN");
        assert!(e.to_string().starts_with("uvs"), "{e}");
        let short = CornerAttrs {
            values: &values,
            corners: &[0, 1, 2],
            batch: 1,
            rows: 3,
            channels: 2,
            arg: "uvs",
        };
        let e = interpolate(&mesh, &params, &fi, &w, &short).expect_err("4 of 6 values");
        assert!(e.to_string().starts_with("uvs"), "{e}");
    }
}
