//! Per-batch-element buffers of the backward pass laid out along sweep lines.

use rayon::prelude::*;

use crate::input::RasterParams;
use crate::setup::FaceSetup;

use super::sweep::LANES;

/// The per-pixel inputs of the sweeps of one batch element, one line after another: image rows for the row sweeps
/// (axis V) or image columns for the column sweeps (axis U), so that the inner loops read memory contiguously.
/// Every buffer ends with [`LANES`] values of padding, so that a vector loop may read a whole block past the end of
/// any line (the lanes past the line's end are masked out).
/// Everything is f64, as in the definition: f32 weights or `delta`s change single contributions near an edge
/// (`delta / EPS` spikes) by more than 1e-5 of a vertex gradient whose terms cancel (measured).
pub(super) struct Lines {
    /// Pixels per line.
    pub len: usize,
    /// Channels `C`.
    channels: usize,
    /// Face drawn at each pixel (-1 on background), as f64 (compared in the same vectors as the depth keys).
    face: Vec<f64>,
    /// Depth-test key of the drawn face (see [`Lines::rows`]).
    key: Vec<f64>,
    /// `sum_c G[P, c] * I[P, c]`, channels in order.
    gi: Vec<f64>,
    /// The cotangent, per line `C` planes of `len` values.
    grad: Vec<f64>,
    /// Per line, the range `[first, last + 1)` of pixels whose cotangent is not all zero (`[0, 0]` when none):
    /// pixels outside it have `delta = 0` and never contribute.
    pub nonzero: Vec<[usize; 2]>,
}

impl Lines {
    /// Row lines from the row-major maps, with the depth-test keys of the drawn faces (`1/z` in perspective, `-z`
    /// in orthographic, larger = nearer; `z` recomputed from the positions exactly as the forward computes it;
    /// `-inf` on background).
    pub fn rows(
        setups: &[FaceSetup],
        face_index: &[i32],
        image: &[f32],
        grad: &[f32],
        c: usize,
        params: &RasterParams,
    ) -> Lines {
        let (h, w) = (params.height, params.width);
        let n = h * w;
        let mut face = vec![0f64; n + LANES];
        let mut key = vec![f64::NEG_INFINITY; n + LANES];
        let mut gi = vec![0f64; n + LANES];
        let mut planes = vec![0f64; n * c + LANES];
        // One pass per row.
        face[..n]
            .par_chunks_mut(w)
            .zip(key[..n].par_chunks_mut(w))
            .zip(gi[..n].par_chunks_mut(w))
            .zip(planes[..n * c].par_chunks_mut(w * c))
            .enumerate()
            .for_each(|(i, (((face, key), gi), planes))| {
                let faces = &face_index[i * w..(i + 1) * w];
                let (g, im) = (
                    &grad[i * w * c..(i + 1) * w * c],
                    &image[i * w * c..(i + 1) * w * c],
                );
                for (j, &f) in faces.iter().enumerate() {
                    face[j] = f as f64;
                    if f >= 0 {
                        let s = &setups[f as usize];
                        key[j] = match s.depth_at(i as i32, j as i32) {
                            Some(z) if s.ortho => -z,
                            Some(z) => 1.0 / z,
                            None => f64::NEG_INFINITY,
                        };
                    }
                    let mut sum = 0f64;
                    for k in 0..c {
                        let gk = g[j * c + k] as f64;
                        sum += gk * im[j * c + k] as f64;
                        planes[k * w + j] = gk;
                    }
                    gi[j] = sum;
                }
            });
        Lines::finish(h, w, c, face, key, gi, planes)
    }

    /// Column lines: the transpose of `rows`.
    pub fn columns(rows: &Lines) -> Lines {
        let (w, h, c) = (rows.len, rows.lines(), rows.channels);
        let n = h * w;
        let mut face = vec![0f64; n + LANES];
        let mut key = vec![0f64; n + LANES];
        let mut gi = vec![0f64; n + LANES];
        let mut planes = vec![0f64; n * c + LANES];
        // One pass per column; row i's channel k is rows.grad[(i * c + k) * w..][..w].
        face[..n]
            .par_chunks_mut(h)
            .zip(key[..n].par_chunks_mut(h))
            .zip(gi[..n].par_chunks_mut(h))
            .zip(planes[..n * c].par_chunks_mut(h * c))
            .enumerate()
            .for_each(|(j, (((face, key), gi), planes))| {
                for i in 0..h {
                    let p = i * w + j;
                    face[i] = rows.face[p];
                    key[i] = rows.key[p];
                    gi[i] = rows.gi[p];
                }
                for (k, plane) in planes.chunks_exact_mut(h).enumerate() {
                    for (i, x) in plane.iter_mut().enumerate() {
                        *x = rows.grad[(i * c + k) * w + j];
                    }
                }
            });
        Lines::finish(w, h, c, face, key, gi, planes)
    }

    /// `lines` lines of `len` pixels from their (padded) planes, with [`Lines::nonzero`] found.
    fn finish(
        lines: usize,
        len: usize,
        channels: usize,
        face: Vec<f64>,
        key: Vec<f64>,
        gi: Vec<f64>,
        grad: Vec<f64>,
    ) -> Lines {
        let mut out = Lines {
            len,
            channels,
            face,
            key,
            gi,
            grad,
            nonzero: vec![[0, 0]; lines],
        };
        out.find_nonzero();
        out
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

    /// Faces drawn along line `d0`.
    #[inline(always)]
    pub fn face(&self, d0: usize) -> &[f64] {
        &self.face[d0 * self.len..(d0 + 1) * self.len]
    }

    /// Faces from the start of line `d0` to the end of the buffer (padding included).
    #[inline(always)]
    pub fn face_from(&self, d0: usize) -> &[f64] {
        &self.face[d0 * self.len..]
    }

    /// Depth keys from the start of line `d0` to the end of the buffer (padding included).
    #[inline(always)]
    pub fn key_from(&self, d0: usize) -> &[f64] {
        &self.key[d0 * self.len..]
    }

    /// `sum_c G I` from the start of line `d0` to the end of the buffer (padding included).
    #[inline(always)]
    pub fn gi_from(&self, d0: usize) -> &[f64] {
        &self.gi[d0 * self.len..]
    }

    /// Cotangent channel `k` from the start of line `d0` to the end of the buffer (padding included).
    #[inline(always)]
    pub fn grad_from(&self, d0: usize, k: usize) -> &[f64] {
        &self.grad[(d0 * self.channels + k) * self.len..]
    }
}
