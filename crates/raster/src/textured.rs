//! A UV-textured surface in one pass per pixel: the face drawn there, its perspective-correct UV, the bilinear
//! texture sample at it; and the backward in one pass: the texel and UV gradients and the vertex gradient of the
//! UVs moving with the vertices (the interior term, exact at fixed face assignment; the visibility term is
//! [`crate::backward::image_vertex_backward`]'s).
//!
//! Per face the perspective numerators `q_k = w_k / z_k` are planes in pixel space ([`crate::surface`]), so the
//! perspective-correct UV is a ratio of planes, `uv = N / Q` with `Q = sum_k q_k` and `N = sum_k q_k uv_k`
//! (orthographic: `Q = 1`, `N = sum_k w_k uv_k`): three planes per face, evaluated at the first pixel centre of each
//! run of the face's pixels along a row and stepped by their slopes from one pixel to the next (forward and backward
//! alike), with no per-pixel weights or UV arrays. The backward sums over each face's pixels (row-major order) the cotangents of
//! `N` and `Q` times `(1, u, v)`, the gradients of the planes' coefficients, which give the UV and vertex gradients
//! once per face. Conventions (UV origin, texel centres, wrap): [`crate::texture`]; the result equals sampling the
//! texture at the UVs that [`crate::surface::interpolate`] gives with [`crate::surface::pixel_weights`], up to
//! rounding. Texel sums run over pixels in row-major order and batch elements in order, the UV and vertex sums over
//! the drawn faces in the order of their first pixels: bit-identical for any thread count. [`UvTexturePlanes`] checks
//! the inputs and builds the drawn faces' planes once for a forward and its backward; the pixel loops run compiled
//! for AVX2 where the CPU has it, with the same bits as the baseline build.

use rayon::prelude::*;

use crate::error::{try_filled_vec, RasterError, Result};
use crate::input::{RasterParams, ScreenMesh};
use crate::simd::Isa;
use crate::surface::{
    add_to_vertices, check_face_index, check_pixel_grad, dot3, CornerAttrs, FacePlanes,
};
use crate::texture::{check_texture_coordinates, Texture};

/// The planes of one face whose ratios are the UV at a pixel: `uv = (N_u, N_v) / Q`.
#[derive(Debug, Clone, Copy, Default)]
struct UvPlanes {
    /// `Q(u, v)`.
    q: [f64; 3],
    /// `N_u(u, v)`.
    nu: [f64; 3],
    /// `N_v(u, v)`.
    nv: [f64; 3],
}

impl UvPlanes {
    fn new(planes: &FacePlanes, uv: [&[f32]; 3]) -> UvPlanes {
        let mut out = UvPlanes::default();
        for (k, uvk) in uv.iter().enumerate() {
            for (i, q) in planes.numerator(k).into_iter().enumerate() {
                out.q[i] += q;
                out.nu[i] += q * uvk[0] as f64;
                out.nv[i] += q * uvk[1] as f64;
            }
        }
        if planes.ortho {
            // sum_k w_k = 1 exactly.
            out.q = [1.0, 0.0, 0.0];
        }
        out
    }

    /// The planes along image row `v`: lines in the column `u`.
    #[inline(always)]
    fn row(&self, v: f64) -> UvRow {
        let line = |p: &[f64; 3]| [p[0] + p[2] * v, p[1]];
        UvRow {
            q: line(&self.q),
            nu: line(&self.nu),
            nv: line(&self.nv),
        }
    }
}

/// [`UvPlanes`] along one image row: `Q = q[0] + q[1] u`, and `N_u`, `N_v` alike.
#[derive(Debug, Clone, Copy)]
struct UvRow {
    q: [f64; 2],
    nu: [f64; 2],
    nv: [f64; 2],
}

impl UvRow {
    /// `(Q, N_u, N_v)` at column `u` of the row.
    #[inline(always)]
    fn at(&self, u: f64) -> [f64; 3] {
        [
            self.q[0] + self.q[1] * u,
            self.nu[0] + self.nu[1] * u,
            self.nv[0] + self.nv[1] * u,
        ]
    }

    /// The change of [`UvRow::at`] from one column to the next.
    #[inline(always)]
    fn step(&self) -> [f64; 3] {
        [self.q[1], self.nu[1], self.nv[1]]
    }
}

/// `(1 / Q, uv)` of the plane values `(Q, N_u, N_v)`, and the values stepped to the next column.
#[inline(always)]
fn uv_and_step(p: &mut [f64; 3], step: &[f64; 3]) -> (f64, f64, f64) {
    let inv = 1.0 / p[0];
    let out = (inv, p[1] * inv, p[2] * inv);
    for (x, d) in p.iter_mut().zip(step) {
        *x += d;
    }
    out
}

/// The runs of equal entries of a line of fragments: `(start, end, face)` with `fi[start..end]` all `face`.
#[inline(always)]
fn runs(fi: &[i32]) -> impl Iterator<Item = (usize, usize, i32)> + '_ {
    let mut start = 0;
    std::iter::from_fn(move || {
        let &f = fi.get(start)?;
        let end = start
            + fi[start..]
                .iter()
                .position(|&g| g != f)
                .unwrap_or(fi.len() - start);
        let run = (start, end, f);
        start = end;
        Some(run)
    })
}

/// The faces of one batch element drawn somewhere in its fragments, in order of their first pixel (row-major), with
/// what the backward needs of their inputs.
#[derive(Debug)]
struct DrawnFaces {
    /// Per face of the mesh: its index among the drawn faces, or `u32::MAX` where it is not drawn.
    slot: Vec<u32>,
    /// The drawn faces' vertices.
    verts: Vec<[u32; 3]>,
    /// Their corners' UV rows.
    uv_rows: Vec<[u32; 3]>,
    /// Their corners' UVs.
    uv_values: Vec<[[f32; 2]; 3]>,
    /// Their weight planes.
    planes: Vec<FacePlanes>,
    /// Their UV planes.
    uv: Vec<UvPlanes>,
}

impl DrawnFaces {
    /// The faces of batch element `b` drawn in its fragments `fi`.
    fn new(
        mesh: &ScreenMesh<'_>,
        params: &RasterParams,
        uvs: &CornerAttrs<'_>,
        b: usize,
        fi: &[i32],
    ) -> DrawnFaces {
        let mut d = DrawnFaces {
            slot: vec![u32::MAX; mesh.num_faces()],
            verts: Vec::new(),
            uv_rows: Vec::new(),
            uv_values: Vec::new(),
            planes: Vec::new(),
            uv: Vec::new(),
        };
        // A run of one face's pixels is looked at once.
        let mut previous = -1;
        for &f in fi {
            if f == previous {
                continue;
            }
            previous = f;
            if f >= 0 && d.slot[f as usize] == u32::MAX {
                let f = f as usize;
                d.slot[f] = d.verts.len() as u32;
                let planes = FacePlanes::new(mesh, b, f, params);
                let rows = &uvs.corners[f * 3..f * 3 + 3];
                let uv: [&[f32]; 3] = std::array::from_fn(|k| uvs.row(b, rows[k] as usize));
                d.verts.push(mesh.face(f).map(|v| v as u32));
                d.uv_rows.push(std::array::from_fn(|k| rows[k] as u32));
                d.uv_values.push(uv.map(|x| [x[0], x[1]]));
                d.uv.push(UvPlanes::new(&planes, uv));
                d.planes.push(planes);
            }
        }
        d
    }

    /// The index among the drawn faces of face `f` of the fragments (`f >= 0`), or an error naming `face_index`
    /// where it is not one of them (fragments other than those the planes were built from).
    #[inline(always)]
    fn slot_of(&self, f: i32) -> Result<usize> {
        match self.slot.get(f as usize) {
            Some(&s) if (s as usize) < self.uv.len() => Ok(s as usize),
            _ => Err(RasterError::Parameter {
                arg: "face_index",
                message: format!(
                    "face {f} is not drawn in the fragments the UV planes were built from"
                ),
            }),
        }
    }
}

/// Checks the mesh, parameters, fragments, UVs (2 channels) and texture of [`sample_uv_texture`].
fn validate(
    mesh: &ScreenMesh<'_>,
    params: &RasterParams,
    face_index: &[i32],
    uvs: &CornerAttrs<'_>,
    texture: &Texture<'_>,
) -> Result<()> {
    mesh.validate()?;
    params.validate()?;
    check_face_index(face_index, mesh, params)?;
    if uvs.channels != 2 {
        return Err(RasterError::shape(
            uvs.arg,
            "(Bv, T, 2)",
            format!("{} channels", uvs.channels),
        ));
    }
    uvs.validate(mesh)?;
    check_texture_coordinates(uvs.arg, uvs.values.iter().map(|&x| x as f64))?;
    texture.validate(mesh.batch)
}

/// `(Bt, Ht, Wt, C)` of a texture.
fn texture_shape(texture: &Texture<'_>) -> [usize; 4] {
    [
        texture.batch,
        texture.height,
        texture.width,
        texture.channels,
    ]
}

/// The checked inputs of a textured pass and the UV planes of the faces drawn in its fragments, built once
/// ([`UvTexturePlanes::new`]) for the forward ([`UvTexturePlanes::sample`]) and the backward
/// ([`UvTexturePlanes::backward`]) alike: neither checks the mesh, UVs and texels again nor rebuilds the planes.
/// The fragments and the texture given to those two must be the ones given to `new` (their shapes are checked; a
/// face of the fragments that `new` did not see drawn is an error naming `face_index`).
#[derive(Debug)]
pub struct UvTexturePlanes {
    params: RasterParams,
    num_verts: usize,
    /// `(Bv, T)` of the UVs.
    uv_shape: [usize; 2],
    texture_shape: [usize; 4],
    /// Per batch element.
    elements: Vec<DrawnFaces>,
}

impl UvTexturePlanes {
    /// Checks the inputs of [`sample_uv_texture`] (the same arguments, the same errors) and builds the drawn faces'
    /// planes.
    pub fn new(
        mesh: &ScreenMesh<'_>,
        params: &RasterParams,
        face_index: &[i32],
        uvs: &CornerAttrs<'_>,
        texture: &Texture<'_>,
    ) -> Result<UvTexturePlanes> {
        validate(mesh, params, face_index, uvs, texture)?;
        let hw = params.pixels();
        let elements = (0..mesh.batch)
            .into_par_iter()
            .map(|b| DrawnFaces::new(mesh, params, uvs, b, &face_index[b * hw..(b + 1) * hw]))
            .collect();
        Ok(UvTexturePlanes {
            params: *params,
            num_verts: mesh.num_verts,
            uv_shape: [uvs.batch, uvs.rows],
            texture_shape: texture_shape(texture),
            elements,
        })
    }

    /// `(Bv, T)` of the UVs given to [`UvTexturePlanes::new`]: the shape of their gradient is `(Bv, T, 2)`.
    pub fn uv_shape(&self) -> [usize; 2] {
        self.uv_shape
    }

    /// `N`, the vertices per batch element of the mesh given to [`UvTexturePlanes::new`].
    pub fn num_verts(&self) -> usize {
        self.num_verts
    }

    /// Checks that `face_index` and `texture` have the shapes of those given to [`UvTexturePlanes::new`] and that
    /// `isa` is available.
    fn check(&self, isa: Isa, face_index: &[i32], texture: &Texture<'_>) -> Result<()> {
        isa.check()?;
        let (b, h, w) = (self.elements.len(), self.params.height, self.params.width);
        if face_index.len() != b * h * w {
            return Err(RasterError::shape(
                "face_index",
                format!("({b}, {h}, {w}) as given to the UV planes"),
                format!("{} values", face_index.len()),
            ));
        }
        let shape = texture_shape(texture);
        if shape != self.texture_shape || texture.texels.len() != shape.iter().product() {
            return Err(RasterError::shape(
                "texture",
                format!("{:?} as given to the UV planes", self.texture_shape),
                format!("{shape:?} with {} values", texture.texels.len()),
            ));
        }
        Ok(())
    }

    /// [`sample_uv_texture`] of the inputs given to [`UvTexturePlanes::new`] (`face_index` and `texture` again) on
    /// the instruction set `isa` (every choice gives the same bits; one this CPU lacks is an error naming `isa`).
    pub fn sample(&self, isa: Isa, face_index: &[i32], texture: &Texture<'_>) -> Result<Vec<f32>> {
        self.check(isa, face_index, texture)?;
        let (c, w, h) = (texture.channels, self.params.width, self.params.height);
        let mut out = try_filled_vec(face_index.len() * c, 0f32, "textured image")?;
        out.par_chunks_mut(w * c)
            .zip(face_index.par_chunks(w))
            .enumerate()
            .try_for_each(|(line, (dst, fi))| {
                let b = line / h;
                let (tex, drawn) = (texture.element(b), &self.elements[b]);
                let v = (line % h) as f64;
                with_channels!(c, C => sample_line_on::<C>(isa, &tex, drawn, fi, v, dst))
            })?;
        Ok(out)
    }

    /// [`sample_uv_texture_backward`] of the inputs given to [`UvTexturePlanes::new`] (`face_index` and `texture`
    /// again) for the cotangent `grad` `(B, H, W, C)`, on the instruction set `isa` (as [`UvTexturePlanes::sample`]).
    pub fn backward(
        &self,
        isa: Isa,
        face_index: &[i32],
        texture: &Texture<'_>,
        grad: &[f32],
    ) -> Result<UvTextureGradients> {
        self.check(isa, face_index, texture)?;
        let c = texture.channels;
        check_pixel_grad(grad, c, self.elements.len(), &self.params)?;
        let (hw, nv) = (self.params.pixels(), self.num_verts);
        let mut grad_verts_screen =
            try_filled_vec(self.elements.len() * nv * 3, 0f32, "grad_verts_screen")?;
        let parts: Vec<ElementGrads> = grad_verts_screen
            .par_chunks_mut(nv * 3)
            .enumerate()
            .map(|(b, gv)| {
                let fi = &face_index[b * hw..(b + 1) * hw];
                let g = &grad[b * hw * c..(b + 1) * hw * c];
                let tex = texture.element(b);
                with_channels!(c, C => element_backward_on::<C>(isa, self, b, fi, &tex, g, gv))
            })
            .collect::<Result<_>>()?;
        // Shared values: the elements' sums added in batch order; per-element values: concatenated.
        let sum_parts = |shared: bool, get: &dyn Fn(&ElementGrads) -> &[f64]| -> Vec<f32> {
            if shared && parts.len() > 1 {
                let mut sum = get(&parts[0]).to_vec();
                for part in &parts[1..] {
                    for (s, &x) in sum.iter_mut().zip(get(part)) {
                        *s += x;
                    }
                }
                sum.iter().map(|&x| x as f32).collect()
            } else if parts.len() == 1 {
                get(&parts[0]).iter().map(|&x| x as f32).collect()
            } else {
                parts.iter().flat_map(get).map(|&x| x as f32).collect()
            }
        };
        Ok(UvTextureGradients {
            grad_texels: sum_parts(texture.batch == 1, &|p| &p.texels),
            grad_uvs: sum_parts(self.uv_shape[0] == 1, &|p| &p.uvs),
            grad_verts_screen,
        })
    }
}

/// The texture sampled at each pixel's perspective-correct UV: `(B, H, W, C)`, 0 on background, for the fragments
/// `face_index` of a forward pass with the same `mesh` and `params`, the per-corner UVs `uvs` (2 channels) and
/// `texture` `(Bt, Ht, Wt, C)`. Errors name the argument at fault: among them, UVs that are not finite or beyond
/// [`crate::texture::MAX_TEXTURE_COORDINATE`] in magnitude. A forward followed by its backward builds the planes
/// once with [`UvTexturePlanes`].
///
/// ```
/// use meshadv_raster::{rasterize_fragments, RasterParams, ScreenMesh};
/// use meshadv_raster::surface::CornerAttrs;
/// use meshadv_raster::textured::sample_uv_texture;
/// use meshadv_raster::texture::{Texture, Wrap};
/// let verts = [-1.0f32, -1.0, 2.0, 1.0, -1.0, 2.0, -1.0, 1.0, 2.0];
/// let mesh = ScreenMesh::new(&verts, &[0, 1, 2], 1, 3).unwrap();
/// let params = RasterParams::new(4, 4, 0.1, 10.0);
/// let frags = rasterize_fragments(&mesh, &params).unwrap();
/// // Every corner at the same UV: the texel there everywhere on the face.
/// let uvs = CornerAttrs { values: &[0.25, 0.75], corners: &[0, 0, 0], batch: 1, rows: 1, channels: 2, arg: "uvs" };
/// let tex = Texture { texels: &[0.1, 0.2, 0.3, 0.4], batch: 1, height: 2, width: 2, channels: 1, wrap: Wrap::Repeat };
/// let out = sample_uv_texture(&mesh, &params, &frags.face_index, &uvs, &tex).unwrap();
/// assert_eq!(out[12], 0.1); // the bottom-left pixel: the top-left texel
/// assert_eq!(out[3], 0.0); // background
/// ```
pub fn sample_uv_texture(
    mesh: &ScreenMesh<'_>,
    params: &RasterParams,
    face_index: &[i32],
    uvs: &CornerAttrs<'_>,
    texture: &Texture<'_>,
) -> Result<Vec<f32>> {
    sample_uv_texture_on(Isa::detect(), mesh, params, face_index, uvs, texture)
}

/// [`sample_uv_texture`] on the instruction set `isa` (for tests and benchmarks: every choice gives the same bits).
/// An `isa` this CPU lacks is an error naming the argument.
pub fn sample_uv_texture_on(
    isa: Isa,
    mesh: &ScreenMesh<'_>,
    params: &RasterParams,
    face_index: &[i32],
    uvs: &CornerAttrs<'_>,
    texture: &Texture<'_>,
) -> Result<Vec<f32>> {
    isa.check()?;
    UvTexturePlanes::new(mesh, params, face_index, uvs, texture)?.sample(isa, face_index, texture)
}

/// [`sample_line`] compiled for `isa` (AVX2 where it is AVX2 or wider; the same bits: no fused multiply-adds).
fn sample_line_on<const C: usize>(
    isa: Isa,
    tex: &Texture<'_>,
    drawn: &DrawnFaces,
    fi: &[i32],
    v: f64,
    dst: &mut [f32],
) -> Result<()> {
    /// # Safety
    /// The CPU must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[allow(unsafe_code)]
    unsafe fn avx2<const C: usize>(
        tex: &Texture<'_>,
        drawn: &DrawnFaces,
        fi: &[i32],
        v: f64,
        dst: &mut [f32],
    ) -> Result<()> {
        sample_line::<C>(tex, drawn, fi, v, dst)
    }
    #[cfg(target_arch = "x86_64")]
    if isa >= Isa::Avx2 {
        // SAFETY: `isa` is available on this CPU.
        #[allow(unsafe_code)]
        return unsafe { avx2::<C>(tex, drawn, fi, v, dst) };
    }
    sample_line::<C>(tex, drawn, fi, v, dst)
}

/// [`sample_uv_texture`] of one image line (row `v`, fragments `fi`) into `dst` (background pixels are left as
/// they are); `C` channels (0: any count).
#[inline(always)]
fn sample_line<const C: usize>(
    tex: &Texture<'_>,
    drawn: &DrawnFaces,
    fi: &[i32],
    v: f64,
    dst: &mut [f32],
) -> Result<()> {
    let c = if C == 0 { tex.channels } else { C };
    for (start, end, f) in runs(fi) {
        if f < 0 {
            continue;
        }
        let row = drawn.uv[drawn.slot_of(f)?].row(v);
        // Along the run the planes are stepped by their slopes, as in the backward pass.
        let (mut p, step) = (row.at(start as f64), row.step());
        for px in dst[start * c..end * c].chunks_exact_mut(c) {
            let (_, s, t) = uv_and_step(&mut p, &step);
            tex.sample_into::<C>(s, t, px);
        }
    }
    Ok(())
}

/// Gradients of [`sample_uv_texture`].
#[derive(Debug, Clone, PartialEq)]
pub struct UvTextureGradients {
    /// `(Bt, Ht, Wt, C)` gradient with respect to the texels.
    pub grad_texels: Vec<f32>,
    /// `(Bv, T, 2)` gradient with respect to the UV values.
    pub grad_uvs: Vec<f32>,
    /// `(B, N, 3)` gradient with respect to `verts_screen` (x, y and z) at fixed face assignment.
    pub grad_verts_screen: Vec<f32>,
}

/// One batch element's share of [`UvTextureGradients`] (f64 sums; the texels and UVs of that element's texture
/// and UV rows).
struct ElementGrads {
    texels: Vec<f64>,
    uvs: Vec<f64>,
}

/// Backward of [`sample_uv_texture`] for the cotangent `grad` `(B, H, W, C)`: exact gradients to the texels, the
/// UV values and the screen-space vertices (the UVs moving with the vertices at fixed face assignment).
pub fn sample_uv_texture_backward(
    mesh: &ScreenMesh<'_>,
    params: &RasterParams,
    face_index: &[i32],
    uvs: &CornerAttrs<'_>,
    texture: &Texture<'_>,
    grad: &[f32],
) -> Result<UvTextureGradients> {
    sample_uv_texture_backward_on(Isa::detect(), mesh, params, face_index, uvs, texture, grad)
}

/// [`sample_uv_texture_backward`] on the instruction set `isa` (for tests and benchmarks: every choice gives the
/// same bits). An `isa` this CPU lacks is an error naming the argument.
pub fn sample_uv_texture_backward_on(
    isa: Isa,
    mesh: &ScreenMesh<'_>,
    params: &RasterParams,
    face_index: &[i32],
    uvs: &CornerAttrs<'_>,
    texture: &Texture<'_>,
    grad: &[f32],
) -> Result<UvTextureGradients> {
    isa.check()?;
    UvTexturePlanes::new(mesh, params, face_index, uvs, texture)?
        .backward(isa, face_index, texture, grad)
}

/// [`element_backward`] compiled for `isa` (AVX2 where it is AVX2 or wider; the same bits).
fn element_backward_on<const C: usize>(
    isa: Isa,
    planes: &UvTexturePlanes,
    b: usize,
    fi: &[i32],
    tex: &Texture<'_>,
    grad: &[f32],
    gv: &mut [f32],
) -> Result<ElementGrads> {
    /// # Safety
    /// The CPU must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[allow(unsafe_code)]
    unsafe fn avx2<const C: usize>(
        planes: &UvTexturePlanes,
        b: usize,
        fi: &[i32],
        tex: &Texture<'_>,
        grad: &[f32],
        gv: &mut [f32],
    ) -> Result<ElementGrads> {
        element_backward::<C>(planes, b, fi, tex, grad, gv)
    }
    #[cfg(target_arch = "x86_64")]
    if isa >= Isa::Avx2 {
        // SAFETY: `isa` is available on this CPU.
        #[allow(unsafe_code)]
        return unsafe { avx2::<C>(planes, b, fi, tex, grad, gv) };
    }
    element_backward::<C>(planes, b, fi, tex, grad, gv)
}

/// [`UvTexturePlanes::backward`] of batch element `b` (fragments `fi`, its texture `tex`, cotangent `grad`): its
/// vertex gradient into `gv` `(N, 3)`, its texel and UV sums returned; `C` channels (0: any count).
#[inline(always)]
fn element_backward<const C: usize>(
    planes: &UvTexturePlanes,
    b: usize,
    fi: &[i32],
    tex: &Texture<'_>,
    grad: &[f32],
    gv: &mut [f32],
) -> Result<ElementGrads> {
    let c = if C == 0 { tex.channels } else { C };
    let (drawn, params) = (&planes.elements[b], &planes.params);
    // One value more than the texels: 3-channel texels are added to four at a time.
    let mut texels = try_filled_vec(tex.texels.len() + 1, 0f64, "texture gradient accumulator")?;
    // Per drawn face, summed over its pixels: dL/dQ, dL/dN_u and dL/dN_v, each times (1, u, v); along a line, over
    // each run of pixels of one face first (the row v is constant there).
    let mut sums = vec![[[0f64; 3]; 3]; drawn.uv.len()];
    for (row, (fi, grad)) in fi
        .chunks_exact(params.width)
        .zip(grad.chunks_exact(params.width * c))
        .enumerate()
    {
        let v = row as f64;
        for (start, end, f) in runs(fi) {
            if f < 0 {
                continue;
            }
            let slot = drawn.slot_of(f)?;
            let line = drawn.uv[slot].row(v);
            let mut run = [[0f64; 2]; 3];
            // The planes stepped along the run by their slopes, as in the forward pass.
            let (mut p, step) = (line.at(start as f64), line.step());
            let mut u = start as f64;
            for g in grad[start * c..end * c].chunks_exact(c) {
                let (inv, s, t) = uv_and_step(&mut p, &step);
                let [gs, gt] = tex.sample_backward_into::<C>(s, t, g, &mut texels);
                // uv = N / Q.
                let (gnu, gnv) = (gs * inv, gt * inv);
                let gq = -(gnu * s + gnv * t);
                for (r, x) in run.iter_mut().zip([gq, gnu, gnv]) {
                    r[0] += x;
                    r[1] += x * u;
                }
                u += 1.0;
            }
            for (a, r) in sums[slot].iter_mut().zip(&run) {
                a[0] += r[0];
                a[1] += r[1];
                a[2] += r[0] * v;
            }
        }
    }
    let mut uv_sums = try_filled_vec(planes.uv_shape[1] * 2, 0f64, "UV gradient accumulator")?;
    let mut vertex_sums =
        try_filled_vec(planes.num_verts * 3, 0f64, "vertex gradient accumulator")?;
    for (i, (a, pl)) in sums.iter().zip(&drawn.planes).enumerate() {
        let uv = &drawn.uv_values[i];
        // dL/dq_k = dL/dQ + uv_k . dL/dN (Q is 1 in orthographic projection, not a function of the q_k).
        let gq: [[f64; 3]; 3] = std::array::from_fn(|k| {
            let (x, y) = (uv[k][0] as f64, uv[k][1] as f64);
            std::array::from_fn(|i| {
                let q = if pl.ortho { 0.0 } else { a[0][i] };
                q + x * a[1][i] + y * a[2][i]
            })
        });
        let verts = drawn.verts[i].map(|v| v as usize);
        add_to_vertices(verts, &pl.vertex_grads(&gq, params), &mut vertex_sums);
        // dL/duv_k = sum_P (q_k / Q) dL/duv = sum_P q_k dL/dN.
        for (k, &r) in drawn.uv_rows[i].iter().enumerate() {
            let q = pl.numerator(k);
            uv_sums[r as usize * 2] += dot3(&q, &a[1]);
            uv_sums[r as usize * 2 + 1] += dot3(&q, &a[2]);
        }
    }
    for (d, &s) in gv.iter_mut().zip(&vertex_sums) {
        *d = s as f32;
    }
    texels.truncate(tex.texels.len());
    Ok(ElementGrads {
        texels,
        uvs: uv_sums,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::input::Projection;
    use crate::parallel::with_threads;
    use crate::raster::rasterize_fragments;
    use crate::surface::{interpolate, pixel_weights};
    use crate::test_rng::Rng;
    use crate::texture::Wrap;

    /// A few random overlapping triangles in front of the camera, `batch` views of them (moved a little).
    fn scene(rng: &mut Rng, faces: usize, batch: usize) -> (Vec<f32>, Vec<i32>) {
        let base: Vec<f32> = (0..faces * 3)
            .flat_map(|_| {
                [
                    (rng.next() * 1.6 - 0.8) as f32,
                    (rng.next() * 1.6 - 0.8) as f32,
                    (1.0 + rng.next() * 3.0) as f32,
                ]
            })
            .collect();
        let verts = (0..batch)
            .flat_map(|b| {
                base.iter()
                    .enumerate()
                    .map(move |(i, &x)| x + (b * (i % 3)) as f32 * 0.01)
            })
            .collect();
        (verts, (0..faces as i32 * 3).collect())
    }

    struct Case {
        verts: Vec<f32>,
        faces: Vec<i32>,
        batch: usize,
        params: RasterParams,
        face_index: Vec<i32>,
        uv_values: Vec<f32>,
        uv_corners: Vec<i32>,
        uv_rows: usize,
        texels: Vec<f32>,
        tex_batch: usize,
        wrap: Wrap,
    }

    impl Case {
        fn new(rng: &mut Rng, batch: usize, tex_batch: usize, projection: Projection) -> Case {
            let (verts, faces) = scene(rng, 5, batch);
            let mut params = RasterParams::new(23, 27, 0.1, 10.0);
            params.projection = projection;
            let mesh =
                ScreenMesh::new(&verts, &faces, batch, verts.len() / 3 / batch).expect("mesh");
            let face_index = rasterize_fragments(&mesh, &params)
                .expect("raster")
                .face_index;
            let uv_rows = 7;
            let uv_corners = (0..faces.len())
                .map(|_| rng.below(uv_rows) as i32)
                .collect();
            let uv_values = (0..uv_rows * 2)
                .map(|_| (rng.next() * 0.6 + 0.2) as f32)
                .collect();
            // A ramp plus a little noise, clamped, UVs inside: the blend's kinks at texel centre lines stay small for
            // the differences.
            let (h, w) = (6, 5);
            let texels = (0..tex_batch * h * w * 3)
                .map(|i| {
                    ((i / 3) % w) as f32 * 0.2
                        + ((i / 3 / w) % h) as f32 * 0.1
                        + rng.next() as f32 * 0.05
                })
                .collect();
            Case {
                verts,
                faces,
                batch,
                params,
                face_index,
                uv_values,
                uv_corners,
                uv_rows,
                texels,
                tex_batch,
                wrap: Wrap::Clamp,
            }
        }

        fn mesh<'a>(&'a self, verts: &'a [f32]) -> ScreenMesh<'a> {
            ScreenMesh::new(verts, &self.faces, self.batch, verts.len() / 3 / self.batch)
                .expect("mesh")
        }

        fn uvs<'a>(&'a self, values: &'a [f32]) -> CornerAttrs<'a> {
            CornerAttrs {
                values,
                corners: &self.uv_corners,
                batch: 1,
                rows: self.uv_rows,
                channels: 2,
                arg: "uvs",
            }
        }

        fn texture<'a>(&self, texels: &'a [f32]) -> Texture<'a> {
            Texture {
                texels,
                batch: self.tex_batch,
                height: 6,
                width: 5,
                channels: 3,
                wrap: self.wrap,
            }
        }

        fn forward(&self, verts: &[f32], uvs: &[f32], texels: &[f32]) -> Vec<f32> {
            sample_uv_texture(
                &self.mesh(verts),
                &self.params,
                &self.face_index,
                &self.uvs(uvs),
                &self.texture(texels),
            )
            .expect("forward")
        }

        fn backward(&self, grad: &[f32]) -> UvTextureGradients {
            sample_uv_texture_backward(
                &self.mesh(&self.verts),
                &self.params,
                &self.face_index,
                &self.uvs(&self.uv_values),
                &self.texture(&self.texels),
                grad,
            )
            .expect("backward")
        }
    }

    fn dot(a: &[f32], b: &[f32]) -> f64 {
        a.iter().zip(b).map(|(x, y)| *x as f64 * *y as f64).sum()
    }

    #[test]
    fn equals_sampling_at_the_interpolated_uvs() {
        let mut rng = Rng(5);
        for (projection, wrap) in [
            (Projection::Perspective, Wrap::Repeat),
            (Projection::Orthographic, Wrap::Clamp),
        ] {
            let mut case = Case::new(&mut rng, 2, 2, projection);
            case.wrap = wrap;
            // UVs beyond [0, 1]: wrapped or clamped texel indices.
            case.uv_values.iter_mut().for_each(|x| *x = *x * 3.0 - 1.0);
            let mesh = case.mesh(&case.verts);
            let got = case.forward(&case.verts, &case.uv_values, &case.texels);
            let w = pixel_weights(&mesh, &case.params, &case.face_index).expect("weights");
            let uv = interpolate(
                &mesh,
                &case.params,
                &case.face_index,
                &w,
                &case.uvs(&case.uv_values),
            )
            .expect("uv");
            let tex = case.texture(&case.texels);
            let hw = case.params.pixels();
            let mut drawn = 0;
            for (p, &f) in case.face_index.iter().enumerate() {
                let px = &got[p * 3..p * 3 + 3];
                if f < 0 {
                    assert_eq!(px, &[0.0; 3]);
                    continue;
                }
                drawn += 1;
                let want = tex
                    .sample(p / hw, [uv[2 * p] as f64, uv[2 * p + 1] as f64])
                    .expect("sample");
                for (a, b) in px.iter().zip(&want) {
                    assert!((a - b).abs() < 1e-4, "{projection:?} pixel {p}: {a} vs {b}");
                }
            }
            assert!(drawn > 200);
        }
    }

    #[test]
    fn gradients_match_finite_differences() {
        let mut rng = Rng(11);
        for projection in [Projection::Perspective, Projection::Orthographic] {
            let case = Case::new(&mut rng, 2, 1, projection);
            let g: Vec<f32> = (0..case.face_index.len() * 3)
                .map(|_| (rng.next() - 0.5) as f32)
                .collect();
            let grads = case.backward(&g);
            // Linear in the texels: the gradient is the exact adjoint.
            let probe: Vec<f32> = (0..case.texels.len())
                .map(|_| (rng.next() - 0.5) as f32)
                .collect();
            let moved = case.forward(&case.verts, &case.uv_values, &probe);
            assert!((dot(&moved, &g) - dot(&probe, &grads.grad_texels)).abs() < 1e-4);
            let loss =
                |verts: &[f32], uvs: &[f32]| dot(&case.forward(verts, uvs, &case.texels), &g);
            let h = 1e-3f32;
            for i in 0..case.uv_values.len() {
                let (mut a, mut b) = (case.uv_values.clone(), case.uv_values.clone());
                a[i] += h;
                b[i] -= h;
                let fd = (loss(&case.verts, &a) - loss(&case.verts, &b)) / (2.0 * h as f64);
                let got = grads.grad_uvs[i] as f64;
                assert!(
                    (fd - got).abs() < 2e-2 * fd.abs().max(1.0),
                    "{projection:?} uv {i}: fd {fd} vs {got}"
                );
            }
            let h = 2e-4f32;
            let mut nonzero = 0;
            for i in 0..case.verts.len() {
                if projection == Projection::Orthographic && i % 3 == 2 {
                    assert_eq!(grads.grad_verts_screen[i], 0.0);
                    continue;
                }
                let (mut a, mut b) = (case.verts.clone(), case.verts.clone());
                a[i] += h;
                b[i] -= h;
                let fd = (loss(&a, &case.uv_values) - loss(&b, &case.uv_values)) / (2.0 * h as f64);
                let got = grads.grad_verts_screen[i] as f64;
                nonzero += (got != 0.0) as usize;
                assert!(
                    (fd - got).abs() < 2e-2 * fd.abs().max(1.0),
                    "{projection:?} coord {i}: fd {fd} vs {got}"
                );
            }
            assert!(nonzero > case.verts.len() / 3);
        }
    }

    #[test]
    fn results_are_bit_identical_for_any_thread_count() {
        let mut rng = Rng(2);
        let case = Case::new(&mut rng, 3, 1, Projection::Perspective);
        let g: Vec<f32> = (0..case.face_index.len() * 3)
            .map(|_| (rng.next() - 0.5) as f32)
            .collect();
        let run = |threads| {
            with_threads(threads, || {
                (
                    case.forward(&case.verts, &case.uv_values, &case.texels),
                    case.backward(&g),
                )
            })
            .expect("pool")
        };
        let (one, three) = (run(1), run(3));
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&one.0), bits(&three.0));
        assert_eq!(bits(&one.1.grad_texels), bits(&three.1.grad_texels));
        assert_eq!(bits(&one.1.grad_uvs), bits(&three.1.grad_uvs));
        assert_eq!(
            bits(&one.1.grad_verts_screen),
            bits(&three.1.grad_verts_screen)
        );
    }

    #[test]
    fn every_instruction_set_gives_the_same_bits() {
        let mut rng = Rng(9);
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        for (projection, wrap, channels) in [
            (Projection::Perspective, Wrap::Repeat, 3),
            (Projection::Perspective, Wrap::Clamp, 1),
            (Projection::Orthographic, Wrap::Repeat, 4),
            (Projection::Perspective, Wrap::Repeat, 5),
        ] {
            let mut case = Case::new(&mut rng, 2, 2, projection);
            // UVs beyond [0, 1]: wrapped or clamped texel indices.
            case.uv_values.iter_mut().for_each(|x| *x = *x * 3.0 - 1.0);
            let texels: Vec<f32> = (0..2 * 6 * 5 * channels)
                .map(|_| rng.next() as f32)
                .collect();
            let tex = Texture {
                channels,
                wrap,
                ..case.texture(&texels)
            };
            let g: Vec<f32> = (0..case.face_index.len() * channels)
                .map(|_| (rng.next() - 0.5) as f32)
                .collect();
            let (mesh, uvs, p, fi) = (
                case.mesh(&case.verts),
                case.uvs(&case.uv_values),
                &case.params,
                &case.face_index[..],
            );
            let run = |isa| {
                let image = sample_uv_texture_on(isa, &mesh, p, fi, &uvs, &tex).expect("forward");
                let grads = sample_uv_texture_backward_on(isa, &mesh, p, fi, &uvs, &tex, &g)
                    .expect("backward");
                [
                    image,
                    grads.grad_texels,
                    grads.grad_uvs,
                    grads.grad_verts_screen,
                ]
            };
            let portable = run(Isa::Portable);
            assert!(portable[0].iter().any(|&x| x != 0.0));
            assert!(portable[3].iter().any(|&x| x != 0.0));
            for isa in Isa::all_available() {
                for (got, want) in run(isa).iter().zip(&portable) {
                    assert_eq!(bits(got), bits(want), "{isa:?} {projection:?} {channels}");
                }
            }
        }
    }

    #[test]
    fn planes_built_once_serve_the_forward_and_the_backward() {
        let mut rng = Rng(4);
        let case = Case::new(&mut rng, 2, 1, Projection::Perspective);
        let (mesh, uvs, tex) = (
            case.mesh(&case.verts),
            case.uvs(&case.uv_values),
            case.texture(&case.texels),
        );
        let (p, fi) = (&case.params, &case.face_index[..]);
        let g: Vec<f32> = (0..fi.len() * 3)
            .map(|_| (rng.next() - 0.5) as f32)
            .collect();
        let planes = UvTexturePlanes::new(&mesh, p, fi, &uvs, &tex).expect("planes");
        let isa = Isa::detect();
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let image = planes.sample(isa, fi, &tex).expect("forward");
        assert_eq!(
            bits(&image),
            bits(&case.forward(&case.verts, &case.uv_values, &case.texels))
        );
        let (got, want) = (
            planes.backward(isa, fi, &tex, &g).expect("backward"),
            case.backward(&g),
        );
        assert_eq!(bits(&got.grad_texels), bits(&want.grad_texels));
        assert_eq!(bits(&got.grad_uvs), bits(&want.grad_uvs));
        assert_eq!(bits(&got.grad_verts_screen), bits(&want.grad_verts_screen));
        // Inputs other than those the planes were built from: errors naming them, no panic. Planes built without
        // the first drawn face, then the fragments with it; a face index beyond the mesh.
        let first = *fi.iter().find(|&&f| f >= 0).expect("a drawn pixel");
        let hidden: Vec<i32> = fi
            .iter()
            .map(|&f| if f == first { -1 } else { f })
            .collect();
        let without = UvTexturePlanes::new(&mesh, p, &hidden, &uvs, &tex).expect("planes");
        let mut beyond = fi.to_vec();
        beyond[fi.iter().position(|&f| f >= 0).expect("a drawn pixel")] = case.faces.len() as i32;
        for (planes, fi) in [(&without, fi), (&planes, &beyond[..])] {
            let e = planes.sample(isa, fi, &tex).expect_err("unseen face");
            assert!(e.to_string().starts_with("face_index"), "{e}");
            let e = planes.backward(isa, fi, &tex, &g).expect_err("unseen face");
            assert!(e.to_string().starts_with("face_index"), "{e}");
        }
        let e = planes.sample(isa, &fi[1..], &tex).expect_err("short map");
        assert!(e.to_string().starts_with("face_index"), "{e}");
        let small = Texture {
            texels: &case.texels[..case.texels.len() / 2],
            height: 3,
            ..tex
        };
        let e = planes
            .backward(isa, fi, &small, &g)
            .expect_err("other texture");
        assert!(e.to_string().starts_with("texture"), "{e}");
        let e = planes
            .backward(isa, fi, &tex, &g[1..])
            .expect_err("short cotangent");
        assert!(e.to_string().starts_with("grad"), "{e}");
    }

    #[test]
    fn bad_uvs_textures_and_cotangents_are_errors_naming_the_argument() {
        let mut rng = Rng(6);
        let case = Case::new(&mut rng, 1, 1, Projection::Perspective);
        let mesh = case.mesh(&case.verts);
        let (p, fi) = (&case.params, &case.face_index[..]);
        let tex = case.texture(&case.texels);
        let three = CornerAttrs {
            channels: 3,
            rows: 4,
            ..case.uvs(&case.uv_values[..12])
        };
        let e = sample_uv_texture(&mesh, p, fi, &three, &tex).expect_err("3 channels");
        assert!(e.to_string().starts_with("uvs"), "{e}");
        let mut nan = case.uv_values.clone();
        nan[3] = f32::NAN;
        let e = sample_uv_texture(&mesh, p, fi, &case.uvs(&nan), &tex).expect_err("NaN");
        assert!(e.to_string().starts_with("uvs"), "{e}");
        let empty = Texture {
            texels: &[],
            height: 0,
            ..tex
        };
        let e =
            sample_uv_texture(&mesh, p, fi, &case.uvs(&case.uv_values), &empty).expect_err("empty");
        assert!(e.to_string().starts_with("texture"), "{e}");
        let e = sample_uv_texture(&mesh, p, &fi[1..], &case.uvs(&case.uv_values), &tex)
            .expect_err("short map");
        assert!(e.to_string().starts_with("face_index"), "{e}");
        let g = vec![0f32; fi.len() * 3 - 1];
        let e = sample_uv_texture_backward(&mesh, p, fi, &case.uvs(&case.uv_values), &tex, &g)
            .expect_err("short");
        assert!(e.to_string().starts_with("grad"), "{e}");
    }
}
