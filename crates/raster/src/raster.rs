//! Forward rasterization: pixel-centre coverage with the top-left tie rule, perspective-correct depth,
//! per-pixel near/far clipping, nearest face wins (lower face index on exact depth ties).
//!
//! Parallel over batch elements and bands of rows; every pixel is written by exactly one task that visits faces in
//! increasing index order, so the result does not depend on the thread count.

use rayon::prelude::*;

use crate::error::{try_filled_vec, Result};
use crate::input::{FaceAttrs, RasterParams, ScreenMesh};
use crate::setup::{setup_faces, FaceSetup};

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
/// narrower ones, finding the span costs more than the columns it skips).
const SPAN_MIN_WIDTH: i32 = 8;

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

/// Rasterizes one band (rows `row_start..row_start + rows`) into `face_index` / `zbuf` (band-local, row-major).
fn raster_band(
    setups: &[FaceSetup],
    bin: &[u32],
    params: &RasterParams,
    row_start: usize,
    face_index: &mut [i32],
    zbuf: &mut [f64],
) {
    let w = params.width;
    let rows = face_index.len() / w;
    let (near, far) = (params.near, params.far);
    let row_end = (row_start + rows) as i32 - 1;
    for &f in bin {
        let s = &setups[f as usize];
        let r0 = s.row0.max(row_start as i32);
        let r1 = s.row1.min(row_end);
        for row in r0..=r1 {
            let vc = row as f64;
            let line = (row as usize - row_start) * w;
            let (first, last) = if s.col1 - s.col0 < SPAN_MIN_WIDTH {
                (s.col0, s.col1)
            } else {
                s.row_span(row)
            };
            for col in first..=last {
                let uc = col as f64;
                let e0 = s.edges[0].eval(uc, vc);
                let e1 = s.edges[1].eval(uc, vc);
                let e2 = s.edges[2].eval(uc, vc);
                if !(s.edges[0].inside(e0) && s.edges[1].inside(e1) && s.edges[2].inside(e2)) {
                    continue;
                }
                let inv = s.inv_area;
                let Some(z) = s.depth_from_weights([e0 * inv, e1 * inv, e2 * inv]) else {
                    continue;
                };
                if !(z >= near && z <= far) {
                    continue;
                }
                let p = line + col as usize;
                // Faces come in increasing order, so strict `<` keeps the lower index on exact ties.
                if z < zbuf[p] {
                    zbuf[p] = z;
                    face_index[p] = f as i32;
                }
            }
        }
    }
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
    face_index
        .par_chunks_mut(BAND_ROWS * w)
        .zip(depth.par_chunks_mut(BAND_ROWS * w))
        .enumerate()
        .for_each(|(band, (fi, dp))| {
            let mut zbuf = vec![f64::INFINITY; fi.len()];
            fi.fill(-1);
            raster_band(setups, &bins[band], params, band * BAND_ROWS, fi, &mut zbuf);
            for (d, (&z, &f)) in dp.iter_mut().zip(zbuf.iter().zip(fi.iter())) {
                *d = if f < 0 { params.far as f32 } else { z as f32 };
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
