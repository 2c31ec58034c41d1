//! The flat (per-face Lambert) render around the rasterizer: the camera projection of world-space vertices, the
//! shading of each face, the box filter of an antialiased render, and the adjoint of each, so that one forward and
//! one backward call do the whole render.
//!
//! Conventions (those of the Python package, `meshadv.render`):
//!
//! * projection: `v_view = R (v - eye)` (rows of `R` the view axes), then perspective
//!   `(x / (z_s * s), y / (z_s * s), z)` with `s = tan(fov / 2)` and `z_s = z` unless `|z| < 1e-12` (then `1e-12`),
//!   or orthographic `(x / s, y / s, z)` with `s` the half extent;
//! * shading: `n = c / max(|c|, 1e-12)` with `c = (v1 - v0) x (v2 - v0)`, flipped toward the camera when two-sided
//!   (perspective: `dot(n, eye - v0) < 0`; orthographic: `dot(n, R[2]) > 0`), then
//!   `clamp(colour * (ambient + sum_j light_j max(dot(n, d_j), 0)), 0, 1)` with unit directions `d_j`; the face's
//!   fourth attribute is 1 (the coverage channel).
//!
//! The forward values are rounded as PyTorch's CPU kernels round the same expressions (element by element, the
//! cross product and the norm with fused multiply-adds as its vectorised AVX2 / AVX-512 kernels compute them), so
//! on such CPUs this path and the PyTorch one give the same bits. The adjoints are computed in `f64` from the `f32`
//! inputs; the sign flip of two-sided normals is piecewise constant and carries no gradient, and a clamp passes the
//! gradient where its argument lies within its bounds, bounds included (PyTorch's rule).
//!
//! Every input with a batch axis has batch 1 (shared by every view) or `B`; gradients have the batch of their input
//! (summed over the views in increasing order when it is 1). Results do not depend on the thread count.

use rayon::prelude::*;

use crate::backward::{rasterize_backward, BackwardInputs, Visibility};
use crate::boxfilter::{box_downsample, box_spread, BoxShape};
use crate::error::{RasterError, Result};
use crate::input::{check_finite, validate_mesh_indices, FaceAttrs, RasterParams, ScreenMesh};
use crate::raster::rasterize;

/// The smallest `|z_view|` divided by in a perspective projection, and the smallest norm a normal is divided by.
const TINY: f32 = 1e-12;

/// Per-view cameras: `rotation` `(Bk, 3, 3)` world-to-view (rows the view axes), `eye` `(Bk, 3)` and `scale` `(Bk,)`
/// (`tan(fov / 2)`, or the orthographic half extent).
#[derive(Debug, Clone, Copy)]
pub struct FlatCamera<'a> {
    /// Flat `(Bk, 3, 3)` rotations.
    pub rotation: &'a [f32],
    /// Flat `(Bk, 3)` eye positions.
    pub eye: &'a [f32],
    /// `(Bk,)` projection scales.
    pub scale: &'a [f32],
    /// Orthographic projection (else perspective).
    pub orthographic: bool,
}

/// Per-view light sets: `K` directional lights of unit `directions` `(Bl, K, 3)` (toward the light) and `colors`
/// `(Bl, K, 3)`, and `ambient` `(Bl, 3)`.
#[derive(Debug, Clone, Copy)]
pub struct FlatLights<'a> {
    /// Flat `(Bl, K, 3)` unit directions.
    pub directions: &'a [f32],
    /// Flat `(Bl, K, 3)` RGB intensities.
    pub colors: &'a [f32],
    /// Flat `(Bl, 3)` RGB ambient intensities.
    pub ambient: &'a [f32],
    /// Lights per set `K`.
    pub count: usize,
}

/// A batch of `batch` views of a world-space mesh with per-face reflectances.
#[derive(Debug, Clone, Copy)]
pub struct FlatScene<'a> {
    /// Flat `(Bv, N, 3)` world-space vertices.
    pub verts: &'a [f32],
    /// Vertex count `N`.
    pub num_verts: usize,
    /// Flat `(M, 3)` vertex indices.
    pub faces: &'a [i32],
    /// Flat `(Bc, M, 3)` reflectances.
    pub colors: &'a [f32],
    /// The cameras.
    pub camera: FlatCamera<'a>,
    /// The lights.
    pub lights: FlatLights<'a>,
    /// Views `B`.
    pub batch: usize,
    /// Flip normals toward the camera before shading.
    pub two_sided: bool,
}

/// Gradients of a [`FlatScene`]'s inputs, flat, each with its input's batch.
#[derive(Debug, Clone, PartialEq)]
pub struct FlatGradients {
    /// `(Bv, N, 3)`.
    pub verts: Vec<f32>,
    /// `(Bc, M, 3)`.
    pub colors: Vec<f32>,
    /// `(Bk, 3, 3)`.
    pub rotation: Vec<f32>,
    /// `(Bk, 3)`.
    pub eye: Vec<f32>,
    /// `(Bk,)`.
    pub scale: Vec<f32>,
    /// `(Bl, K, 3)`.
    pub light_directions: Vec<f32>,
    /// `(Bl, K, 3)`.
    pub light_colors: Vec<f32>,
    /// `(Bl, 3)`.
    pub ambient: Vec<f32>,
}

/// The batch of an input holding `len` values of `per_view` each: 1 or `batch`, else an error naming `arg`.
fn batch_of(
    arg: &'static str,
    len: usize,
    per_view: usize,
    batch: usize,
    shape: &str,
) -> Result<usize> {
    for b in [1, batch] {
        if per_view > 0 && len == b * per_view || per_view == 0 && len == 0 {
            return Ok(b);
        }
    }
    Err(RasterError::shape(
        arg,
        format!("(1, {shape}) or ({batch}, {shape})"),
        format!("{len} values"),
    ))
}

/// Index of view `b`'s entry in an input of batch `n` (1: shared).
#[inline]
fn at(b: usize, n: usize) -> usize {
    if n == 1 {
        0
    } else {
        b
    }
}

/// The batch sizes `(Bv, Bc, Bk, Bl)` of a validated scene.
#[derive(Debug, Clone, Copy)]
struct Batches {
    verts: usize,
    colors: usize,
    camera: usize,
    lights: usize,
}

impl FlatScene<'_> {
    /// Number of faces `M`.
    pub fn num_faces(&self) -> usize {
        self.faces.len() / 3
    }

    /// Checks shapes (each batch 1 or `B`), finiteness and face indices.
    pub fn validate(&self) -> Result<()> {
        self.batches().map(|_| ())
    }

    fn batches(&self) -> Result<Batches> {
        let (n, b, k) = (self.num_verts, self.batch, self.lights.count);
        if b == 0 {
            return Err(RasterError::shape(
                "verts",
                "a batch of at least one view",
                "B = 0",
            ));
        }
        if n == 0 || self.faces.is_empty() {
            return Err(RasterError::EmptyMesh { arg: "verts" });
        }
        if !self.faces.len().is_multiple_of(3) {
            return Err(RasterError::shape(
                "faces",
                "(M, 3)",
                format!("{} values", self.faces.len()),
            ));
        }
        let m = self.num_faces();
        let batches = Batches {
            verts: batch_of("verts", self.verts.len(), n * 3, b, &format!("{n}, 3"))?,
            colors: batch_of(
                "face_colors",
                self.colors.len(),
                m * 3,
                b,
                &format!("{m}, 3"),
            )?,
            camera: batch_of("rotation", self.camera.rotation.len(), 9, b, "3, 3")?,
            lights: batch_of("ambient", self.lights.ambient.len(), 3, b, "3")?,
        };
        let bk = batches.camera;
        if self.camera.eye.len() != bk * 3 {
            return Err(RasterError::shape(
                "eye",
                format!("({bk}, 3)"),
                format!("{} values", self.camera.eye.len()),
            ));
        }
        if self.camera.scale.len() != bk {
            return Err(RasterError::shape(
                "scale",
                format!("({bk},)"),
                format!("{} values", self.camera.scale.len()),
            ));
        }
        let bl = batches.lights;
        for (arg, arr) in [
            ("light_directions", self.lights.directions),
            ("light_colors", self.lights.colors),
        ] {
            if arr.len() != bl * k * 3 {
                return Err(RasterError::shape(
                    arg,
                    format!("({bl}, {k}, 3)"),
                    format!("{} values", arr.len()),
                ));
            }
        }
        validate_mesh_indices("faces", self.faces, n)?;
        for (arg, arr) in [
            ("verts", self.verts),
            ("face_colors", self.colors),
            ("rotation", self.camera.rotation),
            ("eye", self.camera.eye),
            ("scale", self.camera.scale),
            ("light_directions", self.lights.directions),
            ("light_colors", self.lights.colors),
            ("ambient", self.lights.ambient),
        ] {
            check_finite(arg, arr)?;
        }
        if let Some(i) = self.camera.scale.iter().position(|&s| s <= 0.0) {
            return Err(RasterError::Parameter {
                arg: "scale",
                message: format!("must be > 0, got {} for view {i}", self.camera.scale[i]),
            });
        }
        Ok(batches)
    }

    fn vert(&self, bv: usize, i: usize) -> [f32; 3] {
        let o = (bv * self.num_verts + i) * 3;
        [self.verts[o], self.verts[o + 1], self.verts[o + 2]]
    }

    fn rotation(&self, bk: usize) -> &[f32] {
        &self.camera.rotation[bk * 9..bk * 9 + 9]
    }

    fn eye(&self, bk: usize) -> [f32; 3] {
        let e = &self.camera.eye[bk * 3..bk * 3 + 3];
        [e[0], e[1], e[2]]
    }
}

/// `R (v - eye)` of one point, rounded as `meshadv.render.Camera.world_to_view`.
#[inline]
fn to_view(v: [f32; 3], eye: [f32; 3], r: &[f32]) -> [f32; 3] {
    let d = [v[0] - eye[0], v[1] - eye[1], v[2] - eye[2]];
    let row = |m: usize| d[0] * r[3 * m] + d[1] * r[3 * m + 1] + d[2] * r[3 * m + 2];
    [row(0), row(1), row(2)]
}

/// `|z|` clamped away from zero for the perspective division (`1e-12` when `|z| < 1e-12`).
#[inline]
fn safe_depth(z: f32) -> f32 {
    if z.abs() < TINY {
        TINY
    } else {
        z
    }
}

/// Screen-space `(x_ndc, y_ndc, z_view)` of every vertex in every view: `(B, N, 3)`.
pub fn project(scene: &FlatScene<'_>) -> Result<Vec<f32>> {
    let bt = scene.batches()?;
    let n = scene.num_verts;
    let mut out = vec![0f32; scene.batch * n * 3];
    out.par_chunks_mut(n * 3).enumerate().for_each(|(b, view)| {
        let (bv, bk) = (at(b, bt.verts), at(b, bt.camera));
        let (r, eye, s) = (scene.rotation(bk), scene.eye(bk), scene.camera.scale[bk]);
        for (i, p) in view.chunks_exact_mut(3).enumerate() {
            let [x, y, z] = to_view(scene.vert(bv, i), eye, r);
            let den = if scene.camera.orthographic {
                s
            } else {
                safe_depth(z) * s
            };
            p.copy_from_slice(&[x / den, y / den, z]);
        }
    });
    Ok(out)
}

/// `(v1 - v0) x (v2 - v0)` rounded as PyTorch's vectorised `torch.cross` (`a_i b_j - a_j b_i` as one fused
/// multiply-add of the rounded second product).
#[inline]
fn cross_rounded(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    let c = |i: usize, j: usize| a[i].mul_add(b[j], -(a[j] * b[i]));
    [c(1, 2), c(2, 0), c(0, 1)]
}

/// The face's unnormalised normal `c`, its unit normal before the flip and the flip's sign.
struct FaceNormal {
    c: [f32; 3],
    norm: f32,
    n: [f32; 3],
    sign: f32,
}

/// Face `f`'s normal in view `b` (vertex batch `bv`, camera batch `bk`) and its edges `v1 - v0`, `v2 - v0`.
fn face_normal(
    scene: &FlatScene<'_>,
    bv: usize,
    bk: usize,
    f: usize,
) -> (FaceNormal, [[f32; 3]; 2]) {
    let t = &scene.faces[3 * f..3 * f + 3];
    let v = [
        scene.vert(bv, t[0] as usize),
        scene.vert(bv, t[1] as usize),
        scene.vert(bv, t[2] as usize),
    ];
    let e1 = [v[1][0] - v[0][0], v[1][1] - v[0][1], v[1][2] - v[0][2]];
    let e2 = [v[2][0] - v[0][0], v[2][1] - v[0][1], v[2][2] - v[0][2]];
    let c = cross_rounded(e1, e2);
    // torch.linalg.vector_norm: the squares summed by fused multiply-adds, in order.
    let norm = c[2].mul_add(c[2], c[1].mul_add(c[1], c[0] * c[0])).sqrt();
    let s = norm.max(TINY);
    let n = [c[0] / s, c[1] / s, c[2] / s];
    let mut sign = 1.0;
    if scene.two_sided {
        let facing = if scene.camera.orthographic {
            let r = scene.rotation(bk);
            n[0] * -r[6] + n[1] * -r[7] + n[2] * -r[8]
        } else {
            let eye = scene.eye(bk);
            n[0] * (eye[0] - v[0][0]) + n[1] * (eye[1] - v[0][1]) + n[2] * (eye[2] - v[0][2])
        };
        if facing < 0.0 {
            sign = -1.0;
        }
    }
    (FaceNormal { c, norm, n, sign }, [e1, e2])
}

/// `cos_j = max(dot(n, d_j), 0)` before the clamp, for light `j` of set `bl`.
#[inline]
fn light_dot(scene: &FlatScene<'_>, bl: usize, j: usize, n: [f32; 3]) -> f32 {
    let o = (bl * scene.lights.count + j) * 3;
    let d = &scene.lights.directions[o..o + 3];
    n[0] * d[0] + n[1] * d[1] + n[2] * d[2]
}

/// The shaded face attributes `(B, M, 4)`: RGB and the coverage channel 1.
pub fn shade(scene: &FlatScene<'_>) -> Result<Vec<f32>> {
    let bt = scene.batches()?;
    let (m, k) = (scene.num_faces(), scene.lights.count);
    let mut out = vec![0f32; scene.batch * m * 4];
    out.par_chunks_mut(m * 4).enumerate().for_each(|(b, view)| {
        let (bv, bk, bl, bc) = (
            at(b, bt.verts),
            at(b, bt.camera),
            at(b, bt.lights),
            at(b, bt.colors),
        );
        let amb = &scene.lights.ambient[bl * 3..bl * 3 + 3];
        let lc = &scene.lights.colors[bl * k * 3..(bl + 1) * k * 3];
        for (f, px) in view.chunks_exact_mut(4).enumerate() {
            let (fnrm, _) = face_normal(scene, bv, bk, f);
            let n = fnrm.n.map(|x| x * fnrm.sign);
            let mut lit = [0f32; 3];
            for j in 0..k {
                let cos = light_dot(scene, bl, j, n).max(0.0);
                for ch in 0..3 {
                    let term = cos * lc[3 * j + ch];
                    lit[ch] = if j == 0 { term } else { lit[ch] + term };
                }
            }
            let col = &scene.colors[(bc * m + f) * 3..(bc * m + f) * 3 + 3];
            for ch in 0..3 {
                let intensity = if k == 0 { amb[ch] } else { amb[ch] + lit[ch] };
                px[ch] = (col[ch] * intensity).clamp(0.0, 1.0);
            }
            px[3] = 1.0;
        }
    });
    Ok(out)
}

/// One view's gradients before the reduction over views: those of the vertices and colours in `f32`, rounded as
/// PyTorch's autograd rounds them, the camera's and lights' in `f64`.
struct ViewGrads {
    /// The projection's part of the vertex gradient.
    verts_projection: Vec<f32>,
    /// The shading's part of the vertex gradient.
    verts_shading: Vec<f32>,
    colors: Vec<f32>,
    rotation: [f64; 9],
    eye: [f64; 3],
    scale: f64,
    light_directions: Vec<f64>,
    light_colors: Vec<f64>,
    ambient: [f64; 3],
}

fn add3(a: &mut [f32], b: [f32; 3]) {
    a[0] += b[0];
    a[1] += b[1];
    a[2] += b[2];
}

/// One view's shading adjoint: `grad_attrs` `(M, 4)` (the fourth channel is constant) into `g`.
///
/// The vertex and colour gradients follow PyTorch's autograd of `meshadv.render.lighting.shade` operation by
/// operation in `f32` (the clamps' masks, the product rule of each division, the norm's `c / |c|`, the cross
/// products' adjoints `e2 x g` and `g x e1`, and the scatter of each face's corners in face order).
fn shade_view_backward(
    scene: &FlatScene<'_>,
    bt: Batches,
    b: usize,
    grad_attrs: &[f32],
    need_verts: bool,
    g: &mut ViewGrads,
) {
    let (m, k) = (scene.num_faces(), scene.lights.count);
    let (bv, bk, bl, bc) = (
        at(b, bt.verts),
        at(b, bt.camera),
        at(b, bt.lights),
        at(b, bt.colors),
    );
    let amb = &scene.lights.ambient[bl * 3..bl * 3 + 3];
    let lc = &scene.lights.colors[bl * k * 3..(bl + 1) * k * 3];
    let dirs = &scene.lights.directions[bl * k * 3..(bl + 1) * k * 3];
    let mut raw = vec![0f32; k];
    let mut g_raw = vec![0f32; k];
    for f in 0..m {
        let ga = &grad_attrs[4 * f..4 * f + 3];
        if ga.iter().all(|&x| x == 0.0) {
            continue;
        }
        let (fnrm, [e1, e2]) = face_normal(scene, bv, bk, f);
        let n = fnrm.n.map(|x| x * fnrm.sign);
        let mut lit = [0f32; 3];
        for j in 0..k {
            raw[j] = light_dot(scene, bl, j, n);
            for ch in 0..3 {
                let term = raw[j].max(0.0) * lc[3 * j + ch];
                lit[ch] = if j == 0 { term } else { lit[ch] + term };
            }
        }
        let col = &scene.colors[(bc * m + f) * 3..(bc * m + f) * 3 + 3];
        let mut g_int = [0f32; 3];
        for ch in 0..3 {
            let intensity = if k == 0 { amb[ch] } else { amb[ch] + lit[ch] };
            let x = col[ch] * intensity;
            let gx = if (0.0..=1.0).contains(&x) {
                ga[ch]
            } else {
                0.0
            };
            g.colors[3 * f + ch] = gx * intensity;
            g_int[ch] = gx * col[ch];
            g.ambient[ch] += f64::from(g_int[ch]);
        }
        for j in 0..k {
            let l = &lc[3 * j..3 * j + 3];
            let cj = raw[j].max(0.0);
            for (acc, gi) in g.light_colors[3 * j..3 * j + 3].iter_mut().zip(g_int) {
                *acc += f64::from(cj) * f64::from(gi);
            }
            let g_cos = g_int[0] * l[0] + g_int[1] * l[1] + g_int[2] * l[2];
            g_raw[j] = if raw[j] >= 0.0 { g_cos } else { 0.0 };
            for (acc, ni) in g.light_directions[3 * j..3 * j + 3].iter_mut().zip(n) {
                *acc += f64::from(g_raw[j]) * f64::from(ni);
            }
        }
        if !need_verts || k == 0 {
            continue;
        }
        let mut g_n = [0f32; 3];
        for (i, gi) in g_n.iter_mut().enumerate() {
            *gi = g_raw[0] * dirs[i];
            for j in 1..k {
                *gi += g_raw[j] * dirs[3 * j + i];
            }
            *gi *= fnrm.sign;
        }
        // n = c / s with s = max(|c|, tiny): c's two parts, through the division and through the norm.
        let (c, norm) = (fnrm.c, fnrm.norm);
        let s = norm.max(TINY);
        let q = |i: usize| (-g_n[i]) * ((c[i] / s) / s);
        let g_s = q(0) + q(1) + q(2);
        let g_norm = if norm >= TINY { g_s } else { 0.0 };
        let g_c: [f32; 3] = std::array::from_fn(|i| {
            let through_norm = if norm == 0.0 {
                0.0
            } else {
                g_norm * (c[i] / norm)
            };
            g_n[i] / s + through_norm
        });
        let g_e1 = cross_rounded(e2, g_c);
        let g_e2 = cross_rounded(g_c, e1);
        let t = &scene.faces[3 * f..3 * f + 3];
        let corner = |i: i32| 3 * i as usize;
        let g_v0 = [
            -g_e1[0] + -g_e2[0],
            -g_e1[1] + -g_e2[1],
            -g_e1[2] + -g_e2[2],
        ];
        add3(&mut g.verts_shading[corner(t[0])..], g_v0);
        add3(&mut g.verts_shading[corner(t[1])..], g_e1);
        add3(&mut g.verts_shading[corner(t[2])..], g_e2);
    }
}

/// One view's projection adjoint: `grad_screen` `(N, 3)` into `g`; the vertex gradient follows PyTorch's autograd
/// of `meshadv.render.Camera.project` operation by operation in `f32`.
fn project_view_backward(
    scene: &FlatScene<'_>,
    bt: Batches,
    b: usize,
    grad_screen: &[f32],
    g: &mut ViewGrads,
) {
    let (bv, bk) = (at(b, bt.verts), at(b, bt.camera));
    let (r, eye, s) = (scene.rotation(bk), scene.eye(bk), scene.camera.scale[bk]);
    for (i, gs) in grad_screen.chunks_exact(3).enumerate() {
        let [gx, gy, gz] = [gs[0], gs[1], gs[2]];
        if gx == 0.0 && gy == 0.0 && gz == 0.0 {
            continue;
        }
        let v = scene.vert(bv, i);
        let [x, y, z] = to_view(v, eye, r);
        let g_view = if scene.camera.orthographic {
            g.scale -= (f64::from(gx) * f64::from(x) + f64::from(gy) * f64::from(y))
                / (f64::from(s) * f64::from(s));
            [gx / s, gy / s, gz]
        } else {
            let zs = safe_depth(z);
            let den = zs * s;
            let g_den_x = (-gx) * ((x / den) / den);
            let g_den_y = (-gy) * ((y / den) / den);
            g.scale += f64::from(g_den_x * zs) + f64::from(g_den_y * zs);
            let g_zs = g_den_x * s + g_den_y * s;
            let through_zs = if z.abs() < TINY { 0.0 } else { g_zs };
            [gx / den, gy / den, gz + through_zs]
        };
        let d = [v[0] - eye[0], v[1] - eye[1], v[2] - eye[2]];
        let g_d: [f32; 3] =
            std::array::from_fn(|c| g_view[0] * r[c] + g_view[1] * r[3 + c] + g_view[2] * r[6 + c]);
        for (mr, gm) in g_view.iter().enumerate() {
            for (acc, dc) in g.rotation[3 * mr..3 * mr + 3].iter_mut().zip(d) {
                *acc += f64::from(*gm) * f64::from(dc);
            }
        }
        add3(&mut g.verts_projection[3 * i..], g_d);
        for (acc, gc) in g.eye.iter_mut().zip(g_d) {
            *acc -= f64::from(gc);
        }
    }
}

/// The gradients of the scene's inputs from the cotangents of the screen-space vertices `(B, N, 3)` (`None`: no
/// vertex or camera gradient through the projection) and of the shaded attributes `(B, M, 4)`; with `need_verts`
/// false the shading's vertex gradient is skipped too (the vertex and camera gradients are then zero).
///
/// The vertex gradient is the projection's part plus the shading's (each as PyTorch's autograd rounds it); shared
/// inputs sum their views' gradients in increasing view order.
pub fn flat_backward(
    scene: &FlatScene<'_>,
    grad_screen: Option<&[f32]>,
    grad_attrs: &[f32],
    need_verts: bool,
) -> Result<FlatGradients> {
    let bt = scene.batches()?;
    let (b, n, m, k) = (
        scene.batch,
        scene.num_verts,
        scene.num_faces(),
        scene.lights.count,
    );
    if grad_attrs.len() != b * m * 4 {
        return Err(RasterError::shape(
            "grad_attrs",
            format!("({b}, {m}, 4)"),
            format!("{} values", grad_attrs.len()),
        ));
    }
    if let Some(gs) = grad_screen {
        if gs.len() != b * n * 3 {
            return Err(RasterError::shape(
                "grad_screen",
                format!("({b}, {n}, 3)"),
                format!("{} values", gs.len()),
            ));
        }
        check_finite("grad_screen", gs)?;
    }
    check_finite("grad_attrs", grad_attrs)?;
    let vert_len = if need_verts { n * 3 } else { 0 };
    let views: Vec<ViewGrads> = (0..b)
        .into_par_iter()
        .map(|v| {
            let mut g = ViewGrads {
                verts_projection: vec![0.0; vert_len],
                verts_shading: vec![0.0; vert_len],
                colors: vec![0.0; m * 3],
                rotation: [0.0; 9],
                eye: [0.0; 3],
                scale: 0.0,
                light_directions: vec![0.0; k * 3],
                light_colors: vec![0.0; k * 3],
                ambient: [0.0; 3],
            };
            let ga = &grad_attrs[v * m * 4..(v + 1) * m * 4];
            shade_view_backward(scene, bt, v, ga, need_verts, &mut g);
            if let (Some(gs), true) = (grad_screen, need_verts) {
                project_view_backward(scene, bt, v, &gs[v * n * 3..(v + 1) * n * 3], &mut g);
            }
            if need_verts {
                for (p, s) in g.verts_projection.iter_mut().zip(&g.verts_shading) {
                    *p += s;
                }
            }
            g
        })
        .collect();
    // Sum the views into each input's batch, in increasing view order.
    let reduce32 = |batch: usize, len: usize, part: &dyn Fn(&ViewGrads) -> &[f32]| -> Vec<f32> {
        let mut acc = vec![0f32; batch * len];
        let mut seen = vec![false; batch];
        for (v, g) in views.iter().enumerate() {
            let p = part(g);
            if p.is_empty() {
                continue;
            }
            let slot = at(v, batch);
            let dst = &mut acc[slot * len..(slot + 1) * len];
            if seen[slot] {
                dst.iter_mut().zip(p).for_each(|(a, x)| *a += x);
            } else {
                dst.copy_from_slice(p);
                seen[slot] = true;
            }
        }
        acc
    };
    let reduce64 = |batch: usize, len: usize, part: &dyn Fn(&ViewGrads) -> &[f64]| -> Vec<f32> {
        let mut acc = vec![0f64; batch * len];
        for (v, g) in views.iter().enumerate() {
            let slot = at(v, batch);
            let dst = &mut acc[slot * len..(slot + 1) * len];
            dst.iter_mut().zip(part(g)).for_each(|(a, x)| *a += x);
        }
        acc.into_iter().map(|x| x as f32).collect()
    };
    Ok(FlatGradients {
        verts: reduce32(bt.verts, n * 3, &|g| &g.verts_projection),
        colors: reduce32(bt.colors, m * 3, &|g| &g.colors),
        rotation: reduce64(bt.camera, 9, &|g| &g.rotation),
        eye: reduce64(bt.camera, 3, &|g| &g.eye),
        scale: reduce64(bt.camera, 1, &|g| std::slice::from_ref(&g.scale)),
        light_directions: reduce64(bt.lights, k * 3, &|g| &g.light_directions),
        light_colors: reduce64(bt.lights, k * 3, &|g| &g.light_colors),
        ambient: reduce64(bt.lights, 3, &|g| &g.ambient),
    })
}

/// The outputs of [`render_flat`].
#[derive(Debug, Clone, PartialEq)]
pub struct FlatRender {
    /// `(B, H, W, 4)` RGB and coverage, box-filtered by `k` (the supersampled image itself when `k = 1`).
    pub image: Vec<f32>,
    /// `(B, kH, kW, 4)` supersampled image (empty when `k = 1`: it is `image`).
    pub full_image: Vec<f32>,
    /// `(B, kH, kW)` face index of the supersampled render, -1 for background.
    pub face_index: Vec<i32>,
    /// `(B, kH, kW)` view depth of the supersampled render, `far` where empty.
    pub depth: Vec<f32>,
    /// `(B, N, 3)` screen-space vertices.
    pub verts_screen: Vec<f32>,
    /// `(B, M, 4)` shaded face attributes.
    pub attrs: Vec<f32>,
}

/// The flat render of `scene`: projection, shading, rasterization at `k` times `params`' size (`params` holds the
/// supersampled size) with `background` (RGB, then the coverage 0), and the `k x k` box filter.
pub fn render_flat(
    scene: &FlatScene<'_>,
    params: &RasterParams,
    background: [f32; 3],
    k: usize,
) -> Result<FlatRender> {
    params.validate()?;
    let verts_screen = project(scene)?;
    check_clip_range(&verts_screen, scene.batch, params)?;
    let attrs = shade(scene)?;
    let bg = [background[0], background[1], background[2], 0.0];
    let mesh = ScreenMesh::new(&verts_screen, scene.faces, scene.batch, scene.num_verts)?;
    mesh.validate_as("verts_screen")?;
    let face_attrs = FaceAttrs {
        values: &attrs,
        background: &bg,
        channels: 4,
    };
    let out = rasterize(&mesh, &face_attrs, params)?;
    let (image, full_image) = if k == 1 {
        (out.image, Vec::new())
    } else {
        let shape = BoxShape::of_full("image", [scene.batch, params.height, params.width, 4], k)?;
        (box_downsample(&out.image, &shape)?, out.image)
    };
    Ok(FlatRender {
        image,
        full_image,
        face_index: out.face_index,
        depth: out.depth,
        verts_screen,
        attrs,
    })
}

/// An error naming `camera` when every vertex of some views is before the near plane, or (else) beyond the far
/// plane, listing those views.
fn check_clip_range(verts_screen: &[f32], batch: usize, params: &RasterParams) -> Result<()> {
    let n = verts_screen.len() / (3 * batch.max(1));
    for (beyond, plane) in [(false, "near"), (true, "far")] {
        let views: Vec<usize> = (0..batch)
            .filter(|&b| {
                verts_screen[b * n * 3..(b + 1) * n * 3]
                    .chunks_exact(3)
                    .all(|p| {
                        let z = f64::from(p[2]);
                        if beyond {
                            z > params.far
                        } else {
                            z < params.near
                        }
                    })
            })
            .collect();
        if !views.is_empty() {
            let side = if beyond { "beyond" } else { "behind" };
            return Err(RasterError::Parameter {
                arg: "camera",
                message: format!(
                    "all geometry is {side} the camera's {plane} plane in view(s) {views:?}"
                ),
            });
        }
    }
    Ok(())
}

/// What the backward of [`render_flat`] needs of its forward, and the cotangent of its filtered image.
#[derive(Debug, Clone, Copy)]
pub struct FlatBackwardInputs<'a> {
    /// The forward's [`FlatRender::verts_screen`].
    pub verts_screen: &'a [f32],
    /// The forward's [`FlatRender::attrs`].
    pub attrs: &'a [f32],
    /// The forward's supersampled face index.
    pub face_index: &'a [i32],
    /// The forward's supersampled image (its filtered image when `k = 1`).
    pub image: &'a [f32],
    /// `(B, H, W, 4)` cotangent of the filtered image.
    pub grad_image: &'a [f32],
    /// Weight of the rasterization (visibility) gradient on the screen-space vertices.
    pub edge_weight: f32,
    /// Compute the vertex and camera gradients (else they are zero and the vertex sweep is skipped).
    pub need_verts: bool,
    /// The visibility gradient.
    pub visibility: Visibility,
}

/// The backward of [`render_flat`] (same `scene`, `params`, `background` and `k`): the gradients of every input.
pub fn render_flat_backward(
    scene: &FlatScene<'_>,
    params: &RasterParams,
    background: [f32; 3],
    k: usize,
    inputs: &FlatBackwardInputs<'_>,
) -> Result<FlatGradients> {
    params.validate()?;
    let bg = [background[0], background[1], background[2], 0.0];
    let mesh = ScreenMesh::new(
        inputs.verts_screen,
        scene.faces,
        scene.batch,
        scene.num_verts,
    )?;
    let face_attrs = FaceAttrs {
        values: inputs.attrs,
        background: &bg,
        channels: 4,
    };
    let spread;
    let grad_full = if k == 1 {
        inputs.grad_image
    } else {
        let shape = BoxShape::of_full("image", [scene.batch, params.height, params.width, 4], k)?;
        spread = box_spread(inputs.grad_image, &shape)?;
        &spread
    };
    let raster = BackwardInputs {
        face_index: inputs.face_index,
        image: inputs.image,
        grad_image: grad_full,
        vertex_grad: inputs.need_verts,
        visibility: inputs.visibility,
    };
    let mut g = rasterize_backward(&mesh, &face_attrs, params, &raster)?;
    if inputs.edge_weight != 1.0 {
        for x in &mut g.grad_verts_screen {
            *x *= inputs.edge_weight;
        }
    }
    let grad_screen = inputs.need_verts.then_some(&g.grad_verts_screen[..]);
    flat_backward(scene, grad_screen, &g.grad_face_attrs, inputs.need_verts)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Vertices, faces, colours, rotation, eye, scale, light directions and light colours of a test scene.
    type SceneData = (
        Vec<f32>,
        Vec<i32>,
        Vec<f32>,
        Vec<f32>,
        Vec<f32>,
        Vec<f32>,
        Vec<f32>,
        Vec<f32>,
    );

    /// A tilted quad (two faces) seen by one perspective view, lit by two lights.
    fn scene_data() -> SceneData {
        let verts = vec![
            -0.6, -0.5, 0.1, 0.7, -0.4, -0.2, 0.5, 0.6, 0.3, -0.5, 0.55, 0.0,
        ];
        let faces = vec![0, 1, 2, 0, 2, 3];
        let colors = vec![0.8, 0.4, 0.3, 0.2, 0.9, 0.6];
        let (ca, sa) = (0.3f32.cos(), 0.3f32.sin());
        // Rows: x, y, z of a camera at distance 3 rotated about y.
        let rotation = vec![ca, 0.0, sa, 0.0, 1.0, 0.0, -sa, 0.0, ca];
        let eye = vec![3.0 * sa, 0.0, -3.0 * ca];
        let scale = vec![(15f32).to_radians().tan()];
        let dirs = vec![0.0, 0.6, -0.8, 0.6, 0.3, -0.74];
        let lcolors = vec![0.5, 0.4, 0.3, 0.2, 0.3, 0.4];
        (verts, faces, colors, rotation, eye, scale, dirs, lcolors)
    }

    #[test]
    fn backward_matches_finite_differences_of_a_linear_loss() {
        for orthographic in [false, true] {
            check_finite_differences(orthographic);
        }
    }

    fn check_finite_differences(orthographic: bool) {
        let (verts, faces, colors, rotation, eye, scale, mut dirs, lcolors) = scene_data();
        let norm = |d: &mut [f32]| {
            let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            d.iter_mut().for_each(|x| *x /= l);
        };
        norm(&mut dirs[0..3]);
        norm(&mut dirs[3..6]);
        let ambient = vec![0.3, 0.25, 0.2];
        let w_screen: Vec<f32> = (0..12).map(|i| ((i * 7 % 5) as f32 - 2.0) * 0.3).collect();
        let w_attrs: Vec<f32> = (0..8).map(|i| ((i * 3 % 7) as f32 - 3.0) * 0.25).collect();
        let loss = |v: &[f32],
                    c: &[f32],
                    r: &[f32],
                    e: &[f32],
                    s: &[f32],
                    d: &[f32],
                    l: &[f32],
                    a: &[f32]| {
            let sc = FlatScene {
                verts: v,
                num_verts: 4,
                faces: &faces,
                colors: c,
                camera: FlatCamera {
                    rotation: r,
                    eye: e,
                    scale: s,
                    orthographic,
                },
                lights: FlatLights {
                    directions: d,
                    colors: l,
                    ambient: a,
                    count: 2,
                },
                batch: 1,
                two_sided: true,
            };
            let p = project(&sc).expect("a valid scene");
            let at = shade(&sc).expect("a valid scene");
            let dot = |x: &[f32], w: &[f32]| {
                x.iter()
                    .zip(w)
                    .map(|(a, b)| f64::from(*a) * f64::from(*b))
                    .sum::<f64>()
            };
            dot(&p, &w_screen) + dot(&at, &w_attrs)
        };
        let scene = FlatScene {
            verts: &verts,
            num_verts: 4,
            faces: &faces,
            colors: &colors,
            camera: FlatCamera {
                rotation: &rotation,
                eye: &eye,
                scale: &scale,
                orthographic,
            },
            lights: FlatLights {
                directions: &dirs,
                colors: &lcolors,
                ambient: &ambient,
                count: 2,
            },
            batch: 1,
            two_sided: true,
        };
        let g = flat_backward(&scene, Some(&w_screen), &w_attrs, true).expect("a valid scene");
        let inputs: [(&str, &Vec<f32>, &Vec<f32>); 8] = [
            ("verts", &verts, &g.verts),
            ("colors", &colors, &g.colors),
            ("rotation", &rotation, &g.rotation),
            ("eye", &eye, &g.eye),
            ("scale", &scale, &g.scale),
            ("dirs", &dirs, &g.light_directions),
            ("lcolors", &lcolors, &g.light_colors),
            ("ambient", &ambient, &g.ambient),
        ];
        for (slot, (name, x, grad)) in inputs.iter().enumerate() {
            for i in 0..x.len() {
                let h = 1e-3f32;
                let eval = |delta: f32| {
                    let mut args: Vec<Vec<f32>> = vec![
                        verts.clone(),
                        colors.clone(),
                        rotation.clone(),
                        eye.clone(),
                        scale.clone(),
                        dirs.clone(),
                        lcolors.clone(),
                        ambient.clone(),
                    ];
                    args[slot][i] += delta;
                    loss(
                        &args[0], &args[1], &args[2], &args[3], &args[4], &args[5], &args[6],
                        &args[7],
                    )
                };
                let fd = (eval(h) - eval(-h)) / (2.0 * f64::from(h));
                let an = f64::from(grad[i]);
                assert!(
                    (fd - an).abs() <= 2e-2 * (1.0 + an.abs()),
                    "{name}[{i}] (orthographic {orthographic}): analytic {an}, finite differences {fd}"
                );
            }
        }
    }

    #[test]
    fn shared_inputs_sum_their_views_gradients() {
        let (verts, faces, colors, rotation, eye, scale, mut dirs, lcolors) = scene_data();
        dirs.truncate(3);
        let l = (dirs[0] * dirs[0] + dirs[1] * dirs[1] + dirs[2] * dirs[2]).sqrt();
        dirs.iter_mut().for_each(|x| *x /= l);
        let ambient = vec![0.3, 0.25, 0.2];
        let two_rot: Vec<f32> = rotation.iter().chain(rotation.iter()).copied().collect();
        let two_eye: Vec<f32> = eye.iter().chain(eye.iter()).copied().collect();
        let two_scale = vec![scale[0], scale[0]];
        let lc = &lcolors[..3];
        let two = FlatScene {
            verts: &verts,
            num_verts: 4,
            faces: &faces,
            colors: &colors,
            camera: FlatCamera {
                rotation: &two_rot,
                eye: &two_eye,
                scale: &two_scale,
                orthographic: false,
            },
            lights: FlatLights {
                directions: &dirs,
                colors: lc,
                ambient: &ambient,
                count: 1,
            },
            batch: 2,
            two_sided: true,
        };
        let one = FlatScene {
            batch: 1,
            camera: FlatCamera {
                rotation: &rotation,
                eye: &eye,
                scale: &scale,
                orthographic: false,
            },
            ..two
        };
        let gs: Vec<f32> = (0..12).map(|i| i as f32 * 0.1 - 0.5).collect();
        let ga: Vec<f32> = (0..8).map(|i| 0.3 - i as f32 * 0.07).collect();
        let g1 = flat_backward(&one, Some(&gs), &ga, true).expect("a valid scene");
        let gs2: Vec<f32> = gs.iter().chain(gs.iter()).copied().collect();
        let ga2: Vec<f32> = ga.iter().chain(ga.iter()).copied().collect();
        let g2 = flat_backward(&two, Some(&gs2), &ga2, true).expect("a valid scene");
        for (a, b) in g1.verts.iter().zip(&g2.verts) {
            assert!((2.0 * a - b).abs() <= 1e-5 * (1.0 + b.abs()));
        }
        assert_eq!(g2.rotation.len(), 18);
        assert_eq!(&g2.rotation[..9], &g1.rotation[..]);
        assert_eq!(
            project(&two).expect("a valid scene")[..12],
            project(&one).expect("a valid scene")[..]
        );
        assert_eq!(
            shade(&two).expect("a valid scene")[8..],
            shade(&one).expect("a valid scene")[..]
        );
    }

    #[test]
    fn bad_batches_and_values_name_their_argument() {
        let (verts, faces, colors, rotation, eye, scale, mut dirs, lcolors) = scene_data();
        dirs.truncate(3);
        let ambient = vec![0.3, 0.25, 0.2];
        let ok = FlatScene {
            verts: &verts,
            num_verts: 4,
            faces: &faces,
            colors: &colors,
            camera: FlatCamera {
                rotation: &rotation,
                eye: &eye,
                scale: &scale,
                orthographic: false,
            },
            lights: FlatLights {
                directions: &dirs,
                colors: &lcolors[..3],
                ambient: &ambient,
                count: 1,
            },
            batch: 3,
            two_sided: true,
        };
        assert!(ok.validate().is_ok());
        let short = &colors[..3];
        let err = FlatScene {
            colors: short,
            ..ok
        }
        .validate()
        .expect_err("an invalid scene");
        assert!(err.to_string().starts_with("face_colors"), "{err}");
        let bad_faces = [0, 1, 9, 0, 2, 3];
        let err = FlatScene {
            faces: &bad_faces,
            ..ok
        }
        .validate()
        .expect_err("an invalid scene");
        assert!(
            matches!(err, RasterError::FaceIndexOutOfRange { .. }),
            "{err}"
        );
        let nan_eye = [0.0, f32::NAN, 1.0];
        let err = FlatScene {
            camera: FlatCamera {
                eye: &nan_eye,
                ..ok.camera
            },
            ..ok
        }
        .validate()
        .expect_err("an invalid scene");
        assert!(err.to_string().starts_with("eye"), "{err}");
        let zero = [0.0];
        let err = FlatScene {
            camera: FlatCamera {
                scale: &zero,
                ..ok.camera
            },
            ..ok
        }
        .validate()
        .expect_err("an invalid scene");
        assert!(err.to_string().starts_with("scale"), "{err}");
    }
}
