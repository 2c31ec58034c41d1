//! The inner loops of the NMR vertex gradient: the OUT sweep (pixels beyond an edge that the face would cover) and
//! the IN sweep (pixels of the face that would be uncovered) along one line, see `docs/NMR_GRADIENT.md`.
//!
//! Everything is f64, per pixel the same operations as the definition. The OUT sweep, which does nearly all the
//! work, is branch-free (skipped pixels add 0) and sums into [`LANES`] lanes (pixel `i` into lane `i % LANES`),
//! added pairwise in a fixed order. It is written twice with the same operations in the same order and no fused
//! multiply-adds: on lane arrays for any target, and with AVX2 intrinsics (two 4-lane vectors per block), so every
//! instruction set gives the same bits.

use super::lines::Lines;
use super::{Isa, EPS};

/// Lanes of the OUT sweep's accumulators.
pub(super) const LANES: usize = 8;

/// Pixel positions `0, 1, 2, ...` along a line as f64 (loaded by the vectorised loops rather than converted).
pub(super) struct Positions(Vec<f64>);

impl Positions {
    /// Positions for lines of up to `len` pixels.
    pub fn new(len: usize) -> Positions {
        Positions((0..len).map(|d| d as f64).collect())
    }
}

/// One OUT sweep along a line, with local accumulators for the two edge endpoints.
pub(super) struct OutSweep<'a> {
    /// The face, as f64 (compared with the face planes).
    pub fi: f64,
    /// Depth-test key of the face's plane at pixel 0 of the line.
    pub key0: f64,
    /// Key increment per pixel along the line.
    pub key_step: f64,
    /// Smallest key allowed by the clip range.
    pub key_lo: f64,
    /// Largest key allowed by the clip range.
    pub key_hi: f64,
    /// Where the edge crosses the line.
    pub cross: f64,
    /// `to_ndc` motion of endpoint `a` per pixel of crossing motion (0 when `a` is on the line).
    pub ka: f64,
    /// `sign(ka dir) EPS` (1 when `a` is on the line, so that its denominator never vanishes).
    pub ea: f64,
    /// As `ka`, endpoint `c`.
    pub kc: f64,
    /// As `ea`, endpoint `c`.
    pub ec: f64,
    /// The face's attributes.
    pub attrs: &'a [f64],
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

/// Sum of the lanes, in a fixed order.
#[inline(always)]
fn lane_sum(x: &[f64; LANES]) -> f64 {
    ((x[0] + x[1]) + (x[2] + x[3])) + ((x[4] + x[5]) + (x[6] + x[7]))
}

impl OutSweep<'_> {
    /// Depth-test key of the face's plane at pixel `d` of the line.
    #[inline(always)]
    pub fn key(&self, d: usize) -> f64 {
        self.key0 + self.key_step * d as f64
    }

    /// The pixels of `start..end` where the face's key is within the clip range. Exact: the computed key is a
    /// monotone function of `d` (products and sums round monotonically), so these pixels form one range.
    pub fn clip(&self, start: usize, end: usize) -> (usize, usize) {
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

    /// Sums the contributions of pixels `start..end` of line `d0` (`ga` a scratch line). Returns the sums for
    /// endpoints `a` and `c` (meaningful only when their `k` is defined).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub fn run(
        &self,
        ln: &Lines,
        d0: usize,
        start: usize,
        end: usize,
        pos: &Positions,
        ga: &mut [f64],
        isa: Isa,
    ) -> (f64, f64) {
        let (start, end) = self.clip(start, end);
        if start >= end {
            return (0.0, 0.0);
        }
        let r = start..end;
        match self.attrs.len() {
            1 => self.kernel::<1>(ln, d0, r, pos, ga, isa),
            2 => self.kernel::<2>(ln, d0, r, pos, ga, isa),
            3 => self.kernel::<3>(ln, d0, r, pos, ga, isa),
            4 => self.kernel::<4>(ln, d0, r, pos, ga, isa),
            _ => {
                // Any channel count: sum_c G[P, c] A[f, c] into the scratch line first, channels in order.
                let ga = &mut ga[..r.len()];
                for (k, &ak) in self.attrs.iter().enumerate() {
                    let g = &ln.grad(d0, k)[r.clone()];
                    for (x, &g) in ga.iter_mut().zip(g) {
                        *x = if k == 0 { g * ak } else { *x + g * ak };
                    }
                }
                self.kernel::<0>(ln, d0, r, pos, ga, isa)
            }
        }
    }

    /// The OUT sweep over the pixels `r` of line `d0` (already clipped), for `C` channels (`C = 0`: with
    /// `sum_c G[P, c] A[f, c]` precomputed in `pre`), in [`LANES`] lanes.
    #[inline(always)]
    fn kernel<const C: usize>(
        &self,
        ln: &Lines,
        d0: usize,
        r: std::ops::Range<usize>,
        pos: &Positions,
        pre: &[f64],
        isa: Isa,
    ) -> (f64, f64) {
        let n = r.len();
        let k = Pixels::<C> {
            g: std::array::from_fn(|k| &ln.grad(d0, k)[r.clone()]),
            a: std::array::from_fn(|k| self.attrs[k]),
            face: &ln.face(d0)[r.clone()],
            key: &ln.key(d0)[r.clone()],
            gi: &ln.gi(d0)[r.clone()],
            pos: &pos.0[r.clone()],
            pre: &pre[..if C == 0 { n } else { 0 }],
            ka: self.ka,
            ba: self.ea - self.ka * self.cross,
            kc: self.kc,
            bc: self.ec - self.kc * self.cross,
            fi: self.fi,
            key0: self.key0,
            key_step: self.key_step,
        };
        let (mut sa, mut sc) = ([0f64; LANES], [0f64; LANES]);
        let full = n - n % LANES;
        k.blocks(isa, full, &mut sa, &mut sc);
        // The last pixels, pixel `full + l` into lane `l`.
        k.tail(full, n - full, &mut sa, &mut sc);
        (lane_sum(&sa), lane_sum(&sc))
    }
}

/// The per-pixel inputs of one OUT sweep (already cut to its pixels) and its constants (see [`OutSweep`]).
pub(super) struct Pixels<'a, const C: usize> {
    g: [&'a [f64]; C],
    a: [f64; C],
    face: &'a [f64],
    key: &'a [f64],
    gi: &'a [f64],
    pos: &'a [f64],
    pre: &'a [f64],
    /// `da = ka * d + ba` is `ka * (d - cross) + ea`, the displacement of endpoint a (see [`OutSweep`]).
    ka: f64,
    ba: f64,
    /// As `ka`, `ba` for endpoint c.
    kc: f64,
    bc: f64,
    fi: f64,
    key0: f64,
    key_step: f64,
}

impl<const C: usize> Pixels<'_, C> {
    /// Adds the contributions of pixels `0..full` (a multiple of [`LANES`]) to the lanes `sa` (endpoint a) and `sc`.
    #[inline(always)]
    fn blocks(&self, isa: Isa, full: usize, sa: &mut [f64; LANES], sc: &mut [f64; LANES]) {
        match isa {
            #[cfg(target_arch = "x86_64")]
            #[allow(unsafe_code)]
            // SAFETY: `Isa::Avx2` is only passed when the CPU supports AVX2 (see `rasterize_backward_on`).
            Isa::Avx2 => unsafe { avx2::blocks(self, full, sa, sc) },
            _ => {
                for i in (0..full).step_by(LANES) {
                    let (x, y) = self.block(i);
                    for l in 0..LANES {
                        sa[l] += x[l];
                        sc[l] += y[l];
                    }
                }
            }
        }
    }

    /// Adds the contributions of the `rest < LANES` pixels from `full` on to the lanes `0..rest` (one by one, on
    /// every instruction set).
    #[inline(always)]
    fn tail(&self, full: usize, rest: usize, sa: &mut [f64; LANES], sc: &mut [f64; LANES]) {
        for l in 0..rest {
            let (x, y) = self.pixel(full + l);
            sa[l] += x;
            sc[l] += y;
        }
    }

    /// [`Pixels::pixel`] on the block of pixels `i..i + LANES`, one step at a time over the whole block (so that
    /// the compiler vectorises it for the baseline target).
    #[inline(always)]
    fn block(&self, i: usize) -> ([f64; LANES], [f64; LANES]) {
        let r = i..i + LANES;
        let (face, key, gi, pos) = (
            &self.face[r.clone()],
            &self.key[r.clone()],
            &self.gi[r.clone()],
            &self.pos[r.clone()],
        );
        let mut ga = [0f64; LANES];
        if C == 0 {
            ga.copy_from_slice(&self.pre[r.clone()]);
        } else {
            let g0 = &self.g[0][r.clone()];
            for l in 0..LANES {
                ga[l] = g0[l] * self.a[0];
            }
            for ch in 1..C {
                let g = &self.g[ch][r.clone()];
                for l in 0..LANES {
                    ga[l] += g[l] * self.a[ch];
                }
            }
        }
        let mut m = [0f64; LANES];
        for l in 0..LANES {
            let kf = self.key0 + self.key_step * pos[l];
            let delta = ga[l] - gi[l];
            let nearer = (kf > key[l]) | ((kf == key[l]) & (self.fi < face[l]));
            let take = (face[l] != self.fi) & nearer & (delta < 0.0);
            m[l] = if take { delta } else { 0.0 };
        }
        let (mut x, mut y) = ([0f64; LANES], [0f64; LANES]);
        for l in 0..LANES {
            let (da, dc) = (self.ka * pos[l] + self.ba, self.kc * pos[l] + self.bc);
            let q = m[l] / (da * dc);
            x[l] = q * dc;
            y[l] = q * da;
        }
        (x, y)
    }

    /// Contributions of pixel `i` to the endpoints a and c.
    #[inline(always)]
    fn pixel(&self, i: usize) -> (f64, f64) {
        let ga = if C == 0 {
            self.pre[i]
        } else {
            let mut s = self.g[0][i] * self.a[0];
            for ch in 1..C {
                s += self.g[ch][i] * self.a[ch];
            }
            s
        };
        let (fp, kp) = (self.face[i], self.key[i]);
        let kf = self.key0 + self.key_step * self.pos[i];
        let delta = ga - self.gi[i];
        // covers(f, P) (the clip range is handled by `clip`) and delta < 0.
        let nearer = (kf > kp) | ((kf == kp) & (self.fi < fp));
        let take = (fp != self.fi) & nearer & (delta < 0.0);
        let m = if take { delta } else { 0.0 };
        let d = self.pos[i];
        let (da, dc) = (self.ka * d + self.ba, self.kc * d + self.bc);
        // m / da and m / dc with one division.
        let q = m / (da * dc);
        (q * dc, q * da)
    }
}

/// The IN sweep of one line over the pixels `range`: sums of the contributions to the edge endpoints `a` and `c`,
/// whose crossing-motion factors are `ka` and `kc` (meaningful only when defined). `out_color` is the colour of the
/// pixel beyond the edge, `I[pix(d_out)]`.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(super) fn in_sweep(
    ln: &Lines,
    line: usize,
    range: std::ops::Range<usize>,
    fi: f64,
    out_color: &[f32],
    cross: f64,
    ka: f64,
    kc: f64,
) -> (f64, f64) {
    let face = &ln.face(line)[range.clone()];
    let gi = &ln.gi(line)[range.clone()];
    let (mut sa, mut sc) = (0f64, 0f64);
    for (i, (&fp, &gi)) in face.iter().zip(gi).enumerate() {
        if fp != fi {
            continue;
        }
        let d = range.start + i;
        let mut go = 0f64;
        for (k, &oc) in out_color.iter().enumerate() {
            go += ln.grad_at(line, k, d) * oc as f64;
        }
        let delta = go - gi;
        if delta < 0.0 {
            let t = d as f64 - cross;
            let (da, dc) = (nudge(ka * t), nudge(kc * t));
            let q = delta / (da * dc);
            sa += q * dc;
            sc += q * da;
        }
    }
    (sa, sc)
}

/// NMR's `dist = dist + eps` if positive else `dist - eps`.
#[inline(always)]
pub(super) fn nudge(dist: f64) -> f64 {
    dist + if dist > 0.0 { EPS } else { -EPS }
}

/// The OUT sweep's whole blocks with AVX2 intrinsics: [`Pixels::pixel`] on two vectors of four pixels (lanes 0-3
/// and 4-7), the same operations in the same order, so the same bits.
#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod avx2 {
    use std::arch::x86_64::*;

    use super::{Pixels, LANES};

    /// Contributions of the four pixels at `i` to the endpoints a and c (see [`Pixels::pixel`]).
    ///
    /// # Safety
    /// The CPU must support AVX2, and `i + 4` must not exceed any of `k`'s slices.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn quad<const C: usize>(
        k: &Pixels<'_, C>,
        a: &[__m256d; C],
        i: usize,
    ) -> (__m256d, __m256d) {
        let load = |v: &[f64], i: usize| _mm256_loadu_pd(v.as_ptr().add(i));
        let ga = if C == 0 {
            load(k.pre, i)
        } else {
            let mut s = _mm256_mul_pd(load(k.g[0], i), a[0]);
            #[allow(clippy::needless_range_loop)]
            // a plain index loop unrolls; an iterator chain did not
            for ch in 1..C {
                s = _mm256_add_pd(s, _mm256_mul_pd(load(k.g[ch], i), a[ch]));
            }
            s
        };
        let (fp, kp, pos) = (load(k.face, i), load(k.key, i), load(k.pos, i));
        let fi = _mm256_set1_pd(k.fi);
        let kf = _mm256_add_pd(
            _mm256_set1_pd(k.key0),
            _mm256_mul_pd(_mm256_set1_pd(k.key_step), pos),
        );
        let delta = _mm256_sub_pd(ga, load(k.gi, i));
        let tie = _mm256_and_pd(
            _mm256_cmp_pd::<_CMP_EQ_OQ>(kf, kp),
            _mm256_cmp_pd::<_CMP_LT_OQ>(fi, fp),
        );
        let nearer = _mm256_or_pd(_mm256_cmp_pd::<_CMP_GT_OQ>(kf, kp), tie);
        let other = _mm256_cmp_pd::<_CMP_NEQ_UQ>(fp, fi);
        let neg = _mm256_cmp_pd::<_CMP_LT_OQ>(delta, _mm256_setzero_pd());
        let m = _mm256_and_pd(_mm256_and_pd(_mm256_and_pd(other, nearer), neg), delta);
        let da = _mm256_add_pd(
            _mm256_mul_pd(_mm256_set1_pd(k.ka), pos),
            _mm256_set1_pd(k.ba),
        );
        let dc = _mm256_add_pd(
            _mm256_mul_pd(_mm256_set1_pd(k.kc), pos),
            _mm256_set1_pd(k.bc),
        );
        let q = _mm256_div_pd(m, _mm256_mul_pd(da, dc));
        (_mm256_mul_pd(q, dc), _mm256_mul_pd(q, da))
    }

    /// Adds the contributions of pixels `0..full` (a multiple of [`LANES`]) to the lanes `sa` (endpoint a) and `sc`.
    ///
    /// # Safety
    /// The CPU must support AVX2.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn blocks<const C: usize>(
        k: &Pixels<'_, C>,
        full: usize,
        sa: &mut [f64; LANES],
        sc: &mut [f64; LANES],
    ) {
        assert!(
            full <= k.face.len()
                && k.g.iter().all(|g| g.len() >= full)
                && (C != 0 || k.pre.len() >= full)
                && k.key.len() >= full
                && k.gi.len() >= full
                && k.pos.len() >= full
        );
        let a: [__m256d; C] = std::array::from_fn(|ch| _mm256_set1_pd(k.a[ch]));
        let (mut a_lo, mut a_hi) = (
            _mm256_loadu_pd(sa.as_ptr()),
            _mm256_loadu_pd(sa.as_ptr().add(4)),
        );
        let (mut c_lo, mut c_hi) = (
            _mm256_loadu_pd(sc.as_ptr()),
            _mm256_loadu_pd(sc.as_ptr().add(4)),
        );
        let mut i = 0;
        while i < full {
            // SAFETY: `i + LANES <= full`, and every slice holds at least `full` values (asserted above).
            let (x, y) = quad(k, &a, i);
            a_lo = _mm256_add_pd(a_lo, x);
            c_lo = _mm256_add_pd(c_lo, y);
            let (x, y) = quad(k, &a, i + 4);
            a_hi = _mm256_add_pd(a_hi, x);
            c_hi = _mm256_add_pd(c_hi, y);
            i += LANES;
        }
        _mm256_storeu_pd(sa.as_mut_ptr(), a_lo);
        _mm256_storeu_pd(sa.as_mut_ptr().add(4), a_hi);
        _mm256_storeu_pd(sc.as_mut_ptr(), c_lo);
        _mm256_storeu_pd(sc.as_mut_ptr().add(4), c_hi);
    }
}
