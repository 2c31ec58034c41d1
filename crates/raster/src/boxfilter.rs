//! The box filter of an antialiased render and its adjoint: a `(B, kH, kW, C)` supersampled image averaged over
//! `k x k` blocks into `(B, H, W, C)`, and a `(B, H, W, C)` cotangent spread back over the blocks.
//!
//! Both give the bits of torch's `F.avg_pool2d(x, k, k)` and of its backward on float32: a block's samples are
//! added row by row, left to right (the first two added, then each further one), and the sum divided by `k * k`;
//! the cotangent of each sample is its block's cotangent divided by `k * k`. Parallel over output rows; every value
//! is computed by one task in a fixed order, so the result does not depend on the thread count.

use rayon::prelude::*;

use std::mem::MaybeUninit;

use crate::error::{Fill, RasterError, Result};

/// The largest block side accepted.
pub const MAX_BLOCK: usize = 64;

/// The shape of a box filter: `batch` images of `height x width` blocks of `k x k` samples, `channels` each.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BoxShape {
    /// Images.
    pub batch: usize,
    /// Rows of blocks (rows of the filtered image).
    pub height: usize,
    /// Columns of blocks (columns of the filtered image).
    pub width: usize,
    /// Channels per pixel.
    pub channels: usize,
    /// Block side (samples per filtered pixel along each axis).
    pub k: usize,
}

impl BoxShape {
    /// The shape of the box filter of a `(batch, full_height, full_width, channels)` image by `k`; an error naming
    /// `k` unless it is in `[1, MAX_BLOCK]`, or `arg` unless the image has a row, a column and a channel and `k`
    /// divides both sides (an empty batch is allowed).
    pub fn of_full(arg: &'static str, dims: [usize; 4], k: usize) -> Result<BoxShape> {
        let [batch, full_height, full_width, channels] = dims;
        check_block(arg, dims, k)?;
        if full_height % k != 0 || full_width % k != 0 {
            return Err(RasterError::shape(
                arg,
                format!("height and width divisible by k = {k}"),
                format!("({batch}, {full_height}, {full_width}, {channels})"),
            ));
        }
        Ok(BoxShape {
            batch,
            height: full_height / k,
            width: full_width / k,
            channels,
            k,
        })
    }

    /// The shape of the box filter by `k` whose filtered image (or cotangent) is `(batch, height, width,
    /// channels)`; errors as [`BoxShape::of_full`] (every side is a multiple of `k` here).
    pub fn of_filtered(arg: &'static str, dims: [usize; 4], k: usize) -> Result<BoxShape> {
        check_block(arg, dims, k)?;
        let [batch, height, width, channels] = dims;
        Ok(BoxShape {
            batch,
            height,
            width,
            channels,
            k,
        })
    }

    /// `(B, H, W, C)` of the filtered image (or of its cotangent).
    pub fn filtered_dims(&self) -> [usize; 4] {
        [self.batch, self.height, self.width, self.channels]
    }

    /// `(B, kH, kW, C)` of the supersampled image (or of its cotangent).
    pub fn full_dims(&self) -> [usize; 4] {
        [
            self.batch,
            self.height * self.k,
            self.width * self.k,
            self.channels,
        ]
    }

    /// Values of the filtered image (or of its cotangent).
    pub fn filtered_len(&self) -> usize {
        self.filtered_dims().iter().product()
    }

    /// Values of the supersampled image (or of its cotangent).
    pub fn full_len(&self) -> usize {
        self.filtered_len() * self.k * self.k
    }

    /// Checks that `data` (argument `arg`) holds the values of the supersampled (`full`) or the filtered shape.
    fn check_len(&self, arg: &'static str, data: &[f32], full: bool) -> Result<()> {
        let (dims, want) = if full {
            (self.full_dims(), self.full_len())
        } else {
            (self.filtered_dims(), self.filtered_len())
        };
        if data.len() == want {
            return Ok(());
        }
        let [b, h, w, c] = dims;
        Err(RasterError::shape(
            arg,
            format!("({b}, {h}, {w}, {c}) = {want} values"),
            format!("{} values", data.len()),
        ))
    }
}

/// An error naming `k` unless it is in `[1, MAX_BLOCK]`, or `arg` unless the image `dims` (`(B, H, W, C)`) has a
/// row, a column and a channel.
fn check_block(arg: &'static str, dims: [usize; 4], k: usize) -> Result<()> {
    if !(1..=MAX_BLOCK).contains(&k) {
        return Err(RasterError::Parameter {
            arg: "k",
            message: format!("the block side must be in [1, {MAX_BLOCK}], got {k}"),
        });
    }
    let [batch, height, width, channels] = dims;
    if height == 0 || width == 0 || channels == 0 {
        return Err(RasterError::shape(
            arg,
            "at least one row, one column and one channel",
            format!("({batch}, {height}, {width}, {channels})"),
        ));
    }
    Ok(())
}

/// The `k x k` block averages of the supersampled `image` (`(B, kH, kW, C)`, row-major): `(B, H, W, C)`.
///
/// ```
/// use meshadv_raster::boxfilter::{box_downsample, BoxShape};
/// // One 2 x 2 image of one channel, filtered to a single pixel.
/// let shape = BoxShape::of_full("image", [1, 2, 2, 1], 2).unwrap();
/// assert_eq!(box_downsample(&[1.0, 2.0, 3.0, 6.0], &shape).unwrap(), vec![3.0]);
/// ```
pub fn box_downsample(image: &[f32], shape: &BoxShape) -> Result<Vec<f32>> {
    shape.check_len("image", image, true)?;
    let row = shape.width * shape.channels;
    written(shape.filtered_len(), "image", |out| {
        out.par_chunks_mut(row)
            .zip(image.par_chunks(row * shape.k * shape.k))
            .for_each_init(
                || vec![0f32; row],
                |sum, (dst, block_rows)| {
                    with_channels!(shape.channels, C => filter_row::<C>(shape, block_rows, sum));
                    let scale = (shape.k * shape.k) as f32;
                    for (d, &s) in dst.iter_mut().zip(sum.iter()) {
                        d.write(s / scale);
                    }
                },
            )
    })
}

/// The block sums of one row of blocks (`block_rows`: `k` full rows) into `sum` (`width * channels` values), each
/// in the order of `avg_pool2d`: the first two samples of the block's first row, then each further sample row by
/// row, left to right. Pass by pass over the row (one sample position of every block per pass, channels
/// contiguous), so that the additions vectorise; `C` channels (0: any count).
#[inline(always)]
fn filter_row<const C: usize>(shape: &BoxShape, block_rows: &[f32], sum: &mut [f32]) {
    let (c, k) = (if C == 0 { shape.channels } else { C }, shape.k);
    let full_row = shape.width * c * k;
    // The samples at (di, dj) of every block of the row, one block after another.
    let samples = |di: usize, dj: usize| {
        block_rows[di * full_row..(di + 1) * full_row]
            .chunks_exact(k * c)
            .map(move |block| &block[dj * c..(dj + 1) * c])
    };
    if k == 1 {
        for (px, a) in sum.chunks_exact_mut(c).zip(samples(0, 0)) {
            px.copy_from_slice(a);
        }
        return;
    }
    for ((px, a), b) in sum
        .chunks_exact_mut(c)
        .zip(samples(0, 0))
        .zip(samples(0, 1))
    {
        for ch in 0..c {
            px[ch] = a[ch] + b[ch];
        }
    }
    for di in 0..k {
        for dj in (if di == 0 { 2 } else { 0 })..k {
            for (px, a) in sum.chunks_exact_mut(c).zip(samples(di, dj)) {
                for ch in 0..c {
                    px[ch] += a[ch];
                }
            }
        }
    }
}

/// The adjoint of [`box_downsample`]: each value of the filtered cotangent `grad` (`(B, H, W, C)`) divided by
/// `k * k` and given to every sample of its block: `(B, kH, kW, C)`.
///
/// ```
/// use meshadv_raster::boxfilter::{box_spread, BoxShape};
/// let shape = BoxShape::of_full("grad", [1, 2, 2, 1], 2).unwrap();
/// assert_eq!(box_spread(&[4.0], &shape).unwrap(), vec![1.0; 4]);
/// ```
pub fn box_spread(grad: &[f32], shape: &BoxShape) -> Result<Vec<f32>> {
    shape.check_len("grad", grad, false)?;
    let BoxShape {
        width,
        channels: c,
        k,
        ..
    } = *shape;
    let row = width * c;
    let full_row = row * k;
    let scale = (k * k) as f32;
    written(shape.full_len(), "grad", |out| {
        out.par_chunks_mut(full_row * k)
            .zip(grad.par_chunks(row))
            .for_each(|(block_rows, src)| {
                // The block rows' first row, then copies of it.
                let (first, rest) = block_rows.split_at_mut(full_row);
                for (block, px) in first.chunks_exact_mut(k * c).zip(src.chunks_exact(c)) {
                    for sample in block.chunks_exact_mut(c) {
                        for (d, &g) in sample.iter_mut().zip(px) {
                            d.write(g / scale);
                        }
                    }
                }
                for copy in rest.chunks_exact_mut(full_row) {
                    copy.copy_from_slice(first);
                }
            })
    })
}

/// A vector of `len` values written by `fill` without being zeroed first (the outputs are large and written
/// once); `fill` must write every slot it is given.
fn written(
    len: usize,
    what: &'static str,
    fill: impl FnOnce(&mut [MaybeUninit<f32>]),
) -> Result<Vec<f32>> {
    let mut v = Vec::new();
    let mut slots = Fill::new(&mut v, len, 0, 0.0, what)?;
    fill(slots.slots());
    // SAFETY: both callers' `fill` write every slot: each output row of the filter (all `width * channels` values),
    // each block row of the spread (its first row value by value, the others copied from it).
    #[allow(unsafe_code)]
    unsafe {
        slots.done()
    };
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_rng::Rng;

    #[test]
    fn the_filter_and_its_spread_are_adjoint() {
        // <box_downsample(x), g> = <x, box_spread(g)> up to rounding, for random shapes and blocks.
        let mut rng = Rng(3);
        for case in 0..50 {
            let (b, h, w, c, k) = (
                1 + rng.below(2),
                1 + rng.below(5),
                1 + rng.below(6),
                1 + rng.below(4),
                1 + rng.below(4),
            );
            let shape = BoxShape::of_full("image", [b, h * k, w * k, c], k).expect("valid shape");
            let x: Vec<f32> = (0..shape.full_len()).map(|_| rng.next() as f32).collect();
            let g: Vec<f32> = (0..shape.filtered_len())
                .map(|_| rng.next() as f32 - 0.5)
                .collect();
            let y = box_downsample(&x, &shape).expect("filtered");
            let s = box_spread(&g, &shape).expect("spread");
            let dot = |a: &[f32], b: &[f32]| {
                a.iter()
                    .zip(b)
                    .map(|(&a, &b)| a as f64 * b as f64)
                    .sum::<f64>()
            };
            let (lhs, rhs) = (dot(&y, &g), dot(&x, &s));
            assert!(
                (lhs - rhs).abs() <= 1e-5 * (1.0 + lhs.abs()),
                "case {case}: {lhs} vs {rhs}"
            );
        }
    }

    #[test]
    fn a_block_averages_its_samples_in_row_order() {
        // A 3 x 3 block whose sum depends on the order of addition in f32: (1e8 + 1) + ... keeps the bits of the
        // row-by-row order.
        let vals = [1e8f32, 1.0, 1.0, -1e8, 1.0, 1.0, 1.0, 1.0, 1.0];
        let shape = BoxShape::of_full("image", [1, 3, 3, 1], 3).expect("valid shape");
        let mut want = vals[0] + vals[1];
        for v in &vals[2..] {
            want += v;
        }
        let got = box_downsample(&vals, &shape).expect("filtered");
        assert_eq!(got[0].to_bits(), (want / 9.0).to_bits());
    }

    #[test]
    fn bad_shapes_name_the_argument() {
        let err = BoxShape::of_full("image", [1, 5, 4, 1], 2).expect_err("5 rows in blocks of 2");
        assert!(err.to_string().starts_with("image:"), "{err}");
        let err = BoxShape::of_full("image", [1, 4, 4, 1], 0).expect_err("a block side of 0");
        assert!(err.to_string().starts_with("k:"), "{err}");
        for empty in [[1, 0, 4, 1], [1, 4, 0, 1], [1, 4, 4, 0]] {
            let err = BoxShape::of_full("image", empty, 2).expect_err("an empty image");
            assert!(err.to_string().starts_with("image:"), "{err}");
        }
        let err = BoxShape::of_filtered("grad", [1, 2, 2, 0], 2).expect_err("no channel");
        assert!(err.to_string().starts_with("grad:"), "{err}");
        let err = BoxShape::of_filtered("grad", [1, 2, 2, 1], 65).expect_err("a block side of 65");
        assert!(err.to_string().starts_with("k:"), "{err}");
        let spread = BoxShape::of_filtered("grad", [2, 3, 5, 4], 2).expect("valid shape");
        assert_eq!(
            spread,
            BoxShape::of_full("image", [2, 6, 10, 4], 2).expect("valid shape")
        );
        assert_eq!(spread.full_dims(), [2, 6, 10, 4]);
        let none = BoxShape::of_full("image", [0, 4, 4, 1], 2).expect("an empty batch");
        assert!(box_downsample(&[], &none).expect("no images").is_empty());
        assert!(box_spread(&[], &none).expect("no images").is_empty());
        let shape = BoxShape::of_full("image", [1, 4, 4, 1], 2).expect("valid shape");
        let err = box_downsample(&[0.0; 15], &shape).expect_err("15 values for 16");
        assert!(err.to_string().starts_with("image:"), "{err}");
        let err = box_spread(&[0.0; 3], &shape).expect_err("3 values for 4");
        assert!(err.to_string().starts_with("grad:"), "{err}");
    }
}
