//! Forward rasterization: pixel-centre coverage with the top-left tie rule, perspective-correct depth,
//! per-pixel near/far clipping, nearest face wins (lower face index on exact depth ties).
//!
//! Parallel over batch elements and bands of rows; every pixel is written by exactly one task that visits faces in
//! increasing index order, so the result does not depend on the thread count. Each face's rows are tested in
//! vectors of columns (8 with AVX-512, 4 with AVX2, 2 otherwise; picked at run time, see [`Isa`]) with the scalar
//! definitions' operations in their order, so every instruction set gives the same bits.

use rayon::prelude::*;

use crate::error::{try_filled_vec, Result};
use crate::input::{FaceAttrs, RasterParams, ScreenMesh};
use crate::setup::{setup_faces, FaceSetup};
use crate::simd::{F64s, Isa, MAX_LANES};

/// Rows per parallel band.
pub const BAND_ROWS: usize = 8;

/// Outputs of [`rasterize`], flat row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Fragments {
    /// `(B, H, W)` face drawn at each pixel, -1 for background.
    pub face_index: Vec<i32>,
    /// `(B, H, W)` view depth of the drawn face, `far` on background.
    pub depth: Vec<f32>,
}

/// Image plus fragments, flat row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct RasterOutput {
    /// `(B, H, W, C)` attributes of the drawn face (background where empty).
    pub image: Vec<f32>,
    /// `(B, H, W)` face index, -1 for background.
    pub face_index: Vec<i32>,
    /// `(B, H, W)` depth, `far` on background.
    pub depth: Vec<f32>,
}

/// Boxes at least this many columns wide scan each row's [`FaceSetup::row_span`] instead of the whole box (for
/// narrower ones, finding the span costs more than the vectors it skips).
const SPAN_MIN_WIDTH: i32 = 16;

/// Face lists per band of rows, faces in increasing order.
fn bin_faces(setups: &[FaceSetup], height: usize) -> Vec<Vec<u32>> {
    let bands = height.div_ceil(BAND_ROWS);
    let mut bins = vec![Vec::new(); bands];
    for (f, s) in setups.iter().enumerate() {
        if !s.active || s.row0 > s.row1 {
            continue;
        }
        let b0 = s.row0 as usize / BAND_ROWS;
        let b1 = s.row1 as usize / BAND_ROWS;
        for bin in &mut bins[b0..=b1] {
            bin.push(f as u32);
        }
    }
    bins
}

/// The depth-tested fragments of one band of rows: the nearest face's index (as f64, -1 for none) and depth
/// (`+inf` for none), band-local and row-major, with [`MAX_LANES`] values of padding that the vectors may read
/// and write back unchanged.
struct BandBuffers {
    face: Vec<f64>,
    depth: Vec<f64>,
}

impl BandBuffers {
    /// Empty buffers for `pixels` pixels.
    fn new(pixels: usize) -> BandBuffers {
        BandBuffers {
            face: vec![-1.0; pixels + MAX_LANES],
            depth: vec![f64::INFINITY; pixels + MAX_LANES],
        }
    }
}

/// Rasterizes one band (rows `row_start..row_start + rows`) into `buf`, on the instruction set `isa` (which the
/// caller has checked is available). Every instruction set gives the same bits.
fn raster_band(
    setups: &[FaceSetup],
    bin: &[u32],
    params: &RasterParams,
    row_start: usize,
    buf: &mut BandBuffers,
    isa: Isa,
) {
    // SAFETY: `isa` is available (the caller checks); SSE2 is part of the x86-64 baseline.
    #[allow(unsafe_code)]
    unsafe {
        match isa {
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512 => band_avx512(setups, bin, params, row_start, buf),
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2 => band_avx2(setups, bin, params, row_start, buf),
            #[cfg(target_arch = "x86_64")]
            _ => band_on::<std::arch::x86_64::__m128d>(setups, bin, params, row_start, buf),
            #[cfg(not(target_arch = "x86_64"))]
            _ => band_on::<[f64; 2]>(setups, bin, params, row_start, buf),
        }
    }
}

/// [`band_on`] on AVX2 (4 lanes).
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(unsafe_code)]
unsafe fn band_avx2(
    setups: &[FaceSetup],
    bin: &[u32],
    params: &RasterParams,
    row_start: usize,
    buf: &mut BandBuffers,
) {
    band_on::<std::arch::x86_64::__m256d>(setups, bin, params, row_start, buf)
}

/// [`band_on`] on AVX-512 (8 lanes).
///
/// # Safety
/// The CPU must support AVX2, AVX-512F, -DQ and -VL.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,avx512f,avx512dq,avx512vl")]
#[allow(unsafe_code)]
unsafe fn band_avx512(
    setups: &[FaceSetup],
    bin: &[u32],
    params: &RasterParams,
    row_start: usize,
    buf: &mut BandBuffers,
) {
    band_on::<std::arch::x86_64::__m512d>(setups, bin, params, row_start, buf)
}

/// [`raster_band`] on vectors `V`: each face's rows in vectors of `V::N` columns. Per pixel the operations of
/// [`Edge::eval`](crate::setup::Edge::eval), [`Edge::inside`](crate::setup::Edge::inside) and
/// [`FaceSetup::depth_from_weights`] in the same order (so the same bits as the scalar definitions), then the
/// clip range and the depth test, whose winners are blended into the buffers.
///
/// # Safety
/// `V`'s instructions must be supported by the CPU.
#[allow(unsafe_code)]
#[inline(always)]
unsafe fn band_on<V: F64s>(
    setups: &[FaceSetup],
    bin: &[u32],
    params: &RasterParams,
    row_start: usize,
    buf: &mut BandBuffers,
) {
    let w = params.width;
    let rows = (buf.depth.len() - MAX_LANES) / w;
    assert!(buf.face.len() == buf.depth.len() && V::N <= MAX_LANES);
    let row_end = (row_start + rows) as i32 - 1;
    let (zero, one, inf) = (V::splat(0.0), V::splat(1.0), V::splat(f64::INFINITY));
    let (near, far) = (V::splat(params.near), V::splat(params.far));
    let all = V::splat(f64::from_bits(u64::MAX));
    let (face_buf, depth_buf, buf_len) = (
        buf.face.as_mut_ptr(),
        buf.depth.as_mut_ptr(),
        buf.depth.len(),
    );
    for &f in bin {
        let s = &setups[f as usize];
        let r0 = s.row0.max(row_start as i32);
        let r1 = s.row1.min(row_end);
        let fv = V::splat(f as f64);
        let inv = V::splat(s.inv_area);
        let edge = |k: usize| {
            let e = &s.edges[k];
            let owns = if e.owns_ties { all } else { zero };
            (V::splat(e.sign), V::splat(e.dv), V::splat(e.au), owns)
        };
        let edges = [edge(0), edge(1), edge(2)];
        let interp = if s.ortho { s.z } else { s.inv_z };
        let interp = interp.map(|x| V::splat(x));
        for row in r0..=r1 {
            let vc = row as f64;
            let row_terms: [V; 3] =
                std::array::from_fn(|k| V::splat(s.edges[k].du * (vc - s.edges[k].av)));
            let line = (row as usize - row_start) * w;
            let (first, last) = if s.col1 - s.col0 < SPAN_MIN_WIDTH {
                (s.col0, s.col1)
            } else {
                s.row_span(row)
            };
            let last_v = V::splat(last as f64);
            let mut col = first;
            while col <= last {
                let u = V::counting_from(col as f64);
                // Edge::eval: sign * (du * (v - av) - dv * (u - au)); Edge::inside: e > 0, or e == 0 where owned.
                let mut outside = u.gt(last_v);
                let mut wsum = zero;
                for k in 0..3 {
                    let (sign, dv, au, owns) = edges[k];
                    let e = sign.mul(row_terms[k].sub(dv.mul(u.sub(au))));
                    let inside_k = e.gt(zero).or(e.eq(zero).and(owns));
                    outside = inside_k.andnot(all).or(outside);
                    // FaceSetup::depth_from_weights: w0 * i0 + w1 * i1 + w2 * i2, left to right.
                    let term = e.mul(inv).mul(interp[k]);
                    wsum = if k == 0 { term } else { wsum.add(term) };
                }
                let (z, defined) = if s.ortho {
                    (wsum, wsum.sub(wsum).eq(zero))
                } else {
                    (one.div(wsum), wsum.gt(zero).and(wsum.lt(inf)))
                };
                let p = line + col as usize;
                // SAFETY (the loads and stores at `p`): the face's box and spans lie within the image and the band
                // (`0 <= col0 <= first`, `last <= col1 <= w - 1`, `row_start <= row <= row_end`), so `p + V::N <=
                // (rows - 1) * w + (w - 1) + MAX_LANES`, within the buffers' `rows * w + MAX_LANES` values; lanes
                // past `last` write back the values they read.
                debug_assert!(p + V::N <= buf_len);
                let old = V::load(depth_buf.add(p));
                // In the clip range (`defined` excludes NaN) and nearer than what is there.
                let wins = z
                    .lt(near)
                    .or(z.gt(far))
                    .or(outside)
                    .andnot(defined.and(z.lt(old)));
                blend(wins, z, old).store(depth_buf.add(p));
                blend(wins, fv, V::load(face_buf.add(p))).store(face_buf.add(p));
                col += V::N as i32;
            }
        }
    }
}

/// Lane-wise `if mask { a } else { b }` for a mask of all-ones or all-zeros lanes.
#[allow(unsafe_code)]
#[inline(always)]
unsafe fn blend<V: F64s>(mask: V, a: V, b: V) -> V {
    mask.and(a).or(mask.andnot(b))
}

/// Computes the face index and depth maps of batch element `b` into `face_index` / `depth` (each `H * W`).
pub fn rasterize_fragments_one(
    setups: &[FaceSetup],
    params: &RasterParams,
    face_index: &mut [i32],
    depth: &mut [f32],
) {
    let w = params.width;
    let bins = bin_faces(setups, params.height);
    let isa = Isa::detect();
    face_index
        .par_chunks_mut(BAND_ROWS * w)
        .zip(depth.par_chunks_mut(BAND_ROWS * w))
        .enumerate()
        .for_each(|(band, (fi, dp))| {
            let mut buf = BandBuffers::new(fi.len());
            raster_band(setups, &bins[band], params, band * BAND_ROWS, &mut buf, isa);
            for ((i, d), (&f, &z)) in fi
                .iter_mut()
                .zip(dp.iter_mut())
                .zip(buf.face.iter().zip(&buf.depth))
            {
                *i = f as i32;
                *d = if f < 0.0 { params.far as f32 } else { z as f32 };
            }
        });
}

/// Rasterizes all batch elements: face index and depth maps only. Elements whose vertices equal an earlier
/// element's bit for bit (e.g. one mesh under several colourings) are rasterized once and copied.
pub fn rasterize_fragments(mesh: &ScreenMesh<'_>, params: &RasterParams) -> Result<Fragments> {
    mesh.validate()?;
    params.validate()?;
    let hw = params.pixels();
    let len = mesh.batch.saturating_mul(hw);
    let mut face_index = try_filled_vec(len, -1i32, "face_index")?;
    let mut depth = try_filled_vec(len, 0f32, "depth")?;
    let first = mesh.first_with_same_verts();
    face_index
        .par_chunks_mut(hw)
        .zip(depth.par_chunks_mut(hw))
        .enumerate()
        .filter(|(b, _)| first[*b] == *b)
        .for_each(|(b, (fi, dp))| {
            let setups = setup_faces(mesh, b, params);
            rasterize_fragments_one(&setups, params, fi, dp);
        });
    for (b, &f) in first.iter().enumerate().filter(|(b, f)| *b != **f) {
        face_index.copy_within(f * hw..(f + 1) * hw, b * hw);
        depth.copy_within(f * hw..(f + 1) * hw, b * hw);
    }
    Ok(Fragments { face_index, depth })
}

/// Writes one image line: each pixel the attributes of the face drawn there (of batch element `b`), or the
/// background; `C` channels (`C = 0`: `attrs.channels`, copied slice by slice).
#[inline(always)]
fn fill_line<const C: usize>(
    px: &mut [f32],
    fi: &[i32],
    attrs: &FaceAttrs<'_>,
    b: usize,
    m: usize,
) {
    let c = if C == 0 { attrs.channels } else { C };
    for (dst, &f) in px.chunks_exact_mut(c).zip(fi) {
        let src = if f < 0 {
            attrs.background
        } else {
            attrs.face(b, m, f as usize)
        };
        if C == 0 {
            dst.copy_from_slice(src);
        } else {
            dst[..C].copy_from_slice(&src[..C]);
        }
    }
}

/// Full forward rasterization: face index, depth and the per-face attribute image.
///
/// ```
/// use meshadv_raster::{rasterize, FaceAttrs, RasterParams, ScreenMesh};
/// // One triangle covering the lower-left half of a 4 x 4 image, at depth 2.
/// let verts = [-1.0f32, -1.0, 2.0, 1.0, -1.0, 2.0, -1.0, 1.0, 2.0];
/// let mesh = ScreenMesh::new(&verts, &[0, 1, 2], 1, 3).unwrap();
/// let attrs = FaceAttrs { values: &[0.5], background: &[0.0], channels: 1 };
/// let out = rasterize(&mesh, &attrs, &RasterParams::new(4, 4, 0.1, 10.0)).unwrap();
/// assert_eq!(out.face_index[12], 0); // bottom-left pixel
/// assert_eq!(out.image[12], 0.5);
/// assert_eq!(out.face_index[3], -1); // top-right pixel
/// assert_eq!(out.depth[3], 10.0);
/// ```
pub fn rasterize(
    mesh: &ScreenMesh<'_>,
    attrs: &FaceAttrs<'_>,
    params: &RasterParams,
) -> Result<RasterOutput> {
    attrs.validate(mesh)?;
    let Fragments { face_index, depth } = rasterize_fragments(mesh, params)?;
    let c = attrs.channels;
    let m = mesh.num_faces();
    let mut image = try_filled_vec(face_index.len().saturating_mul(c), 0f32, "image")?;
    image
        .par_chunks_mut(params.width * c)
        .enumerate()
        .for_each(|(line, px)| {
            let b = line / params.height;
            let fi = &face_index[line * params.width..(line + 1) * params.width];
            with_channels!(c, C => fill_line::<C>(px, fi, attrs, b, m))
        });
    Ok(RasterOutput {
        image,
        face_index,
        depth,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::input::{Projection, ScreenMesh};
    use crate::test_rng::Rng;

    /// The definition, pixel by pixel: every face of the band in increasing order, the scalar inside test, depth,
    /// clip range and depth test (strict `<`, so the lower index wins exact ties).
    fn scalar_band(
        setups: &[FaceSetup],
        bin: &[u32],
        params: &RasterParams,
        row_start: usize,
        rows: usize,
    ) -> (Vec<i32>, Vec<f64>) {
        let w = params.width;
        let (mut face, mut depth) = (vec![-1; rows * w], vec![f64::INFINITY; rows * w]);
        for &f in bin {
            let s = &setups[f as usize];
            for row in s.row0.max(row_start as i32)..=s.row1.min((row_start + rows) as i32 - 1) {
                for col in s.col0..=s.col1 {
                    let (u, v) = (col as f64, row as f64);
                    if !s.edges.iter().all(|e| e.inside(e.eval(u, v))) {
                        continue;
                    }
                    let Some(z) = s.depth_from_weights(s.barycentric(u, v)) else {
                        continue;
                    };
                    let p = (row as usize - row_start) * w + col as usize;
                    if z >= params.near && z <= params.far && z < depth[p] {
                        (face[p], depth[p]) = (f as i32, z);
                    }
                }
            }
        }
        (face, depth)
    }

    /// A random NDC coordinate: mostly inside the image, sometimes on a pixel centre (edges through centres, ties).
    fn coordinate(rng: &mut Rng, size: usize) -> f32 {
        if rng.below(3) == 0 {
            let px = rng.below(size + 2) as f64 - 1.0;
            ((2.0 * px - size as f64 + 1.0) / size as f64) as f32
        } else {
            (rng.next() * 2.4 - 1.2) as f32
        }
    }

    #[test]
    fn every_instruction_set_gives_the_bits_of_the_scalar_definition() {
        // Random soups of triangles (large and small, shared corners, exact depth ties, faces crossing the clip
        // range), perspective and orthographic: each band's face index and depth, on every instruction set this
        // CPU has, equal the pixel-by-pixel definition bit for bit.
        let mut rng = Rng(41);
        let (mut drawn, mut ties) = (0usize, 0usize);
        for case in 0..60 {
            let (h, w) = (19 + rng.below(20), 17 + rng.below(30));
            let nv = 30;
            let mut verts = Vec::new();
            for _ in 0..nv {
                verts.push(coordinate(&mut rng, w));
                verts.push(coordinate(&mut rng, h));
                // a few depths repeat exactly, so that faces tie
                verts.push([1.0, 2.0, (0.5 + rng.next() * 4.0) as f32][rng.below(3)]);
            }
            let faces: Vec<i32> = (0..3 * 40).map(|_| rng.below(nv) as i32).collect();
            let mesh = ScreenMesh::new(&verts, &faces, 1, nv).expect("valid mesh");
            let mut params = RasterParams::new(h, w, 0.9, 3.5);
            if case % 3 == 0 {
                params.projection = Projection::Orthographic;
            }
            let setups = setup_faces(&mesh, 0, &params);
            let bins = bin_faces(&setups, h);
            for (band, bin) in bins.iter().enumerate() {
                let row_start = band * BAND_ROWS;
                let rows = BAND_ROWS.min(h - row_start);
                let (face, depth) = scalar_band(&setups, bin, &params, row_start, rows);
                drawn += face.iter().filter(|&&f| f >= 0).count();
                ties += depth.iter().filter(|&&z| z == 1.0 || z == 2.0).count();
                for isa in Isa::all_available() {
                    let mut buf = BandBuffers::new(rows * w);
                    raster_band(&setups, bin, &params, row_start, &mut buf, isa);
                    let got: Vec<i32> = buf.face[..rows * w].iter().map(|&f| f as i32).collect();
                    assert_eq!(got, face, "case {case} band {band} {isa:?}");
                    let bits = |z: &[f64]| z.iter().map(|z| z.to_bits()).collect::<Vec<_>>();
                    assert_eq!(
                        bits(&buf.depth[..rows * w]),
                        bits(&depth),
                        "case {case} band {band} {isa:?}"
                    );
                }
            }
        }
        assert!(
            drawn > 10_000 && ties > 100,
            "{drawn} pixels drawn, {ties} at tied depths"
        );
    }
}
