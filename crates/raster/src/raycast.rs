//! Exact ray cast of view-space triangles through an obvhs BVH: one primary ray through each pixel centre.
//!
//! Gives the same `face_index` and `depth` as the rasterizer for the same camera, except on exact ties (a pixel centre
//! exactly on a shared edge is claimed by both faces here, and the nearer / lower-index one wins) and within float
//! rounding of an edge. Used as the rasterizer's oracle in tests, for picking, and as an alternative method for very
//! large meshes. Faces are active under the same rules as in the rasterizer: perspective faces with a vertex at
//! `z <= 0` are skipped, degenerate faces are skipped, and back faces (normal pointing away from the eye,
//! `dot(n, v0) > 0` in perspective, `n.z > 0` in orthographic view space) are skipped when culling.
//!
//! Intersection is done in float64 on the float32 vertices: the pixel ray hits the face when the three scalar triple
//! products of the ray direction with the edges (perspective) or the three 2D edge functions (orthographic) have the
//! same sign, zero included; the depth is the view z of the hit point.

use std::time::Duration;

use glam::{DVec3, Vec3A};
use obvhs::aabb::Aabb;
use obvhs::bvh2::builder::build_bvh2;
use obvhs::bvh2::Bvh2;
use obvhs::ray::{Ray, RayHit};
use obvhs::BvhBuildParams;
use rayon::prelude::*;

use crate::error::{try_filled_vec, RasterError, Result};
use crate::input::{RasterParams, ScreenMesh};
use crate::raster::Fragments;

/// Largest accepted view-space coordinate magnitude (the BVH boxes are float32 and padded).
pub const MAX_COORD: f32 = 1e18;

/// Projection of the primary rays.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayCamera {
    /// Full field of view in degrees (perspective): the ray through NDC `(x, y)` has direction
    /// `(x tan(a/2), y tan(a/2), 1)`.
    pub viewing_angle: f64,
    /// Orthographic rays: origin `(x s, y s, 0)`, direction `(0, 0, 1)`.
    pub orthographic: bool,
    /// Half the visible extent `s` (orthographic).
    pub ortho_scale: f64,
}

impl RayCamera {
    fn validate(&self) -> Result<()> {
        if !(self.viewing_angle.is_finite()
            && self.viewing_angle > 0.0
            && self.viewing_angle < 180.0)
        {
            return Err(RasterError::Parameter {
                arg: "viewing_angle",
                message: format!("must be in (0, 180) degrees, got {}", self.viewing_angle),
            });
        }
        if !(self.ortho_scale.is_finite() && self.ortho_scale > 0.0) {
            return Err(RasterError::Parameter {
                arg: "ortho_scale",
                message: format!("must be finite and > 0, got {}", self.ortho_scale),
            });
        }
        Ok(())
    }
}

/// A prepared face in view space.
#[derive(Clone, Copy)]
struct Tri {
    v: [DVec3; 3],
    n: DVec3,
    active: bool,
}

fn prepare(mesh: &ScreenMesh<'_>, b: usize, ortho: bool, cull: bool) -> Vec<Tri> {
    (0..mesh.num_faces())
        .map(|f| {
            let idx = mesh.face(f);
            let v = idx.map(|k| {
                let p = mesh.vert(b, k);
                DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)
            });
            let n = (v[1] - v[0]).cross(v[2] - v[0]);
            let facing = if ortho { n.z } else { n.dot(v[0]) };
            let behind = !ortho && v.iter().any(|p| p.z <= 0.0);
            let active = facing != 0.0 && facing.is_finite() && !behind && !(cull && facing > 0.0);
            Tri { v, n, active }
        })
        .collect()
}

/// Hit depth (view z) of the ray, or `None`.
#[inline]
fn intersect(t: &Tri, origin: DVec3, dir: DVec3, ortho: bool) -> Option<f64> {
    let s = if ortho {
        let e =
            |a: DVec3, b: DVec3| (b.x - a.x) * (origin.y - a.y) - (b.y - a.y) * (origin.x - a.x);
        [e(t.v[0], t.v[1]), e(t.v[1], t.v[2]), e(t.v[2], t.v[0])]
    } else {
        [
            dir.dot(t.v[0].cross(t.v[1])),
            dir.dot(t.v[1].cross(t.v[2])),
            dir.dot(t.v[2].cross(t.v[0])),
        ]
    };
    let inside =
        (s[0] >= 0.0 && s[1] >= 0.0 && s[2] >= 0.0) || (s[0] <= 0.0 && s[1] <= 0.0 && s[2] <= 0.0);
    if !inside {
        return None;
    }
    let denom = t.n.dot(dir);
    if denom == 0.0 {
        return None;
    }
    let tt = t.n.dot(t.v[0] - origin) / denom;
    let z = origin.z + tt * dir.z;
    z.is_finite().then_some(z)
}

fn build(tris: &[Tri]) -> Bvh2 {
    let aabbs: Vec<Aabb> = tris
        .iter()
        .map(|t| {
            if !t.active {
                // Far away and empty-ish: never hit by a primary ray in front of the camera.
                return Aabb::new(Vec3A::splat(-1e30), Vec3A::splat(-1e30));
            }
            let lo = t.v[0].min(t.v[1]).min(t.v[2]);
            let hi = t.v[0].max(t.v[1]).max(t.v[2]);
            // Pad so f32 box tests never reject a ray that the f64 test accepts.
            let pad = (hi - lo).max_element().max(hi.abs().max_element()) * 1e-5 + 1e-9;
            Aabb::new((lo - pad).as_vec3().into(), (hi + pad).as_vec3().into())
        })
        .collect();
    build_bvh2(
        &aabbs,
        BvhBuildParams::fast_build(),
        &mut Duration::default(),
    )
}

/// Casts one primary ray per pixel centre for every batch element of `verts_view` (flat `(B, N, 3)` view space).
/// `params.projection` is ignored (the camera says it); `params.cull_backfaces` is honoured.
pub fn raycast(
    mesh_view: &ScreenMesh<'_>,
    camera: &RayCamera,
    params: &RasterParams,
) -> Result<Fragments> {
    mesh_view.validate_as("verts_view")?;
    params.validate()?;
    camera.validate()?;
    if let Some(index) = mesh_view
        .verts_screen
        .iter()
        .position(|v| v.abs() > MAX_COORD)
    {
        return Err(RasterError::Parameter {
            arg: "verts_view",
            message: format!(
                "coordinate {} at flat index {index} exceeds {MAX_COORD:e} (the BVH works in float32)",
                mesh_view.verts_screen[index]
            ),
        });
    }
    let (h, w) = (params.height, params.width);
    let hw = h * w;
    let ortho = camera.orthographic;
    let tw = (camera.viewing_angle.to_radians() / 2.0).tan();
    let len = mesh_view.batch.saturating_mul(hw);
    let mut face_index = try_filled_vec(len, -1i32, "face_index")?;
    let mut depth = try_filled_vec(len, params.far as f32, "depth")?;
    face_index
        .par_chunks_mut(hw)
        .zip(depth.par_chunks_mut(hw))
        .enumerate()
        .for_each(|(b, (fi, dp))| {
            let tris = prepare(mesh_view, b, ortho, params.cull_backfaces);
            let bvh = build(&tris);
            fi.par_chunks_mut(w)
                .zip(dp.par_chunks_mut(w))
                .enumerate()
                .for_each(|(i, (fi_row, dp_row))| {
                    let y = -((2 * i + 1) as f64 - h as f64) / h as f64;
                    for j in 0..w {
                        let x = ((2 * j + 1) as f64 - w as f64) / w as f64;
                        let (origin, dir) = if ortho {
                            (
                                DVec3::new(x * camera.ortho_scale, y * camera.ortho_scale, 0.0),
                                DVec3::Z,
                            )
                        } else {
                            (DVec3::ZERO, DVec3::new(x * tw, y * tw, 1.0))
                        };
                        // t equals z because dir.z == 1 (and origin.z == 0).
                        let ray = Ray::new(
                            origin.as_vec3().into(),
                            dir.as_vec3().into(),
                            params.near as f32 * 0.999,
                            (params.far * 1.001) as f32,
                        );
                        let mut best: Option<(f64, usize)> = None;
                        let mut hit = RayHit::none();
                        bvh.ray_traverse(ray, &mut hit, |_ray, id| {
                            let f = bvh.primitive_indices[id] as usize;
                            let t = &tris[f];
                            if !t.active {
                                return f32::INFINITY;
                            }
                            let Some(z) = intersect(t, origin, dir, ortho) else {
                                return f32::INFINITY;
                            };
                            if !(z >= params.near && z <= params.far) {
                                return f32::INFINITY;
                            }
                            let better = match best {
                                None => true,
                                Some((bz, bf)) => z < bz || (z == bz && f < bf),
                            };
                            if better {
                                best = Some((z, f));
                            }
                            // Report a slightly larger distance so that the traversal keeps testing exact ties.
                            let bz = best.map_or(z, |(bz, _)| bz);
                            (bz * (1.0 + 1e-6) + 1e-12) as f32
                        });
                        if let Some((z, f)) = best {
                            fi_row[j] = f as i32;
                            dp_row[j] = z as f32;
                        }
                    }
                });
        });
    Ok(Fragments { face_index, depth })
}
