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
//! centre line, where the blend has a kink and the one-sided derivative of the cell the sample is in is used). Texel
//! gradients are summed over pixels in row-major order, batch elements in order: bit-identical for any thread count.

use rayon::prelude::*;

use crate::error::{try_filled_vec, RasterError, Result};
use crate::input::check_finite;
use crate::setup::floor;

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
        let n = size as i64;
        if i >= 0 && i + 1 < n {
            return (i as usize, i as usize + 1);
        }
        match self.wrap {
            Wrap::Repeat => (i.rem_euclid(n) as usize, (i + 1).rem_euclid(n) as usize),
            Wrap::Clamp => (i.clamp(0, n - 1) as usize, (i + 1).clamp(0, n - 1) as usize),
        }
    }

    /// The four texel offsets (flat, into `texels`) and the fractions `(fx, fy)` of a sample of element `b` at `uv`.
    #[inline(always)]
    fn cell(&self, b: usize, uv: [f32; 2]) -> ([usize; 4], f64, f64) {
        let x = uv[0] as f64 * self.width as f64 - 0.5;
        let y = (1.0 - uv[1] as f64) * self.height as f64 - 0.5;
        let (x0, y0) = (floor(x), floor(y));
        let (fx, fy) = (x - x0, y - y0);
        // Far outside the image (beyond i64) the position saturates; it is a texel index all the same.
        let (c0, c1) = self.pair(x0 as i64, self.width);
        let (r0, r1) = self.pair(y0 as i64, self.height);
        let b = if self.batch == 1 { 0 } else { b };
        let base = b * self.height * self.width;
        let at = |r: usize, c: usize| (base + r * self.width + c) * self.channels;
        ([at(r0, c0), at(r0, c1), at(r1, c0), at(r1, c1)], fx, fy)
    }
}

/// Checks the per-pixel UVs `(B, H, W, 2)` and the mask `(B, H, W)` (a face index map: pixels `>= 0` are sampled).
fn check_pixels(uv: &[f32], mask: &[i32], batch: usize) -> Result<()> {
    if batch == 0 || !mask.len().is_multiple_of(batch) {
        return Err(RasterError::shape(
            "face_index",
            "(B, H, W) with B >= 1",
            format!("{} values for batch {batch}", mask.len()),
        ));
    }
    if uv.len() != mask.len() * 2 {
        return Err(RasterError::shape(
            "uv",
            "(B, H, W, 2) like face_index",
            format!("{} values for {} pixels", uv.len(), mask.len()),
        ));
    }
    // Only the drawn pixels' UVs are read: background pixels may hold anything finite.
    check_finite("uv", uv)
}

/// Samples `texture` at `uv` `(B, H, W, 2)` on the pixels where `mask` `(B, H, W)` is `>= 0`: `(B, H, W, C)`, 0 on the
/// others.
///
/// ```
/// use meshadv_raster::texture::{sample, Texture, Wrap};
/// // A 1 x 2 texture: black left texel, white right texel; the middle of the image is half grey.
/// let tex = Texture { texels: &[0.0, 1.0], batch: 1, height: 1, width: 2, channels: 1, wrap: Wrap::Clamp };
/// let out = sample(&tex, &[0.5, 0.5, 0.75, 0.5], &[0, 0], 1).unwrap();
/// assert_eq!(out, vec![0.5, 1.0]);
/// ```
pub fn sample(texture: &Texture<'_>, uv: &[f32], mask: &[i32], batch: usize) -> Result<Vec<f32>> {
    texture.validate(batch)?;
    check_pixels(uv, mask, batch)?;
    let c = texture.channels;
    let per_elem = mask.len() / batch;
    let mut out = try_filled_vec(mask.len() * c, 0f32, "sampled texture")?;
    const CHUNK: usize = 1024;
    out.par_chunks_mut(CHUNK * c)
        .enumerate()
        .for_each(|(chunk, dst)| {
            with_channels!(c, C => sample_chunk::<C>(texture, uv, mask, per_elem, chunk * CHUNK, dst))
        });
    Ok(out)
}

/// The bilinear weights of the four texels of a cell with fractions `(fx, fy)`.
#[inline(always)]
fn bilinear_weights(fx: f64, fy: f64) -> [f64; 4] {
    [
        (1.0 - fx) * (1.0 - fy),
        fx * (1.0 - fy),
        (1.0 - fx) * fy,
        fx * fy,
    ]
}

/// [`sample`] of the pixels `p0..` that `dst` holds, for `C` channels (0: any count).
#[inline(always)]
fn sample_chunk<const C: usize>(
    texture: &Texture<'_>,
    uv: &[f32],
    mask: &[i32],
    per_elem: usize,
    p0: usize,
    dst: &mut [f32],
) {
    let c = if C == 0 { texture.channels } else { C };
    for (i, px) in dst.chunks_exact_mut(c).enumerate() {
        let p = p0 + i;
        if mask[p] < 0 {
            continue;
        }
        let (t, fx, fy) = texture.cell(p / per_elem, [uv[2 * p], uv[2 * p + 1]]);
        let wts = bilinear_weights(fx, fy);
        let tx: [&[f32]; 4] = std::array::from_fn(|k| &texture.texels[t[k]..t[k] + c]);
        for ch in 0..c {
            let mut s = 0f64;
            for k in 0..4 {
                s += wts[k] * tx[k][ch] as f64;
            }
            px[ch] = s as f32;
        }
    }
}

/// Gradients of [`sample`].
#[derive(Debug, Clone, PartialEq)]
pub struct SampleGradients {
    /// `(Bt, Ht, Wt, C)` gradient with respect to the texels.
    pub grad_texels: Vec<f32>,
    /// `(B, H, W, 2)` gradient with respect to the UVs (0 on unsampled pixels).
    pub grad_uv: Vec<f32>,
}

/// Backward of [`sample`] for the cotangent `grad` `(B, H, W, C)`.
pub fn sample_backward(
    texture: &Texture<'_>,
    uv: &[f32],
    mask: &[i32],
    batch: usize,
    grad: &[f32],
) -> Result<SampleGradients> {
    texture.validate(batch)?;
    check_pixels(uv, mask, batch)?;
    let c = texture.channels;
    if grad.len() != mask.len() * c {
        return Err(RasterError::shape(
            "grad",
            format!("(B, H, W, {c}) like face_index"),
            format!("{} values for {} pixels", grad.len(), mask.len()),
        ));
    }
    check_finite("grad", grad)?;
    let per_elem = mask.len() / batch;
    let mut grad_uv = try_filled_vec(mask.len() * 2, 0f32, "grad_uv")?;
    let mut acc = try_filled_vec(texture.texels.len(), 0f64, "texture gradient accumulator")?;
    with_channels!(c, C => sample_backward_pixels::<C>(texture, uv, mask, per_elem, grad, &mut grad_uv, &mut acc));
    Ok(SampleGradients {
        grad_texels: acc.iter().map(|&x| x as f32).collect(),
        grad_uv,
    })
}

/// [`sample_backward`]'s one pass in pixel order (the texel sums' order): the UV gradient and the texels' shares of
/// each sample, for `C` channels (0: any count).
#[inline(always)]
fn sample_backward_pixels<const C: usize>(
    texture: &Texture<'_>,
    uv: &[f32],
    mask: &[i32],
    per_elem: usize,
    grad: &[f32],
    grad_uv: &mut [f32],
    acc: &mut [f64],
) {
    let c = if C == 0 { texture.channels } else { C };
    let (wf, hf) = (texture.width as f64, texture.height as f64);
    for (p, &f) in mask.iter().enumerate() {
        if f < 0 {
            continue;
        }
        let g = &grad[p * c..(p + 1) * c];
        let (t, fx, fy) = texture.cell(p / per_elem, [uv[2 * p], uv[2 * p + 1]]);
        let wts = bilinear_weights(fx, fy);
        let tx: [&[f32]; 4] = std::array::from_fn(|k| &texture.texels[t[k]..t[k] + c]);
        let (mut gx, mut gy) = (0f64, 0f64);
        for ch in 0..c {
            let gc = g[ch] as f64;
            let v: [f64; 4] = std::array::from_fn(|k| tx[k][ch] as f64);
            gx += gc * ((1.0 - fy) * (v[1] - v[0]) + fy * (v[3] - v[2]));
            gy += gc * ((1.0 - fx) * (v[2] - v[0]) + fx * (v[3] - v[1]));
        }
        for k in 0..4 {
            let a = &mut acc[t[k]..t[k] + c];
            for ch in 0..c {
                a[ch] += wts[k] * g[ch] as f64;
            }
        }
        // x = u W - 0.5, y = (1 - v) H - 0.5.
        grad_uv[2 * p] = (gx * wf) as f32;
        grad_uv[2 * p + 1] = (-gy * hf) as f32;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_rng::Rng;

    fn random_texture(rng: &mut Rng, h: usize, w: usize, c: usize) -> Vec<f32> {
        (0..h * w * c).map(|_| rng.next() as f32).collect()
    }

    #[test]
    fn texel_centres_sample_their_texel_exactly() {
        let mut rng = Rng(4);
        let (h, w) = (5, 7);
        let texels = random_texture(&mut rng, h, w, 3);
        for wrap in [Wrap::Repeat, Wrap::Clamp] {
            let tex = Texture {
                texels: &texels,
                batch: 1,
                height: h,
                width: w,
                channels: 3,
                wrap,
            };
            let mut uv = Vec::new();
            for i in 0..h {
                for j in 0..w {
                    uv.extend_from_slice(&[
                        (j as f32 + 0.5) / w as f32,
                        1.0 - (i as f32 + 0.5) / h as f32,
                    ]);
                }
            }
            let out = sample(&tex, &uv, &vec![0; h * w], 1).expect("sample");
            for (a, b) in out.iter().zip(&texels) {
                assert!((a - b).abs() < 1e-5, "{wrap:?}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn repeat_is_periodic_and_clamp_holds_the_border() {
        let mut rng = Rng(8);
        let texels = random_texture(&mut rng, 4, 6, 3);
        let uv: Vec<f32> = (0..40).map(|_| rng.next() as f32).collect();
        let shifted: Vec<f32> = uv
            .iter()
            .enumerate()
            .map(|(i, &x)| x + if i % 2 == 0 { 3.0 } else { -2.0 })
            .collect();
        let mask = vec![0; 20];
        let rep = Texture {
            texels: &texels,
            batch: 1,
            height: 4,
            width: 6,
            channels: 3,
            wrap: Wrap::Repeat,
        };
        let (a, b) = (
            sample(&rep, &uv, &mask, 1).expect("a"),
            sample(&rep, &shifted, &mask, 1).expect("b"),
        );
        for (x, y) in a.iter().zip(&b) {
            assert!((x - y).abs() < 1e-5);
        }
        let clamp = Texture {
            wrap: Wrap::Clamp,
            ..rep
        };
        // Far to the left of the image: the left column's texels, blended only vertically.
        let far = sample(&clamp, &[-5.0, 1.0 - 0.5 / 4.0], &[0], 1).expect("far");
        assert_eq!(far, texels[0..3].to_vec());
    }

    #[test]
    fn gradients_match_finite_differences() {
        let mut rng = Rng(12);
        for wrap in [Wrap::Repeat, Wrap::Clamp] {
            let (h, w, c, n) = (4, 5, 3, 30);
            let texels = random_texture(&mut rng, h, w, c);
            // UVs inside and outside [0, 1], away from texel centre lines (where the blend has a kink).
            let away = |t: f32| (0.05..0.95).contains(&t.rem_euclid(1.0));
            let mut uv = Vec::new();
            while uv.len() < 2 * n {
                let (u, v) = (
                    (rng.next() * 1.6 - 0.3) as f32,
                    (rng.next() * 1.6 - 0.3) as f32,
                );
                if away(u * w as f32 - 0.5) && away((1.0 - v) * h as f32 - 0.5) {
                    uv.extend_from_slice(&[u, v]);
                }
            }
            let mask: Vec<i32> = (0..n).map(|i| if i % 7 == 3 { -1 } else { 0 }).collect();
            let g: Vec<f32> = (0..n * c).map(|_| (rng.next() - 0.5) as f32).collect();
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

            let loss = |t: &[f32], uv: &[f32]| -> f64 {
                let out = sample(&texture(t, h, w, c, wrap), uv, &mask, 1).expect("sample");
                out.iter().zip(&g).map(|(a, b)| *a as f64 * *b as f64).sum()
            };
            let grads = sample_backward(&texture(&texels, h, w, c, wrap), &uv, &mask, 1, &g)
                .expect("backward");
            let eps = 1e-3f32;
            for i in 0..uv.len() {
                let (mut a, mut b) = (uv.clone(), uv.clone());
                a[i] += eps;
                b[i] -= eps;
                let fd = (loss(&texels, &a) - loss(&texels, &b)) / (2.0 * eps as f64);
                let got = grads.grad_uv[i] as f64;
                assert!(
                    (fd - got).abs() < 2e-2 * fd.abs().max(1.0),
                    "{wrap:?} uv {i}: fd {fd} vs {got}"
                );
            }
            for i in 0..texels.len() {
                let (mut a, mut b) = (texels.clone(), texels.clone());
                a[i] += eps;
                b[i] -= eps;
                let fd = (loss(&a, &uv) - loss(&b, &uv)) / (2.0 * eps as f64);
                let got = grads.grad_texels[i] as f64;
                assert!(
                    (fd - got).abs() < 1e-3 * fd.abs().max(1.0),
                    "{wrap:?} texel {i}: fd {fd} vs {got}"
                );
            }
        }
    }

    #[test]
    fn empty_or_non_finite_textures_and_uvs_are_errors_naming_the_argument() {
        let tex = Texture {
            texels: &[],
            batch: 1,
            height: 0,
            width: 4,
            channels: 3,
            wrap: Wrap::Repeat,
        };
        let e = sample(&tex, &[0.5, 0.5], &[0], 1).expect_err("zero size");
        assert!(e.to_string().starts_with("texture"), "{e}");
        let texels = [0.5f32; 12];
        let tex = Texture {
            texels: &texels,
            batch: 1,
            height: 2,
            width: 2,
            channels: 3,
            wrap: Wrap::Repeat,
        };
        let e = sample(&tex, &[f32::NAN, 0.5], &[0], 1).expect_err("NaN uv");
        assert!(e.to_string().starts_with("uv"), "{e}");
        let e = sample(&tex, &[0.5, 0.5], &[0, 0], 1).expect_err("short uv");
        assert!(e.to_string().starts_with("uv"), "{e}");
        let short = Texture {
            texels: &texels[..11],
            ..tex
        };
        assert!(sample(&short, &[0.5, 0.5], &[0], 1)
            .expect_err("11 texels")
            .to_string()
            .starts_with("texture"));
    }
}
