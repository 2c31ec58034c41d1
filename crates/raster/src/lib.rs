//! meshadv-raster: the pure Rust core of meshadv's differentiable mesh renderer.
//!
//! * [`setup`]: per-face setup (edge functions, area, bounding box, cull and degenerate flags).
//! * [`raster`]: forward rasterization of screen-space triangles with per-face attributes.
//! * [`backward`]: exact attribute gradients and the Neural Mesh Renderer's approximate vertex gradients.
//! * [`boxfilter`]: the box filter of an antialiased (supersampled) render and its adjoint.
//! * [`camera`], [`shading`], [`pipeline`]: NMR camera conventions, Lambert shading and the full forward render.
//! * [`flat`]: the flat render around the rasterizer (projection, Lambert shading, box filter) and its adjoint.
//! * [`surface`], [`texture`], [`textured`]: per-pixel perspective-correct weights and interpolated attributes,
//!   bilinear texture samples, and a UV-textured surface (UV, sample and their gradients) in one pass per pixel.
//! * [`raycast`]: BVH ray cast (obvhs), the rasterizer's oracle and an alternative for very large meshes.
//!
//! Conventions are those of `docs/ARCHITECTURE.md` (Neural Mesh Renderer's). Every function validates its input and
//! returns a [`RasterError`] rather than panicking; results are bit-identical for any thread count.

/// Evaluates `$body` with the constant `$C` set to the channel count `$channels` for 1 to 4 channels (so that
/// per-channel loops are unrolled), and to 0 ("any count", read at run time) otherwise:
/// `with_channels!(c, C => fill_line::<C>(...))`.
macro_rules! with_channels {
    ($channels:expr, $C:ident => $body:expr) => {
        match $channels {
            1 => with_channels!(@as 1, $C => $body),
            2 => with_channels!(@as 2, $C => $body),
            3 => with_channels!(@as 3, $C => $body),
            4 => with_channels!(@as 4, $C => $body),
            _ => with_channels!(@as 0, $C => $body),
        }
    };
    (@as $n:literal, $C:ident => $body:expr) => {{
        const $C: usize = $n;
        $body
    }};
}

pub mod backward;
pub mod boxfilter;
pub mod camera;
pub mod error;
pub mod flat;
pub mod input;
pub mod parallel;
pub mod pipeline;
pub mod raster;
pub mod raycast;
pub mod setup;
pub mod shading;
mod simd;
pub mod surface;
#[cfg(test)]
mod test_rng;
pub mod texture;
pub mod textured;

pub use backward::{rasterize_backward, BackwardInputs, Gradients};
pub use camera::MIN_VIEWING_ANGLE;
pub use error::{try_filled_vec, ErrorKind, RasterError, Result};
pub use input::{
    bits_hash, FaceAttrs, Projection, RasterParams, ScreenMesh, MAX_IMAGE_SIZE, MAX_MESH_FILE_BYTES,
};
pub use parallel::{with_threads, MAX_CACHED_POOLS};
pub use raster::{rasterize, rasterize_fragments, Fragments, RasterOutput};
pub use shading::MIN_LIGHT_DIRECTION;
