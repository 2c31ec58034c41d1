//! Backward pass of the rasterizer.
//!
//! * `grad_face_attrs` is exact: the cotangent of each pixel goes to the face drawn there.
//! * `grad_verts_screen` is the Neural Mesh Renderer's approximate rasterization gradient (Kato, Ushiku, Harada,
//!   CVPR 2018, sec. 3), with occlusion-aware OUT sweeps. The backward pass recomputes everything it needs from the
//!   face-index map and the positions (per-face setup, depths at pixel centres); nothing is stored by the forward.
//!
//! Determinism: each face's contribution is computed independently (in parallel) into its own partial, and the
//! partials are added to the vertices in increasing face order; pixels are summed in row-major order for
//! `grad_face_attrs`. Results are therefore bit-identical for any thread count.
//!
//! The exact, step-by-step definition (the same text as `docs/NMR_GRADIENT.md`) follows.
//!
#![doc = include_str!("../../../docs/NMR_GRADIENT.md")]

use rayon::prelude::*;

use crate::error::{RasterError, Result};
use crate::input::{check_finite, FaceAttrs, RasterParams, ScreenMesh};
use crate::setup::{setup_faces, FaceSetup};

/// NMR's `eps` added to the signed displacement (NDC units) before dividing.
pub const EPS: f64 = 1e-4;

/// Gradients returned by [`rasterize_backward`], flat row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Gradients {
    /// `(B, N, 3)` gradient with respect to `verts_screen` (z component 0).
    pub grad_verts_screen: Vec<f32>,
    /// `(B, M, C)` gradient with respect to `face_attrs`.
    pub grad_face_attrs: Vec<f32>,
}

/// The forward outputs and the image cotangent needed by the backward pass.
#[derive(Debug, Clone, Copy)]
pub struct BackwardInputs<'a> {
    /// `(B, H, W)` face index map from the forward pass.
    pub face_index: &'a [i32],
    /// `(B, H, W, C)` image from the forward pass.
    pub image: &'a [f32],
    /// `(B, H, W, C)` cotangent of the image.
    pub grad_image: &'a [f32],
}

impl BackwardInputs<'_> {
    fn validate(&self, batch: usize, num_faces: usize, channels: usize, params: &RasterParams) -> Result<()> {
        let (h, w) = (params.height, params.width);
        let n = batch * h * w;
        if self.face_index.len() != n {
            return Err(RasterError::shape(
                "face_index",
                format!("({batch}, {h}, {w})"),
                format!("{} values", self.face_index.len()),
            ));
        }
        for (arg, arr) in [("image", self.image), ("grad_image", self.grad_image)] {
            if arr.len() != n * channels {
                return Err(RasterError::shape(
                    arg,
                    format!("({batch}, {h}, {w}, {channels})"),
                    format!("{} values", arr.len()),
                ));
            }
            check_finite(arg, arr)?;
        }
        if let Some(index) = self.face_index.iter().position(|&f| f < -1 || f as i64 >= num_faces as i64) {
            return Err(RasterError::FaceMapOutOfRange {
                index,
                value: self.face_index[index] as i64,
                num_faces,
            });
        }
        Ok(())
    }
}

/// Per-batch-element context of the gradient sweeps.
struct Ctx<'a> {
    setups: &'a [FaceSetup],
    face_index: &'a [i32],
    image: &'a [f32],
    grad: &'a [f32],
    attrs: &'a [f32],
    channels: usize,
    params: &'a RasterParams,
}

/// Sweep axis: lines are image columns (`U`, moves vertices in v, gives the y gradient) or rows (`V`, gives x).
#[derive(Clone, Copy, PartialEq)]
enum Axis {
    U,
    V,
}

impl Ctx<'_> {
    /// Whether face `f` would be drawn at pixel `(row, col)` if it extended there (depth test against the face
    /// currently drawn, recomputed from the positions; lower index wins exact ties).
    fn covers(&self, f: usize, row: i32, col: i32) -> bool {
        let Some(zf) = self.setups[f].depth_at(row, col) else { return false };
        if !(zf >= self.params.near && zf <= self.params.far) {
            return false;
        }
        let fp = self.face_index[row as usize * self.params.width + col as usize];
        if fp < 0 {
            return true;
        }
        match self.setups[fp as usize].depth_at(row, col) {
            None => true,
            Some(zp) => zf < zp || (zf == zp && f < fp as usize),
        }
    }

    /// `sum_c G[P, c] * (new[c] - I[P, c])`.
    #[inline]
    fn delta(&self, p: usize, new: &[f32]) -> f64 {
        let c = self.channels;
        let (g, i) = (&self.grad[p * c..(p + 1) * c], &self.image[p * c..(p + 1) * c]);
        let mut acc = 0.0f64;
        for k in 0..c {
            acc += g[k] as f64 * (new[k] as f64 - i[k] as f64);
        }
        acc
    }

    /// NMR gradient partial of face `f`: `[corner][x or y]`.
    fn face_grad(&self, f: usize) -> [[f64; 2]; 3] {
        let s = &self.setups[f];
        let (h, w) = (self.params.height as i64, self.params.width as i64);
        let c = self.channels;
        let attrs_f = &self.attrs[f * c..(f + 1) * c];
        let mut g = [[0.0f64; 2]; 3];
        for e in 0..3 {
            let (a, cc, o) = (e, (e + 1) % 3, (e + 2) % 3);
            for axis in [Axis::U, Axis::V] {
                let (p, q) = match axis {
                    Axis::U => (&s.u, &s.v),
                    Axis::V => (&s.v, &s.u),
                };
                let (lines, len) = match axis {
                    Axis::U => (w, h),
                    Axis::V => (h, w),
                };
                let (pa, qa, pc, qc, po, qo) = (p[a], q[a], p[cc], q[cc], p[o], q[o]);
                if pa == pc {
                    continue;
                }
                let slope = (qc - qa) / (pc - pa);
                let q_line = qa + slope * (po - pa);
                let dir: i64 = if qo > q_line { -1 } else { 1 };
                let lo = pa.min(pc).ceil().max(0.0);
                let hi = pa.max(pc).floor().min((lines - 1) as f64);
                if lo > hi {
                    continue;
                }
                let comp = if axis == Axis::U { 1 } else { 0 };
                let to_ndc = |disp: f64| match axis {
                    Axis::U => -2.0 * disp / h as f64,
                    Axis::V => 2.0 * disp / w as f64,
                };
                let pix = |d0: i64, d: i64| -> usize {
                    match axis {
                        Axis::U => (d * w + d0) as usize,
                        Axis::V => (d0 * w + d) as usize,
                    }
                };
                let rc = |d0: i64, d: i64| -> (i32, i32) {
                    match axis {
                        Axis::U => (d as i32, d0 as i32),
                        Axis::V => (d0 as i32, d as i32),
                    }
                };
                for d0 in (lo as i64)..=(hi as i64) {
                    let d0f = d0 as f64;
                    let cross = qa + slope * (d0f - pa);
                    let d_in_f = if dir > 0 { cross.floor() } else { cross.ceil() };
                    if !(d_in_f >= 0.0 && d_in_f <= (len - 1) as f64) {
                        continue;
                    }
                    let d_in = d_in_f as i64;
                    let d_out = d_in + dir;
                    if d_out < 0 || d_out >= len {
                        continue;
                    }
                    let contribute = |g: &mut [[f64; 2]; 3], d: i64, delta: f64| {
                        let t = d as f64 - cross;
                        if pc != d0f {
                            let dist = nudge(to_ndc((pc - pa) / (pc - d0f) * t));
                            g[a][comp] += delta / dist;
                        }
                        if pa != d0f {
                            let dist = nudge(to_ndc((pc - pa) / (d0f - pa) * t));
                            g[cc][comp] += delta / dist;
                        }
                    };
                    // OUT: pixels beyond the edge that the face would cover.
                    if self.face_index[pix(d0, d_in)] == f as i32 {
                        let mut d = d_out;
                        while d >= 0 && d < len {
                            let px = pix(d0, d);
                            let (row, col) = rc(d0, d);
                            if self.face_index[px] != f as i32 && self.covers(f, row, col) {
                                let delta = self.delta(px, attrs_f);
                                if delta < 0.0 {
                                    contribute(&mut g, d, delta);
                                }
                            }
                            d += dir;
                        }
                    }
                    // IN: pixels of the face that would be uncovered.
                    let cross2 = if (d0f - pa) * (d0f - po) < 0.0 {
                        qa + (qo - qa) / (po - pa) * (d0f - pa)
                    } else if pc != po {
                        qo + (qc - qo) / (pc - po) * (d0f - po)
                    } else {
                        qo
                    };
                    let limit = if dir > 0 { cross2.ceil() } else { cross2.floor() };
                    let from = d_in_f.min(limit).max(0.0) as i64;
                    let to = d_in_f.max(limit).min((len - 1) as f64) as i64;
                    let out_px = pix(d0, d_out);
                    let out_color = &self.image[out_px * c..(out_px + 1) * c];
                    for d in from..=to {
                        let px = pix(d0, d);
                        if self.face_index[px] != f as i32 {
                            continue;
                        }
                        let delta = self.delta(px, out_color);
                        if delta < 0.0 {
                            contribute(&mut g, d, delta);
                        }
                    }
                }
            }
        }
        g
    }
}

/// NMR's `dist = dist + eps` if positive else `dist - eps`.
#[inline]
fn nudge(dist: f64) -> f64 {
    if dist > 0.0 {
        dist + EPS
    } else {
        dist - EPS
    }
}

/// Backward pass: exact attribute gradient and NMR's approximate vertex gradient (see the module docs).
///
/// `mesh`, `attrs` and `params` must be those of the forward pass; `inputs` holds its outputs and the cotangent.
pub fn rasterize_backward(
    mesh: &ScreenMesh<'_>,
    attrs: &FaceAttrs<'_>,
    params: &RasterParams,
    inputs: &BackwardInputs<'_>,
) -> Result<Gradients> {
    mesh.validate()?;
    params.validate()?;
    attrs.validate(mesh)?;
    let (m, c, hw) = (mesh.num_faces(), attrs.channels, params.pixels());
    inputs.validate(mesh.batch, m, c, params)?;
    let nv = mesh.num_verts;
    let mut grad_verts_screen = vec![0f32; mesh.batch * nv * 3];
    let mut grad_face_attrs = vec![0f32; mesh.batch * m * c];
    grad_verts_screen.par_chunks_mut(nv * 3).zip(grad_face_attrs.par_chunks_mut(m * c)).enumerate().for_each(
        |(b, (gv, ga))| {
            let face_index = &inputs.face_index[b * hw..(b + 1) * hw];
            let image = &inputs.image[b * hw * c..(b + 1) * hw * c];
            let grad = &inputs.grad_image[b * hw * c..(b + 1) * hw * c];
            // Exact attribute gradient, summed in pixel order.
            let mut acc = vec![0f64; m * c];
            let mut visible = vec![false; m];
            for (p, &f) in face_index.iter().enumerate() {
                if f >= 0 {
                    let f = f as usize;
                    visible[f] = true;
                    for k in 0..c {
                        acc[f * c + k] += grad[p * c + k] as f64;
                    }
                }
            }
            for (dst, &src) in ga.iter_mut().zip(&acc) {
                *dst = src as f32;
            }
            // NMR vertex gradient: per-face partials in parallel, reduced in face order.
            let setups = setup_faces(mesh, b, params);
            let ctx = Ctx {
                setups: &setups,
                face_index,
                image,
                grad,
                attrs: &attrs.values[b * m * c..(b + 1) * m * c],
                channels: c,
                params,
            };
            let partials: Vec<[[f64; 2]; 3]> = (0..m)
                .into_par_iter()
                .map(|f| if visible[f] && setups[f].active { ctx.face_grad(f) } else { [[0.0; 2]; 3] })
                .collect();
            let mut accv = vec![0f64; nv * 2];
            for (f, part) in partials.iter().enumerate() {
                for (k, &vi) in mesh.face(f).iter().enumerate() {
                    accv[vi * 2] += part[k][0];
                    accv[vi * 2 + 1] += part[k][1];
                }
            }
            for (k, xy) in accv.chunks_exact(2).enumerate() {
                gv[k * 3] = xy[0] as f32;
                gv[k * 3 + 1] = xy[1] as f32;
            }
        },
    );
    Ok(Gradients { grad_verts_screen, grad_face_attrs })
}
