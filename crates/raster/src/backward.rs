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
    /// Compute the (expensive) NMR vertex gradient; when false `grad_verts_screen` is all zeros.
    pub vertex_grad: bool,
}

impl BackwardInputs<'_> {
    fn validate(
        &self,
        batch: usize,
        num_faces: usize,
        channels: usize,
        params: &RasterParams,
    ) -> Result<()> {
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
        if let Some(index) = self
            .face_index
            .iter()
            .position(|&f| f < -1 || f as i64 >= num_faces as i64)
        {
            return Err(RasterError::FaceMapOutOfRange {
                index,
                value: self.face_index[index] as i64,
                num_faces,
            });
        }
        Ok(())
    }
}

/// Per-pixel buffers of one batch element laid out along sweep lines: pixel `d` of line `d0` is at `d0 * len + d`.
/// Row-major for the row sweeps (axis V); a transposed copy for the column sweeps (axis U) keeps the inner loops
/// contiguous.
struct Lines {
    /// Face index per pixel.
    face: Vec<i32>,
    /// Depth-test key of the drawn face per pixel (larger = nearer): `1/z` in perspective, `-z` in orthographic,
    /// with `z` recomputed from the positions as in the forward; `-inf` on background.
    key: Vec<f64>,
    /// `sum_c G[P, c] * I[P, c]`.
    gi: Vec<f64>,
    /// Cotangent, `C` per pixel.
    grad: Vec<f64>,
    /// Image, `C` per pixel.
    image: Vec<f32>,
    /// Line length.
    len: usize,
}

impl Lines {
    /// Builds the buffers; `transpose` gives column-major lines.
    fn new(
        setups: &[FaceSetup],
        face_index: &[i32],
        image: &[f32],
        grad: &[f32],
        c: usize,
        params: &RasterParams,
        transpose: bool,
    ) -> Lines {
        let (h, w) = (params.height, params.width);
        let n = h * w;
        let (mut face, mut key, mut gi) =
            (vec![-1i32; n], vec![f64::NEG_INFINITY; n], vec![0f64; n]);
        let (mut g, mut im) = (vec![0f64; n * c], vec![0f32; n * c]);
        for i in 0..h {
            for j in 0..w {
                let p = i * w + j;
                let q = if transpose { j * h + i } else { p };
                let f = face_index[p];
                face[q] = f;
                if f >= 0 {
                    let s = &setups[f as usize];
                    key[q] = match s.depth_at(i as i32, j as i32) {
                        Some(z) if s.ortho => -z,
                        Some(z) => 1.0 / z,
                        None => f64::NEG_INFINITY,
                    };
                }
                let mut acc = 0f64;
                for k in 0..c {
                    acc += grad[p * c + k] as f64 * image[p * c + k] as f64;
                }
                gi[q] = acc;
                for k in 0..c {
                    g[q * c + k] = grad[p * c + k] as f64;
                }
                im[q * c..(q + 1) * c].copy_from_slice(&image[p * c..(p + 1) * c]);
            }
        }
        Lines {
            face,
            key,
            gi,
            grad: g,
            image: im,
            len: if transpose { h } else { w },
        }
    }
}

/// Per-batch-element context of the gradient sweeps.
struct Ctx<'a> {
    setups: &'a [FaceSetup],
    rows: &'a Lines,
    cols: &'a Lines,
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
    /// NMR gradient partial of face `f`: `[corner][x or y]`, dispatching to a channel-count specialisation.
    fn face_grad(&self, f: usize) -> [[f64; 2]; 3] {
        match self.channels {
            1 => self.face_grad_c::<1>(f),
            3 => self.face_grad_c::<3>(f),
            4 => self.face_grad_c::<4>(f),
            _ => self.face_grad_c::<0>(f),
        }
    }

    /// [`Ctx::face_grad`] for `C` channels (`C = 0`: read the count at run time).
    fn face_grad_c<const C: usize>(&self, f: usize) -> [[f64; 2]; 3] {
        let s = &self.setups[f];
        let (h, w) = (self.params.height as i64, self.params.width as i64);
        // Depth window on the interpolated quantity: 1/z in [1/far, 1/near] (perspective) or z in [near, far].
        let (near, far) = (self.params.near, self.params.far);
        let (lo_key, hi_key) = if s.ortho {
            (near, far)
        } else {
            (1.0 / far, 1.0 / near)
        };
        let c = if C == 0 { self.channels } else { C };
        let fi = f as i32;
        let attrs_f = &self.attrs[f * c..(f + 1) * c];
        let mut g = [[0.0f64; 2]; 3];
        for e in 0..3 {
            let (a, cc, o) = (e, (e + 1) % 3, (e + 2) % 3);
            for axis in [Axis::U, Axis::V] {
                let (p, q, lines, len, ln) = match axis {
                    Axis::U => (&s.u, &s.v, w, h, self.cols),
                    Axis::V => (&s.v, &s.u, h, w, self.rows),
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
                // to_ndc(disp): U -> -2 disp / H, V -> 2 disp / W.
                let ndc = match axis {
                    Axis::U => -2.0 / h as f64,
                    Axis::V => 2.0 / w as f64,
                };
                // The face's interpolated depth quantity along a line: plane(u, v) with (u, v) = (d0, d) or (d, d0).
                let (pl_line, pl_step) = match axis {
                    Axis::U => (s.plane[0], s.plane[1]),
                    Axis::V => (s.plane[1], s.plane[0]),
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
                    let base = d0 as usize * ln.len;
                    // Endpoint motion needed per pixel of crossing motion (None when the endpoint is on the line).
                    let ka = (pc != d0f).then(|| ndc * (pc - pa) / (pc - d0f));
                    let kc = (pa != d0f).then(|| ndc * (pc - pa) / (d0f - pa));
                    let contribute = |g: &mut [[f64; 2]; 3], d: i64, delta: f64| {
                        let t = d as f64 - cross;
                        if let Some(k) = ka {
                            g[a][comp] += delta / nudge(k * t);
                        }
                        if let Some(k) = kc {
                            g[cc][comp] += delta / nudge(k * t);
                        }
                    };
                    // OUT: pixels beyond the edge that the face would cover.
                    if ln.face[base + d_in as usize] == fi {
                        let pl0 = pl_line * d0f + s.plane[2];
                        let eps_of = |k: Option<f64>| {
                            k.map_or(0.0, |k| if k * dir as f64 > 0.0 { EPS } else { -EPS })
                        };
                        let (eps_a, eps_c) = (eps_of(ka), eps_of(kc));
                        let (start, end) = if dir > 0 {
                            (d_out as usize, len as usize)
                        } else {
                            (0, d_out as usize + 1)
                        };
                        let (lo_px, hi_px) = (base + start, base + end);
                        let it = ln.face[lo_px..hi_px]
                            .iter()
                            .zip(&ln.key[lo_px..hi_px])
                            .zip(&ln.gi[lo_px..hi_px])
                            .zip(ln.grad[lo_px * c..hi_px * c].chunks_exact(c))
                            .enumerate();
                        let sweep = OutSweep {
                            fi,
                            start,
                            pl0,
                            pl_step,
                            lo_key,
                            hi_key,
                            ortho: s.ortho,
                            cross,
                            ka: ka.unwrap_or(0.0),
                            kc: kc.unwrap_or(0.0),
                            eps_a,
                            eps_c,
                            attrs: attrs_f,
                        };
                        let (sa, sc) = if dir > 0 {
                            sweep.run(it)
                        } else {
                            sweep.run(it.rev())
                        };
                        if ka.is_some() {
                            g[a][comp] += sa;
                        }
                        if kc.is_some() {
                            g[cc][comp] += sc;
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
                    let limit = if dir > 0 {
                        cross2.ceil()
                    } else {
                        cross2.floor()
                    };
                    let from = d_in_f.min(limit).max(0.0) as i64;
                    let to = d_in_f.max(limit).min((len - 1) as f64) as i64;
                    let out_px = base + d_out as usize;
                    let out_color = &ln.image[out_px * c..(out_px + 1) * c];
                    for d in from..=to {
                        let px = base + d as usize;
                        if ln.face[px] != fi {
                            continue;
                        }
                        let gp = &ln.grad[px * c..(px + 1) * c];
                        let mut go = 0f64;
                        for k in 0..c {
                            go += gp[k] * out_color[k] as f64;
                        }
                        let delta = go - ln.gi[px];
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

/// One OUT sweep along a line (see the module docs), with local accumulators for the two edge endpoints.
struct OutSweep<'a> {
    fi: i32,
    start: usize,
    pl0: f64,
    pl_step: f64,
    lo_key: f64,
    hi_key: f64,
    ortho: bool,
    cross: f64,
    ka: f64,
    kc: f64,
    eps_a: f64,
    eps_c: f64,
    attrs: &'a [f32],
}

impl OutSweep<'_> {
    /// Sums the contributions of the pixels produced by `it` (`(i, (((face, key), gi), grad))`, `d = start + i`),
    /// in iteration order. Returns the sums for endpoints `a` and `c` (meaningful only when their `k` is defined).
    #[inline(always)]
    fn run<'b>(
        &self,
        it: impl Iterator<Item = (usize, (((&'b i32, &'b f64), &'b f64), &'b [f64]))>,
    ) -> (f64, f64) {
        let (mut sa, mut sc) = (0f64, 0f64);
        for (i, (((&fp, &kp), &gi), gp)) in it {
            if fp == self.fi {
                continue;
            }
            let d = (self.start + i) as f64;
            let val = self.pl0 + self.pl_step * d;
            if !(val >= self.lo_key && val <= self.hi_key) {
                continue;
            }
            let kf = if self.ortho { -val } else { val };
            if !(kf > kp || (kf == kp && self.fi < fp)) {
                continue;
            }
            let mut ga = 0f64;
            for (gk, ak) in gp.iter().zip(self.attrs) {
                ga += gk * *ak as f64;
            }
            // Branch-free form of `if delta < 0 { contribute(d, delta) }`: beyond the edge `t = d - cross` has the
            // sign of `dir` and is never 0, so `nudge(k t)` is `k t + sign(k dir) EPS`; a skipped pixel adds 0.
            let m = (ga - gi).min(0.0);
            let t = d - self.cross;
            sa += m / (self.ka * t + self.eps_a);
            sc += m / (self.kc * t + self.eps_c);
        }
        (sa, sc)
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
    grad_verts_screen
        .par_chunks_mut(nv * 3)
        .zip(grad_face_attrs.par_chunks_mut(m * c))
        .enumerate()
        .for_each(|(b, (gv, ga))| {
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
            if !inputs.vertex_grad {
                return;
            }
            // NMR vertex gradient: per-face partials in parallel, reduced in face order.
            let setups = setup_faces(mesh, b, params);
            let (rows, cols) = rayon::join(
                || Lines::new(&setups, face_index, image, grad, c, params, false),
                || Lines::new(&setups, face_index, image, grad, c, params, true),
            );
            let ctx = Ctx {
                setups: &setups,
                rows: &rows,
                cols: &cols,
                attrs: &attrs.values[b * m * c..(b + 1) * m * c],
                channels: c,
                params,
            };
            let partials: Vec<[[f64; 2]; 3]> = (0..m)
                .into_par_iter()
                .map(|f| {
                    if visible[f] && setups[f].active {
                        ctx.face_grad(f)
                    } else {
                        [[0.0; 2]; 3]
                    }
                })
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
        });
    Ok(Gradients {
        grad_verts_screen,
        grad_face_attrs,
    })
}
