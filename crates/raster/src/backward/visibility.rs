//! Which visibility (rasterization) gradient the backward computes for the vertices: NMR's sweeps out to the image
//! border, or the same sweeps truncated to a few pixels of the edge (`docs/LOCAL_GRADIENT.md`).
//!
//! The truncation only shortens the ranges of pixels the sweeps visit; every pixel still visited contributes the
//! same terms as in NMR's definition, in the same order, so the local gradient's cost grows with the edges times
//! the radius instead of the edges times the image width.

use crate::error::{RasterError, Result};

/// The vertex gradient of the backward pass (see `docs/NMR_GRADIENT.md` and `docs/LOCAL_GRADIENT.md`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Visibility {
    /// NMR's approximate rasterization gradient: every sweep runs to the image border (OUT) or to the face's other
    /// boundary on the line (IN).
    #[default]
    Nmr,
    /// NMR's sweeps truncated to the `radius` pixels (`radius >= 1`) of each line nearest the edge: an OUT sweep
    /// visits `d_out, d_out + dir, ..., d_out + (radius - 1) dir`, an IN sweep only pixels within `radius - 1` of
    /// `d_in`.
    Local {
        /// Pixels per sweep (raster pixels, i.e. supersampled ones under antialiasing), at least 1.
        radius: usize,
    },
}

impl Visibility {
    /// Checks the radius (an error naming `visibility` for 0).
    pub fn validate(&self) -> Result<()> {
        match *self {
            Visibility::Local { radius: 0 } => Err(RasterError::Parameter {
                arg: "visibility",
                message: "the local sweep radius must be at least 1 pixel".to_string(),
            }),
            _ => Ok(()),
        }
    }

    /// The OUT sweep's pixels `start..end` of a line of `len` pixels whose first pixel beyond the edge is `d_out`
    /// (in `0..len`) and whose sweep runs in direction `dir` (`+1` or `-1`).
    #[inline(always)]
    pub(super) fn out_range(&self, d_out: usize, dir: i64, len: usize) -> (usize, usize) {
        match (*self, dir > 0) {
            (Visibility::Nmr, true) => (d_out, len),
            (Visibility::Nmr, false) => (0, d_out + 1),
            (Visibility::Local { radius }, true) => (d_out, d_out.saturating_add(radius).min(len)),
            (Visibility::Local { radius }, false) => {
                ((d_out + 1).saturating_sub(radius), d_out + 1)
            }
        }
    }

    /// The box `lb..=ub` an IN sweep of a line is cut to, given the face's drawn pixels `lb..=ub` along the line and
    /// the sweep's first pixel `d_in` (the pixels within `radius - 1` of it, for the local gradient).
    #[inline(always)]
    pub(super) fn in_box(&self, d_in: i64, lb: i64, ub: i64) -> (i64, i64) {
        match *self {
            Visibility::Nmr => (lb, ub),
            Visibility::Local { radius } => {
                let r = radius.min(i64::MAX as usize / 2) as i64 - 1;
                (lb.max(d_in - r), ub.min(d_in + r))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_local_ranges_hold_the_radius_nearest_pixels_of_nmr_s() {
        for len in 1..12usize {
            for d_out in 0..len {
                for dir in [1i64, -1] {
                    let nmr: Vec<usize> = {
                        let (s, e) = Visibility::Nmr.out_range(d_out, dir, len);
                        (s..e).collect()
                    };
                    for radius in 1..14 {
                        let (s, e) = Visibility::Local { radius }.out_range(d_out, dir, len);
                        let want: Vec<usize> = nmr
                            .iter()
                            .copied()
                            .filter(|&d| (d as i64 - d_out as i64).abs() < radius as i64)
                            .collect();
                        assert_eq!(
                            (s..e).collect::<Vec<_>>(),
                            want,
                            "len {len} d_out {d_out} dir {dir}"
                        );
                        assert!(want.contains(&d_out));
                    }
                }
            }
        }
        let local = Visibility::Local { radius: 3 };
        assert_eq!(local.in_box(5, 0, 9), (3, 7));
        assert_eq!(local.in_box(1, 2, 9), (2, 3));
        assert_eq!(
            Visibility::Local { radius: usize::MAX }.in_box(5, 0, 9),
            (0, 9)
        );
        assert_eq!(Visibility::Nmr.in_box(5, 4, 6), (4, 6));
    }

    #[test]
    fn a_zero_radius_is_an_error_naming_the_argument() {
        let zero = Visibility::Local { radius: 0 };
        match zero.validate() {
            Err(err) => assert!(err.to_string().contains("visibility"), "{err}"),
            Ok(()) => panic!("a zero radius was accepted"),
        }
        assert!(Visibility::Local { radius: 1 }.validate().is_ok());
        assert!(Visibility::Nmr.validate().is_ok());
    }
}
