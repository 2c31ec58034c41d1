//! Borrowed, validated views of the rasterizer's inputs (flat row-major slices plus their shapes).

use crate::error::{RasterError, Result};

/// Largest accepted image height or width.
pub const MAX_IMAGE_SIZE: usize = 16384;

/// Largest mesh file the readers open, in bytes (1 GiB): the render binary's and the Python loader's limit.
pub const MAX_MESH_FILE_BYTES: u64 = 1 << 30;

/// How screen-space depth is interpolated (and how the view rays are formed in the ray cast).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Projection {
    /// Perspective: `1/z` is interpolated linearly in screen space; faces with a vertex at `z <= 0` are not drawn.
    #[default]
    Perspective,
    /// Orthographic: `z` is interpolated linearly in screen space.
    Orthographic,
}

/// Screen-space triangle mesh, batched: `verts_screen` is `(B, N, 3)` of `(x_ndc, y_ndc, z_view)`,
/// `faces` is `(M, 3)` shared by the batch.
#[derive(Debug, Clone, Copy)]
pub struct ScreenMesh<'a> {
    /// Flat `(B, N, 3)` vertices in screen space.
    pub verts_screen: &'a [f32],
    /// Flat `(M, 3)` vertex indices.
    pub faces: &'a [i32],
    /// Batch size `B`.
    pub batch: usize,
    /// Vertex count `N`.
    pub num_verts: usize,
}

impl<'a> ScreenMesh<'a> {
    /// Wraps flat slices, checking that their lengths match `batch` and `num_verts`.
    ///
    /// ```
    /// use meshadv_raster::ScreenMesh;
    /// let verts = [0.0f32, 0.0, 1.0, 1.0, 0.0, 1.0, 0.0, 1.0, 1.0];
    /// let mesh = ScreenMesh::new(&verts, &[0, 1, 2], 1, 3).unwrap();
    /// assert_eq!(mesh.num_faces(), 1);
    /// ```
    pub fn new(
        verts_screen: &'a [f32],
        faces: &'a [i32],
        batch: usize,
        num_verts: usize,
    ) -> Result<Self> {
        if verts_screen.len() != batch * num_verts * 3 {
            return Err(RasterError::shape(
                "verts_screen",
                format!(
                    "({batch}, {num_verts}, 3) = {} values",
                    batch * num_verts * 3
                ),
                format!("{} values", verts_screen.len()),
            ));
        }
        if !faces.len().is_multiple_of(3) {
            return Err(RasterError::shape(
                "faces",
                "(M, 3)",
                format!("{} values", faces.len()),
            ));
        }
        Ok(ScreenMesh {
            verts_screen,
            faces,
            batch,
            num_verts,
        })
    }

    /// Number of faces `M`.
    pub fn num_faces(&self) -> usize {
        self.faces.len() / 3
    }

    /// Vertex indices of face `f` (already validated by [`ScreenMesh::validate`]).
    #[inline]
    pub fn face(&self, f: usize) -> [usize; 3] {
        let t = &self.faces[3 * f..3 * f + 3];
        [t[0] as usize, t[1] as usize, t[2] as usize]
    }

    /// Vertex `k` of batch element `b`.
    #[inline]
    pub fn vert(&self, b: usize, k: usize) -> [f32; 3] {
        let o = (b * self.num_verts + k) * 3;
        [
            self.verts_screen[o],
            self.verts_screen[o + 1],
            self.verts_screen[o + 2],
        ]
    }

    /// The `(N, 3)` vertices of batch element `b`, flat.
    #[inline]
    pub fn verts_of(&self, b: usize) -> &'a [f32] {
        let n = self.num_verts * 3;
        &self.verts_screen[b * n..(b + 1) * n]
    }

    /// For each batch element, the first element with the same vertices bit for bit (itself when none before it
    /// has them): elements that share their geometry share their fragments.
    pub fn first_with_same_verts(&self) -> Vec<usize> {
        // Only elements with equal hashes of their bits are compared in full.
        let hash = |v: &[f32]| bits_hash(v.iter().map(|x| x.to_bits()));
        let same = |a: &[f32], b: &[f32]| a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits());
        let mut firsts: Vec<(u64, usize)> = Vec::new();
        (0..self.batch)
            .map(|b| {
                let v = self.verts_of(b);
                let h = hash(v);
                match firsts
                    .iter()
                    .find(|&&(fh, f)| fh == h && same(self.verts_of(f), v))
                {
                    Some(&(_, f)) => f,
                    None => {
                        firsts.push((h, b));
                        b
                    }
                }
            })
            .collect()
    }

    /// Checks: non-empty, finite vertices, face indices in range, and that each batch element has a vertex
    /// in front of the camera (`z > 0`).
    pub fn validate(&self) -> Result<()> {
        self.validate_as("verts_screen")
    }

    /// [`ScreenMesh::validate`] with errors naming `arg` as the vertex array.
    pub fn validate_as(&self, arg: &'static str) -> Result<()> {
        if self.batch == 0 {
            return Err(RasterError::shape(arg, "(B, N, 3) with B >= 1", "B = 0"));
        }
        validate_mesh_indices("faces", self.faces, self.num_verts)?;
        check_finite(arg, self.verts_screen)?;
        for b in 0..self.batch {
            let any_front = (0..self.num_verts).any(|k| self.vert(b, k)[2] > 0.0);
            if !any_front {
                return Err(RasterError::BehindCamera { arg, batch: b });
            }
        }
        Ok(())
    }
}

/// The first entry of a face-index map that is neither -1 nor a face in `0..num_faces`, if any.
pub(crate) fn first_bad_face(face_index: &[i32], num_faces: usize) -> Option<usize> {
    // Blocks of 64 values without branching (vectorised), then the first bad value is searched. `-1 <= f < M` is
    // one unsigned comparison of `f + 1` (wrapping: `i32::MAX + 1` is out of range too).
    let limit = u32::try_from(num_faces).unwrap_or(u32::MAX);
    let bad = |f: i32| f.wrapping_add(1) as u32 > limit;
    let block_ok = |b: &[i32]| b.iter().fold(true, |ok, &f| ok & !bad(f));
    face_index
        .chunks(64)
        .position(|b| !block_ok(b))
        .and_then(|k| {
            face_index[k * 64..]
                .iter()
                .position(|&f| bad(f))
                .map(|i| k * 64 + i)
        })
}

/// A hash (FNV-1a) of a sequence of 32-bit words, e.g. the bits of an array of `f32`: equal bits give equal hashes,
/// to find repeated inputs or to compare outputs of two builds bit for bit.
pub fn bits_hash(words: impl IntoIterator<Item = u32>) -> u64 {
    words.into_iter().fold(0xcbf2_9ce4_8422_2325u64, |h, x| {
        (h ^ u64::from(x)).wrapping_mul(0x100_0000_01b3)
    })
}

/// Checks that `faces` (flat `(M, 3)`) is non-empty and refers to existing vertices.
pub fn validate_mesh_indices(arg: &'static str, faces: &[i32], num_verts: usize) -> Result<()> {
    if faces.is_empty() || num_verts < 3 {
        return Err(RasterError::EmptyMesh { arg });
    }
    if !faces.len().is_multiple_of(3) {
        return Err(RasterError::shape(
            arg,
            "(M, 3)",
            format!("{} values", faces.len()),
        ));
    }
    for (i, &v) in faces.iter().enumerate() {
        if v < 0 || v as usize >= num_verts {
            return Err(RasterError::FaceIndexOutOfRange {
                face: i / 3,
                vertex: v as i64,
                num_vertices: num_verts,
            });
        }
    }
    Ok(())
}

/// Returns an error naming `arg` if any value is NaN or infinite.
pub fn check_finite(arg: &'static str, values: &[f32]) -> Result<()> {
    // Blocks of 64 values are checked without branching (vectorised), then the first bad block is searched.
    const BLOCK: usize = 64;
    let finite = |block: &[f32]| block.iter().fold(true, |ok, x| ok & x.is_finite());
    let Some(bad) = values.chunks(BLOCK).position(|b| !finite(b)) else {
        return Ok(());
    };
    match values[bad * BLOCK..]
        .iter()
        .position(|x| !x.is_finite())
        .map(|i| bad * BLOCK + i)
    {
        Some(index) => Err(RasterError::NonFinite {
            arg,
            index,
            value: values[index],
        }),
        None => Ok(()),
    }
}

/// Image size, clipping range, culling and projection of one rasterization.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RasterParams {
    /// Image height `H` in pixels.
    pub height: usize,
    /// Image width `W` in pixels.
    pub width: usize,
    /// Near clipping depth (view-space z).
    pub near: f64,
    /// Far clipping depth (view-space z); also the depth written on background pixels.
    pub far: f64,
    /// Drop back-facing faces (counter-clockwise in y-up NDC, see ARCHITECTURE.md) instead of drawing both sides.
    pub cull_backfaces: bool,
    /// Depth interpolation rule.
    pub projection: Projection,
}

impl RasterParams {
    /// Perspective parameters with the given size and clip range, two-sided.
    pub fn new(height: usize, width: usize, near: f64, far: f64) -> Self {
        RasterParams {
            height,
            width,
            near,
            far,
            cull_backfaces: false,
            projection: Projection::Perspective,
        }
    }

    /// Checks image size (1..=16384) and `0 <= near < far`, both finite.
    pub fn validate(&self) -> Result<()> {
        check_image_size("height", self.height as i64)?;
        check_image_size("width", self.width as i64)?;
        if !(self.near.is_finite()
            && self.far.is_finite()
            && self.near >= 0.0
            && self.near < self.far)
        {
            return Err(RasterError::ClipRange {
                near: self.near,
                far: self.far,
            });
        }
        Ok(())
    }

    /// Pixels per image `H * W`.
    pub fn pixels(&self) -> usize {
        self.height * self.width
    }
}

/// Checks one image dimension.
pub fn check_image_size(arg: &'static str, value: i64) -> Result<usize> {
    if value < 1 || value > MAX_IMAGE_SIZE as i64 {
        return Err(RasterError::ImageSize {
            arg,
            value,
            max: MAX_IMAGE_SIZE,
        });
    }
    Ok(value as usize)
}

/// Per-face attributes `(B, M, C)` and the background value `(C,)`.
#[derive(Debug, Clone, Copy)]
pub struct FaceAttrs<'a> {
    /// Flat `(B, M, C)` attributes.
    pub values: &'a [f32],
    /// Flat `(C,)` background.
    pub background: &'a [f32],
    /// Channel count `C`.
    pub channels: usize,
}

impl<'a> FaceAttrs<'a> {
    /// Checks shapes against the mesh and finiteness.
    pub fn validate(&self, mesh: &ScreenMesh<'_>) -> Result<()> {
        let c = self.channels;
        if c == 0 {
            return Err(RasterError::shape(
                "face_attrs",
                "(B, M, C) with C >= 1",
                "C = 0",
            ));
        }
        let want = mesh.batch * mesh.num_faces() * c;
        if self.values.len() != want {
            return Err(RasterError::shape(
                "face_attrs",
                format!("({}, {}, {c})", mesh.batch, mesh.num_faces()),
                format!("{} values", self.values.len()),
            ));
        }
        if self.background.len() != c {
            return Err(RasterError::shape(
                "background",
                format!("({c},)"),
                format!("({},)", self.background.len()),
            ));
        }
        check_finite("face_attrs", self.values)?;
        check_finite("background", self.background)
    }

    /// Attributes of face `f` in batch element `b`.
    #[inline]
    pub fn face(&self, b: usize, num_faces: usize, f: usize) -> &[f32] {
        let o = (b * num_faces + f) * self.channels;
        &self.values[o..o + self.channels]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn check_finite_reports_the_first_non_finite_value() {
        for len in [0usize, 1, 63, 64, 65, 200, 1000] {
            let ok = vec![1.5f32; len];
            assert!(check_finite("x", &ok).is_ok(), "len {len}");
            for first in [0, 1, 62, 63, 64, 65, 127, 128, 999]
                .into_iter()
                .filter(|&i| i < len)
            {
                for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
                    let mut v = ok.clone();
                    v[first] = bad;
                    // A later bad value must not be reported instead.
                    if first + 70 < len {
                        v[first + 70] = f32::NAN;
                    }
                    match check_finite("x", &v) {
                        Err(RasterError::NonFinite { arg, index, .. }) => {
                            assert_eq!((arg, index), ("x", first), "len {len}, {bad}")
                        }
                        other => panic!("len {len}, first {first}: {other:?}"),
                    }
                }
            }
        }
    }

    #[test]
    fn elements_with_the_same_vertex_bits_point_to_the_first_of_them() {
        let a = [0.1f32, 0.2, 1.0, 0.5, 0.1, 1.5, -0.3, 0.4, 2.0];
        let mut b = a;
        b[8] = 2.5; // differs in the last value only
        let (mut pos_zero, mut neg_zero) = (a, a);
        pos_zero[0] = 0.0;
        neg_zero[0] = -0.0; // equal to +0 as a number, not in its bits
        let batch: Vec<f32> = [a, b, a, neg_zero, pos_zero, b, pos_zero].concat();
        let mesh = ScreenMesh::new(&batch, &[0, 1, 2], 7, 3).expect("valid");
        assert_eq!(mesh.first_with_same_verts(), vec![0, 1, 0, 3, 4, 1, 4]);
    }
}
