//! Backward pass of the rasterizer.
//!
//! * `grad_face_attrs` is exact: the cotangent of each pixel goes to the face drawn there.
//! * `grad_verts_screen` is the Neural Mesh Renderer's approximate rasterization gradient (Kato, Ushiku, Harada,
//!   CVPR 2018, sec. 3), with occlusion-aware OUT sweeps. The backward pass recomputes everything it needs from the
//!   face-index map and the positions (per-face setup, depths at pixel centres); nothing is stored by the forward.
//!
//! Determinism: each face's contribution is computed independently (in parallel) into its own partial, and the
//! partials are added to the vertices in increasing face order; pixels are summed in row-major order for
//! `grad_face_attrs`. Results are therefore bit-identical for any thread count, and for any [`Isa`].
//!
//! How the core computes it (per-pixel line buffers, planned sweeps, vector kernels, kept buffers, the instruction
//! sets) is described in `docs/NMR_GRADIENT.md`, "How the core computes it"; the local gradient's truncation in
//! `docs/LOCAL_GRADIENT.md` ([`Visibility`]).
//!
//! The exact, step-by-step definition and those notes (the text of `docs/NMR_GRADIENT.md`) follow.
//!
#![doc = include_str!("../../../docs/NMR_GRADIENT.md")]

mod lines;
mod sweep;
mod visibility;
mod workspace;

use rayon::prelude::*;

use crate::error::{try_clear_for, try_refill, RasterError, Result};
use crate::input::{check_finite, FaceAttrs, RasterParams, ScreenMesh};
use crate::setup::{ceil, floor, FaceSetup};
pub use crate::simd::Isa;
use sweep::{index_f64, run_lines, Clip, FaceLines, LineJob, Positions};
pub use visibility::Visibility;

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
    /// `(B, H, W, C)` image from the forward pass (the forward's own: where the vertex gradient needs the colour of a
    /// pixel beyond an edge it takes the attributes of the face drawn there, which debug builds check against it).
    pub image: &'a [f32],
    /// `(B, H, W, C)` cotangent of the image.
    pub grad_image: &'a [f32],
    /// Compute the vertex gradient; when false `grad_verts_screen` is all zeros.
    pub vertex_grad: bool,
    /// Which vertex gradient: NMR's (the default) or its sweeps truncated to a few pixels of each edge.
    pub visibility: Visibility,
}

impl BackwardInputs<'_> {
    fn validate(
        &self,
        batch: usize,
        num_faces: usize,
        channels: usize,
        params: &RasterParams,
    ) -> Result<()> {
        self.visibility.validate()?;
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
        if let Some(index) = crate::input::first_bad_face(self.face_index, num_faces) {
            return Err(RasterError::FaceMapOutOfRange {
                index,
                value: self.face_index[index] as i64,
                num_faces,
            });
        }
        Ok(())
    }
}

/// Per-task scratch of the sweeps, reused across faces: `sum_c G A` of one line (more than four channels only),
/// the planned sweeps of one edge along one axis, and (per-pixel colours) the colours those sweeps read, as f64.
struct Scratch {
    ga: Vec<f64>,
    jobs: Vec<LineJob>,
    colors: Vec<f64>,
}

/// Per-batch-element context of the gradient sweeps.
struct Ctx<'a> {
    setups: &'a [FaceSetup],
    /// Where each face is drawn.
    drawn: &'a [Drawn],
    rows: &'a lines::Lines,
    cols: &'a lines::Lines,
    /// Per-face colours: `(M + 1, C)` colours as f64, the face attributes, then the background (row `M`). The
    /// forward drew `I[P] = colors[F[P]]` (background where `F[P] = -1`), so the IN sweeps read the colour beyond an
    /// edge here, by the face index of the line buffers, rather than from the image (a cache and TLB miss per column
    /// line). Per-pixel colours ([`Ctx::per_pixel`]): empty; the sweeps' few pixels of the image are read into
    /// [`Scratch`] as f64 as they are planned.
    colors: &'a [f64],
    /// Whether the colours are per pixel (a textured or smooth-shaded image): the OUT sweep's face colour on a line is
    /// that of the face's pixel at the edge (`I[pix(d_in)]`) and the IN sweep's colour beyond the edge `I[pix(d_out)]`,
    /// NMR's rule for images that vary within a face; with per-face colours both are the face attributes.
    per_pixel: bool,
    /// `(H, W, C)` image (row-major, as given; debug builds check the colours read against it).
    image: &'a [f32],
    /// The channels of the image (and of `attrs`) whose cotangent is not all zero, ascending: the line buffers and
    /// `colors` hold these, `kept.len()` channels (see [`nonzero_channels`]).
    kept: &'a [usize],
    /// Pixel positions along a line.
    pos: &'a Positions,
    params: &'a RasterParams,
    /// How far the sweeps run.
    visibility: Visibility,
}

/// The box of the pixels a face is drawn on (inclusive): no pixel outside it has `F[P] == f`, so a line outside it
/// has no OUT sweep (its in-pixel is not the face's) and an IN sweep contributes only inside it.
#[derive(Debug, Clone, Copy)]
struct Drawn {
    rows: [usize; 2],
    cols: [usize; 2],
}

impl Drawn {
    /// No pixel.
    const EMPTY: Drawn = Drawn {
        rows: [usize::MAX, 0],
        cols: [usize::MAX, 0],
    };

    /// Adds pixel `(i, j)`.
    #[inline(always)]
    fn add(&mut self, i: usize, j: usize) {
        self.rows = [self.rows[0].min(i), self.rows[1].max(i)];
        self.cols = [self.cols[0].min(j), self.cols[1].max(j)];
    }

    /// Whether the box holds no pixel.
    fn is_empty(&self) -> bool {
        self.rows[0] > self.rows[1]
    }
}

/// Adds each pixel's cotangent to the face drawn there (`acc[f * c + k]`, pixels in row-major order) and grows
/// the faces' drawn boxes, for `C = c` channels (`C = 0`: any count `c`).
#[inline(always)]
fn attr_grad<const C: usize>(
    face_index: &[i32],
    grad: &[f32],
    w: usize,
    c: usize,
    acc: &mut [f64],
    drawn: &mut [Drawn],
) {
    let c = if C == 0 { c } else { C };
    for (i, (row, g)) in face_index
        .chunks_exact(w)
        .zip(grad.chunks_exact(w * c))
        .enumerate()
    {
        if C > 0 {
            // Runs of one face along the row: its sums are added in registers, in the same order as pixel by
            // pixel (so to the same bits), and its drawn box grows once per run.
            let mut j = 0;
            while j < w {
                let f = row[j];
                if f < 0 {
                    j += 1;
                    continue;
                }
                let (fu, j0) = (f as usize, j);
                let a = &mut acc[fu * C..(fu + 1) * C];
                let mut sum: [f64; C] = std::array::from_fn(|k| a[k]);
                while j < w && row[j] == f {
                    let g = &g[j * C..(j + 1) * C];
                    for k in 0..C {
                        sum[k] += g[k] as f64;
                    }
                    j += 1;
                }
                a.copy_from_slice(&sum);
                drawn[fu].add(i, j0);
                drawn[fu].add(i, j - 1);
            }
            continue;
        }
        for (j, (&f, g)) in row.iter().zip(g.chunks_exact(c)).enumerate() {
            if f >= 0 {
                let f = f as usize;
                drawn[f].add(i, j);
                let a = &mut acc[f * c..(f + 1) * c];
                for k in 0..c {
                    a[k] += g[k] as f64;
                }
            }
        }
    }
}

/// Sweep axis: lines are image columns (`U`, moves vertices in v, gives the y gradient) or rows (`V`, gives x).
#[derive(Clone, Copy, PartialEq)]
enum Axis {
    U,
    V,
}

/// [`Ctx::face_grad`] compiled for AVX2 (`C` channels, or 0: any count).
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(unsafe_code)]
unsafe fn face_grad_avx2<const C: usize>(
    ctx: &Ctx<'_>,
    f: usize,
    scratch: &mut Scratch,
) -> [[f64; 2]; 3] {
    ctx.face_grad::<C>(f, scratch, Isa::Avx2)
}

/// [`Ctx::face_grad`] compiled for AVX-512 (`C` channels, or 0: any count).
///
/// # Safety
/// The CPU must support AVX2, AVX-512F, -DQ and -VL.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,avx512f,avx512dq,avx512vl")]
#[allow(unsafe_code)]
unsafe fn face_grad_avx512<const C: usize>(
    ctx: &Ctx<'_>,
    f: usize,
    scratch: &mut Scratch,
) -> [[f64; 2]; 3] {
    ctx.face_grad::<C>(f, scratch, Isa::Avx512)
}

impl Ctx<'_> {
    /// [`Ctx::face_grad`] on the instruction set `isa` (which the caller has checked is available).
    /// The channel count is made a constant for 1 to 4 channels.
    fn face_grad_on(&self, isa: Isa, f: usize, scratch: &mut Scratch) -> [[f64; 2]; 3] {
        match isa {
            #[cfg(target_arch = "x86_64")]
            #[allow(unsafe_code)]
            // SAFETY: `rasterize_backward_on` only passes `Isa::Avx2` when the CPU supports AVX2.
            Isa::Avx2 => unsafe {
                with_channels!(self.kept.len(), C => face_grad_avx2::<C>(self, f, scratch))
            },
            #[cfg(target_arch = "x86_64")]
            #[allow(unsafe_code)]
            // SAFETY: `rasterize_backward_on` only passes `Isa::Avx512` when the CPU supports it.
            Isa::Avx512 => unsafe {
                with_channels!(self.kept.len(), C => face_grad_avx512::<C>(self, f, scratch))
            },
            _ => {
                with_channels!(self.kept.len(), C => self.face_grad::<C>(f, scratch, Isa::Portable))
            }
        }
    }

    /// NMR gradient partial of face `f`: `[corner][x or y]`, for `C` channels (`C = 0`: any count; otherwise
    /// `C` must be the number of [`Ctx::kept`] channels).
    #[inline(always)]
    fn face_grad<const C: usize>(
        &self,
        f: usize,
        scratch: &mut Scratch,
        isa: Isa,
    ) -> [[f64; 2]; 3] {
        let s = &self.setups[f];
        let drawn = self.drawn[f];
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
        let c = if C == 0 { self.kept.len() } else { C };
        let fi = f as f64;
        let background = if self.per_pixel {
            0
        } else {
            self.colors.len() / c - 1
        };
        let Scratch {
            ga: scratch_ga,
            jobs,
            colors: pixel_colors,
        } = scratch;
        // Per-pixel colours: the kept channels of image pixel `px` appended to `pixel_colors`, and their offset.
        let ci = self.image.len() / self.params.pixels().max(1);
        let every = ci == c;
        let push_pixel = |pixel_colors: &mut Vec<f64>, px: usize| {
            let at = pixel_colors.len();
            let img = &self.image[px * ci..(px + 1) * ci];
            if C != 0 && every {
                let v: [f64; C] = std::array::from_fn(|k| img[k] as f64);
                pixel_colors.extend_from_slice(&v);
            } else {
                pixel_colors.extend(self.kept.iter().map(|&ch| img[ch] as f64));
            }
            at
        };
        let mut g = [[0.0f64; 2]; 3];
        for e in 0..3 {
            let (a, cc, o) = (e, (e + 1) % 3, (e + 2) % 3);
            for axis in [Axis::U, Axis::V] {
                // The face's drawn pixels: lines `across`, positions along a line `along`.
                let (p, q, lines, len, ln, across, along) = match axis {
                    Axis::U => (&s.u, &s.v, w, h, self.cols, drawn.cols, drawn.rows),
                    Axis::V => (&s.v, &s.u, h, w, self.rows, drawn.rows, drawn.cols),
                };
                let (pa, qa, pc, qc, po, qo) = (p[a], q[a], p[cc], q[cc], p[o], q[o]);
                if pa == pc {
                    continue;
                }
                let slope = (qc - qa) / (pc - pa);
                let q_line = qa + slope * (po - pa);
                let dir: i64 = if qo > q_line { -1 } else { 1 };
                // Lines outside the drawn box have neither sweep.
                let lo = ceil(pa.min(pc)).max(index_f64(across[0]));
                let hi = floor(pa.max(pc)).min(index_f64(across[1].min(lines as usize - 1)));
                if lo > hi {
                    continue;
                }
                let comp = if axis == Axis::U { 1 } else { 0 };
                // The flat pixel index of position `d` along line `line`.
                let pix = |line: usize, d: usize| match axis {
                    Axis::U => d * w as usize + line,
                    Axis::V => line * w as usize + d,
                };
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
                let key_step = sgn * pl_step;
                // First the lines' sweeps are planned (scalar work), then run together (vector work), then their
                // sums are added to `g` line by line (OUT, then IN), in the order of the definition.
                jobs.clear();
                pixel_colors.clear();
                for d0 in (lo as i64)..=(hi as i64) {
                    let d0f = d0 as f64;
                    let cross = qa + slope * (d0f - pa);
                    // d_in = floor(cross) (dir > 0) or ceil(cross), skipped outside 0..len (and for NaN). On the
                    // pixels kept `cross` is in (-1, len), where the truncation `cross as i64` is exact and
                    // floor = truncation for cross >= 0, ceil = truncation + 1 where the truncation is below cross.
                    let d_in = if dir > 0 {
                        if !(cross >= 0.0 && cross < len as f64) {
                            continue;
                        }
                        // SAFETY: `cross` is in [0, len), within i64 (the truncation is exact).
                        #[allow(unsafe_code)]
                        unsafe {
                            cross.to_int_unchecked::<i64>()
                        }
                    } else {
                        if !(cross > -1.0 && cross <= (len - 1) as f64) {
                            continue;
                        }
                        // SAFETY: `cross` is in (-1, len - 1], within i64 (the truncation is exact).
                        #[allow(unsafe_code)]
                        let t = unsafe { cross.to_int_unchecked::<i64>() };
                        t + i64::from((t as f64) < cross)
                    };
                    let d_out = d_in + dir;
                    if d_out < 0 || d_out >= len {
                        continue;
                    }
                    let line = d0 as usize;
                    // Endpoint motion needed per pixel of crossing motion (0 when the endpoint is on the line,
                    // whose sums are then not added).
                    let ka = if pc != d0f {
                        ndc * (pc - pa) / (pc - d0f)
                    } else {
                        0.0
                    };
                    let kc = if pa != d0f {
                        ndc * (pc - pa) / (d0f - pa)
                    } else {
                        0.0
                    };
                    let mut job = LineJob {
                        line,
                        cross,
                        ka,
                        kc,
                        out: (0, 0),
                        ea: 1.0,
                        ec: 1.0,
                        key0: 0.0,
                        inside: (0, 0),
                        out_color: 0,
                        // Per-pixel colours: the pixel, made an offset into `pixel_colors` once the job is kept.
                        in_color: if self.per_pixel {
                            pix(line, d_in as usize)
                        } else {
                            f * c
                        },
                        sums: [0.0; 4],
                    };
                    // OUT: pixels beyond the edge that the face would cover (only where the cotangent is not zero).
                    if ln.face_at(line, d_in as usize) == f as i32 {
                        let (start, end) = self.visibility.out_range(d_out as usize, dir, ln.len);
                        let [nz0, nz1] = ln.nonzero[line];
                        let (start, end) = (start.max(nz0), end.min(nz1));
                        if start < end {
                            // `nudge(k t)` is `k t + sign(k dir) EPS` beyond the edge (`t` has the sign of `dir`);
                            // an endpoint on the line gets 1, so that its denominator never vanishes.
                            let nudge = |k: f64, on: bool| match on {
                                true => 1.0,
                                false if k * dir as f64 > 0.0 => EPS,
                                false => -EPS,
                            };
                            job.ea = nudge(ka, pc == d0f);
                            job.ec = nudge(kc, pa == d0f);
                            job.key0 = sgn * (pl_line * d0f + s.plane[2]);
                            let clip = Clip {
                                key0: job.key0,
                                key_step,
                                key_lo,
                                key_hi,
                            };
                            job.out = clip.clip(start, end);
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
                    // Cut to the drawn box (only the face's pixels contribute).
                    let (lb, ub) = self
                        .visibility
                        .in_box(d_in, along[0] as i64, along[1] as i64);
                    let (from, to) = in_range(d_in, cross2, dir, lb, ub);
                    if from <= to {
                        job.inside = (from as usize, to as usize + 1);
                        let beyond = ln.face_at(line, d_out as usize);
                        let row = usize::try_from(beyond).unwrap_or(background);
                        job.out_color = if self.per_pixel {
                            pix(line, d_out as usize)
                        } else {
                            row * c
                        };
                        if cfg!(debug_assertions) && !self.per_pixel {
                            let out_px = match axis {
                                Axis::U => d_out as usize * w as usize + line,
                                Axis::V => line * w as usize + d_out as usize,
                            };
                            assert!(
                                self.image_shows(out_px, row),
                                "the image is not the forward's"
                            );
                        }
                    }
                    if job.out.0 < job.out.1 || from <= to {
                        if self.per_pixel {
                            if job.out.0 < job.out.1 {
                                job.in_color = push_pixel(pixel_colors, job.in_color);
                            }
                            if from <= to {
                                job.out_color = push_pixel(pixel_colors, job.out_color);
                            }
                        }
                        jobs.push(job);
                    }
                }
                let face = FaceLines {
                    ln,
                    pos: self.pos,
                    fi,
                    key_step,
                    channels: c,
                    own: (along[0], along[1]),
                    colors: if self.per_pixel {
                        pixel_colors
                    } else {
                        self.colors
                    },
                };
                run_lines::<C>(&face, jobs, scratch_ga, isa);
                for job in jobs.iter() {
                    // A sweep that did not run has sums +0, and adding +0 leaves `g` as it is (`g` is never -0: it
                    // starts at +0, and a sum is -0 only from two -0s or under round-down).
                    let (on_a, on_c) = (pc != index_f64(job.line), pa != index_f64(job.line));
                    if on_a {
                        g[a][comp] += job.sums[0];
                    }
                    if on_c {
                        g[cc][comp] += job.sums[1];
                    }
                    if on_a {
                        g[a][comp] += job.sums[2];
                    }
                    if on_c {
                        g[cc][comp] += job.sums[3];
                    }
                }
            }
        }
        g
    }

    /// Whether the image holds colour row `row` at pixel `px`, as the forward drew it (checked in debug builds).
    fn image_shows(&self, px: usize, row: usize) -> bool {
        let (c, k) = (self.image.len() / self.params.pixels(), self.kept.len());
        let drawn = &self.image[px * c..(px + 1) * c];
        let color = &self.colors[row * k..(row + 1) * k];
        self.kept
            .iter()
            .zip(color)
            .all(|(&ch, &a)| drawn[ch] as f64 == a)
    }
}

/// The IN sweep's pixels `from..=to` (empty when `from > to`): `limit = ceil(cross2)` (`dir > 0`) or
/// `floor(cross2)`, `from = max(min(d_in, limit), lb)`, `to = min(max(d_in, limit), ub)` (the range between the two
/// crossings, cut to the drawn box `lb..=ub`); a NaN limit is ignored, as by `f64::min`. In integers: `cross2` is
/// first clamped to `[lb - 1, ub + 1]`, where its truncation is exact. Same range as without the clamp (or both
/// empty): ceil and floor commute with a clamp to integers, a limit below `lb - 1` gives `from = lb` either way
/// and `to` equal or below `lb`, and symmetrically above `ub + 1` (tested).
#[inline(always)]
fn in_range(d_in: i64, cross2: f64, dir: i64, lb: i64, ub: i64) -> (i64, i64) {
    let limit = if cross2.is_nan() {
        d_in
    } else {
        // (Not NaN here, so plain compares clamp it.)
        let (lo, hi) = ((lb - 1) as f64, (ub + 1) as f64);
        let x = if cross2 > hi { hi } else { cross2 };
        let x = if x < lo { lo } else { x };
        // SAFETY: `x` is in [lb - 1, ub + 1], pixel indices, within i64.
        #[allow(unsafe_code)]
        let t = unsafe { x.to_int_unchecked::<i64>() };
        if dir > 0 {
            t + i64::from((t as f64) < x)
        } else {
            t - i64::from((t as f64) > x)
        }
    };
    (d_in.min(limit).max(lb), d_in.max(limit).min(ub))
}

/// Backward pass: exact attribute gradient and NMR's approximate vertex gradient (see the module docs), on the
/// fastest instruction set of this CPU.
///
/// `mesh`, `attrs` and `params` must be those of the forward pass; `inputs` holds its outputs and the cotangent.
pub fn rasterize_backward(
    mesh: &ScreenMesh<'_>,
    attrs: &FaceAttrs<'_>,
    params: &RasterParams,
    inputs: &BackwardInputs<'_>,
) -> Result<Gradients> {
    rasterize_backward_on(Isa::detect(), mesh, attrs, params, inputs)
}

/// [`rasterize_backward`] on the instruction set `isa` (for tests and benchmarks: every choice gives the same bits).
/// An `isa` this CPU lacks is an error naming the argument.
pub fn rasterize_backward_on(
    isa: Isa,
    mesh: &ScreenMesh<'_>,
    attrs: &FaceAttrs<'_>,
    params: &RasterParams,
    inputs: &BackwardInputs<'_>,
) -> Result<Gradients> {
    isa.check()?;
    mesh.validate()?;
    params.validate()?;
    attrs.validate(mesh)?;
    let (m, c) = (mesh.num_faces(), attrs.channels);
    inputs.validate(mesh.batch, m, c, params)?;
    let nv = mesh.num_verts;
    let mut grad_verts_screen = vec![0f32; mesh.batch * nv * 3];
    let mut grad_face_attrs = vec![0f32; mesh.batch * m * c];
    grad_verts_screen
        .par_chunks_mut(nv * 3)
        .zip(grad_face_attrs.par_chunks_mut(m * c))
        .enumerate()
        .try_for_each(|(b, (gv, ga))| {
            let mut ws = workspace::take();
            let colors = Colors::Faces(attrs);
            let done = element_grads(isa, mesh, colors, c, params, inputs, b, gv, ga, &mut ws);
            workspace::give(ws);
            done
        })?;
    Ok(Gradients {
        grad_verts_screen,
        grad_face_attrs,
    })
}

/// NMR's vertex gradient of an image whose colours vary within faces (textured or smooth-shaded): `(B, N, 3)`
/// gradient with respect to `verts_screen` (z component 0), for the forward's face index `(B, H, W)`, its image
/// `(B, H, W, C)` and the image's cotangent `(B, H, W, C)`; `visibility` picks NMR's sweeps or their local truncation.
///
/// The definition of [`rasterize_backward`] (docs/NMR_GRADIENT.md) with the colours read from the image, as NMR does
/// for textured faces: the colour a face would give a pixel beyond its edge is the image at the face's last pixel on
/// that line (`I[pix(d_in)]`), and the colour uncovered inside a face is the image at the first pixel beyond the edge
/// (`I[pix(d_out)]`). For an image drawn with per-face colours this is [`rasterize_backward`]'s vertex gradient bit
/// for bit (tested). The interior change of the colours (UVs, normals moving with the vertices) is not part of it:
/// see [`crate::surface::pixel_weights_backward`].
pub fn image_vertex_backward(
    mesh: &ScreenMesh<'_>,
    params: &RasterParams,
    face_index: &[i32],
    image: &[f32],
    grad_image: &[f32],
    channels: usize,
    visibility: Visibility,
) -> Result<Vec<f32>> {
    let isa = Isa::detect();
    mesh.validate()?;
    params.validate()?;
    if channels == 0 {
        return Err(RasterError::shape(
            "image",
            "(B, H, W, C) with C >= 1",
            "C = 0",
        ));
    }
    let inputs = BackwardInputs {
        face_index,
        image,
        grad_image,
        vertex_grad: true,
        visibility,
    };
    let (m, c) = (mesh.num_faces(), channels);
    inputs.validate(mesh.batch, m, c, params)?;
    let nv = mesh.num_verts;
    let mut grad_verts_screen = vec![0f32; mesh.batch * nv * 3];
    grad_verts_screen
        .par_chunks_mut(nv * 3)
        .enumerate()
        .try_for_each(|(b, gv)| {
            let mut ws = workspace::take();
            let done = element_grads(
                isa,
                mesh,
                Colors::Pixels,
                c,
                params,
                &inputs,
                b,
                gv,
                &mut [],
                &mut ws,
            );
            workspace::give(ws);
            done
        })?;
    Ok(grad_verts_screen)
}

/// Where the vertex gradient reads the colours the forward drew.
#[derive(Clone, Copy)]
enum Colors<'a> {
    /// Per-face attributes (flat): the attributes of the face drawn at a pixel, or the background.
    Faces(&'a FaceAttrs<'a>),
    /// The image itself, per pixel.
    Pixels,
}

/// The channels (ascending) of the interleaved `(H, W, c)` cotangent `grad` that are not zero at every pixel.
///
/// A channel that is zero everywhere (e.g. the coverage channel of a render whose alpha feeds nothing) adds only zero
/// terms to the vertex gradient's sums (`0 * a`, and `+-0` to a sum leaves it as it is, up to the sign of a zero,
/// which `min(delta, -0)` removes), so the sweeps leave it out: the same bits with fewer bytes per pixel.
fn nonzero_channels(grad: &[f32], c: usize) -> Vec<usize> {
    // Each channel's bits OR-ed together with the sign dropped (-0 is zero), in blocks of `BLOCK` values that start
    // at a pixel (so that value `i` of a block is channel `i % c`) and vectorise; the scan stops once every channel
    // has a non-zero value, which in most cotangents is within the first pixels.
    const BLOCK: usize = 48;
    const BLOCKS_PER_CHECK: usize = 64;
    let mut any = vec![0u32; c];
    let bits = |x: f32| x.to_bits() << 1;
    if !BLOCK.is_multiple_of(c) {
        for (i, &x) in grad.iter().enumerate() {
            any[i % c] |= bits(x);
        }
    } else {
        for part in grad.chunks(BLOCK * BLOCKS_PER_CHECK) {
            let mut lanes = [0u32; BLOCK];
            let mut blocks = part.chunks_exact(BLOCK);
            for block in &mut blocks {
                for (l, &x) in lanes.iter_mut().zip(block) {
                    *l |= bits(x);
                }
            }
            for (i, &x) in lanes.iter().enumerate() {
                any[i % c] |= x;
            }
            for (i, &x) in blocks.remainder().iter().enumerate() {
                any[i % c] |= bits(x);
            }
            if any.iter().all(|&a| a != 0) {
                break;
            }
        }
    }
    (0..c).filter(|&k| any[k] != 0).collect()
}

/// The gradients of batch element `b` (`gv`: its `(N, 3)` vertex gradient, `ga`: its `(M, C)` attribute gradient,
/// empty for per-pixel colours), for `c` channels, in the buffers of `ws` (each refilled before it is read).
#[allow(clippy::too_many_arguments)]
fn element_grads(
    isa: Isa,
    mesh: &ScreenMesh<'_>,
    source: Colors<'_>,
    c: usize,
    params: &RasterParams,
    inputs: &BackwardInputs<'_>,
    b: usize,
    gv: &mut [f32],
    ga: &mut [f32],
    ws: &mut workspace::Workspace,
) -> Result<()> {
    let (m, hw) = (mesh.num_faces(), params.pixels());
    let nv = mesh.num_verts;
    let workspace::Workspace {
        rows,
        cols,
        setups,
        drawn,
        acc,
        colors,
        partials,
        accv,
    } = ws;
    let face_index = &inputs.face_index[b * hw..(b + 1) * hw];
    let image = &inputs.image[b * hw * c..(b + 1) * hw * c];
    let grad = &inputs.grad_image[b * hw * c..(b + 1) * hw * c];
    // Exact attribute gradient, summed in pixel order.
    // Also the box of the pixels each face is drawn on (empty: not drawn).
    try_refill(acc, m * c, 0.0, "backward attribute accumulator")?;
    try_refill(drawn, m, Drawn::EMPTY, "backward face boxes")?;
    let w = params.width;
    with_channels!(c, C => attr_grad::<C>(face_index, grad, w, c, acc, drawn));
    let drawn = &*drawn;
    let visible = |f: usize| !drawn[f].is_empty();
    for (dst, &src) in ga.iter_mut().zip(acc.iter()) {
        *dst = src as f32;
    }
    if !inputs.vertex_grad {
        return Ok(());
    }
    let kept = nonzero_channels(grad, c);
    if kept.is_empty() {
        // A zero cotangent: every delta is zero, and so is the vertex gradient (`gv` is all +0 already).
        return Ok(());
    }
    // NMR vertex gradient: per-face partials in parallel, reduced in face order.
    // Only the faces drawn somewhere take part (and only their depths are needed).
    try_clear_for(setups, m, "backward face setups")?;
    setups.extend((0..m).map(|f| {
        if visible(f) {
            FaceSetup::new(mesh, b, f, params)
        } else {
            FaceSetup::default()
        }
    }));
    rows.fill_rows(isa, setups, face_index, image, grad, c, &kept, params)?;
    cols.fill_columns(isa, rows)?;
    match source {
        Colors::Faces(attrs) => face_colors(attrs, b, m, c, &kept, colors)?,
        // Read pixel by pixel as the sweeps are planned.
        Colors::Pixels => colors.clear(),
    }
    let longest = params.height.max(params.width);
    let pos = Positions::new(longest);
    let ctx = Ctx {
        setups,
        drawn,
        rows,
        cols,
        colors,
        per_pixel: matches!(source, Colors::Pixels),
        image,
        kept: &kept,
        pos: &pos,
        params,
        visibility: inputs.visibility,
    };
    try_clear_for(partials, m, "backward face partials")?;
    let ga_len = if kept.len() > 4 {
        longest + sweep::LANES
    } else {
        0
    };
    partials.par_extend((0..m).into_par_iter().map_init(
        || Scratch {
            ga: vec![0.0; ga_len],
            jobs: Vec::with_capacity(longest),
            colors: Vec::with_capacity(2 * longest * kept.len()),
        },
        |scratch, f| {
            if visible(f) && ctx.setups[f].active {
                ctx.face_grad_on(isa, f, scratch)
            } else {
                [[0.0; 2]; 3]
            }
        },
    ));
    try_refill(accv, nv * 2, 0.0, "backward vertex accumulator")?;
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
    Ok(())
}

/// Fills `colors` with the `(M + 1, kept)` per-face colours of batch element `b` (attributes, then the background).
fn face_colors(
    attrs: &FaceAttrs<'_>,
    b: usize,
    m: usize,
    c: usize,
    kept: &[usize],
    colors: &mut Vec<f64>,
) -> Result<()> {
    try_clear_for(colors, (m + 1) * kept.len(), "backward colours")?;
    let values = &attrs.values[b * m * c..(b + 1) * m * c];
    if kept.len() == c {
        // Every channel: one flat conversion (vectorised).
        colors.extend(values.iter().chain(attrs.background).map(|&x| x as f64));
    } else {
        colors.extend(
            values
                .chunks_exact(c)
                .chain([attrs.background])
                .flat_map(|row| kept.iter().map(|&ch| row[ch] as f64)),
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_rng::Rng;

    #[test]
    fn the_attribute_gradient_by_runs_matches_pixel_by_pixel_bit_for_bit() {
        let (h, w) = (7, 23);
        let mut rng = Rng(5);
        for c in 1..=5 {
            // Runs of faces (and background) of random lengths, a few faces repeated across rows.
            let mut face_index = Vec::new();
            while face_index.len() < h * w {
                let f = rng.below(7) as i32 - 1;
                face_index.extend(std::iter::repeat_n(f, 1 + rng.below(6)));
            }
            face_index.truncate(h * w);
            let grad: Vec<f32> = (0..h * w * c)
                .map(|_| {
                    ((rng.next() - 0.5) * 1e3) as f32 * if rng.below(9) == 0 { 0.0 } else { 1.0 }
                })
                .collect();
            let start: Vec<f64> = (0..6 * c).map(|_| rng.next() * 1e-7).collect();
            let (mut acc, mut drawn) = (start.clone(), vec![Drawn::EMPTY; 6]);
            with_channels!(c, C => attr_grad::<C>(&face_index, &grad, w, c, &mut acc, &mut drawn));
            let (mut want, mut want_drawn) = (start, vec![Drawn::EMPTY; 6]);
            for (p, &f) in face_index.iter().enumerate() {
                if f >= 0 {
                    let f = f as usize;
                    want_drawn[f].add(p / w, p % w);
                    for k in 0..c {
                        want[f * c + k] += grad[p * c + k] as f64;
                    }
                }
            }
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&acc), bits(&want), "{c} channels");
            for (d, e) in drawn.iter().zip(&want_drawn) {
                assert_eq!((d.rows, d.cols), (e.rows, e.cols), "{c} channels");
            }
        }
    }

    #[test]
    fn nonzero_channels_finds_every_channel_with_a_nonzero_value() {
        let mut rng = Rng(5);
        // Channel counts that divide the scan's block and one that does not; pixel counts around its block sizes.
        for c in [1, 2, 3, 4, 5] {
            for pixels in [1, 15, 16, 17, 48 * 64 / c, 48 * 64 / c + 1, 5000] {
                for trial in 0..4 {
                    let mut grad = vec![0f32; pixels * c];
                    for (i, x) in grad.iter_mut().enumerate() {
                        if i % 3 == 0 {
                            *x = -0.0; // a zero all the same
                        }
                    }
                    // Each channel non-zero at one pixel (the last one for trial 0: past every early check), or not.
                    let mut want = Vec::new();
                    for k in 0..c {
                        if rng.below(2) == 0 {
                            let px = if trial == 0 {
                                pixels - 1
                            } else {
                                rng.below(pixels)
                            };
                            grad[px * c + k] = if rng.below(2) == 0 { 1e-30 } else { -3.0 };
                            want.push(k);
                        }
                    }
                    assert_eq!(nonzero_channels(&grad, c), want, "c {c}, {pixels} pixels");
                }
            }
        }
    }

    #[test]
    fn the_in_range_matches_the_unclamped_definition() {
        let mut rng = Rng(3);
        let mut cases = 0;
        for _ in 0..20000 {
            let len = 1 + rng.below(40) as i64;
            let d_in = rng.below(len as usize) as i64;
            let lb = rng.below(len as usize) as i64;
            let ub = lb + rng.below((len - lb) as usize) as i64;
            let dir = if rng.below(2) == 0 { 1 } else { -1 };
            let cross2 = match rng.below(8) {
                0 => f64::NAN,
                1 => (rng.next() - 0.5) * 1e300,
                2 => f64::INFINITY * (rng.next() - 0.5).signum(),
                3 => (rng.below(60) as f64 - 10.0) * 0.5,
                _ => (rng.next() - 0.3) * 2.0 * len as f64,
            };
            // The definition: f64 ceil / floor, a saturating conversion, NaN ignored.
            let limit = if dir > 0 {
                cross2.ceil()
            } else {
                cross2.floor()
            };
            let limit = if limit.is_nan() { d_in } else { limit as i64 };
            let (from, to) = (d_in.min(limit).max(lb), d_in.max(limit).min(ub));
            let got = in_range(d_in, cross2, dir, lb, ub);
            if from <= to {
                assert_eq!(
                    got,
                    (from, to),
                    "d_in {d_in} cross2 {cross2} dir {dir} box {lb}..={ub}"
                );
                cases += 1;
            } else {
                assert!(
                    got.0 > got.1,
                    "d_in {d_in} cross2 {cross2} dir {dir} box {lb}..={ub}: {got:?}"
                );
            }
        }
        assert!(cases > 5000);
    }

    #[test]
    fn clip_keeps_exactly_the_pixels_in_the_clip_range() {
        let mut rng = Rng(2);
        for _ in 0..2000 {
            let (lo, hi) = (rng.next(), 1.0 + rng.next() * 2.0);
            let s = Clip {
                key0: rng.next() * 4.0 - 1.0,
                key_step: (rng.next() - 0.5) * 0.05 * (rng.next() < 0.9) as i32 as f64,
                key_lo: lo,
                key_hi: hi,
            };
            let (start, end) = ((rng.next() * 60.0) as usize, (rng.next() * 120.0) as usize);
            let (a, b) = s.clip(start, end);
            for d in start..end {
                let k = s.key(d);
                let inside = k >= s.key_lo && k <= s.key_hi;
                assert_eq!(inside, a <= d && d < b, "d = {d}, range {a}..{b}");
            }
        }
    }
}
