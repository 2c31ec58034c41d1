//! Per-face setup, computed once per face and batch element: pixel-space corners, oriented edge functions
//! (evaluated in a canonical vertex order so that a shared edge gives exactly opposite values in its two faces),
//! top-left tie flags, signed area, clipped bounding box and the active flag.
//!
//! Pixel space: `u = (x_ndc * W + W - 1) / 2` (column), `v = (H - 1 - y_ndc * H) / 2` (row, down); pixel `(i, j)`
//! has its centre at `(u, v) = (j, i)`.

use crate::input::{Projection, RasterParams, ScreenMesh};

/// One oriented edge function `E(u, v) = sign * (du * (v - av) - dv * (u - au))`, positive inside the face.
#[derive(Debug, Clone, Copy, Default)]
pub struct Edge {
    /// Canonical start corner u.
    pub au: f64,
    /// Canonical start corner v.
    pub av: f64,
    /// Canonical end minus start, u.
    pub du: f64,
    /// Canonical end minus start, v.
    pub dv: f64,
    /// +1 or -1: orients the canonical function so that the inside is positive.
    pub sign: f64,
    /// Whether a pixel centre exactly on this edge belongs to the face (top-left rule).
    pub owns_ties: bool,
}

impl Edge {
    /// Builds the edge from corner `a` to corner `b` for a face with orientation `orient` (sign of its area).
    fn new(a: [f64; 2], b: [f64; 2], orient: f64) -> Edge {
        // Canonical order: lexicographic on (u, v), so both faces sharing an edge evaluate the same expression.
        let (s, c, swap) = if (a[0], a[1]) <= (b[0], b[1]) {
            (a, b, 1.0)
        } else {
            (b, a, -1.0)
        };
        let sign = swap * orient;
        let (du, dv) = (c[0] - s[0], c[1] - s[1]);
        // Inward normal = sign * (-dv, du). Top-left: normal points to +u (left edge), or is vertical and
        // points to +v (down, i.e. a top edge).
        let (nu, nv) = (-dv * sign, du * sign);
        let owns_ties = nu > 0.0 || (nu == 0.0 && nv > 0.0);
        Edge {
            au: s[0],
            av: s[1],
            du,
            dv,
            sign,
            owns_ties,
        }
    }

    /// Oriented edge function at `(u, v)`.
    #[inline(always)]
    pub fn eval(&self, u: f64, v: f64) -> f64 {
        self.sign * (self.du * (v - self.av) - self.dv * (u - self.au))
    }

    /// Whether a point with edge value `e` is inside with respect to this edge.
    #[inline(always)]
    pub fn inside(&self, e: f64) -> bool {
        e > 0.0 || (e == 0.0 && self.owns_ties)
    }
}

/// Setup of one face in one batch element.
#[derive(Debug, Clone, Copy, Default)]
pub struct FaceSetup {
    /// Corner columns (pixel space).
    pub u: [f64; 3],
    /// Corner rows (pixel space).
    pub v: [f64; 3],
    /// Corner depths (view z).
    pub z: [f64; 3],
    /// Corner inverse depths (perspective interpolation).
    pub inv_z: [f64; 3],
    /// Oriented edges; `edges[k]` is the edge opposite corner `k` (from corner k+1 to k+2), so its value divided by
    /// `area` is the barycentric weight of corner `k`.
    pub edges: [Edge; 3],
    /// Twice the unsigned area in pixel units (oriented so that it is positive).
    pub area: f64,
    /// Twice the signed area in pixel space (v down): negative means counter-clockwise in y-up NDC.
    pub signed_area: f64,
    /// Whether the face is drawn at all.
    pub active: bool,
    /// Clipped bounding box of pixel centres: columns `col0..=col1`, rows `row0..=row1` (empty when `col0 > col1`).
    pub col0: i32,
    /// See `col0`.
    pub col1: i32,
    /// See `col0`.
    pub row0: i32,
    /// See `col0`.
    pub row1: i32,
    /// Orthographic (linear z) or perspective (linear 1/z) depth.
    pub ortho: bool,
    /// `1 / area`.
    pub inv_area: f64,
    /// The interpolated quantity (`1/z` in perspective, `z` in orthographic) as a plane in pixel space:
    /// `plane[0] * u + plane[1] * v + plane[2]` (used by the backward pass's extrapolated depth tests).
    pub plane: [f64; 3],
}

/// Converts NDC x to pixel-space u.
#[inline]
pub fn ndc_to_u(x: f32, width: usize) -> f64 {
    (x as f64 * width as f64 + width as f64 - 1.0) / 2.0
}

/// Converts NDC y to pixel-space v.
#[inline]
pub fn ndc_to_v(y: f32, height: usize) -> f64 {
    (height as f64 - 1.0 - y as f64 * height as f64) / 2.0
}

impl FaceSetup {
    /// Sets up face `f` of batch element `b`.
    pub fn new(mesh: &ScreenMesh<'_>, b: usize, f: usize, params: &RasterParams) -> FaceSetup {
        let idx = mesh.face(f);
        let mut s = FaceSetup {
            ortho: params.projection == Projection::Orthographic,
            ..Default::default()
        };
        for (k, &vi) in idx.iter().enumerate() {
            let p = mesh.vert(b, vi);
            s.u[k] = ndc_to_u(p[0], params.width);
            s.v[k] = ndc_to_v(p[1], params.height);
            s.z[k] = p[2] as f64;
            s.inv_z[k] = 1.0 / p[2] as f64;
        }
        s.signed_area =
            (s.u[1] - s.u[0]) * (s.v[2] - s.v[0]) - (s.v[1] - s.v[0]) * (s.u[2] - s.u[0]);
        let orient = if s.signed_area >= 0.0 { 1.0 } else { -1.0 };
        for k in 0..3 {
            let (a, c) = ((k + 1) % 3, (k + 2) % 3);
            s.edges[k] = Edge::new([s.u[a], s.v[a]], [s.u[c], s.v[c]], orient);
        }
        s.area = s.signed_area.abs();
        s.inv_area = 1.0 / s.area;
        for k in 0..3 {
            let e = &s.edges[k];
            let val = if s.ortho { s.z[k] } else { s.inv_z[k] } * e.sign * s.inv_area;
            s.plane[0] -= val * e.dv;
            s.plane[1] += val * e.du;
            s.plane[2] += val * (e.dv * e.au - e.du * e.av);
        }
        let behind = !s.ortho && s.z.iter().any(|&z| z <= 0.0);
        // Back-facing = counter-clockwise in y-up NDC = clockwise in v-down pixel space = signed_area < 0 here.
        let culled = params.cull_backfaces && s.signed_area < 0.0;
        s.active = s.area > 0.0 && s.area.is_finite() && !behind && !culled;
        let (w, h) = (params.width as f64, params.height as f64);
        let umin = s.u[0].min(s.u[1]).min(s.u[2]);
        let umax = s.u[0].max(s.u[1]).max(s.u[2]);
        let vmin = s.v[0].min(s.v[1]).min(s.v[2]);
        let vmax = s.v[0].max(s.v[1]).max(s.v[2]);
        s.col0 = ceil(umin).clamp(0.0, w) as i32;
        s.col1 = floor(umax).clamp(-1.0, w - 1.0) as i32;
        s.row0 = ceil(vmin).clamp(0.0, h) as i32;
        s.row1 = floor(vmax).clamp(-1.0, h - 1.0) as i32;
        if !s.active || s.col0 > s.col1 || s.row0 > s.row1 {
            s.col0 = 1;
            s.col1 = 0;
            s.row0 = 1;
            s.row1 = 0;
        }
        s
    }

    /// Barycentric weights of the pixel-space point `(u, v)` (may be negative outside the face), as the forward
    /// computes them (times `inv_area`, which [`FaceSetup::new`] sets to `1 / area`).
    #[inline(always)]
    pub fn barycentric(&self, u: f64, v: f64) -> [f64; 3] {
        let inv = self.inv_area;
        [
            self.edges[0].eval(u, v) * inv,
            self.edges[1].eval(u, v) * inv,
            self.edges[2].eval(u, v) * inv,
        ]
    }

    /// Depth from barycentric weights: perspective-correct (`1/z` linear) or linear (orthographic).
    /// `None` when undefined (non-positive or non-finite interpolated `1/z`).
    #[inline(always)]
    pub fn depth_from_weights(&self, w: [f64; 3]) -> Option<f64> {
        if self.ortho {
            let z = w[0] * self.z[0] + w[1] * self.z[1] + w[2] * self.z[2];
            z.is_finite().then_some(z)
        } else {
            let iz = w[0] * self.inv_z[0] + w[1] * self.inv_z[1] + w[2] * self.inv_z[2];
            if iz > 0.0 && iz.is_finite() {
                Some(1.0 / iz)
            } else {
                None
            }
        }
    }

    /// Depth of the face's plane at pixel centre `(row, col)`, extrapolated outside the face.
    #[inline(always)]
    pub fn depth_at(&self, row: i32, col: i32) -> Option<f64> {
        self.depth_from_weights(self.barycentric(col as f64, row as f64))
    }

    /// Columns of row `row` that may pass the forward's inside test, a conservative cut of `col0..=col1`: every
    /// column outside the returned range has some edge value that [`Edge::inside`] rejects (empty when
    /// `first > last`). Each edge bounds the columns by where it crosses the row, widened by its rounding error
    /// and a pixel; an edge whose bound is not finite does not cut.
    #[inline]
    pub fn row_span(&self, row: i32) -> (i32, i32) {
        let v = row as f64;
        let (mut lo, mut hi) = (self.col0, self.col1);
        for e in &self.edges {
            let r = e.du * (v - e.av);
            if e.dv == 0.0 {
                if !e.inside(e.sign * r) {
                    return (1, 0);
                }
                continue;
            }
            let q = r / e.dv;
            let cross = e.au + q;
            // `Edge::eval` at a column `u` of the box is within a few ulp-sized errors of `|r| + |dv (u - au)|` of
            // its exact value; divided by |dv| that is a few ulps of `|q| + |u - au|` in columns, and `cross`
            // rounds by a few ulps of `|q| + |au|`. Twice that, and a pixel for the truncation below.
            let reach = (self.col0 as f64 - e.au)
                .abs()
                .max((self.col1 as f64 - e.au).abs());
            let margin = 1.0 + 8.0 * f64::EPSILON * (q.abs() + reach + e.au.abs() + 1.0);
            if !(cross.is_finite() && margin.is_finite()) {
                continue;
            }
            // `as` truncates toward zero (and saturates): less than a column from the bound, which the pixel in
            // `margin` covers.
            if e.sign * e.dv > 0.0 {
                hi = hi.min((cross + margin) as i32);
            } else {
                lo = lo.max((cross - margin) as i32);
            }
        }
        (lo, hi)
    }

    /// [`FaceSetup::depth_at`] along row `row`: the terms of the edge functions that depend only on the row are
    /// computed once (the same operations on the same values, so [`RowDepth::at`] gives the same bits).
    #[inline(always)]
    pub fn row_depth(&self, row: i32) -> RowDepth<'_> {
        let v = row as f64;
        RowDepth {
            s: self,
            row_terms: std::array::from_fn(|k| self.edges[k].du * (v - self.edges[k].av)),
        }
    }
}

/// A face's depth along one row, see [`FaceSetup::row_depth`].
pub struct RowDepth<'a> {
    s: &'a FaceSetup,
    /// `du * (v - av)` of each edge.
    pub row_terms: [f64; 3],
}

impl RowDepth<'_> {
    /// [`FaceSetup::depth_at`] of this row at column `col`.
    #[inline(always)]
    pub fn at(&self, col: i32) -> Option<f64> {
        let (s, u) = (self.s, col as f64);
        // `Edge::eval` times `inv_area`, as `FaceSetup::barycentric`.
        let w = std::array::from_fn(|k| {
            let e = &s.edges[k];
            e.sign * (self.row_terms[k] - e.dv * (u - e.au)) * s.inv_area
        });
        s.depth_from_weights(w)
    }
}

/// `x.floor()` without a library call (the baseline x86-64 target has no rounding instruction).
#[inline(always)]
pub(crate) fn floor(x: f64) -> f64 {
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
pub(crate) fn ceil(x: f64) -> f64 {
    -floor(-x)
}

/// Sets up every face of batch element `b`.
pub fn setup_faces(mesh: &ScreenMesh<'_>, b: usize, params: &RasterParams) -> Vec<FaceSetup> {
    (0..mesh.num_faces())
        .map(|f| FaceSetup::new(mesh, b, f, params))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_rng::Rng;

    /// A random NDC coordinate: usually inside the image, sometimes on a pixel centre, sometimes far outside.
    fn coordinate(rng: &mut Rng, size: usize) -> f32 {
        match rng.below(8) {
            0 => {
                // a pixel centre (or half-way between two), so that edges pass exactly through centres
                let px = (rng.below(2 * size + 4) as f64 - 2.0) / 2.0;
                ((2.0 * px - size as f64 + 1.0) / size as f64) as f32
            }
            1 => ((rng.next() - 0.5) * 10f64.powi(rng.below(30) as i32)) as f32,
            _ => (rng.next() * 2.6 - 1.3) as f32,
        }
    }

    #[test]
    fn row_spans_keep_every_pixel_the_inside_test_accepts() {
        // Random triangles (thin, nearly parallel to the rows, through pixel centres, far outside the image): every
        // pixel of the box that passes all three edge tests lies in its row's span, and the spans cut the box.
        let mut rng = Rng(29);
        let (mut inside, mut in_spans, mut in_boxes) = (0usize, 0usize, 0usize);
        for case in 0..4000 {
            let (h, w) = (37, 41);
            let mut verts: Vec<f32> = (0..9)
                .map(|k| match k % 3 {
                    0 => coordinate(&mut rng, w),
                    1 => coordinate(&mut rng, h),
                    _ => (0.5 + rng.next() * 4.0) as f32,
                })
                .collect();
            if case % 5 == 0 {
                // an edge almost parallel to the rows
                verts[4] = verts[1] + (rng.next() * 1e-5) as f32;
            }
            let mesh = ScreenMesh::new(&verts, &[0, 1, 2], 1, 3).expect("valid mesh");
            let s = FaceSetup::new(&mesh, 0, 0, &RasterParams::new(h, w, 0.1, 100.0));
            for row in s.row0..=s.row1 {
                let (first, last) = s.row_span(row);
                assert!(
                    first > last || (s.col0 <= first && last <= s.col1),
                    "case {case} row {row}"
                );
                in_spans += (last - first + 1).max(0) as usize;
                in_boxes += (s.col1 - s.col0 + 1) as usize;
                for col in s.col0..=s.col1 {
                    let (u, v) = (col as f64, row as f64);
                    if s.edges.iter().all(|e| e.inside(e.eval(u, v))) {
                        inside += 1;
                        assert!(
                            (first..=last).contains(&col),
                            "case {case}: ({row}, {col}) outside {first}..={last}"
                        );
                    }
                }
            }
        }
        assert!(inside > 100_000, "{inside} pixels inside");
        assert!(
            in_spans < in_boxes * 3 / 4,
            "spans {in_spans} of {in_boxes} box pixels"
        );
    }

    #[test]
    fn the_row_depth_gives_the_bits_of_depth_at() {
        // Random triangles (perspective, and orthographic), depths along their rows and beyond (extrapolated).
        let mut rng = Rng(11);
        let mut next = || rng.next();
        let mut checked = 0;
        for case in 0..300 {
            let verts: Vec<f32> = (0..9)
                .map(|k| {
                    if k % 3 == 2 {
                        (0.5 + next() * 5.0) as f32
                    } else {
                        (next() * 2.4 - 1.2) as f32
                    }
                })
                .collect();
            let mesh = ScreenMesh::new(&verts, &[0, 1, 2], 1, 3).expect("valid mesh");
            let mut params = RasterParams::new(23, 31, 0.1, 100.0);
            if case % 3 == 0 {
                params.projection = Projection::Orthographic;
            }
            let s = FaceSetup::new(&mesh, 0, 0, &params);
            for row in -2..25 {
                let rd = s.row_depth(row);
                for col in -2..33 {
                    let (a, b) = (rd.at(col), s.depth_at(row, col));
                    assert_eq!(
                        a.map(f64::to_bits),
                        b.map(f64::to_bits),
                        "case {case} ({row}, {col})"
                    );
                    checked += usize::from(a.is_some());
                }
            }
        }
        assert!(checked > 10000);
    }

    #[test]
    fn floor_and_ceil_match_the_library() {
        let mut rng = Rng(1);
        let mut xs = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            2.5e15,
            -2.5e15,
            4503599627370495.5,
            -4503599627370495.5,
            1e300,
            -1e300,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ];
        xs.extend((0..1000).map(|_| (rng.next() - 0.5) * 1000.0));
        for x in xs {
            assert_eq!(floor(x), x.floor(), "floor({x})");
            assert_eq!(ceil(x), x.ceil(), "ceil({x})");
        }
        assert!(floor(f64::NAN).is_nan() && ceil(f64::NAN).is_nan());
    }
}
