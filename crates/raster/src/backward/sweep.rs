//! The inner loops of the NMR vertex gradient: the OUT sweep (pixels beyond an edge that the face would cover) and
//! the IN sweep (pixels of the face that would be uncovered) along one line, see `docs/NMR_GRADIENT.md`.
//!
//! The arithmetic is f64, per pixel the same operations as the definition (the cotangent, stored as f32, and the
//! face index, stored as i32, are converted to f64 exactly when loaded). Both sweeps are branch-free (skipped pixels
//! add 0) and sum into [`LANES`] lanes (pixel `i` of the sweep into lane `i % LANES`), added pairwise in a fixed
//! order. Each is written once ([`Kernel`]), generic over a vector of f64 lanes ([`F64s`]: 4 lanes with AVX2, 2 with
//! SSE2 on any x86-64, 2 plain f64 elsewhere), with the same operations in the same order and no fused
//! multiply-adds, so every instruction set gives the same bits. The last, partial block reads past the sweep's end
//! (every line buffer has [`LANES`] values of padding) and masks those lanes out. The tests in this file check every
//! path against the others bit for bit.

use std::marker::PhantomData;

use super::lines::{LineAt, Lines};
use super::{Isa, EPS};
use crate::simd::F64s;

/// `d as f64` for a pixel index or count (below 2^63): through `i64`, which x86-64 converts in one instruction
/// (`usize` takes five).
#[inline(always)]
pub(super) fn index_f64(d: usize) -> f64 {
    d as i64 as f64
}

/// Lanes of the OUT sweep's accumulators.
pub(super) const LANES: usize = 4;

/// Pixel positions `0, 1, 2, ...` along a line as f64 (loaded by the vectorised loops rather than converted).
pub(super) struct Positions(Vec<f64>);

impl Positions {
    /// Positions for lines of up to `len` pixels (plus [`LANES`] of padding).
    pub fn new(len: usize) -> Positions {
        Positions((0..len + LANES).map(|d| d as f64).collect())
    }

    /// The positions of lines of `len` pixels (checked once), for many [`PositionsOf::at`].
    #[inline(always)]
    fn of(&self, len: usize) -> PositionsOf<'_> {
        assert!(len + LANES <= self.0.len());
        PositionsOf {
            p: self.0.as_ptr(),
            len,
            _data: PhantomData,
        }
    }
}

/// The positions of lines of `len` pixels, see [`Positions::of`].
#[derive(Clone, Copy)]
struct PositionsOf<'a> {
    p: *const f64,
    len: usize,
    _data: PhantomData<&'a f64>,
}

impl PositionsOf<'_> {
    /// The positions from `start` on, readable for `(end - start).next_multiple_of(LANES)` values.
    #[inline(always)]
    fn at(&self, start: usize, end: usize) -> *const f64 {
        assert!(start <= end && end <= self.len);
        // SAFETY: `start <= len`, and `Positions::of` checked that `len + LANES` values exist, which covers the
        // reads (`start + (end - start).next_multiple_of(LANES) <= len + LANES - 1`).
        #[allow(unsafe_code)]
        unsafe {
            self.p.add(start)
        }
    }
}

/// The clip range of an OUT sweep's depth test along one line: the face's key at pixel `d` is
/// `key0 + key_step * d` (its plane), and only keys in `key_lo..=key_hi` (the clip range) may be covered.
pub(super) struct Clip {
    /// Depth-test key of the face's plane at pixel 0 of the line.
    pub key0: f64,
    /// Key increment per pixel along the line.
    pub key_step: f64,
    /// Smallest key allowed by the clip range.
    pub key_lo: f64,
    /// Largest key allowed by the clip range.
    pub key_hi: f64,
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
    (x[0] + x[1]) + (x[2] + x[3])
}

impl Clip {
    /// Depth-test key of the face's plane at pixel `d` of the line.
    #[inline(always)]
    pub fn key(&self, d: usize) -> f64 {
        self.key0 + self.key_step * index_f64(d)
    }

    /// The pixels of `start..end` where the face's key is within the clip range. Exact: the computed key is a
    /// monotone function of `d` (products and sums round monotonically), so these pixels form one range.
    #[inline(always)]
    pub fn clip(&self, start: usize, end: usize) -> (usize, usize) {
        let above_lo = |d: usize| self.key(d) >= self.key_lo;
        let below_hi = |d: usize| self.key(d) <= self.key_hi;
        let inside = |d: usize| above_lo(d) && below_hi(d);
        if start >= end || (inside(start) && inside(end - 1)) {
            (start, end)
        } else {
            self.search(start, end)
        }
    }

    /// [`Clip::clip`] where an end of `start..end` (not empty) is outside the clip range.
    #[cold]
    #[inline(never)]
    fn search(&self, start: usize, end: usize) -> (usize, usize) {
        let above_lo = |d: usize| self.key(d) >= self.key_lo;
        let below_hi = |d: usize| self.key(d) <= self.key_hi;
        if self.key_step > 0.0 {
            let s = partition_point(start, end, |d| !above_lo(d));
            (s, partition_point(s, end, below_hi))
        } else if self.key_step < 0.0 {
            let s = partition_point(start, end, |d| !below_hi(d));
            (s, partition_point(s, end, above_lo))
        } else {
            (start, start)
        }
    }
}

/// The sweeps of one line of a face's edge along one axis, as planned by the caller: what the sweeps need per line,
/// and (after [`run_lines`]) their sums. A sweep with an empty range does not run and leaves its sums 0.
#[derive(Clone, Copy)]
pub(super) struct LineJob {
    /// The line.
    pub line: usize,
    /// Where the edge crosses the line.
    pub cross: f64,
    /// `to_ndc` motion of endpoint `a` per pixel of crossing motion (0 when `a` is on the line).
    pub ka: f64,
    /// As `ka`, endpoint `c`.
    pub kc: f64,
    /// The OUT sweep's pixels (already cut to the cotangent's span and the clip range).
    pub out: (usize, usize),
    /// The OUT sweep's `sign(ka dir) EPS` (1 when `a` is on the line, so that its denominator never vanishes).
    pub ea: f64,
    /// As `ea`, endpoint `c`.
    pub ec: f64,
    /// Depth-test key of the face's plane at pixel 0 of the line.
    pub key0: f64,
    /// The IN sweep's pixels.
    pub inside: (usize, usize),
    /// Offset of `I[pix(d_out)]` (the colour beyond the edge) in [`FaceLines::colors`].
    pub out_color: usize,
    /// Offset of the face's colour on this line (the OUT sweep's `A`) in [`FaceLines::colors`].
    pub in_color: usize,
    /// Sums for endpoints a and c of the OUT sweep, then of the IN sweep.
    pub sums: [f64; 4],
}

/// What the sweeps of one face along one axis share.
pub(super) struct FaceLines<'a> {
    /// The line buffers of the axis.
    pub ln: &'a Lines,
    /// Pixel positions.
    pub pos: &'a Positions,
    /// The face, as f64 (compared with the face planes).
    pub fi: f64,
    /// The face's key increment per pixel along a line.
    pub key_step: f64,
    /// The channel count of [`FaceLines::colors`].
    pub channels: usize,
    /// The face's drawn pixels along a line lie in `own.0..=own.1` (from its drawn box): only there does an OUT
    /// sweep's pixel need the test `F[P] != f`.
    pub own: (usize, usize),
    /// The colours the forward draws: `(M + 1, C)`, every face's attributes, then the background (per-face
    /// colours), or `(H * W, C)`, the image (per-pixel colours).
    pub colors: &'a [f64],
}

/// Runs the OUT and IN sweeps of `jobs` (see [`LineJob`]) on the instruction set `isa`, for `C` channels (0: any
/// count; otherwise the attributes' length), writing their sums into the jobs. `scratch` is a line of at least the
/// longest sweep plus [`LANES`] values (used with more than 4 channels).
#[inline(always)]
pub(super) fn run_lines<const C: usize>(
    face: &FaceLines<'_>,
    jobs: &mut [LineJob],
    scratch: &mut [f64],
    isa: Isa,
) {
    // SAFETY: `Isa::Avx2` and `Isa::Avx512` are only passed when the CPU supports them (see
    // `rasterize_backward_on`); SSE2 is part of the x86-64 baseline.
    #[allow(unsafe_code)]
    unsafe {
        match isa {
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512 => lines_avx512::<C>(face, jobs, scratch),
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2 => lines_avx2::<C>(face, jobs, scratch),
            #[cfg(target_arch = "x86_64")]
            _ => lines_on::<Blocks<std::arch::x86_64::__m128d>, C>(face, jobs, scratch),
            #[cfg(not(target_arch = "x86_64"))]
            _ => lines_on::<Blocks<[f64; 2]>, C>(face, jobs, scratch),
        }
    }
}

/// [`lines_on`] on AVX2.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(unsafe_code)]
#[inline]
unsafe fn lines_avx2<const C: usize>(
    face: &FaceLines<'_>,
    jobs: &mut [LineJob],
    scratch: &mut [f64],
) {
    lines_on::<Blocks<std::arch::x86_64::__m256d>, C>(face, jobs, scratch)
}

/// [`lines_on`] on AVX-512 (two blocks per vector, see [`x86::Pairs`]).
///
/// # Safety
/// The CPU must support AVX2, AVX-512F, -DQ and -VL.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,avx512f,avx512dq,avx512vl")]
#[allow(unsafe_code)]
#[inline]
unsafe fn lines_avx512<const C: usize>(
    face: &FaceLines<'_>,
    jobs: &mut [LineJob],
    scratch: &mut [f64],
) {
    lines_on::<x86::Pairs, C>(face, jobs, scratch)
}

/// How the lane sums of a sweep are taken on some instruction set.
trait Sweeps {
    /// The lane sums of the sweep `k` (see [`lanes`]: every implementation gives its bits).
    ///
    /// # Safety
    /// The instructions must be supported by the CPU, and `k`'s slices padded as [`lanes`] requires.
    #[allow(unsafe_code)]
    unsafe fn lanes<K: Kernel>(k: &K) -> ([f64; LANES], [f64; LANES]);
}

/// Blocks of [`LANES`] pixels on vectors `V` of at most [`LANES`] lanes ([`lanes`]).
struct Blocks<V>(PhantomData<V>);

impl<V: F64s> Sweeps for Blocks<V> {
    #[allow(unsafe_code)]
    #[inline(always)]
    unsafe fn lanes<K: Kernel>(k: &K) -> ([f64; LANES], [f64; LANES]) {
        lanes::<V, K>(k)
    }
}

/// [`run_lines`] on the sweeps `S`, job by job: its OUT sweep, then its IN sweep.
///
/// # Safety
/// `S`'s instructions must be supported by the CPU.
#[allow(unsafe_code)]
#[inline(always)]
unsafe fn lines_on<S: Sweeps, const C: usize>(
    face: &FaceLines<'_>,
    jobs: &mut [LineJob],
    scratch: &mut [f64],
) {
    let ln = face.ln;
    let c = if C == 0 { face.channels } else { C };
    let (lines, pos) = (ln.of::<C>(), face.pos.of(ln.len));
    for job in jobs.iter_mut() {
        let (start, end) = job.out;
        if start < end {
            let attrs = &face.colors[job.in_color..job.in_color + c];
            let r = start..end;
            let at = lines.at(job.line, start, end);
            let pre = if C == 0 {
                dot_into(ln, job.line, &r, |k| attrs[k], c, scratch)
            } else {
                &[]
            };
            // The sweep's pixels that may be the face's own, relative to its start.
            let own_lo = face.own.0.max(start).min(end) - start;
            let own_hi = (face.own.1 + 1).max(start).min(end) - start;
            let k = OutKernel {
                n: r.len(),
                own: (own_lo, own_hi.max(own_lo)),
                end: index_f64(end),
                dot: Dot::new(&at, attrs, pre, r.len()),
                face: at.face,
                key: at.key,
                gi: at.gi,
                pos: pos.at(start, end),
                ka: job.ka,
                ba: job.ea - job.ka * job.cross,
                kc: job.kc,
                bc: job.ec - job.kc * job.cross,
                fi: face.fi,
                key0: job.key0,
                key_step: face.key_step,
            };
            // SAFETY: the pointers come from `Lines::at`, `Positions::at` and `Dot::new`, readable for the padded
            // block count; the caller vouches for `V`.
            let (sa, sc) = S::lanes(&k);
            job.sums[0] = lane_sum(&sa);
            job.sums[1] = lane_sum(&sc);
        }
        let (start, end) = job.inside;
        if start < end {
            let r = start..end;
            let out_color = &face.colors[job.out_color..job.out_color + c];
            let mut w = [0f64; 4];
            for (w, &o) in w.iter_mut().zip(out_color) {
                *w = o;
            }
            let at = lines.at(job.line, start, end);
            let pre = if C == 0 {
                dot_into(ln, job.line, &r, |k| out_color[k], c, scratch)
            } else {
                &[]
            };
            let k = InSweep {
                n: r.len(),
                end: index_f64(end),
                face: at.face,
                gi: at.gi,
                pos: pos.at(start, end),
                fi: face.fi,
                cross: job.cross,
                ka: job.ka,
                kc: job.kc,
                _data: PhantomData,
            }
            .with(Dot::new(&at, &w, pre, r.len()));
            // SAFETY: as for the OUT sweeps.
            let (sa, sc) = S::lanes(&k);
            job.sums[2] = lane_sum(&sa);
            job.sums[3] = lane_sum(&sc);
        }
    }
}

/// `sum_c G[P, c] w[c]` over the pixels `r` of line `d0` into `scratch` (channels in order; the padding lanes up
/// to the next multiple of [`LANES`] too: they are masked out by the kernels, but must be defined).
fn dot_into<'s>(
    ln: &Lines,
    d0: usize,
    r: &std::ops::Range<usize>,
    w: impl Fn(usize) -> f64,
    channels: usize,
    scratch: &'s mut [f64],
) -> &'s [f64] {
    let n = r.len().next_multiple_of(LANES);
    let out = &mut scratch[..n];
    for k in 0..channels {
        let (g, wk) = (&ln.grad_from(d0, k)[r.start..r.start + n], w(k));
        for (x, &g) in out.iter_mut().zip(g) {
            let g = g as f64;
            *x = if k == 0 { g * wk } else { *x + g * wk };
        }
    }
    out
}

/// `sum_c G[P, c] w[c]` along a sweep: the cotangent planes and weights of `C` channels, or (`C = 0`) the sums
/// precomputed by [`dot_into`]. Every pointer starts at the sweep's first pixel and may be read for the sweep's
/// length rounded up to a multiple of [`LANES`].
struct Dot<'a, const C: usize> {
    g: [*const f32; C],
    w: [f64; C],
    pre: *const f64,
    _data: PhantomData<&'a f64>,
}

impl<'a, const C: usize> Dot<'a, C> {
    /// The dot product of the cotangent of a line (`at`) with the weights `w[..C]`, or (`C = 0`) the sums `pre`
    /// precomputed by [`dot_into`] for a sweep of `n` pixels.
    #[inline(always)]
    fn new(at: &LineAt<'a, C>, w: &[f64], pre: &'a [f64], n: usize) -> Self {
        if C == 0 {
            assert!(pre.len() >= n.next_multiple_of(LANES));
        }
        Dot {
            g: at.grad,
            w: std::array::from_fn(|k| w[k]),
            pre: pre.as_ptr(),
            _data: PhantomData,
        }
    }
}

impl<const C: usize> Dot<'_, C> {
    /// The weights as vectors.
    #[allow(unsafe_code)]
    #[inline(always)]
    unsafe fn weights<V: F64s>(&self) -> [V; C] {
        std::array::from_fn(|k| V::splat(self.w[k]))
    }

    /// The dot products of the `V::N` pixels at `i`.
    ///
    /// # Safety
    /// `V`'s instructions must be supported by the CPU and `i + V::N` must not exceed the slices.
    #[allow(unsafe_code)]
    #[inline(always)]
    unsafe fn at<V: F64s>(&self, w: &[V; C], i: usize) -> V {
        if C == 0 {
            V::load(self.pre.add(i))
        } else {
            let mut s = V::load_f32(self.g[0].add(i)).mul(w[0]);
            #[allow(clippy::needless_range_loop)]
            // a plain index loop unrolls; an iterator chain does not
            for k in 1..C {
                s = s.add(V::load_f32(self.g[k].add(i)).mul(w[k]));
            }
            s
        }
    }
}

/// A sweep's kernel: the contributions of a vector of pixels to the two edge endpoints.
trait Kernel {
    /// Whether sweeps are short, so that every block runs masked (one loop, no separate last block).
    const SHORT: bool = false;
    /// The kernel's constants as vectors.
    type Consts<V: F64s>;
    /// Pixels in the sweep (every per-pixel pointer may be read for this rounded up to a multiple of [`LANES`]).
    fn len(&self) -> usize;
    /// The pixels of the sweep (from its start) that need [`Kernel::vec`]'s `OWN` test; the others may skip it.
    fn own(&self) -> (usize, usize);
    /// The constants.
    ///
    /// # Safety
    /// `V`'s instructions must be supported by the CPU.
    #[allow(unsafe_code)]
    unsafe fn consts<V: F64s>(&self) -> Self::Consts<V>;
    /// Contributions of the `V::N` pixels at `i` of the sweep to the endpoints a and c; with `MASKED`, lanes at or
    /// past the sweep's end give 0; without `OWN`, the pixels must lie outside [`Kernel::own`].
    ///
    /// # Safety
    /// `V`'s instructions must be supported by the CPU, and `i + V::N` must not exceed any slice.
    #[allow(unsafe_code)]
    unsafe fn vec<V: F64s, const MASKED: bool, const OWN: bool>(
        &self,
        c: &Self::Consts<V>,
        i: usize,
    ) -> (V, V);
}

/// A sweep's lane sums on vectors `V`: whole blocks of [`LANES`] pixels (pixel `i` into lane `i % LANES`), then
/// the last partial block with the lanes past the end masked out. The blocks that meet [`Kernel::own`] (and the
/// last) run the kernel's `OWN` variant.
///
/// # Safety
/// `V`'s instructions must be supported by the CPU, and every slice of `k` must hold `k.len()` rounded up to a
/// multiple of [`LANES`] values.
#[allow(unsafe_code)]
#[inline(always)]
unsafe fn lanes<V: F64s, K: Kernel>(k: &K) -> ([f64; LANES], [f64; LANES]) {
    let per = LANES / V::N;
    let c = k.consts::<V>();
    let zero = V::splat(0.0);
    // Only the first `per` accumulators are used.
    let (mut sa, mut sc) = ([zero; LANES], [zero; LANES]);
    let n = k.len();
    if K::SHORT {
        // Every block masked (a whole block's mask keeps every lane: the same sums).
        let mut i = 0;
        while i < n {
            for j in 0..per {
                let (x, y) = k.vec::<V, true, true>(&c, i + j * V::N);
                sa[j] = sa[j].add(x);
                sc[j] = sc[j].add(y);
            }
            i += LANES;
        }
        return store_lanes::<V>(&sa, &sc);
    }
    let [own_lo, own_hi, full] = blocks(n, k.own());
    let mut i = 0;
    macro_rules! blocks {
        ($to:expr, $own:expr) => {
            while i < $to {
                for j in 0..per {
                    let (x, y) = k.vec::<V, false, { $own }>(&c, i + j * V::N);
                    sa[j] = sa[j].add(x);
                    sc[j] = sc[j].add(y);
                }
                i += LANES;
            }
        };
    }
    // Before, in and after the own blocks; the blocks outside are one loop in the code, run twice (with a loop for
    // each of them the compiler allocates the registers of one of the two worse).
    let mut to = own_lo;
    let mut own_next = true;
    loop {
        blocks!(to, false);
        if !own_next {
            break;
        }
        blocks!(own_hi, true);
        (to, own_next) = (full, false);
    }
    if full < n {
        for j in 0..per {
            let (x, y) = k.vec::<V, true, true>(&c, full + j * V::N);
            sa[j] = sa[j].add(x);
            sc[j] = sc[j].add(y);
        }
    }
    store_lanes::<V>(&sa, &sc)
}

/// The lanes of the accumulators of [`lanes`] (the first `LANES / V::N` vectors of each).
///
/// # Safety
/// `V`'s instructions must be supported by the CPU.
#[allow(unsafe_code)]
#[inline(always)]
unsafe fn store_lanes<V: F64s>(sa: &[V; LANES], sc: &[V; LANES]) -> ([f64; LANES], [f64; LANES]) {
    let (mut xa, mut xc) = ([0f64; LANES], [0f64; LANES]);
    for j in 0..LANES / V::N {
        sa[j].store(xa.as_mut_ptr().add(j * V::N));
        sc[j].store(xc.as_mut_ptr().add(j * V::N));
    }
    (xa, xc)
}

/// The pixels where the whole blocks of a sweep of `n` pixels meeting `own` start and end, and where its whole
/// blocks end (multiples of [`LANES`]); the blocks before, meeting and after `own`, then the last partial block.
#[inline(always)]
fn blocks(n: usize, own: (usize, usize)) -> [usize; 3] {
    let full = n - n % LANES;
    let lo = (own.0 - own.0 % LANES).min(full);
    let hi = if own.1 > lo {
        own.1.next_multiple_of(LANES).min(full)
    } else {
        lo
    };
    [lo, hi, full]
}

/// The per-pixel inputs of one OUT sweep, each pointer at its first pixel and readable for
/// `n.next_multiple_of(LANES)` values (the line buffers' padding), and its constants (see [`LineJob`]).
struct OutKernel<'a, const C: usize> {
    /// Pixels in the sweep.
    n: usize,
    /// See [`Kernel::own`].
    own: (usize, usize),
    /// Position just past the last pixel, as f64 (lanes at or beyond it are masked out).
    end: f64,
    /// `sum_c G[P, c] A[f, c]`.
    dot: Dot<'a, C>,
    face: *const i32,
    key: *const f64,
    gi: *const f64,
    pos: *const f64,
    /// `da = ka * d + ba` is `ka * (d - cross) + ea`, the displacement of endpoint a (see [`LineJob`]).
    ka: f64,
    ba: f64,
    /// As `ka`, `ba` for endpoint c.
    kc: f64,
    bc: f64,
    fi: f64,
    key0: f64,
    key_step: f64,
}

/// [`OutKernel`]'s constants as vectors.
struct OutConsts<V, const C: usize> {
    w: [V; C],
    fi: V,
    key0: V,
    key_step: V,
    ka: V,
    ba: V,
    kc: V,
    bc: V,
    end: V,
    neg_zero: V,
}

impl<const C: usize> Kernel for OutKernel<'_, C> {
    type Consts<V: F64s> = OutConsts<V, C>;

    #[inline(always)]
    fn len(&self) -> usize {
        self.n
    }

    #[inline(always)]
    fn own(&self) -> (usize, usize) {
        self.own
    }

    #[allow(unsafe_code)]
    #[inline(always)]
    unsafe fn consts<V: F64s>(&self) -> OutConsts<V, C> {
        OutConsts {
            w: self.dot.weights(),
            fi: V::splat(self.fi),
            key0: V::splat(self.key0),
            key_step: V::splat(self.key_step),
            ka: V::splat(self.ka),
            ba: V::splat(self.ba),
            kc: V::splat(self.kc),
            bc: V::splat(self.bc),
            end: V::splat(self.end),
            // Opaque to the compiler, so that the loop reads it as a memory operand rather than re-broadcasting a
            // constant in every block.
            neg_zero: V::splat(std::hint::black_box(-0.0)),
        }
    }

    #[allow(unsafe_code)]
    #[inline(always)]
    unsafe fn vec<V: F64s, const MASKED: bool, const OWN: bool>(
        &self,
        c: &OutConsts<V, C>,
        i: usize,
    ) -> (V, V) {
        let load = |v: *const f64| V::load(v.add(i));
        let (fp, pos) = (V::load_i32(self.face.add(i)), load(self.pos));
        let kf = c.key0.add(c.key_step.mul(pos));
        // covers(f, P) (the clip range is handled by `clip`): `kf > kP`, or `kf == kP` and `f < F[P]`; and
        // `F[P] != f` (only possible in `own`).
        let kp = load(self.key);
        let nearer = kf.nearer(kp, fp.gt(c.fi));
        let covers = if OWN { nearer.and(fp.ne(c.fi)) } else { nearer };
        // delta where covers and delta < 0, else a zero (`min(delta, -0)` is -0 for delta >= 0 and NaN). A zero
        // contributes zeros, which leave the lane sums as they are whatever their signs (the sums start at +0, so
        // they are never -0); -0 rather than +0 because it is not built by zeroing a register in the loop.
        let delta = self.dot.at(&c.w, i).sub(load(self.gi));
        let m = delta.min(c.neg_zero).and(covers);
        let da = c.ka.mul(pos).add(c.ba);
        let dc = c.kc.mul(pos).add(c.bc);
        // m / da and m / dc with one division.
        let q = m.div(da.mul(dc));
        let (x, y) = (q.mul(dc), q.mul(da));
        if MASKED {
            let valid = pos.lt(c.end);
            (x.and(valid), y.and(valid))
        } else {
            (x, y)
        }
    }
}

/// The per-pixel inputs of one IN sweep (each pointer at its first pixel, readable as for [`OutKernel`]) and its
/// constants.
struct InSweep<'a> {
    n: usize,
    end: f64,
    face: *const i32,
    gi: *const f64,
    pos: *const f64,
    fi: f64,
    cross: f64,
    ka: f64,
    kc: f64,
    _data: PhantomData<&'a f64>,
}

impl<'a> InSweep<'a> {
    /// The kernel with `sum_c G[P, c] I[pix(d_out), c]` from `dot`.
    #[inline(always)]
    fn with<const C: usize>(self, dot: Dot<'a, C>) -> InKernel<'a, C> {
        InKernel { s: self, dot }
    }
}

/// An IN sweep with its dot product.
struct InKernel<'a, const C: usize> {
    s: InSweep<'a>,
    /// `sum_c G[P, c] I[pix(d_out), c]`.
    dot: Dot<'a, C>,
}

/// [`InKernel`]'s constants as vectors.
struct InConsts<V, const C: usize> {
    w: [V; C],
    fi: V,
    cross: V,
    ka: V,
    kc: V,
    eps: V,
    eps2: V,
    end: V,
    zero: V,
}

impl<const C: usize> Kernel for InKernel<'_, C> {
    // IN sweeps are cut to the face's drawn box: a few pixels.
    const SHORT: bool = true;
    type Consts<V: F64s> = InConsts<V, C>;

    #[inline(always)]
    fn len(&self) -> usize {
        self.s.n
    }

    #[inline(always)]
    fn own(&self) -> (usize, usize) {
        (0, 0)
    }

    #[allow(unsafe_code)]
    #[inline(always)]
    unsafe fn consts<V: F64s>(&self) -> InConsts<V, C> {
        InConsts {
            w: self.dot.weights(),
            fi: V::splat(self.s.fi),
            cross: V::splat(self.s.cross),
            ka: V::splat(self.s.ka),
            kc: V::splat(self.s.kc),
            eps: V::splat(EPS),
            eps2: V::splat(2.0 * EPS),
            end: V::splat(self.s.end),
            zero: V::splat(0.0),
        }
    }

    #[allow(unsafe_code)]
    #[inline(always)]
    unsafe fn vec<V: F64s, const MASKED: bool, const OWN: bool>(
        &self,
        c: &InConsts<V, C>,
        i: usize,
    ) -> (V, V) {
        let load = |v: *const f64| V::load(v.add(i));
        let go = self.dot.at(&c.w, i);
        let pos = load(self.s.pos);
        let delta = go.sub(load(self.s.gi));
        let own = V::load_i32(self.s.face.add(i)).eq(c.fi);
        let m = delta.min(c.zero).and(own);
        let t = pos.sub(c.cross);
        // NMR's nudge: x + (EPS if x > 0 else -EPS); (2 EPS or 0) - EPS is exact.
        let nudge = |x: V| x.add(x.gt(c.zero).and(c.eps2).sub(c.eps));
        let (da, dc) = (nudge(c.ka.mul(t)), nudge(c.kc.mul(t)));
        let q = m.div(da.mul(dc));
        let (x, y) = (q.mul(dc), q.mul(da));
        if MASKED {
            let valid = pos.lt(c.end);
            (x.and(valid), y.and(valid))
        } else {
            (x, y)
        }
    }
}

/// SSE2 (every x86-64 CPU), AVX2 and AVX-512 vectors, and the AVX-512 sweeps.
#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod x86 {
    use std::arch::x86_64::*;

    use super::{blocks, lanes, store_lanes, Kernel, Sweeps, LANES};

    const _: () = assert!(
        LANES == 4,
        "Pairs adds the halves of an 8-lane vector to 4-lane block sums"
    );

    /// The sweeps on AVX-512: two blocks of [`LANES`] pixels per 8-lane vector, whose halves are added to the
    /// 4-lane block sums one after the other, so every lane sums the same pixels in the same order as [`lanes`]
    /// (the same bits). A segment's odd last block, the sweep's partial last block and the short IN sweeps run
    /// on 4 lanes.
    pub(super) struct Pairs;

    impl Sweeps for Pairs {
        #[inline(always)]
        #[allow(unused_assignments)] // the last segment's `i`
        unsafe fn lanes<K: Kernel>(k: &K) -> ([f64; LANES], [f64; LANES]) {
            if K::SHORT {
                return lanes::<__m256d, K>(k);
            }
            let (c8, c4) = (k.consts::<__m512d>(), k.consts::<__m256d>());
            let (mut sa, mut sc) = ([_mm256_setzero_pd(); LANES], [_mm256_setzero_pd(); LANES]);
            let n = k.len();
            let [own_lo, own_hi, full] = blocks(n, k.own());
            let mut i = 0;
            macro_rules! blocks {
                ($to:expr, $own:expr) => {
                    while i + 2 * LANES <= $to {
                        let (x, y) = k.vec::<__m512d, false, { $own }>(&c8, i);
                        let lo = |v: __m512d| _mm512_castpd512_pd256(v);
                        let hi = |v: __m512d| _mm512_extractf64x4_pd::<1>(v);
                        sa[0] = _mm256_add_pd(_mm256_add_pd(sa[0], lo(x)), hi(x));
                        sc[0] = _mm256_add_pd(_mm256_add_pd(sc[0], lo(y)), hi(y));
                        i += 2 * LANES;
                    }
                    if i < $to {
                        let (x, y) = k.vec::<__m256d, false, { $own }>(&c4, i);
                        sa[0] = _mm256_add_pd(sa[0], x);
                        sc[0] = _mm256_add_pd(sc[0], y);
                        i += LANES;
                    }
                };
            }
            blocks!(own_lo, false);
            blocks!(own_hi, true);
            blocks!(full, false);
            if full < n {
                let (x, y) = k.vec::<__m256d, true, true>(&c4, full);
                sa[0] = _mm256_add_pd(sa[0], x);
                sc[0] = _mm256_add_pd(sc[0], y);
            }
            store_lanes::<__m256d>(&sa, &sc)
        }
    }

    /// [`Pairs`]'s lane sums, compiled for AVX-512 (for the tests, which compare every path).
    ///
    /// # Safety
    /// The CPU must support AVX2, AVX-512F, -DQ and -VL, and `k`'s slices be padded as [`lanes`] requires.
    #[cfg(test)]
    #[target_feature(enable = "avx2,avx512f,avx512dq,avx512vl")]
    pub(super) unsafe fn pairs_lanes<K: Kernel>(k: &K) -> ([f64; LANES], [f64; LANES]) {
        Pairs::lanes(k)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::test_rng::Rng;

    /// The lane sums of one OUT kernel on every code path this CPU has: generic on `[f64; 2]`, SSE2 and AVX2
    /// vectors, and AVX-512's pairs of blocks; all must give the same bits.
    #[allow(unsafe_code)]
    fn all_paths(k: &OutKernel<'_, 4>) -> Vec<([f64; LANES], [f64; LANES])> {
        // SAFETY: the kernel's buffers are padded (built by the caller); SSE2 is baseline, AVX2 and AVX-512 are
        // checked.
        unsafe {
            let mut out = vec![lanes::<[f64; 2], _>(k)];
            #[cfg(target_arch = "x86_64")]
            {
                out.push(lanes::<std::arch::x86_64::__m128d, _>(k));
                if Isa::Avx2.available() {
                    out.push(lanes::<std::arch::x86_64::__m256d, _>(k));
                }
                if Isa::Avx512.available() {
                    out.push(x86::pairs_lanes(k));
                }
            }
            out
        }
    }

    #[test]
    fn the_out_kernels_give_the_same_bits_on_every_path() {
        let mut rng = Rng(7);
        let mut checked = 0;
        for case in 0..3000 {
            // One line of `len` pixels plus padding; the sweep covers `start..start + n`.
            let len = 1 + rng.below(80);
            let padded = len + LANES;
            let start = rng.below(len);
            let n = 1 + rng.below(len - start);
            let fi = 5.0;
            let (key0, key_step) = (rng.next() * 2.0, (rng.next() - 0.5) * 0.1);
            let pos: Vec<f64> = (0..padded).map(|d| d as f64).collect();
            let kf = |d: usize| key0 + key_step * pos[d];
            // The own pixels: anywhere in the sweep (or none).
            let own_a = rng.below(n + 1);
            let own = (own_a, own_a + rng.below(n + 1 - own_a));
            // Faces: background, lower and higher indices, and the face itself (only among the own pixels, as
            // the kernels require); keys: random, or exact ties.
            let face: Vec<i32> = (0..padded)
                .map(|d| match [-1, 2, fi as i32, 9][rng.below(4)] {
                    f if f as f64 == fi && !(start + own.0 <= d && d < start + own.1) => 9,
                    f => f,
                })
                .collect();
            let key: Vec<f64> = (0..padded)
                .map(|d| match rng.below(4) {
                    0 => kf(d),
                    1 if face[d] < 0 => f64::NEG_INFINITY,
                    _ => key0 + (rng.next() - 0.5) * 0.5,
                })
                .collect();
            let gi: Vec<f64> = (0..padded).map(|_| rng.next() - 0.5).collect();
            let g: Vec<Vec<f32>> = (0..4)
                .map(|_| {
                    (0..padded)
                        .map(|_| {
                            if rng.below(8) == 0 {
                                0.0
                            } else {
                                (rng.next() - 0.5) as f32
                            }
                        })
                        .collect()
                })
                .collect();
            let (cross, dir) = (start as f64 - rng.next() * 2.0, 1.0);
            let ka = if case % 7 == 0 {
                0.0
            } else {
                (rng.next() - 0.3) * 0.02
            };
            let kc = (rng.next() - 0.7) * 0.02;
            let nudge = |k: f64| {
                if k == 0.0 {
                    1.0
                } else if k * dir > 0.0 {
                    EPS
                } else {
                    -EPS
                }
            };
            let (ea, ec) = (nudge(ka), nudge(kc));
            let at = |v: &Vec<f64>| v[start..].as_ptr();
            let at32 = |v: &Vec<f32>| v[start..].as_ptr();
            let k = OutKernel::<4> {
                n,
                own,
                end: (start + n) as f64,
                dot: Dot {
                    g: [at32(&g[0]), at32(&g[1]), at32(&g[2]), at32(&g[3])],
                    w: [rng.next(), rng.next(), rng.next(), rng.next()],
                    pre: std::ptr::null(),
                    _data: PhantomData,
                },
                face: face[start..].as_ptr(),
                key: at(&key),
                gi: at(&gi),
                pos: at(&pos),
                ka,
                ba: ea - ka * cross,
                kc,
                bc: ec - kc * cross,
                fi,
                key0,
                key_step,
            };
            let sums = all_paths(&k);
            // The generic pairs, then one path per instruction set (SSE2 on x86-64's baseline).
            #[cfg(target_arch = "x86_64")]
            assert_eq!(sums.len(), 1 + Isa::all_available().len());
            let bits =
                |s: &([f64; LANES], [f64; LANES])| (s.0.map(f64::to_bits), s.1.map(f64::to_bits));
            for s in &sums[1..] {
                assert_eq!(bits(s), bits(&sums[0]), "case {case}");
            }
            // The sums are those of the definition, pixel by pixel (lane i % LANES; own pixels never count).
            let (mut wa, mut wc) = ([0f64; LANES], [0f64; LANES]);
            for i in 0..n {
                let d = start + i;
                let fd = face[d] as f64;
                let nearer = kf(d) > key[d] || (kf(d) == key[d] && fi < fd);
                let delta = (0..4)
                    .map(|c| g[c][d] as f64 * k.dot.w[c])
                    .fold(0.0, |s, x| s + x)
                    - gi[d];
                if fd != fi && nearer && delta < 0.0 {
                    let (da, dc) = (ka * pos[d] + k.ba, kc * pos[d] + k.bc);
                    let q = delta / (da * dc);
                    wa[i % LANES] += q * dc;
                    wc[i % LANES] += q * da;
                }
            }
            let close = |x: f64, y: f64| (x - y).abs() <= 1e-12 * (1.0 + x.abs().max(y.abs()));
            for l in 0..LANES {
                assert!(
                    close(sums[0].0[l], wa[l]) && close(sums[0].1[l], wc[l]),
                    "case {case}: {:?} vs {wa:?}, {:?} vs {wc:?}",
                    sums[0].0,
                    sums[0].1
                );
            }
            checked += sums.len();
        }
        assert!(checked >= 3000);
    }

    #[test]
    fn the_in_kernels_give_the_same_bits_on_every_path() {
        let mut rng = Rng(8);
        for case in 0..3000 {
            let len = 1 + rng.below(40);
            let padded = len + LANES;
            let start = rng.below(len);
            let n = 1 + rng.below(len - start);
            let fi = 5.0;
            let pos: Vec<f64> = (0..padded).map(|d| d as f64).collect();
            let face: Vec<i32> = (0..padded)
                .map(|_| [-1, 2, fi as i32, fi as i32][rng.below(4)])
                .collect();
            let gi: Vec<f64> = (0..padded).map(|_| rng.next() - 0.5).collect();
            let g: Vec<Vec<f32>> = (0..4)
                .map(|_| (0..padded).map(|_| (rng.next() - 0.5) as f32).collect())
                .collect();
            // The crossing: sometimes exactly on a pixel centre (t = 0 there).
            let cross = if case % 5 == 0 {
                (start + rng.below(n)) as f64
            } else {
                start as f64 + (rng.next() - 0.5) * 4.0
            };
            let ka = if case % 7 == 0 {
                0.0
            } else {
                (rng.next() - 0.5) * 0.02
            };
            let kc = (rng.next() - 0.5) * 0.02;
            let at = |v: &Vec<f64>| v[start..].as_ptr();
            let at32 = |v: &Vec<f32>| v[start..].as_ptr();
            let w = [rng.next(), rng.next(), rng.next(), rng.next()];
            let k = InSweep {
                n,
                end: (start + n) as f64,
                face: face[start..].as_ptr(),
                gi: at(&gi),
                pos: at(&pos),
                fi,
                cross,
                ka,
                kc,
                _data: PhantomData,
            }
            .with(Dot::<4> {
                g: [at32(&g[0]), at32(&g[1]), at32(&g[2]), at32(&g[3])],
                w,
                pre: std::ptr::null(),
                _data: PhantomData,
            });
            #[allow(unsafe_code)]
            // SAFETY: padded buffers; SSE2 is baseline, AVX2 and AVX-512 are checked.
            let sums = unsafe {
                let mut out = vec![lanes::<[f64; 2], _>(&k)];
                #[cfg(target_arch = "x86_64")]
                {
                    out.push(lanes::<std::arch::x86_64::__m128d, _>(&k));
                    if Isa::Avx2.available() {
                        out.push(lanes::<std::arch::x86_64::__m256d, _>(&k));
                    }
                    if Isa::Avx512.available() {
                        out.push(x86::pairs_lanes(&k));
                    }
                }
                out
            };
            let bits =
                |s: &([f64; LANES], [f64; LANES])| (s.0.map(f64::to_bits), s.1.map(f64::to_bits));
            for s in &sums[1..] {
                assert_eq!(bits(s), bits(&sums[0]), "case {case}");
            }
            // The definition, pixel by pixel.
            let nudge = |x: f64| x + if x > 0.0 { EPS } else { -EPS };
            let (mut wa, mut wc) = ([0f64; LANES], [0f64; LANES]);
            for i in 0..n {
                let d = start + i;
                let delta = (0..4)
                    .map(|c| g[c][d] as f64 * w[c])
                    .fold(0.0, |s, x| s + x)
                    - gi[d];
                if face[d] as f64 == fi && delta < 0.0 {
                    let t = pos[d] - cross;
                    let (da, dc) = (nudge(ka * t), nudge(kc * t));
                    let q = delta / (da * dc);
                    wa[i % LANES] += q * dc;
                    wc[i % LANES] += q * da;
                }
            }
            let close = |x: f64, y: f64| (x - y).abs() <= 1e-12 * (1.0 + x.abs().max(y.abs()));
            for l in 0..LANES {
                assert!(
                    close(sums[0].0[l], wa[l]) && close(sums[0].1[l], wc[l]),
                    "case {case}"
                );
            }
        }
    }
}
