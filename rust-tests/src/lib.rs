//! Helpers shared by the integration tests of `meshadv-raster`: a tiny deterministic RNG, mesh generators and
//! convenience wrappers around the core API, and a plain implementation of the backward pass as a reference
//! ([`nmr_reference`]).

pub mod nmr_reference;

use meshadv_raster::backward::Visibility;
use meshadv_raster::camera::project;
use meshadv_raster::{
    rasterize, rasterize_backward, BackwardInputs, FaceAttrs, Gradients, Projection, RasterOutput,
    RasterParams, ScreenMesh,
};

/// SplitMix64: small, deterministic, good enough for test geometry.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    /// New generator from a seed.
    pub fn new(seed: u64) -> Rng {
        Rng(seed)
    }

    /// Next raw 64-bit value.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `[lo, hi)`.
    pub fn uniform(&mut self, lo: f32, hi: f32) -> f32 {
        let u = (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32;
        lo + (hi - lo) * u
    }

    /// Uniform integer in `[0, n)`.
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n as u64) as usize
    }
}

/// A batch-1 screen-space mesh with owned buffers.
#[derive(Debug, Clone)]
pub struct OwnedMesh {
    /// `(B, N, 3)` vertices.
    pub verts: Vec<f32>,
    /// `(M, 3)` faces.
    pub faces: Vec<i32>,
    /// Batch size.
    pub batch: usize,
}

impl OwnedMesh {
    /// Single-batch mesh.
    pub fn new(verts: Vec<f32>, faces: Vec<i32>) -> OwnedMesh {
        OwnedMesh {
            verts,
            faces,
            batch: 1,
        }
    }

    /// Borrowed view.
    pub fn view(&self) -> ScreenMesh<'_> {
        let n = self.verts.len() / 3 / self.batch;
        ScreenMesh::new(&self.verts, &self.faces, self.batch, n).expect("consistent test mesh")
    }

    /// Number of faces.
    pub fn num_faces(&self) -> usize {
        self.faces.len() / 3
    }
}

/// `count` random triangles with vertices in `[-1.2, 1.2]^2` (NDC) and depths in `[zlo, zhi]`.
pub fn random_soup(rng: &mut Rng, count: usize, zlo: f32, zhi: f32) -> OwnedMesh {
    let mut verts = Vec::new();
    let mut faces = Vec::new();
    for f in 0..count {
        let (cx, cy) = (rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0));
        let r = rng.uniform(0.05, 0.6);
        for _ in 0..3 {
            verts.extend_from_slice(&[
                cx + rng.uniform(-r, r),
                cy + rng.uniform(-r, r),
                rng.uniform(zlo, zhi),
            ]);
        }
        faces.extend_from_slice(&[3 * f as i32, 3 * f as i32 + 1, 3 * f as i32 + 2]);
    }
    OwnedMesh::new(verts, faces)
}

/// A view-space random soup in front of the camera: triangles inside the 30 degree frustum at depths `[2, 6]`.
pub fn random_view_soup(rng: &mut Rng, count: usize) -> Vec<f32> {
    let mut verts = Vec::new();
    for _ in 0..count {
        let z = rng.uniform(2.0, 6.0);
        let half = z * (15f32).to_radians().tan();
        let (cx, cy) = (rng.uniform(-half, half), rng.uniform(-half, half));
        let r = rng.uniform(0.05, 0.5) * half;
        for _ in 0..3 {
            verts.extend_from_slice(&[
                cx + rng.uniform(-r, r),
                cy + rng.uniform(-r, r),
                z + rng.uniform(-0.5, 0.5),
            ]);
        }
    }
    verts
}

/// Perspective projection with a 30 degree field of view (NMR's default).
pub fn project30(verts_view: &[f32]) -> Vec<f32> {
    project(verts_view, 30.0, false, 1.0)
}

/// Sequential faces `[0, 1, 2], [3, 4, 5], ...` for `count` triangles.
pub fn soup_faces(count: usize) -> Vec<i32> {
    (0..3 * count as i32).collect()
}

/// Forward with constant per-face RGB attributes derived from the face index, plus an alpha channel.
pub fn forward(
    mesh: &OwnedMesh,
    attrs: &[f32],
    channels: usize,
    params: &RasterParams,
) -> RasterOutput {
    let bg = vec![0.0f32; channels];
    let a = FaceAttrs {
        values: attrs,
        background: &bg,
        channels,
    };
    rasterize(&mesh.view(), &a, params).expect("valid test input")
}

/// Backward (NMR's vertex gradient) of [`forward`] with cotangent `grad`.
pub fn backward(
    mesh: &OwnedMesh,
    attrs: &[f32],
    channels: usize,
    params: &RasterParams,
    out: &RasterOutput,
    grad: &[f32],
) -> Gradients {
    backward_of(Visibility::Nmr, mesh, attrs, channels, params, out, grad)
}

/// [`backward`] with the vertex gradient `visibility`.
pub fn backward_of(
    visibility: Visibility,
    mesh: &OwnedMesh,
    attrs: &[f32],
    channels: usize,
    params: &RasterParams,
    out: &RasterOutput,
    grad: &[f32],
) -> Gradients {
    let bg = vec![0.0f32; channels];
    let a = FaceAttrs {
        values: attrs,
        background: &bg,
        channels,
    };
    let inputs = BackwardInputs {
        face_index: &out.face_index,
        image: &out.image,
        grad_image: grad,
        vertex_grad: true,
        visibility,
    };
    rasterize_backward(&mesh.view(), &a, params, &inputs).expect("valid test input")
}

/// Random attributes in `[0, 1)`: `(B, M, C)`.
pub fn random_attrs(rng: &mut Rng, len: usize) -> Vec<f32> {
    (0..len).map(|_| rng.uniform(0.0, 1.0)).collect()
}

/// Perspective parameters, two-sided.
pub fn params(h: usize, w: usize) -> RasterParams {
    RasterParams::new(h, w, 0.1, 100.0)
}

/// Orthographic parameters, two-sided.
pub fn ortho_params(h: usize, w: usize) -> RasterParams {
    RasterParams {
        projection: Projection::Orthographic,
        ..RasterParams::new(h, w, 0.1, 100.0)
    }
}
