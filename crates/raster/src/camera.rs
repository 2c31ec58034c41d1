//! Camera conventions of the Neural Mesh Renderer (see docs/ARCHITECTURE.md): spherical eye position, look-at with
//! tilt, perspective and orthographic projection to screen space `(x_ndc, y_ndc, z_view)`.

use glam::DVec3;

use crate::error::{RasterError, Result};

/// Smallest accepted perspective field of view, degrees: narrower views project unit coordinates beyond what
/// float32 screen coordinates hold (the Python camera refuses the same range).
pub const MIN_VIEWING_ANGLE: f64 = 1e-4;

/// A camera on a sphere around the origin, NMR's `get_points_from_angles` plus tilt. Angles in degrees.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SphericalCamera {
    /// Distance of the eye from the origin.
    pub distance: f64,
    /// Azimuth in degrees.
    pub azimuth: f64,
    /// Elevation in degrees.
    pub elevation: f64,
    /// Roll of the up vector about the viewing axis, degrees, counter-clockwise in the image.
    pub tilt: f64,
    /// Full vertical field of view in degrees (perspective).
    pub viewing_angle: f64,
    /// Near clipping depth.
    pub near: f64,
    /// Far clipping depth.
    pub far: f64,
    /// Orthographic instead of perspective projection.
    pub orthographic: bool,
    /// Half the visible extent (orthographic).
    pub ortho_scale: f64,
}

impl Default for SphericalCamera {
    fn default() -> Self {
        SphericalCamera {
            distance: 2.732,
            azimuth: 0.0,
            elevation: 0.0,
            tilt: 0.0,
            viewing_angle: 30.0,
            near: 0.1,
            far: 100.0,
            orthographic: false,
            ortho_scale: 1.0,
        }
    }
}

/// World-to-view rotation: rows are the view axes `x`, `y`, `z` in world space, plus the eye position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewTransform {
    /// Eye position (world).
    pub eye: DVec3,
    /// View x axis (world).
    pub x: DVec3,
    /// View y axis (world).
    pub y: DVec3,
    /// View z axis = viewing direction (world).
    pub z: DVec3,
}

impl ViewTransform {
    /// `verts_view = (p - eye) @ [x; y; z]^T`.
    #[inline]
    pub fn to_view(&self, p: DVec3) -> DVec3 {
        let d = p - self.eye;
        DVec3::new(d.dot(self.x), d.dot(self.y), d.dot(self.z))
    }
}

/// NMR look-at: `z = normalize(at - eye)`, `x = normalize(cross(up, z))`, `y = cross(z, x)`; then the tilt rolls
/// the axes: `x' = cos t x + sin t y`, `y' = cos t y - sin t x`.
///
/// Errors when `eye == at` or `up` is parallel to the viewing direction.
pub fn look_at(eye: DVec3, at: DVec3, up: DVec3, tilt_deg: f64) -> Result<ViewTransform> {
    let z = (at - eye)
        .try_normalize()
        .ok_or_else(|| RasterError::Parameter {
            arg: "eye",
            message: "eye and at coincide (no viewing direction)".into(),
        })?;
    let x = up
        .cross(z)
        .try_normalize()
        .ok_or_else(|| RasterError::Parameter {
            arg: "up",
            message: "up is parallel to the viewing direction".into(),
        })?;
    let y = z.cross(x);
    let (st, ct) = tilt_deg.to_radians().sin_cos();
    Ok(ViewTransform {
        eye,
        x: ct * x + st * y,
        y: ct * y - st * x,
        z,
    })
}

impl SphericalCamera {
    /// Checks the parameters: finite, `distance > 0`, `MIN_VIEWING_ANGLE <= viewing_angle < 180`,
    /// `0 <= near < far`, `ortho_scale > 0`.
    pub fn validate(&self) -> Result<()> {
        let vals = [
            ("distance", self.distance),
            ("azimuth", self.azimuth),
            ("elevation", self.elevation),
            ("tilt", self.tilt),
            ("viewing_angle", self.viewing_angle),
            ("ortho_scale", self.ortho_scale),
        ];
        for (arg, v) in vals {
            if !v.is_finite() {
                return Err(RasterError::Parameter {
                    arg,
                    message: format!("must be finite, got {v}"),
                });
            }
        }
        if self.distance <= 0.0 {
            return Err(RasterError::Parameter {
                arg: "distance",
                message: format!("must be > 0, got {}", self.distance),
            });
        }
        if !(self.viewing_angle >= MIN_VIEWING_ANGLE && self.viewing_angle < 180.0) {
            return Err(RasterError::Parameter {
                arg: "viewing_angle",
                message: format!(
                    "must be in [{MIN_VIEWING_ANGLE}, 180) degrees, got {}",
                    self.viewing_angle
                ),
            });
        }
        if self.ortho_scale <= 0.0 {
            return Err(RasterError::Parameter {
                arg: "ortho_scale",
                message: format!("must be > 0, got {}", self.ortho_scale),
            });
        }
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

    /// Eye position `d * (cos(el) sin(az), sin(el), -cos(el) cos(az))`.
    pub fn eye(&self) -> DVec3 {
        let (az, el) = (self.azimuth.to_radians(), self.elevation.to_radians());
        self.distance * DVec3::new(el.cos() * az.sin(), el.sin(), -el.cos() * az.cos())
    }

    /// The view transform: look at the origin from [`SphericalCamera::eye`] with up `+Y`, then tilt.
    ///
    /// At the poles (`cos(el) = 0`) the x axis is taken as the limit `sign(cos el) * (cos az, 0, sin az)`, as in the
    /// Python camera.
    pub fn view(&self) -> Result<ViewTransform> {
        let (az, el) = (self.azimuth.to_radians(), self.elevation.to_radians());
        let (ce, se, ca, sa) = (el.cos(), el.sin(), az.cos(), az.sin());
        let z = DVec3::new(-ce * sa, -se, ce * ca);
        let sign = if ce >= 0.0 { 1.0 } else { -1.0 };
        let x = DVec3::new(ca, 0.0, sa) * sign;
        let y = z.cross(x);
        let (st, ct) = self.tilt.to_radians().sin_cos();
        Ok(ViewTransform {
            eye: self.eye(),
            x: ct * x + st * y,
            y: ct * y - st * x,
            z,
        })
    }

    /// Projects view-space points (flat `(N, 3)`) to screen space `(x_ndc, y_ndc, z_view)`.
    pub fn project_view(&self, verts_view: &[f32]) -> Vec<f32> {
        project(
            verts_view,
            self.viewing_angle,
            self.orthographic,
            self.ortho_scale,
        )
    }
}

/// Projects view-space points (flat `(N, 3)`) to screen space: perspective `x / (z tan(angle/2))`, orthographic
/// `x / scale`; the third component is `z_view`. Points at `z = 0` (perspective) get infinite coordinates.
pub fn project(
    verts_view: &[f32],
    viewing_angle: f64,
    orthographic: bool,
    ortho_scale: f64,
) -> Vec<f32> {
    let width = (viewing_angle.to_radians() / 2.0).tan();
    verts_view
        .chunks_exact(3)
        .flat_map(|p| {
            let (x, y, z) = (p[0] as f64, p[1] as f64, p[2] as f64);
            if orthographic {
                [(x / ortho_scale) as f32, (y / ortho_scale) as f32, p[2]]
            } else {
                [(x / (z * width)) as f32, (y / (z * width)) as f32, p[2]]
            }
        })
        .collect()
}

/// Transforms world points (flat `(N, 3)`) to view space.
pub fn world_to_view(verts_world: &[f32], view: &ViewTransform) -> Vec<f32> {
    verts_world
        .chunks_exact(3)
        .flat_map(|p| {
            let v = view.to_view(DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64));
            [v.x as f32, v.y as f32, v.z as f32]
        })
        .collect()
}
