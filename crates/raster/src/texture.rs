//! Bilinear texture sampling of an image texture at per-pixel UVs, with exact gradients to the texels and the UVs.
//!
//! Conventions (those of OpenGL, OBJ's `vt`, glTF after its flip, and PyTorch3D's `TexturesUV` with
//! `align_corners=False`): `u` runs left to right and `v` bottom to top over the whole image, `(0, 0)` is the bottom-left
//! corner of the image's bottom-left texel and `(1, 1)` the top-right corner of the top-right one; texel `(row i,
//! column j)` (row 0 at the top of the stored image) has its centre at `u = (j + 0.5) / W`, `v = 1 - (i + 0.5) / H`.
//! A UV maps to the continuous texel position `x = u W - 0.5`, `y = (1 - v) H - 0.5`, and the sample blends the four
//! texels around it, `(1 - fx)(1 - fy) t00 + fx (1 - fy) t10 + (1 - fx) fy t01 + fx fy t11`. Texel indices outside the
//! image wrap around ([`Wrap::Repeat`]) or are clamped to the border ([`Wrap::Clamp`]).
//!
//! The gradient to the UVs is the derivative of this bilinear blend (exact wherever the sample is not on a texel
//! centre line, where the blend has a kink and the one-sided derivative of the cell the sample is in is used). The
//! per-pixel sampling of a rendered surface and its sums over pixels are [`crate::textured`]'s.

use crate::error::{RasterError, Result};
use crate::input::check_finite;

/// Largest accepted magnitude of a texture coordinate in the UVs given to the core ([`Texture::sample`],
/// [`crate::textured::sample_uv_texture`]): a UV a million tiles away from `[0, 1]` is a broken file.
pub const MAX_TEXTURE_COORDINATE: f64 = 1e6;

/// Checks that every value in `uv` is finite and at most [`MAX_TEXTURE_COORDINATE`] in magnitude; the error names
/// `arg` and the flat index of the first bad value.
pub fn check_texture_coordinates(
    arg: &'static str,
    uv: impl IntoIterator<Item = f64>,
) -> Result<()> {
    match uv
        .into_iter()
        .enumerate()
        .find(|(_, x)| x.is_nan() || x.abs() > MAX_TEXTURE_COORDINATE)
    {
        Some((i, x)) => Err(RasterError::Parameter {
            arg,
            message: format!(
                "texture coordinate {x} at flat index {i}: expected a finite value of magnitude at most \
                 {MAX_TEXTURE_COORDINATE:e}"
            ),
        }),
        None => Ok(()),
    }
}

/// How texel indices outside the image are mapped back into it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Wrap {
    /// Periodic: index `i` reads texel `i mod size` (a tiling texture; UVs may leave `[0, 1]`).
    #[default]
    Repeat,
    /// Clamp to the border texel (OpenGL `CLAMP_TO_EDGE`).
    Clamp,
}

/// A borrowed image texture `(Bt, Ht, Wt, C)`, row 0 at the top; `Bt` is 1 (one texture for the whole batch) or the
/// batch size.
#[derive(Debug, Clone, Copy)]
pub struct Texture<'a> {
    /// Flat `(Bt, Ht, Wt, C)` texels.
    pub texels: &'a [f32],
    /// `Bt`.
    pub batch: usize,
    /// `Ht`.
    pub height: usize,
    /// `Wt`.
    pub width: usize,
    /// `C`.
    pub channels: usize,
    /// Index mapping outside the image.
    pub wrap: Wrap,
}

impl Texture<'_> {
    /// Checks a non-empty texture whose texel count matches its shape, finite texels, and a batch of 1 or `batch`.
    pub fn validate(&self, batch: usize) -> Result<()> {
        if self.height == 0 || self.width == 0 || self.channels == 0 {
            return Err(RasterError::shape(
                "texture",
                "(Ht, Wt, C) with Ht, Wt, C >= 1",
                format!("({}, {}, {})", self.height, self.width, self.channels),
            ));
        }
        if self.batch != 1 && self.batch != batch {
            return Err(RasterError::shape(
                "texture",
                format!("batch 1 or {batch}"),
                format!("batch {}", self.batch),
            ));
        }
        if self.texels.len() != self.batch * self.height * self.width * self.channels {
            return Err(RasterError::shape(
                "texture",
                format!(
                    "({}, {}, {}, {})",
                    self.batch, self.height, self.width, self.channels
                ),
                format!("{} values", self.texels.len()),
            ));
        }
        check_finite("texture", self.texels)
    }

    /// The texel indices along an axis of `size` texels of the integer positions `i` and `i + 1`.
    #[inline(always)]
    fn pair(&self, i: i64, size: usize) -> (usize, usize) {
        // One comparison for `0 <= i && i + 1 < size`.
        if (i as u64) < size as u64 - 1 {
            return (i as usize, i as usize + 1);
        }
        let n = size as i64;
        match self.wrap {
            Wrap::Repeat => (i.rem_euclid(n) as usize, (i + 1).rem_euclid(n) as usize),
            Wrap::Clamp => (i.clamp(0, n - 1) as usize, (i + 1).clamp(0, n - 1) as usize),
        }
    }

    /// The two texel indices along an axis of `size` texels around the continuous position `x`, and the fraction
    /// of the way from the first to the second (`x - floor(x)`). Positions `2^31` texels or more from the origin
    /// are clamped to `+-2^31` (their cell's texels, fraction 0) and NaN reads as 0, so that no index overflows
    /// and the fraction stays finite; a per-pixel UV gets there only from fragments of a face not drawn there.
    #[inline(always)]
    fn axis(&self, x: f64, size: usize) -> (usize, usize, f64) {
        // Below 2^31 in magnitude, adding 1.5 * 2^52 rounds `x` to the nearest integer, which the low bits of the
        // sum hold in two's complement; one step down where that rounded up gives the floor.
        const ROUND: f64 = 6_755_399_441_055_744.0;
        if x.abs() < 2_147_483_648.0 {
            let r = x + ROUND;
            // The floor without a branch, in integers (a float select is a branch on x86-64): which way `x`
            // rounds is a coin toss from one pixel to the next, and mispredicting it cost more than the rest of
            // the axis. The floor converts back exactly.
            let i = r.to_bits() as i32 as i64 - i64::from(r - ROUND > x);
            let (a, b) = self.pair(i, size);
            return (a, b, x - i as f64);
        }
        // Far outside the image, or NaN: the clamped position, a texel index all the same.
        let i = if x > 0.0 {
            1 << 31
        } else if x < 0.0 {
            -(1 << 31)
        } else {
            0
        };
        let (a, b) = self.pair(i, size);
        (a, b, 0.0)
    }

    /// The texture of batch element `b` alone (batch 1; the whole texture when it has batch 1).
    #[inline]
    pub(crate) fn element(&self, b: usize) -> Texture<'_> {
        let n = self.height * self.width * self.channels;
        let b = if self.batch == 1 { 0 } else { b };
        Texture {
            texels: &self.texels[b * n..(b + 1) * n],
            batch: 1,
            ..*self
        }
    }

    /// The cell of a sample at `(u, v)` (of batch element 0): the four texels' offsets (flat, into `texels`) and the
    /// fractions `(fx, fy)`.
    #[inline(always)]
    fn cell(&self, u: f64, v: f64) -> Cell {
        let (c0, c1, fx) = self.axis(u * self.width as f64 - 0.5, self.width);
        let (r0, r1, fy) = self.axis((1.0 - v) * self.height as f64 - 0.5, self.height);
        let (row0, row1) = (r0 * self.width, r1 * self.width);
        let ch = self.channels;
        Cell {
            offsets: [
                (row0 + c0) * ch,
                (row0 + c1) * ch,
                (row1 + c0) * ch,
                (row1 + c1) * ch,
            ],
            fx,
            fy,
        }
    }

    /// The cell of a sample at `(u, v)` and its four texels (`c` channels each), or `None` for an empty texture.
    #[inline(always)]
    fn cell_texels(&self, u: f64, v: f64, c: usize) -> Option<(Cell, [&[f32]; 4])> {
        if self.height == 0 || self.width == 0 || c != self.channels {
            return None;
        }
        let texels = &self.texels[..self.height * self.width * c];
        let cell = self.cell(u, v);
        // SAFETY: the cell's texel indices are below `height` and `width` (`pair` maps every integer into the
        // image of a non-empty axis), so `offset + c <= height * width * c = texels.len()`.
        #[allow(unsafe_code)]
        let tx = cell
            .offsets
            .map(|o| unsafe { texels.get_unchecked(o..o + c) });
        Some((cell, tx))
    }

    /// The bilinear sample at `(u, v)` (of batch element 0) into `out` (`C` channels; `C = 0`: `channels`, read at
    /// run time).
    #[inline(always)]
    pub(crate) fn sample_into<const C: usize>(&self, u: f64, v: f64, out: &mut [f32]) {
        let c = if C == 0 { self.channels } else { C };
        let Some((cell, tx)) = self.cell_texels(u, v, c) else {
            return;
        };
        // In f32, the texels' precision.
        let wts = cell.weights().map(|w| w as f32);
        for (ch, o) in out[..c].iter_mut().enumerate() {
            *o = wts[0] * tx[0][ch] + wts[1] * tx[1][ch] + wts[2] * tx[2][ch] + wts[3] * tx[3][ch];
        }
    }

    /// Backward of [`Texture::sample_into`] for the cotangent `grad` (`C` values): adds the texels' shares to
    /// `grad_texels` (laid out as one element's texels, with one value more when `C` is 3: a sum that starts at
    /// +0 and is left as it is) and returns the gradient with respect to `(u, v)`.
    #[inline(always)]
    pub(crate) fn sample_backward_into<const C: usize>(
        &self,
        u: f64,
        v: f64,
        grad: &[f32],
        grad_texels: &mut [f64],
    ) -> [f64; 2] {
        let c = if C == 0 { self.channels } else { C };
        let Some((cell, tx)) = self.cell_texels(u, v, c) else {
            return [0.0; 2];
        };
        // Three channels: each texel's values and the next one's first, as four lanes (see below).
        let padded = C == 3;
        let grad_texels = &mut grad_texels[..self.texels.len() + padded as usize];
        let (fx, fy) = (cell.fx, cell.fy);
        let wts = cell.weights();
        // The cotangent's dot product with each texel's colour; the sample is bilinear in them.
        let mut d32 = [0f32; 4];
        for (ch, &g) in grad[..c].iter().enumerate() {
            for (dk, t) in d32.iter_mut().zip(&tx) {
                *dk += g * t[ch];
            }
        }
        let d = d32.map(|x| x as f64);
        let gx = (1.0 - fy) * (d[1] - d[0]) + fy * (d[3] - d[2]);
        let gy = (1.0 - fx) * (d[2] - d[0]) + fx * (d[3] - d[1]);
        if padded {
            // The fourth lane adds +0 to the next value: no change of its bits (a sum that starts at +0 is never
            // -0, and the weights are not negative).
            let g4 = [grad[0] as f64, grad[1] as f64, grad[2] as f64, 0.0];
            for (&o, w) in cell.offsets.iter().zip(wts) {
                #[allow(unsafe_code)]
                // SAFETY: `o` is an offset of `cell_texels`, so `o + 4 <= texels.len() + 1 = grad_texels.len()`.
                let a = unsafe { grad_texels.get_unchecked_mut(o..o + 4) };
                for (a, g) in a.iter_mut().zip(g4) {
                    *a += w * g;
                }
            }
            return [gx * self.width as f64, -gy * self.height as f64];
        }
        // Channels in pairs (two f64 lanes), the cotangent converted once.
        let mut g = [[0f64; 2]; 2];
        let paired = c <= 4;
        for (ch, &x) in grad[..c.min(4)].iter().enumerate() {
            g[ch / 2][ch % 2] = x as f64;
        }
        for (&o, w) in cell.offsets.iter().zip(wts) {
            #[allow(unsafe_code)]
            // SAFETY: `o` is an offset of `cell_texels`, so `o + c <= texels.len() = grad_texels.len()`.
            let a = unsafe { grad_texels.get_unchecked_mut(o..o + c) };
            if !paired {
                for (a, &g) in a.iter_mut().zip(&grad[..c]) {
                    *a += w * g as f64;
                }
                continue;
            }
            let mut chunks = a.chunks_exact_mut(2);
            for (pair, g) in (&mut chunks).zip(&g) {
                pair[0] += w * g[0];
                pair[1] += w * g[1];
            }
            if let Some(last) = chunks.into_remainder().first_mut() {
                *last += w * g[c / 2][0];
            }
        }
        // x = u W - 0.5, y = (1 - v) H - 0.5.
        [gx * self.width as f64, -gy * self.height as f64]
    }

    /// Checks the texture ([`Texture::validate`]), a batch element `b` it has (any `b` when it has batch 1) and,
    /// for a backward, the cotangent and gradient lengths.
    fn check_sample(&self, b: usize, grad: Option<(&[f32], usize)>) -> Result<()> {
        self.validate(self.batch)?;
        if self.batch != 1 && b >= self.batch {
            return Err(RasterError::shape(
                "texture",
                format!("a batch element {b}"),
                format!("batch {}", self.batch),
            ));
        }
        if let Some((grad, grad_texels)) = grad {
            if grad.len() != self.channels {
                return Err(RasterError::shape(
                    "grad",
                    format!("({},)", self.channels),
                    format!("{} values", grad.len()),
                ));
            }
            if grad_texels != self.texels.len() {
                return Err(RasterError::shape(
                    "grad_texels",
                    "the texture's shape",
                    format!("{grad_texels} values"),
                ));
            }
        }
        Ok(())
    }

    /// The bilinear sample of batch element `b` (any `b` when the texture has batch 1) at `uv`: `channels` values.
    /// Errors: a bad texture or batch element, or a `uv` that is not finite or beyond [`MAX_TEXTURE_COORDINATE`].
    ///
    /// ```
    /// use meshadv_raster::texture::{Texture, Wrap};
    /// // A 1 x 2 texture: black left texel, white right texel; the middle of the image is half grey.
    /// let tex = Texture { texels: &[0.0, 1.0], batch: 1, height: 1, width: 2, channels: 1, wrap: Wrap::Clamp };
    /// assert_eq!(tex.sample(0, [0.5, 0.5]).unwrap(), vec![0.5]);
    /// assert_eq!(tex.sample(0, [0.75, 0.5]).unwrap(), vec![1.0]);
    /// ```
    pub fn sample(&self, b: usize, uv: [f64; 2]) -> Result<Vec<f32>> {
        self.check_sample(b, None)?;
        check_texture_coordinates("uv", uv)?;
        let mut out = vec![0f32; self.channels];
        self.element(b).sample_into::<0>(uv[0], uv[1], &mut out);
        Ok(out)
    }

    /// Backward of [`Texture::sample`] for the cotangent `grad` (`channels` values): adds the texels' shares to
    /// `grad_texels` (`(Bt, Ht, Wt, C)` like `texels`) and returns the gradient with respect to `uv` (exact off the
    /// texel centre lines; on one, the derivative of the cell the sample falls in).
    pub fn sample_backward(
        &self,
        b: usize,
        uv: [f64; 2],
        grad: &[f32],
        grad_texels: &mut [f64],
    ) -> Result<[f64; 2]> {
        self.check_sample(b, Some((grad, grad_texels.len())))?;
        check_texture_coordinates("uv", uv)?;
        check_finite("grad", grad)?;
        let n = self.height * self.width * self.channels;
        let b = if self.batch == 1 { 0 } else { b };
        Ok(self.element(b).sample_backward_into::<0>(
            uv[0],
            uv[1],
            grad,
            &mut grad_texels[b * n..(b + 1) * n],
        ))
    }
}

/// The four texels around a sample (flat offsets of texels `(r0, c0)`, `(r0, c1)`, `(r1, c0)`, `(r1, c1)`) and the
/// sample's fractions between them.
#[derive(Debug, Clone, Copy)]
struct Cell {
    offsets: [usize; 4],
    fx: f64,
    fy: f64,
}

impl Cell {
    /// The bilinear weights of the four texels, in the order of `offsets`.
    #[inline(always)]
    fn weights(&self) -> [f64; 4] {
        let (fx, fy) = (self.fx, self.fy);
        [
            (1.0 - fx) * (1.0 - fy),
            fx * (1.0 - fy),
            (1.0 - fx) * fy,
            fx * fy,
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_rng::Rng;

    fn random_texture(rng: &mut Rng, h: usize, w: usize, c: usize) -> Vec<f32> {
        (0..h * w * c).map(|_| rng.next() as f32).collect()
    }

    fn texture(
        texels: &[f32],
        height: usize,
        width: usize,
        channels: usize,
        wrap: Wrap,
    ) -> Texture<'_> {
        Texture {
            texels,
            batch: 1,
            height,
            width,
            channels,
            wrap,
        }
    }

    #[test]
    fn texel_centres_sample_their_texel_exactly() {
        let mut rng = Rng(4);
        let (h, w) = (5, 7);
        let texels = random_texture(&mut rng, h, w, 3);
        for wrap in [Wrap::Repeat, Wrap::Clamp] {
            let tex = texture(&texels, h, w, 3, wrap);
            for i in 0..h {
                for j in 0..w {
                    let uv = [
                        (j as f64 + 0.5) / w as f64,
                        1.0 - (i as f64 + 0.5) / h as f64,
                    ];
                    let want = &texels[(i * w + j) * 3..(i * w + j) * 3 + 3];
                    for (a, b) in tex.sample(0, uv).expect("sample").iter().zip(want) {
                        assert!((a - b).abs() < 1e-5, "{wrap:?}: {a} vs {b}");
                    }
                }
            }
        }
    }

    #[test]
    fn repeat_is_periodic_and_clamp_holds_the_border() {
        let mut rng = Rng(8);
        let texels = random_texture(&mut rng, 4, 6, 3);
        let rep = texture(&texels, 4, 6, 3, Wrap::Repeat);
        for _ in 0..20 {
            let uv = [rng.next(), rng.next()];
            let (a, b) = (
                rep.sample(0, uv).expect("a"),
                rep.sample(0, [uv[0] + 3.0, uv[1] - 2.0]).expect("b"),
            );
            for (x, y) in a.iter().zip(&b) {
                assert!((x - y).abs() < 1e-5);
            }
        }
        let clamp = Texture {
            wrap: Wrap::Clamp,
            ..rep
        };
        // Far to the left of the image: the left column's texels, blended only vertically.
        assert_eq!(
            clamp.sample(0, [-5.0, 1.0 - 0.5 / 4.0]).expect("far"),
            texels[0..3].to_vec()
        );
    }

    #[test]
    fn gradients_match_finite_differences() {
        let mut rng = Rng(12);
        for (wrap, c) in [
            (Wrap::Repeat, 3),
            (Wrap::Clamp, 3),
            (Wrap::Repeat, 1),
            (Wrap::Clamp, 2),
            (Wrap::Repeat, 5),
        ] {
            let (h, w, n) = (4, 5, 30);
            let texels = random_texture(&mut rng, h, w, c);
            // UVs inside and outside [0, 1], away from texel centre lines (where the blend has a kink).
            let away = |t: f64| (0.05..0.95).contains(&t.rem_euclid(1.0));
            let mut uv = Vec::new();
            while uv.len() < n {
                let (u, v) = (rng.next() * 1.6 - 0.3, rng.next() * 1.6 - 0.3);
                if away(u * w as f64 - 0.5) && away((1.0 - v) * h as f64 - 0.5) {
                    uv.push([u, v]);
                }
            }
            let g: Vec<f32> = (0..n * c).map(|_| (rng.next() - 0.5) as f32).collect();
            let loss = |t: &[f32], uv: &[[f64; 2]]| -> f64 {
                let tex = texture(t, h, w, c, wrap);
                uv.iter()
                    .enumerate()
                    .map(|(i, &p)| {
                        let s = tex.sample(0, p).expect("sample");
                        (0..c)
                            .map(|ch| s[ch] as f64 * g[i * c + ch] as f64)
                            .sum::<f64>()
                    })
                    .sum()
            };
            let tex = texture(&texels, h, w, c, wrap);
            let mut grad_texels = vec![0f64; texels.len()];
            let grad_uv: Vec<[f64; 2]> = uv
                .iter()
                .enumerate()
                .map(|(i, &p)| {
                    tex.sample_backward(0, p, &g[i * c..(i + 1) * c], &mut grad_texels)
                        .expect("backward")
                })
                .collect();
            let eps = 1e-3;
            for i in 0..n {
                for axis in 0..2 {
                    let (mut a, mut b) = (uv.clone(), uv.clone());
                    a[i][axis] += eps;
                    b[i][axis] -= eps;
                    let fd = (loss(&texels, &a) - loss(&texels, &b)) / (2.0 * eps);
                    let got = grad_uv[i][axis];
                    assert!(
                        (fd - got).abs() < 2e-2 * fd.abs().max(1.0),
                        "{wrap:?} uv {i}.{axis}: fd {fd} vs {got}"
                    );
                }
            }
            let eps = 1e-3f32;
            for i in 0..texels.len() {
                let (mut a, mut b) = (texels.clone(), texels.clone());
                a[i] += eps;
                b[i] -= eps;
                let fd = (loss(&a, &uv) - loss(&b, &uv)) / (2.0 * eps as f64);
                let got = grad_texels[i];
                assert!(
                    (fd - got).abs() < 1e-3 * fd.abs().max(1.0),
                    "{wrap:?} texel {i}: fd {fd} vs {got}"
                );
            }
        }
    }

    #[test]
    fn empty_or_non_finite_textures_are_errors_naming_the_argument() {
        let tex = texture(&[], 0, 4, 3, Wrap::Repeat);
        let e = tex.validate(1).expect_err("zero size");
        assert!(e.to_string().starts_with("texture"), "{e}");
        let texels = [0.5f32; 12];
        let short = texture(&texels[..11], 2, 2, 3, Wrap::Repeat);
        assert!(short
            .validate(1)
            .expect_err("11 texels")
            .to_string()
            .starts_with("texture"));
        let mut nan = texels;
        nan[5] = f32::NAN;
        let e = texture(&nan, 2, 2, 3, Wrap::Repeat)
            .validate(1)
            .expect_err("NaN");
        assert!(e.to_string().starts_with("texture"), "{e}");
        let e = texture(&texels, 2, 2, 3, Wrap::Repeat);
        let e = Texture { batch: 2, ..e }
            .validate(3)
            .expect_err("batch 2 of 3");
        assert!(e.to_string().starts_with("texture"), "{e}");
        // Sampling checks the texture and the cotangent too.
        let e = short.sample(0, [0.5, 0.5]).expect_err("11 texels");
        assert!(e.to_string().starts_with("texture"), "{e}");
        let tex = texture(&texels, 2, 2, 3, Wrap::Repeat);
        let mut grad_texels = vec![0f64; 12];
        let e = tex
            .sample_backward(0, [0.5, 0.5], &[1.0; 2], &mut grad_texels)
            .expect_err("2 of 3 channels");
        assert!(e.to_string().starts_with("grad"), "{e}");
    }
}
