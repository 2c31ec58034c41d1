//! Full forward render in the core: world vertices + spherical camera + Lambert lights + per-face reflectances ->
//! RGB image, alpha, depth and face index. Used by the `meshadv-render` binary and to cross-check the Python
//! pipeline (which does camera and shading in PyTorch and calls the same rasterizer).

use glam::DVec3;

use crate::camera::{project, world_to_view, SphericalCamera};
use crate::error::{RasterError, Result};
use crate::input::{
    check_finite, validate_mesh_indices, FaceAttrs, Projection, RasterParams, ScreenMesh,
};
use crate::raster::rasterize;
pub use crate::shading::Lights;
use crate::shading::{face_normal, flip_toward_camera, lambert};

/// Image size, background and sidedness of a full render.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderSettings {
    /// Image height in pixels.
    pub height: usize,
    /// Image width in pixels.
    pub width: usize,
    /// RGB background.
    pub background: [f32; 3],
    /// Two-sided (NMR `fill_back`): draw back faces with normals flipped toward the camera; else cull them.
    pub fill_back: bool,
}

impl Default for RenderSettings {
    fn default() -> Self {
        RenderSettings {
            height: 256,
            width: 256,
            background: [1.0, 1.0, 1.0],
            fill_back: true,
        }
    }
}

/// Output of [`render`], flat row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderOutput {
    /// `(H, W, 3)` RGB in `[0, 1]`.
    pub image: Vec<f32>,
    /// `(H, W)` 1 where a face is drawn, else 0.
    pub alpha: Vec<f32>,
    /// `(H, W)` view depth, `far` on background.
    pub depth: Vec<f32>,
    /// `(H, W)` face index, -1 on background.
    pub face_index: Vec<i32>,
}

/// Shaded RGB of every face (flat `(M, 3)`), normals flipped toward the camera when `two_sided`.
pub fn shade_faces(
    verts_world: &[f32],
    faces: &[i32],
    reflectance: &[f32],
    camera: &SphericalCamera,
    lights: &Lights,
    two_sided: bool,
) -> Result<Vec<f32>> {
    let view = camera.view()?;
    let p = |k: i32| {
        let o = k as usize * 3;
        DVec3::new(
            verts_world[o] as f64,
            verts_world[o + 1] as f64,
            verts_world[o + 2] as f64,
        )
    };
    let mut out = Vec::with_capacity(faces.len());
    for (f, tri) in faces.chunks_exact(3).enumerate() {
        let v = [p(tri[0]), p(tri[1]), p(tri[2])];
        let n = match face_normal(v) {
            Some(n) if two_sided => {
                flip_toward_camera(n, v[0], view.eye, view.z, camera.orthographic)
            }
            Some(n) => n,
            None => DVec3::ZERO,
        };
        let r = [
            reflectance[3 * f],
            reflectance[3 * f + 1],
            reflectance[3 * f + 2],
        ];
        out.extend_from_slice(&lambert(n, r, lights));
    }
    Ok(out)
}

/// Renders one view of a mesh (flat `(N, 3)` vertices, `(M, 3)` faces, `(M, 3)` reflectances in `[0, 1]`).
///
/// ```
/// use meshadv_raster::camera::SphericalCamera;
/// use meshadv_raster::pipeline::{render, Lights, RenderSettings};
/// let verts = [-1.0f32, -1.0, 0.0, 1.0, -1.0, 0.0, 0.0, 1.0, 0.0];
/// let settings = RenderSettings { height: 16, width: 16, ..Default::default() };
/// let out = render(&verts, &[0, 1, 2], &[1.0, 0.0, 0.0], &SphericalCamera::default(), &Lights::default(), &settings)
///     .unwrap();
/// assert_eq!(out.face_index[8 * 16 + 8], 0); // the centre pixel shows the triangle
/// assert_eq!(out.alpha[0], 0.0);
/// ```
pub fn render(
    verts_world: &[f32],
    faces: &[i32],
    reflectance: &[f32],
    camera: &SphericalCamera,
    lights: &Lights,
    settings: &RenderSettings,
) -> Result<RenderOutput> {
    camera.validate()?;
    if !verts_world.len().is_multiple_of(3) {
        return Err(RasterError::shape(
            "verts_world",
            "(N, 3)",
            format!("{} values", verts_world.len()),
        ));
    }
    let n = verts_world.len() / 3;
    validate_mesh_indices("faces", faces, n)?;
    check_finite("verts_world", verts_world)?;
    if reflectance.len() != faces.len() {
        return Err(RasterError::shape(
            "face_colors",
            format!("({}, 3)", faces.len() / 3),
            format!("{} values", reflectance.len()),
        ));
    }
    check_finite("face_colors", reflectance)?;
    lights.validate()?;
    check_finite("background", &settings.background)?;
    let view = camera.view()?;
    let verts_view = world_to_view(verts_world, &view);
    let verts_screen = project(
        &verts_view,
        camera.viewing_angle,
        camera.orthographic,
        camera.ortho_scale,
    );
    let colors = shade_faces(
        verts_world,
        faces,
        reflectance,
        camera,
        lights,
        settings.fill_back,
    )?;
    let m = faces.len() / 3;
    let mut attrs = Vec::with_capacity(m * 4);
    for c in colors.chunks_exact(3) {
        attrs.extend_from_slice(&[c[0], c[1], c[2], 1.0]);
    }
    let bg = [
        settings.background[0],
        settings.background[1],
        settings.background[2],
        0.0,
    ];
    // Vertices at z <= 0 project to infinity; the rasterizer skips their faces, so give them finite placeholders.
    // A vertex in front of the camera must project to finite screen coordinates.
    let mut verts_screen = verts_screen;
    for (k, p) in verts_screen.chunks_exact_mut(3).enumerate() {
        if p.iter().all(|x| x.is_finite()) {
            continue;
        }
        if p[2] > 0.0 || camera.orthographic {
            return Err(RasterError::Parameter {
                arg: "verts_world",
                message: format!(
                    "vertex {k} projects beyond float32 screen coordinates (viewing_angle {} too narrow or the \
                     vertex too far out)",
                    camera.viewing_angle
                ),
            });
        }
        for x in p.iter_mut().filter(|x| !x.is_finite()) {
            *x = 0.0;
        }
    }
    let mesh = ScreenMesh::new(&verts_screen, faces, 1, n)?;
    let params = RasterParams {
        height: settings.height,
        width: settings.width,
        near: camera.near,
        far: camera.far,
        cull_backfaces: !settings.fill_back,
        projection: if camera.orthographic {
            Projection::Orthographic
        } else {
            Projection::Perspective
        },
    };
    let out = rasterize(
        &mesh,
        &FaceAttrs {
            values: &attrs,
            background: &bg,
            channels: 4,
        },
        &params,
    )?;
    let hw = params.pixels();
    let mut image = Vec::with_capacity(hw * 3);
    let mut alpha = Vec::with_capacity(hw);
    for px in out.image.chunks_exact(4) {
        image.extend_from_slice(&px[..3]);
        alpha.push(px[3]);
    }
    Ok(RenderOutput {
        image,
        alpha,
        depth: out.depth,
        face_index: out.face_index,
    })
}
