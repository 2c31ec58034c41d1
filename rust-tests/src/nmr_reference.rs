//! A plain (scalar, unplanned) implementation of the backward pass of `docs/NMR_GRADIENT.md`, with the local
//! gradient's truncation of `docs/LOCAL_GRADIENT.md`, without input validation (the callers' inputs pass it): the
//! reference the core's backward is compared against on randomized and existing scenes (`tests/backward_reference.rs`).
#![allow(clippy::too_many_arguments)]

use rayon::prelude::*;

use meshadv_raster::backward::{BackwardInputs, Gradients, Visibility};
use meshadv_raster::input::{FaceAttrs, RasterParams, ScreenMesh};
use meshadv_raster::setup::{setup_faces, FaceSetup};
use meshadv_raster::Result;

/// NMR's `eps` added to the signed displacement (NDC units) before dividing.
const EPS: f64 = 1e-4;

/// Line field: index of the drawn face (as f64, -1 on background).
const FACE: usize = 0;
/// Line field: depth-test key of the drawn face (see [`depth_keys`]).
const KEY: usize = 1;
/// Line field: `sum_c G[P, c] * I[P, c]`.
const GI: usize = 2;
/// Line field: first cotangent channel (channel `k` is field `GRAD + k`).
const GRAD: usize = 3;

/// Depth-test key of the face drawn at each pixel (row-major; larger = nearer): `1/z` in perspective, `-z` in
/// orthographic, with `z` recomputed from the positions exactly as the forward computes it; `-inf` on background.
fn depth_keys(setups: &[FaceSetup], face_index: &[i32], params: &RasterParams) -> Vec<f64> {
    let w = params.width;
    let mut key = vec![f64::NEG_INFINITY; face_index.len()];
    key.par_chunks_mut(w)
        .zip(face_index.par_chunks(w))
        .enumerate()
        .for_each(|(i, (key, faces))| {
            for (j, (k, &f)) in key.iter_mut().zip(faces).enumerate() {
                if f >= 0 {
                    let s = &setups[f as usize];
                    *k = match s.depth_at(i as i32, j as i32) {
                        Some(z) if s.ortho => -z,
                        Some(z) => 1.0 / z,
                        None => f64::NEG_INFINITY,
                    };
                }
            }
        });
    key
}

/// Per-pixel buffers of one batch element laid out along sweep lines (image rows for the row sweeps, axis V, or
/// image columns for the column sweeps, axis U), so that the inner loops read memory contiguously: line `d0` holds
/// the planes of its fields ([`FACE`], [`KEY`], [`GI`], then the `C` cotangent channels), `len` f64 values each.
struct Lines {
    /// The planes, line after line, field after field.
    data: Vec<f64>,
    /// Line length in pixels.
    len: usize,
    /// Fields per pixel, `GRAD + C`.
    fields: usize,
    /// Per line, the range `[first, last + 1)` of pixels whose cotangent is not all zero (`[0, 0]` when none):
    /// pixels outside it have `delta = 0` and never contribute.
    nonzero: Vec<[usize; 2]>,
}

impl Lines {
    /// Builds the buffers; `transpose` gives column lines.
    fn new(
        key: &[f64],
        face_index: &[i32],
        image: &[f32],
        grad: &[f32],
        c: usize,
        params: &RasterParams,
        transpose: bool,
    ) -> Lines {
        let (h, w) = (params.height, params.width);
        let (lines, len) = if transpose { (w, h) } else { (h, w) };
        let fields = GRAD + c;
        let mut data = vec![0f64; lines * fields * len];
        let mut nonzero = vec![[0usize; 2]; lines];
        data.par_chunks_mut(fields * len)
            .zip(nonzero.par_iter_mut())
            .enumerate()
            .for_each(|(d0, (line, nz))| {
                let (mut first, mut last) = (len, 0);
                for d in 0..len {
                    let p = if transpose { d * w + d0 } else { d0 * w + d };
                    line[FACE * len + d] = face_index[p] as f64;
                    line[KEY * len + d] = key[p];
                    let (gp, ip) = (&grad[p * c..(p + 1) * c], &image[p * c..(p + 1) * c]);
                    let mut gi = 0f64;
                    for k in 0..c {
                        gi += gp[k] as f64 * ip[k] as f64;
                        line[(GRAD + k) * len + d] = gp[k] as f64;
                    }
                    line[GI * len + d] = gi;
                    if gp.iter().any(|&x| x != 0.0) {
                        first = first.min(d);
                        last = d + 1;
                    }
                }
                *nz = if first < last { [first, last] } else { [0, 0] };
            });
        Lines {
            data,
            len,
            fields,
            nonzero,
        }
    }

    /// Field `field` of the pixels `range` of line `d0`.
    #[inline(always)]
    fn plane(&self, d0: usize, field: usize, range: std::ops::Range<usize>) -> &[f64] {
        let o = (d0 * self.fields + field) * self.len;
        &self.data[o + range.start..o + range.end]
    }

    /// Field `field` of pixel `d` of line `d0`.
    #[inline(always)]
    fn get(&self, d0: usize, d: usize, field: usize) -> f64 {
        self.data[(d0 * self.fields + field) * self.len + d]
    }
}

/// Per-task scratch buffers of the OUT sweeps (one line each), reused across faces.
struct Scratch {
    /// `sum_c G[P, c] A[f, c]` per pixel of the sweep.
    ga: Vec<f64>,
    /// Contribution to endpoint `a` per pixel.
    out_a: Vec<f64>,
    /// Contribution to endpoint `c` per pixel.
    out_c: Vec<f64>,
}

impl Scratch {
    /// Buffers for lines of up to `len` pixels.
    fn new(len: usize) -> Scratch {
        Scratch {
            ga: vec![0.0; len],
            out_a: vec![0.0; len],
            out_c: vec![0.0; len],
        }
    }
}

/// `0, 1, 2, ...` as f64 (pixel positions along a line).
fn positions(len: usize) -> Vec<f64> {
    (0..len).map(|d| d as f64).collect()
}

/// Per-batch-element context of the gradient sweeps.
struct Ctx<'a> {
    setups: &'a [FaceSetup],
    rows: &'a Lines,
    cols: &'a Lines,
    /// `(M, C)` face attributes as f64.
    attrs: &'a [f64],
    /// `(H, W, C)` image (row-major, as given).
    image: &'a [f32],
    /// Pixel positions along a line, see [`positions`].
    pos: &'a [f64],
    channels: usize,
    params: &'a RasterParams,
    /// The local gradient's sweep length in pixels (`None`: NMR's, unbounded).
    radius: Option<usize>,
}

/// Sweep axis: lines are image columns (`U`, moves vertices in v, gives the y gradient) or rows (`V`, gives x).
#[derive(Clone, Copy, PartialEq)]
enum Axis {
    U,
    V,
}

impl Ctx<'_> {
    /// NMR gradient partial of face `f`: `[corner][x or y]`.
    fn face_grad(&self, f: usize, scratch: &mut Scratch) -> [[f64; 2]; 3] {
        let s = &self.setups[f];
        let (h, w) = (self.params.height as i64, self.params.width as i64);
        // Depth-test keys (1/z in perspective, -z in orthographic) allowed by the clip range [near, far].
        let (near, far) = (self.params.near, self.params.far);
        let (key_lo, key_hi) = if s.ortho {
            (-far, -near)
        } else {
            (1.0 / far, 1.0 / near)
        };
        // The key is `sgn * plane(u, v)`: the plane interpolates 1/z (perspective) or z (orthographic).
        let sgn = if s.ortho { -1.0 } else { 1.0 };
        let c = self.channels;
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
                    let d_in_f = if dir > 0 { floor(cross) } else { ceil(cross) };
                    if !(d_in_f >= 0.0 && d_in_f <= (len - 1) as f64) {
                        continue;
                    }
                    let d_in = d_in_f as i64;
                    let d_out = d_in + dir;
                    if d_out < 0 || d_out >= len {
                        continue;
                    }
                    let line = d0 as usize;
                    // Endpoint motion needed per pixel of crossing motion (None when the endpoint is on the line).
                    let ka = (pc != d0f).then(|| ndc * (pc - pa) / (pc - d0f));
                    let kc = (pa != d0f).then(|| ndc * (pc - pa) / (d0f - pa));
                    // OUT: pixels beyond the edge that the face would cover (only where the cotangent is not zero).
                    if ln.get(line, d_in as usize, FACE) == fi as f64 {
                        let (start, end) = if dir > 0 {
                            (d_out as usize, ln.len)
                        } else {
                            (0, d_out as usize + 1)
                        };
                        // The local gradient: only the `radius` pixels nearest the edge, `d_out` first.
                        let (start, end) = match self.radius {
                            Some(r) if dir > 0 => (start, end.min(d_out as usize + r)),
                            Some(r) => (start.max((d_out + 1 - r as i64).max(0) as usize), end),
                            None => (start, end),
                        };
                        let [nz0, nz1] = ln.nonzero[line];
                        let (start, end) = (start.max(nz0), end.min(nz1));
                        if start < end {
                            // `nudge(k t)` is `k t + sign(k dir) EPS` beyond the edge (`t` has the sign of `dir`).
                            let split = |k: Option<f64>| match k {
                                Some(k) => (k, if k * dir as f64 > 0.0 { EPS } else { -EPS }),
                                None => (0.0, 1.0),
                            };
                            let ((ka_, ea), (kc_, ec)) = (split(ka), split(kc));
                            let sweep = OutSweep {
                                fi: fi as f64,
                                key0: sgn * (pl_line * d0f + s.plane[2]),
                                key_step: sgn * pl_step,
                                key_lo,
                                key_hi,
                                cross,
                                ka: ka_,
                                ea,
                                kc: kc_,
                                ec,
                                attrs: attrs_f,
                            };
                            let (sa, sc) = sweep.run(ln, line, start, end, self.pos, scratch);
                            if ka.is_some() {
                                g[a][comp] += sa;
                            }
                            if kc.is_some() {
                                g[cc][comp] += sc;
                            }
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
                    let limit = if dir > 0 { ceil(cross2) } else { floor(cross2) };
                    let from = d_in_f.min(limit).max(0.0) as i64;
                    let to = d_in_f.max(limit).min((len - 1) as f64) as i64;
                    // The local gradient: only the pixels within `radius - 1` of `d_in`.
                    let (from, to) = match self.radius {
                        Some(r) => (
                            from.max(d_in - (r as i64 - 1)),
                            to.min(d_in + (r as i64 - 1)),
                        ),
                        None => (from, to),
                    };
                    let out_px = match axis {
                        Axis::U => d_out as usize * w as usize + line,
                        Axis::V => line * w as usize + d_out as usize,
                    };
                    let out_color = &self.image[out_px * c..(out_px + 1) * c];
                    if from <= to {
                        let (sa, sc) = in_sweep(
                            ln,
                            line,
                            from as usize..to as usize + 1,
                            fi as f64,
                            out_color,
                            cross,
                            ka.unwrap_or(0.0),
                            kc.unwrap_or(0.0),
                        );
                        if ka.is_some() {
                            g[a][comp] += sa;
                        }
                        if kc.is_some() {
                            g[cc][comp] += sc;
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
    /// The face, as f64 (compared with the [`FACE`] field).
    fi: f64,
    /// Depth-test key of the face's plane at pixel 0 of the line.
    key0: f64,
    /// Key increment per pixel along the line.
    key_step: f64,
    /// Smallest key allowed by the clip range.
    key_lo: f64,
    /// Largest key allowed by the clip range.
    key_hi: f64,
    /// Where the edge crosses the line.
    cross: f64,
    /// `to_ndc` motion of endpoint `a` per pixel of crossing motion (0 when `a` is on the line).
    ka: f64,
    /// `sign(ka dir) EPS` (1 when `a` is on the line, so that its denominator never vanishes).
    ea: f64,
    /// As `ka`, endpoint `c`.
    kc: f64,
    /// As `ea`, endpoint `c`.
    ec: f64,
    /// The face's attributes.
    attrs: &'a [f64],
}

/// First index in `lo..hi` where `pred` is false, for a predicate that is true then false (`hi` if none).
#[inline]
fn partition_point(mut lo: usize, mut hi: usize, pred: impl Fn(usize) -> bool) -> usize {
    while lo < hi {
        let mid = lo + (hi - lo) / 2;
        if pred(mid) {
            lo = mid + 1;
        } else {
            hi = mid;
        }
    }
    lo
}

/// Sum of `v` in a fixed order (eight interleaved partial sums, then added pairwise).
#[inline(always)]
fn fixed_sum(v: &[f64]) -> f64 {
    let mut acc = [0f64; 8];
    let mut chunks = v.chunks_exact(8);
    for ch in &mut chunks {
        for l in 0..8 {
            acc[l] += ch[l];
        }
    }
    for (l, &x) in chunks.remainder().iter().enumerate() {
        acc[l] += x;
    }
    ((acc[0] + acc[1]) + (acc[2] + acc[3])) + ((acc[4] + acc[5]) + (acc[6] + acc[7]))
}

impl OutSweep<'_> {
    /// Depth-test key of the face's plane at pixel `d` of the line.
    #[inline(always)]
    fn key(&self, d: usize) -> f64 {
        self.key0 + self.key_step * d as f64
    }

    /// The pixels of `start..end` where the face's key is within the clip range. Exact: the computed key is a
    /// monotone function of `d` (products and sums round monotonically), so these pixels form one range.
    fn clip(&self, start: usize, end: usize) -> (usize, usize) {
        let above_lo = |d: usize| self.key(d) >= self.key_lo;
        let below_hi = |d: usize| self.key(d) <= self.key_hi;
        let inside = |d: usize| above_lo(d) && below_hi(d);
        if start >= end || (inside(start) && inside(end - 1)) {
            (start, end)
        } else if self.key_step > 0.0 {
            let s = partition_point(start, end, |d| !above_lo(d));
            (s, partition_point(s, end, below_hi))
        } else if self.key_step < 0.0 {
            let s = partition_point(start, end, |d| !below_hi(d));
            (s, partition_point(s, end, above_lo))
        } else {
            (start, start)
        }
    }

    /// Sums the contributions of pixels `start..end` of line `d0`. Returns the sums for endpoints `a` and `c`
    /// (meaningful only when their `k` is defined), each added in a fixed order.
    fn run(
        &self,
        ln: &Lines,
        d0: usize,
        start: usize,
        end: usize,
        pos: &[f64],
        scratch: &mut Scratch,
    ) -> (f64, f64) {
        let (start, end) = self.clip(start, end);
        if start >= end {
            return (0.0, 0.0);
        }
        let r = start..end;
        match self.attrs.len() {
            1 => self.kernel_ties::<1>(ln, d0, r, pos, scratch),
            2 => self.kernel_ties::<2>(ln, d0, r, pos, scratch),
            3 => self.kernel_ties::<3>(ln, d0, r, pos, scratch),
            4 => self.kernel_ties::<4>(ln, d0, r, pos, scratch),
            _ => {
                // Any channel count: sum_c G[P, c] A[f, c] into the scratch buffer first, channel by channel.
                let ga = &mut scratch.ga[..r.len()];
                ga.fill(0.0);
                for (k, &ak) in self.attrs.iter().enumerate() {
                    for (x, &g) in ga.iter_mut().zip(ln.plane(d0, GRAD + k, r.clone())) {
                        *x += g * ak;
                    }
                }
                self.kernel_ties::<0>(ln, d0, r, pos, scratch)
            }
        }
    }

    /// [`OutSweep::kernel`] without the exact-tie rule of the depth test, then with it if some pixel's key equals
    /// the face's (rare: coplanar neighbours), which is cheaper than testing ties at every pixel.
    #[inline(always)]
    fn kernel_ties<const C: usize>(
        &self,
        ln: &Lines,
        d0: usize,
        r: std::ops::Range<usize>,
        pos: &[f64],
        scratch: &mut Scratch,
    ) -> (f64, f64) {
        match self.kernel::<C, false>(ln, d0, r.clone(), pos, scratch) {
            Some(sums) => sums,
            None => self
                .kernel::<C, true>(ln, d0, r, pos, scratch)
                .unwrap_or((0.0, 0.0)),
        }
    }

    /// The OUT sweep over the pixels `r` of line `d0` (already clipped), for `C` channels (`C = 0`: with
    /// `sum_c G[P, c] A[f, c]` precomputed in `scratch.ga`). Without `TIES`, pixels whose key equals the face's are
    /// not handled and their presence gives `None`.
    #[inline(always)]
    fn kernel<const C: usize, const TIES: bool>(
        &self,
        ln: &Lines,
        d0: usize,
        r: std::ops::Range<usize>,
        pos: &[f64],
        scratch: &mut Scratch,
    ) -> Option<(f64, f64)> {
        let n = r.len();
        let mut tie = false;
        let g: [&[f64]; C] = std::array::from_fn(|k| &ln.plane(d0, GRAD + k, r.clone())[..n]);
        let a: [f64; C] = std::array::from_fn(|k| self.attrs[k]);
        let Scratch { ga, out_a, out_c } = scratch;
        let (pre, out_a, out_c) = (&ga[..n], &mut out_a[..n], &mut out_c[..n]);
        let face = &ln.plane(d0, FACE, r.clone())[..n];
        let key = &ln.plane(d0, KEY, r.clone())[..n];
        let gi = &ln.plane(d0, GI, r.clone())[..n];
        let pos = &pos[r][..n];
        for i in 0..n {
            let mut ga = if C == 0 { pre[i] } else { g[0][i] * a[0] };
            for k in 1..C {
                ga += g[k][i] * a[k];
            }
            let (fp, kp, d) = (face[i], key[i], pos[i]);
            let kf = self.key0 + self.key_step * d;
            let delta = ga - gi[i];
            // covers(f, P) (the clip range is handled by `clip`) and delta < 0.
            let nearer = if TIES {
                (kf > kp) | ((kf == kp) & (self.fi < fp))
            } else {
                tie |= kf == kp;
                kf > kp
            };
            let take = (fp != self.fi) & nearer & (delta < 0.0);
            let m = if take { delta } else { 0.0 };
            let t = d - self.cross;
            let (da, dc) = (self.ka * t + self.ea, self.kc * t + self.ec);
            // m / da and m / dc with one division.
            let q = m / (da * dc);
            out_a[i] = q * dc;
            out_c[i] = q * da;
        }
        (!tie).then(|| (fixed_sum(out_a), fixed_sum(out_c)))
    }
}

/// The IN sweep of one line over the pixels `range` (see the module docs): sums of the contributions to the edge
/// endpoints `a` and `c`, whose crossing-motion factors are `ka` and `kc` (meaningful only when defined).
#[allow(clippy::too_many_arguments)]
fn in_sweep(
    ln: &Lines,
    line: usize,
    range: std::ops::Range<usize>,
    fi: f64,
    out_color: &[f32],
    cross: f64,
    ka: f64,
    kc: f64,
) -> (f64, f64) {
    let (face, gi) = (
        ln.plane(line, FACE, range.clone()),
        ln.plane(line, GI, range.clone()),
    );
    let (mut sa, mut sc) = (0f64, 0f64);
    for (i, (&fp, &gi)) in face.iter().zip(gi).enumerate() {
        let d = range.start + i;
        let mut go = 0f64;
        for (k, &oc) in out_color.iter().enumerate() {
            go += ln.get(line, d, GRAD + k) * oc as f64;
        }
        let delta = go - gi;
        // Branch-free form of `if F[P] == f && delta < 0 { contribute(d, delta) }`.
        let m = if (fp == fi) & (delta < 0.0) {
            delta
        } else {
            0.0
        };
        let t = d as f64 - cross;
        let (da, dc) = (nudge(ka * t), nudge(kc * t));
        let q = m / (da * dc);
        sa += q * dc;
        sc += q * da;
    }
    (sa, sc)
}

/// `x.floor()` without a library call (the baseline x86-64 target has no rounding instruction).
#[inline(always)]
fn floor(x: f64) -> f64 {
    // Beyond 2^52 (and for infinities and NaN) `x` is its own floor.
    if x.abs() < 4503599627370496.0 {
        let t = x as i64 as f64;
        if t > x {
            t - 1.0
        } else {
            t
        }
    } else {
        x
    }
}

/// `x.ceil()` without a library call, see [`floor`].
#[inline(always)]
fn ceil(x: f64) -> f64 {
    -floor(-x)
}

/// NMR's `dist = dist + eps` if positive else `dist - eps`.
#[inline(always)]
fn nudge(dist: f64) -> f64 {
    dist + if dist > 0.0 { EPS } else { -EPS }
}

/// Backward pass: exact attribute gradient and NMR's approximate vertex gradient (see the module docs).
///
/// `mesh`, `attrs` and `params` must be those of the forward pass; `inputs` holds its outputs and the cotangent.
pub fn reference_backward(
    mesh: &ScreenMesh<'_>,
    attrs: &FaceAttrs<'_>,
    params: &RasterParams,
    inputs: &BackwardInputs<'_>,
) -> Result<Gradients> {
    mesh.validate()?;
    params.validate()?;
    attrs.validate(mesh)?;
    let (m, c, hw) = (mesh.num_faces(), attrs.channels, params.pixels());
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
            let key = depth_keys(&setups, face_index, params);
            let (rows, cols) = rayon::join(
                || Lines::new(&key, face_index, image, grad, c, params, false),
                || Lines::new(&key, face_index, image, grad, c, params, true),
            );
            let attrs_b: Vec<f64> = attrs.values[b * m * c..(b + 1) * m * c]
                .iter()
                .map(|&x| x as f64)
                .collect();
            let pos = positions(params.height.max(params.width));
            let ctx = Ctx {
                setups: &setups,
                rows: &rows,
                cols: &cols,
                attrs: &attrs_b,
                image,
                pos: &pos,
                channels: c,
                params,
                radius: match inputs.visibility {
                    Visibility::Nmr => None,
                    Visibility::Local { radius } => Some(radius),
                },
            };
            let partials: Vec<[[f64; 2]; 3]> = (0..m)
                .into_par_iter()
                .map_init(
                    || Scratch::new(params.height.max(params.width)),
                    |scratch, f| {
                        if visible[f] && setups[f].active {
                            ctx.face_grad(f, scratch)
                        } else {
                            [[0.0; 2]; 3]
                        }
                    },
                )
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
