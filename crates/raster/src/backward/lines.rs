//! Per-batch-element buffers of the backward pass laid out along sweep lines.

use std::marker::PhantomData;
use std::mem::MaybeUninit;

use rayon::prelude::*;

use crate::error::{try_refill, Fill, Result};
use crate::input::RasterParams;
use crate::setup::FaceSetup;

use super::sweep::LANES;
use super::Isa;
use crate::simd::F64s;

/// The per-pixel inputs of the sweeps of one batch element, one line after another: image rows for the row sweeps
/// (axis V) or image columns for the column sweeps (axis U), so that the inner loops read memory contiguously.
/// Every buffer ends with [`LANES`] values of padding, so that a vector loop may read a whole block past the end of
/// any line (the lanes past the line's end are masked out).
/// The sums are f64, as in the definition: f32 weights or `delta`s change single contributions near an edge
/// (`delta / EPS` spikes) by more than 1e-5 of a vertex gradient whose terms cancel (measured). What is exact in
/// fewer bytes is stored so, because the sweeps are bound by the bytes they read: the cotangent as the f32 it was
/// given (converted to f64 exactly when loaded) and the face index as i32 (36 instead of 64 bytes per pixel with 4
/// channels).
/// The buffers are refilled in place ([`Lines::fill_rows`], [`Lines::fill_columns`]), so that a `Lines` kept
/// between calls (see `workspace`) allocates nothing once it is large enough.
#[derive(Default)]
pub(super) struct Lines {
    /// Pixels per line.
    pub len: usize,
    /// Channels `C`.
    channels: usize,
    /// Face drawn at each pixel (-1 on background).
    face: Vec<i32>,
    /// Depth-test key of the drawn face (see [`Lines::fill_rows`]).
    key: Vec<f64>,
    /// `sum_c G[P, c] * I[P, c]` (f64 products and sums), channels in order.
    gi: Vec<f64>,
    /// The cotangent, per line `C` planes of `len` values.
    grad: Vec<f32>,
    /// Per line, the range `[first, last + 1)` of pixels whose cotangent is not all zero (`[0, 0]` when none):
    /// pixels outside it have `delta = 0` and never contribute.
    pub nonzero: Vec<[usize; 2]>,
}

impl Lines {
    /// Becomes the row lines of the row-major maps, with the depth-test keys of the drawn faces (`1/z` in
    /// perspective, `-z` in orthographic, larger = nearer; `z` recomputed from the positions exactly as the forward
    /// computes it; `-inf` on background; on the instruction set `isa`, which the caller has checked is available).
    /// Every value is rewritten; only the buffers' memory is reused. The cotangent planes hold the channels
    /// `kept` (ascending indices into the `c` channels of `image` and `grad`); `gI` sums over all `c`.
    #[allow(clippy::too_many_arguments)]
    pub fn fill_rows(
        &mut self,
        isa: Isa,
        setups: &[FaceSetup],
        face_index: &[i32],
        image: &[f32],
        grad: &[f32],
        c: usize,
        kept: &[usize],
        params: &RasterParams,
    ) -> Result<()> {
        let (h, w) = (params.height, params.width);
        let n = h * w;
        let k = kept.len();
        // Kept channels `0..k` (all of them, or all but the coverage channel: the usual cases) are copied by
        // the loop for `k` channels, any other choice by the one for a list of channels.
        let prefix = kept.iter().enumerate().all(|(s, &ch)| s == ch);
        let (mut face, mut key, mut gi, mut planes) = self.fills(n, k)?;
        // One pass per row.
        face.slots()
            .par_chunks_mut(w)
            .zip(key.slots().par_chunks_mut(w))
            .zip(gi.slots().par_chunks_mut(w))
            .zip(planes.slots().par_chunks_mut(w * k))
            .enumerate()
            .for_each(|(i, (((face, key), gi), planes))| {
                let faces = &face_index[i * w..(i + 1) * w];
                // By runs of one face along the row (its depth's row terms computed once per run).
                let mut j = 0;
                while j < w {
                    let f = faces[j];
                    let j0 = j;
                    while j < w && faces[j] == f {
                        face[j].write(f);
                        j += 1;
                    }
                    match setups.get(f as usize) {
                        Some(s) if f >= 0 => row_keys_on(isa, s, i as i32, j0, &mut key[j0..j]),
                        _ => key[j0..j]
                            .iter_mut()
                            .for_each(|k| _ = k.write(f64::NEG_INFINITY)),
                    }
                }
                let (g, im) = (
                    &grad[i * w * c..(i + 1) * w * c],
                    &image[i * w * c..(i + 1) * w * c],
                );
                if prefix {
                    with_channels!(k, K => with_channels!(c, C => channels::<C, K>(g, im, w, kept, gi, planes)))
                } else {
                    with_channels!(c, C => channels::<C, 0>(g, im, w, kept, gi, planes))
                }
            });
        // SAFETY: the row passes above wrote every slot: each row chunk writes its `w` face, key and gi values and
        // its `w * k` plane values.
        #[allow(unsafe_code)]
        unsafe {
            face.done();
            key.done();
            gi.done();
            planes.done();
        }
        self.finish(h, w, k)
    }

    /// Becomes the column lines: the transpose of `rows`, in groups of [`GROUP`] columns (so that each row is read
    /// in runs), with the tiles of the instruction set `isa` (which the caller has checked is available). Every
    /// value is rewritten; only the buffers' memory is reused.
    pub fn fill_columns(&mut self, isa: Isa, rows: &Lines) -> Result<()> {
        let (w, h, c) = (rows.len, rows.lines(), rows.channels);
        let n = h * w;
        let (mut face, mut key, mut gi, mut planes) = self.fills(n, c)?;
        face.slots()
            .par_chunks_mut(GROUP * h)
            .zip(key.slots().par_chunks_mut(GROUP * h))
            .zip(gi.slots().par_chunks_mut(GROUP * h))
            .zip(planes.slots().par_chunks_mut(GROUP * c * h))
            .enumerate()
            .for_each(|(group, (((face, key), gi), planes))| {
                let j0 = group * GROUP;
                // Columns `j0..j0 + cols` (the last group may be narrower), one buffer at a time.
                let cols = face.len() / h.max(1);
                transpose_on(isa, &rows.face[j0..], w, cols, h, face, h);
                transpose_on(isa, &rows.key[j0..], w, cols, h, key, h);
                transpose_on(isa, &rows.gi[j0..], w, cols, h, gi, h);
                // Row i's channel k is rows.grad[(i * c + k) * w..][..w]; column j's is planes[(j * c + k) * h..].
                for k in 0..c {
                    let plane = &mut planes[k * h..];
                    transpose_on(isa, &rows.grad[k * w + j0..], c * w, cols, h, plane, c * h);
                }
            });
        // SAFETY: every group of `cols` columns wrote its `cols * h` face, key and gi values and `cols * c * h` plane
        // values (all rows i, all columns jj, all channels).
        #[allow(unsafe_code)]
        unsafe {
            face.done();
            key.done();
            gi.done();
            planes.done();
        }
        self.finish(w, h, c)
    }

    /// Sets the shape (`lines` lines of `len` pixels, `channels` channels; the planes are filled) and finds
    /// [`Lines::nonzero`].
    fn finish(&mut self, lines: usize, len: usize, channels: usize) -> Result<()> {
        self.len = len;
        self.channels = channels;
        try_refill(&mut self.nonzero, lines, [0, 0], "backward line ranges")?;
        self.find_nonzero();
        Ok(())
    }

    /// Bytes held (capacity) by the buffers.
    pub fn bytes(&self) -> usize {
        fn held<T>(v: &Vec<T>) -> usize {
            v.capacity() * std::mem::size_of::<T>()
        }
        held(&self.face) + held(&self.key) + held(&self.gi) + held(&self.grad) + held(&self.nonzero)
    }

    /// Number of lines.
    fn lines(&self) -> usize {
        self.nonzero.len()
    }

    /// Fills [`Lines::nonzero`] from the cotangent planes.
    fn find_nonzero(&mut self) {
        let (len, c) = (self.len, self.channels);
        self.nonzero
            .par_iter_mut()
            .zip(self.grad.par_chunks(len * c))
            .for_each(|(nz, planes)| {
                let zero = |d: usize| (0..c).all(|k| planes[k * len + d] == 0.0);
                *nz = match (0..len).position(|d| !zero(d)) {
                    Some(first) => [
                        first,
                        (0..len).rposition(|d| !zero(d)).map_or(first, |l| l) + 1,
                    ],
                    None => [0, 0],
                };
            });
    }

    /// The face drawn at pixel `d` of line `d0` (`d < len`).
    #[inline(always)]
    pub fn face_at(&self, d0: usize, d: usize) -> i32 {
        debug_assert!(d < self.len);
        self.face[d0 * self.len + d]
    }

    /// Cotangent channel `k` from the start of line `d0` to the end of the buffer (padding included).
    #[inline(always)]
    pub fn grad_from(&self, d0: usize, k: usize) -> &[f32] {
        &self.grad[(d0 * self.channels + k) * self.len..]
    }

    /// The buffers' pointers for [`LinesOf::at`], with `C` channels (or 0: no cotangent pointers).
    #[inline(always)]
    pub fn of<const C: usize>(&self) -> LinesOf<'_, C> {
        assert!(C == 0 || C == self.channels);
        LinesOf {
            face: self.face.as_ptr(),
            key: self.key.as_ptr(),
            gi: self.gi.as_ptr(),
            grad: self.grad.as_ptr(),
            len: self.len,
            lines: self.lines(),
            channels: self.channels,
            _lines: PhantomData,
        }
    }
}

/// The buffers of a [`Lines`] with `C` channels (checked once), for many [`LinesOf::at`].
#[derive(Clone, Copy)]
pub(super) struct LinesOf<'a, const C: usize> {
    face: *const i32,
    key: *const f64,
    gi: *const f64,
    grad: *const f32,
    len: usize,
    lines: usize,
    channels: usize,
    _lines: PhantomData<&'a Lines>,
}

impl<'a, const C: usize> LinesOf<'a, C> {
    /// Pointers to the data of pixels `start..end` of line `d0` (one bounds check for all of them). Each pointer may
    /// be read for `(end - start).next_multiple_of(LANES)` values: past `end` it reads the next line's data, or for
    /// the last line the buffer's padding.
    #[inline(always)]
    pub fn at(&self, d0: usize, start: usize, end: usize) -> LineAt<'a, C> {
        assert!(d0 < self.lines && start <= end && end <= self.len);
        let o = d0 * self.len + start;
        // SAFETY: `o < lines * len`, within every buffer (which hold `lines * len` values, or `lines * channels *
        // len` for the cotangent, plus LANES), and so is `(d0 * channels + k) * len + start` for `k < C <=
        // channels` (`Lines::of`). Reads: `start + (end - start).next_multiple_of(LANES) <= len + LANES - 1`, so
        // from line `d0` they stay within `(d0 + 1) * len + LANES - 1 <= lines * len + LANES - 1` (cotangent:
        // `lines * channels * len + LANES - 1`), inside the buffers.
        #[allow(unsafe_code)]
        unsafe {
            let g = self.grad.add((d0 * self.channels) * self.len + start);
            LineAt {
                face: self.face.add(o),
                key: self.key.add(o),
                gi: self.gi.add(o),
                grad: std::array::from_fn(|k| g.add(k * self.len)),
                _lines: PhantomData,
            }
        }
    }
}

/// [`row_keys`] on the instruction set `isa` (which the caller has checked is available): four pixels at a time
/// with AVX2, two in SSE2 lanes (x86-64 baseline), plain pairs elsewhere.
#[inline(always)]
fn row_keys_on(isa: Isa, s: &FaceSetup, row: i32, j0: usize, key: &mut [MaybeUninit<f64>]) {
    // SAFETY: `rasterize_backward_on` only passes `Isa::Avx2` or `Isa::Avx512` (which includes AVX2) when the CPU
    // supports it; SSE2 is part of the x86-64 baseline.
    #[allow(unsafe_code)]
    unsafe {
        match isa {
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2 | Isa::Avx512 => row_keys_avx2(s, row, j0, key),
            #[cfg(target_arch = "x86_64")]
            _ => row_keys::<std::arch::x86_64::__m128d>(s, row, j0, key),
            #[cfg(not(target_arch = "x86_64"))]
            _ => row_keys::<[f64; 2]>(s, row, j0, key),
        }
    }
}

/// [`row_keys`] on AVX2.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(unsafe_code)]
unsafe fn row_keys_avx2(s: &FaceSetup, row: i32, j0: usize, key: &mut [MaybeUninit<f64>]) {
    row_keys::<std::arch::x86_64::__m256d>(s, row, j0, key)
}

/// The depth-test keys of the pixels `j0..j0 + key.len()` of row `row`, all drawn by the face of `s`: `1/z`
/// (perspective) or `-z` (orthographic) of [`FaceSetup::depth_at`], `-inf` where it is undefined. `V::N` pixels at a
/// time: lane by lane the operations of `RowDepth::at` and `depth_from_weights`, so the same bits (tested).
///
/// # Safety
/// `V`'s instructions must be supported by the CPU.
#[allow(unsafe_code)]
#[inline(always)]
unsafe fn row_keys<V: F64s>(s: &FaceSetup, row: i32, j0: usize, key: &mut [MaybeUninit<f64>]) {
    let rd = s.row_depth(row);
    let sp = |x: f64| V::splat(x);
    let e = &s.edges;
    let (au, dv, sign, rt) = (
        [sp(e[0].au), sp(e[1].au), sp(e[2].au)],
        [sp(e[0].dv), sp(e[1].dv), sp(e[2].dv)],
        [sp(e[0].sign), sp(e[1].sign), sp(e[2].sign)],
        [
            sp(rd.row_terms[0]),
            sp(rd.row_terms[1]),
            sp(rd.row_terms[2]),
        ],
    );
    let inv = sp(s.inv_area);
    let m = if s.ortho { s.z } else { s.inv_z };
    let m = [sp(m[0]), sp(m[1]), sp(m[2])];
    let (zero, one, inf, neg_inf) = (sp(0.0), sp(1.0), sp(f64::INFINITY), sp(f64::NEG_INFINITY));
    let (neg_one, step) = (sp(-1.0), sp(V::N as f64));
    let mut u = V::counting_from(j0 as f64);
    for out in key.chunks_mut(V::N) {
        // Barycentric weights as `RowDepth::at`: sign * (row term - dv * (u - au)) * inv_area.
        let w: [V; 3] =
            std::array::from_fn(|k| sign[k].mul(rt[k].sub(dv[k].mul(u.sub(au[k])))).mul(inv));
        // `depth_from_weights`: w0 m0 + w1 m1 + w2 m2, then the key where defined.
        let x = w[0].mul(m[0]).add(w[1].mul(m[1])).add(w[2].mul(m[2]));
        let (k, ok) = if s.ortho {
            // -z (a product by -1 negates exactly, zeros included); defined where z is finite.
            (x.mul(neg_one), x.lt(inf).and(neg_inf.lt(x)))
        } else {
            // 1 / (1 / iz); defined where iz > 0 and finite.
            (one.div(one.div(x)), x.gt(zero).and(x.lt(inf)))
        };
        let k = ok.and(k).or(ok.andnot(neg_inf));
        if out.len() == V::N {
            // SAFETY: `MaybeUninit<f64>` has the layout of `f64`, and the chunk holds `V::N` values.
            k.store(out.as_mut_ptr().cast::<f64>());
        } else {
            // The last, partial chunk (one value at a time, not a library copy of a variable length).
            let mut lanes = [0f64; 4];
            k.store(lanes.as_mut_ptr());
            match out {
                [a] => _ = a.write(lanes[0]),
                [a, b] => (_, _) = (a.write(lanes[0]), b.write(lanes[1])),
                [a, b, c] => (_, _, _) = (a.write(lanes[0]), b.write(lanes[1]), c.write(lanes[2])),
                _ => unreachable!("chunks of at most {} values", V::N),
            }
        }
        u = u.add(step);
    }
}

/// Writes one row's cotangent planes of the channels `kept` (`planes[s * w + j] = G[j, kept[s]]`) and
/// `gi[j] = sum_c G[j, c] I[j, c]` (all channels, in order) from the interleaved row `g` and image row `im`, for `C`
/// channels (`C = 0`: any count); `K > 0`: the kept channels are `0..K`, `K = 0`: they are `kept`.
#[inline(always)]
fn channels<const C: usize, const K: usize>(
    g: &[f32],
    im: &[f32],
    w: usize,
    kept: &[usize],
    gi: &mut [MaybeUninit<f64>],
    planes: &mut [MaybeUninit<f32>],
) {
    let c = if C == 0 { g.len() / w } else { C };
    for (j, ((x, g), im)) in gi
        .iter_mut()
        .zip(g.chunks_exact(c))
        .zip(im.chunks_exact(c))
        .enumerate()
    {
        let mut sum = 0f64;
        for ch in 0..c {
            sum += g[ch] as f64 * im[ch] as f64;
        }
        if K > 0 {
            // The first `K` channels (a constant: the loop over the row vectorises).
            for s in 0..K {
                planes[s * w + j].write(g[s]);
            }
        } else {
            for (s, &ch) in kept.iter().enumerate() {
                planes[s * w + j].write(g[ch]);
            }
        }
        x.write(sum);
    }
}

/// Columns transposed together by [`Lines::fill_columns`].
const GROUP: usize = 8;

/// Rows transposed together by [`transpose`]: few enough that their pages and cache lines stay in the first-level
/// TLB and cache while every column of a group is written (one column at a time over all rows does not: at 448 x
/// 448 each of its reads is a TLB miss).
const ROWS: usize = 32;

/// [`transpose`] with the widest tiles of the instruction set `isa` (which the caller has checked is available):
/// 8 x 8 (32-bit values) or 4 x 4 (f64) with AVX2, 4 x 4 or 2 x 2 with SSE2 (x86-64 baseline), single values
/// elsewhere. Every choice moves the same bits.
#[inline(always)]
fn transpose_on<T: Copy>(
    isa: Isa,
    src: &[T],
    stride: usize,
    cols: usize,
    h: usize,
    out: &mut [MaybeUninit<T>],
    out_stride: usize,
) where
    Sse: Tiles<T>,
    Avx: Tiles<T>,
{
    match isa {
        // SAFETY: `Isa::Avx2` and `Isa::Avx512` (which includes AVX2) are only passed when the CPU supports them.
        #[cfg(target_arch = "x86_64")]
        #[allow(unsafe_code)]
        Isa::Avx2 | Isa::Avx512 => unsafe { transpose_avx(src, stride, cols, h, out, out_stride) },
        _ => transpose::<T, Sse>(src, stride, cols, h, out, out_stride),
    }
}

/// [`transpose`] with [`Avx`] tiles.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(unsafe_code)]
unsafe fn transpose_avx<T: Copy>(
    src: &[T],
    stride: usize,
    cols: usize,
    h: usize,
    out: &mut [MaybeUninit<T>],
    out_stride: usize,
) where
    Avx: Tiles<T>,
{
    transpose::<T, Avx>(src, stride, cols, h, out, out_stride)
}

/// A transpose of `cols` columns and `h` rows: `out[jj * out_stride + i] = src[i * stride + jj]` for `jj < cols`
/// and `i < h`, in blocks of [`ROWS`] rows; within a block, tiles of `S::K` x `S::K` values are moved by vector
/// loads, shuffles and stores (the values' bits are copied, never computed), the rest one value at a time.
#[inline(always)]
fn transpose<T: Copy, S: Tiles<T>>(
    src: &[T],
    stride: usize,
    cols: usize,
    h: usize,
    out: &mut [MaybeUninit<T>],
    out_stride: usize,
) {
    if h == 0 || cols == 0 {
        return;
    }
    assert!(src.len() > (h - 1) * stride + cols - 1 && out.len() >= (cols - 1) * out_stride + h);
    let (sp, op) = (src.as_ptr(), out.as_mut_ptr().cast::<T>());
    let k = S::K;
    // Columns that whole tiles cover.
    let cv = cols - cols % k;
    for i0 in (0..h).step_by(ROWS) {
        let i1 = (i0 + ROWS).min(h);
        // Rows of this block that whole tiles cover.
        let iv = i1 - (i1 - i0) % k;
        // SAFETY: every tile reads rows `i..i + K <= iv <= h` at columns `jj..jj + K <= cv <= cols` and writes
        // columns `jj..jj + K` at rows `i..i + K`, all within the lengths asserted above; the single moves stay
        // within `i < h`, `jj < cols` likewise. The caller vouches for `S`'s instructions.
        #[allow(unsafe_code)]
        unsafe {
            for jj in (0..cv).step_by(k) {
                for i in (i0..iv).step_by(k) {
                    S::tile(
                        sp.add(i * stride + jj),
                        stride,
                        op.add(jj * out_stride + i),
                        out_stride,
                    );
                }
            }
            let one = |i: usize, jj: usize| {
                *op.add(jj * out_stride + i) = *sp.add(i * stride + jj);
            };
            for jj in cv..cols {
                (i0..i1).for_each(|i| one(i, jj));
            }
            for jj in 0..cv {
                (iv..i1).for_each(|i| one(i, jj));
            }
        }
    }
}

/// How [`transpose`] moves square tiles of values `T` on some instruction set.
trait Tiles<T> {
    /// Tile side.
    const K: usize;
    /// Transposes the `K x K` tile at `src` (rows `stride` apart) to `out` (columns `out_stride` apart).
    ///
    /// # Safety
    /// The instructions must be supported by the CPU; `src + r * stride + c` must be readable and
    /// `out + c * out_stride + r` writable for `r, c < K`.
    #[allow(unsafe_code)]
    unsafe fn tile(src: *const T, stride: usize, out: *mut T, out_stride: usize);
}

/// Tiles of the x86-64 baseline (SSE2): 4 x 4 32-bit values, 2 x 2 f64 (single values on other targets).
struct Sse;

/// Tiles of AVX2: 8 x 8 32-bit values, 4 x 4 f64 (x86-64 only; see [`transpose_on`]).
struct Avx;

/// A 4 x 4 tile of 32-bit values with SSE2 (part of the x86-64 baseline): 4 loads, 8 shuffles, 4 stores.
///
/// # Safety
/// As [`Tiles::tile`], for 4-byte values.
#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
#[inline(always)]
unsafe fn tile4x32(src: *const f32, stride: usize, out: *mut f32, out_stride: usize) {
    use std::arch::x86_64::*;
    let r = |i: usize| _mm_loadu_ps(src.add(i * stride));
    let (r0, r1, r2, r3) = (r(0), r(1), r(2), r(3));
    let (t0, t1) = (_mm_unpacklo_ps(r0, r1), _mm_unpacklo_ps(r2, r3));
    let (t2, t3) = (_mm_unpackhi_ps(r0, r1), _mm_unpackhi_ps(r2, r3));
    _mm_storeu_ps(out, _mm_movelh_ps(t0, t1));
    _mm_storeu_ps(out.add(out_stride), _mm_movehl_ps(t1, t0));
    _mm_storeu_ps(out.add(2 * out_stride), _mm_movelh_ps(t2, t3));
    _mm_storeu_ps(out.add(3 * out_stride), _mm_movehl_ps(t3, t2));
}

/// An 8 x 8 tile of 32-bit values with AVX: 8 loads, 24 shuffles, 8 stores.
///
/// # Safety
/// As [`Tiles::tile`], for 4-byte values, on a CPU with AVX.
#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
#[inline(always)]
unsafe fn tile8x32(src: *const f32, stride: usize, out: *mut f32, out_stride: usize) {
    use std::arch::x86_64::*;
    let r: [__m256; 8] = std::array::from_fn(|i| _mm256_loadu_ps(src.add(i * stride)));
    // Pairs of rows interleaved: t[2p] = (r[2p][0], r[2p+1][0], r[2p][1], r[2p+1][1] | the same of 4, 5).
    let t: [__m256; 8] = std::array::from_fn(|i| {
        let (a, b) = (r[i / 2 * 2], r[i / 2 * 2 + 1]);
        if i % 2 == 0 {
            _mm256_unpacklo_ps(a, b)
        } else {
            _mm256_unpackhi_ps(a, b)
        }
    });
    // Quads: q[j] (j < 4) holds columns j and j + 4 of rows 0-3, q[j + 4] of rows 4-7.
    let quad = |lo: __m256, hi: __m256, upper: bool| {
        if upper {
            _mm256_shuffle_ps::<0xEE>(lo, hi)
        } else {
            _mm256_shuffle_ps::<0x44>(lo, hi)
        }
    };
    let q: [__m256; 8] = std::array::from_fn(|j| {
        let base = if j < 4 { 0 } else { 4 };
        let (jj, pair) = (j % 4, j % 4 / 2);
        quad(t[base + pair], t[base + 2 + pair], jj % 2 == 1)
    });
    for j in 0..4 {
        _mm256_storeu_ps(
            out.add(j * out_stride),
            _mm256_permute2f128_ps::<0x20>(q[j], q[j + 4]),
        );
        _mm256_storeu_ps(
            out.add((j + 4) * out_stride),
            _mm256_permute2f128_ps::<0x31>(q[j], q[j + 4]),
        );
    }
}

/// A 4 x 4 tile of f64 with AVX: 4 loads, 8 shuffles, 4 stores.
///
/// # Safety
/// As [`Tiles::tile`], on a CPU with AVX.
#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
#[inline(always)]
unsafe fn tile4x64(src: *const f64, stride: usize, out: *mut f64, out_stride: usize) {
    use std::arch::x86_64::*;
    let r = |i: usize| _mm256_loadu_pd(src.add(i * stride));
    let (r0, r1, r2, r3) = (r(0), r(1), r(2), r(3));
    // (r0[0], r1[0], r0[2], r1[2]), (r0[1], r1[1], r0[3], r1[3]), and the same of rows 2 and 3.
    let (t0, t1) = (_mm256_unpacklo_pd(r0, r1), _mm256_unpackhi_pd(r0, r1));
    let (t2, t3) = (_mm256_unpacklo_pd(r2, r3), _mm256_unpackhi_pd(r2, r3));
    _mm256_storeu_pd(out, _mm256_permute2f128_pd::<0x20>(t0, t2));
    _mm256_storeu_pd(out.add(out_stride), _mm256_permute2f128_pd::<0x20>(t1, t3));
    _mm256_storeu_pd(
        out.add(2 * out_stride),
        _mm256_permute2f128_pd::<0x31>(t0, t2),
    );
    _mm256_storeu_pd(
        out.add(3 * out_stride),
        _mm256_permute2f128_pd::<0x31>(t1, t3),
    );
}

/// A 2 x 2 tile of f64 with SSE2 (part of the x86-64 baseline): 2 loads, 2 shuffles, 2 stores.
///
/// # Safety
/// As [`Tiles::tile`].
#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
#[inline(always)]
unsafe fn tile2x64(src: *const f64, stride: usize, out: *mut f64, out_stride: usize) {
    use std::arch::x86_64::*;
    let (r0, r1) = (_mm_loadu_pd(src), _mm_loadu_pd(src.add(stride)));
    _mm_storeu_pd(out, _mm_unpacklo_pd(r0, r1));
    _mm_storeu_pd(out.add(out_stride), _mm_unpackhi_pd(r0, r1));
}

/// `Tiles<T>` for the instruction set `$set`, each `T` of the list moved as `$via` values by the tile function
/// `$tile` of side `$k` on x86-64, one value at a time elsewhere.
macro_rules! tiles {
    ($set:ty, $k:literal, $tile:ident as $via:ty: $($t:ty),*) => {$(
        #[allow(unsafe_code)]
        impl Tiles<$t> for $set {
            const K: usize = if cfg!(target_arch = "x86_64") { $k } else { 1 };
            #[inline(always)]
            unsafe fn tile(src: *const $t, stride: usize, out: *mut $t, out_stride: usize) {
                #[cfg(target_arch = "x86_64")]
                $tile(src.cast::<$via>(), stride, out.cast::<$via>(), out_stride);
                #[cfg(not(target_arch = "x86_64"))]
                {
                    let _ = (stride, out_stride);
                    *out = *src;
                }
            }
        }
    )*};
}
tiles!(Sse, 4, tile4x32 as f32: f32, i32, u32);
tiles!(Avx, 8, tile8x32 as f32: f32, i32, u32);
tiles!(Sse, 2, tile2x64 as f64: f64);
tiles!(Avx, 4, tile4x64 as f64: f64);

impl Lines {
    /// The four buffers of `n` pixels (`c` channels for the cotangent planes), each to be written once: face
    /// indices, depth keys, the image's cotangent dot product and the cotangent planes.
    fn fills(&mut self, n: usize, c: usize) -> Result<Fills<'_>> {
        const WHAT: &str = "backward line buffers";
        Ok((
            Fill::new(&mut self.face, n, LANES, -1, WHAT)?,
            Fill::new(&mut self.key, n, LANES, f64::NEG_INFINITY, WHAT)?,
            Fill::new(&mut self.gi, n, LANES, 0.0, WHAT)?,
            Fill::new(&mut self.grad, n.saturating_mul(c), LANES, 0.0, WHAT)?,
        ))
    }
}

/// The buffers [`Lines::fills`] returns, in its order.
type Fills<'a> = (Fill<'a, i32>, Fill<'a, f64>, Fill<'a, f64>, Fill<'a, f32>);

/// Pointers to the per-pixel data of one line from a pixel on (see [`LinesOf::at`] for how far they may be read).
#[derive(Clone, Copy)]
pub(super) struct LineAt<'a, const C: usize> {
    /// Face index.
    pub face: *const i32,
    /// Depth-test key.
    pub key: *const f64,
    /// `sum_c G I`.
    pub gi: *const f64,
    /// Cotangent channels.
    pub grad: [*const f32; C],
    _lines: PhantomData<&'a Lines>,
}

#[cfg(test)]
mod tests {
    use std::mem::MaybeUninit;

    use super::{row_keys_on, transpose_on, Avx, Sse, Tiles, ROWS};
    use crate::backward::Isa;
    use crate::input::{Projection, RasterParams, ScreenMesh};
    use crate::setup::FaceSetup;
    use crate::test_rng::Rng;

    #[test]
    fn the_row_keys_give_the_bits_of_the_scalar_depth() {
        // Random triangles, perspective (some with corners behind the camera, so that 1/z is not positive everywhere)
        // and orthographic, keys along rows through and beyond them, runs of every length and start.
        let mut rng = Rng(5);
        let mut next = || rng.next();
        let mut defined = 0;
        for case in 0..300 {
            let verts: Vec<f32> = (0..9)
                .map(|k| {
                    if k % 3 == 2 {
                        (next() * 6.0 - 0.5) as f32
                    } else {
                        (next() * 2.4 - 1.2) as f32
                    }
                })
                .collect();
            let mesh = ScreenMesh::new(&verts, &[0, 1, 2], 1, 3).expect("valid mesh");
            let mut params = RasterParams::new(19, 27, 0.1, 100.0);
            if case % 3 == 0 {
                params.projection = Projection::Orthographic;
            }
            let s = FaceSetup::new(&mesh, 0, 0, &params);
            for row in 0..19 {
                let j0 = (next() * 20.0) as usize;
                let n = 1 + (next() * 7.0) as usize;
                for isa in Isa::all_available() {
                    let mut got = vec![MaybeUninit::new(0.0); n];
                    row_keys_on(isa, &s, row, j0, &mut got);
                    for (jj, g) in got.iter().enumerate() {
                        // SAFETY: every slot was initialised above.
                        #[allow(unsafe_code)]
                        let g = unsafe { g.assume_init() };
                        let want = match s.depth_at(row, (j0 + jj) as i32) {
                            Some(z) if s.ortho => -z,
                            Some(z) => 1.0 / z,
                            None => f64::NEG_INFINITY,
                        };
                        assert_eq!(
                            g.to_bits(),
                            want.to_bits(),
                            "case {case} row {row} col {}",
                            j0 + jj
                        );
                        defined += usize::from(want > f64::NEG_INFINITY);
                    }
                }
            }
        }
        assert!(defined > 5000, "{defined}");
    }

    /// Checks [`transpose`] on values `value(x)` (bits compared through `bits`), untouched slots holding `fill`.
    fn check<T: Copy + std::fmt::Debug>(
        value: impl Fn(usize) -> T,
        fill: T,
        bits: impl Fn(T) -> u64,
    ) where
        Sse: Tiles<T>,
        Avx: Tiles<T>,
    {
        // Heights below, at and past a block of rows and tile sides; widths below, at and past a tile and at a
        // group; strides with gaps.
        for h in [1, 2, 3, 5, ROWS - 1, ROWS, ROWS + 1, 2 * ROWS + 5] {
            for cols in [1, 2, 3, 5, 8, 9, 12, 17] {
                for (stride, out_stride) in [(cols, h), (cols + 5, h + 2)] {
                    for isa in Isa::all_available() {
                        let src: Vec<T> = (0..(h - 1) * stride + cols).map(&value).collect();
                        let n = (cols - 1) * out_stride + h;
                        let mut out = vec![MaybeUninit::new(fill); n];
                        transpose_on(isa, &src, stride, cols, h, &mut out, out_stride);
                        // SAFETY: every slot was initialised above.
                        #[allow(unsafe_code)]
                        let out: Vec<T> = out.iter().map(|x| unsafe { x.assume_init() }).collect();
                        for (k, &x) in out.iter().enumerate() {
                            let (jj, i) = (k / out_stride, k % out_stride);
                            let want = if i < h { src[i * stride + jj] } else { fill };
                            assert_eq!(
                                bits(x),
                                bits(want),
                                "{isa:?} h {h} cols {cols} stride {stride}: slot {k}"
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn the_blocked_transpose_writes_every_value_once_in_place() {
        check(|x| x as u32 * 7 + 1, u32::MAX, u64::from);
        check(|x| x as i32 * -7 - 1, -1, |x| x as u32 as u64);
        // NaNs with payloads, signed zeros and subnormals keep their bits.
        let f32s = [f32::from_bits(0x7fc0_1234), -0.0, f32::from_bits(1), 1.5];
        check(
            |x| f32s[x % 4] * if x % 8 < 4 { 1.0 } else { -1.0 },
            f32::NAN,
            |x| x.to_bits() as u64,
        );
        let f64s = [
            f64::from_bits(0x7ff8_0000_0000_beef),
            -0.0,
            f64::from_bits(3),
            0.1,
        ];
        check(
            |x| if x % 5 == 4 { x as f64 } else { f64s[x % 5] },
            f64::INFINITY,
            f64::to_bits,
        );
    }
}
