//! Lambert flat shading with `k` directional lights and ambient light, two-sided (normals flipped toward the camera).
//!
//! `s = ambient + sum_j color_j * max(dot(dir_j, n), 0)` with `dir_j` the unit direction FROM the surface TOWARD light
//! `j` (normalized here), `face_color = clamp(reflectance * s, 0, 1)`.

use glam::DVec3;

use crate::error::{RasterError, Result};
use crate::input::check_finite;

/// A light direction whose components are all at most this in magnitude is refused as the zero vector (it has
/// no direction; the Python lights refuse the same).
pub const MIN_LIGHT_DIRECTION: f32 = 1e-9;

/// Directional lights plus ambient light.
#[derive(Debug, Clone, PartialEq)]
pub struct Lights {
    /// Directions toward each light (normalized before use).
    pub directions: Vec<[f32; 3]>,
    /// RGB intensity of each light.
    pub colors: Vec<[f32; 3]>,
    /// RGB ambient intensity.
    pub ambient: [f32; 3],
}

impl Default for Lights {
    /// NMR's defaults: ambient 0.5 and one white light of intensity 0.5 toward `(0, 1, 0)`.
    fn default() -> Self {
        Lights {
            directions: vec![[0.0, 1.0, 0.0]],
            colors: vec![[0.5, 0.5, 0.5]],
            ambient: [0.5, 0.5, 0.5],
        }
    }
}

impl Lights {
    /// Checks one colour per direction, finite values and non-zero directions (see [`MIN_LIGHT_DIRECTION`]).
    pub fn validate(&self) -> Result<()> {
        if self.directions.len() != self.colors.len() {
            return Err(RasterError::shape(
                "light_colors",
                format!("({}, 3) like light_directions", self.directions.len()),
                format!("({}, 3)", self.colors.len()),
            ));
        }
        check_finite("light_directions", self.directions.as_flattened())?;
        check_finite("light_colors", self.colors.as_flattened())?;
        check_finite("ambient", &self.ambient)?;
        if let Some(k) = self
            .directions
            .iter()
            .position(|d| d.iter().all(|x| x.abs() <= MIN_LIGHT_DIRECTION))
        {
            return Err(RasterError::Parameter {
                arg: "light_directions",
                message: format!(
                    "light {k} has the zero direction {:?}; give a non-zero vector toward the light",
                    self.directions[k]
                ),
            });
        }
        Ok(())
    }
}

/// Unit normal `normalize((v1 - v0) x (v2 - v0))`, or `None` for a degenerate face.
pub fn face_normal(v: [DVec3; 3]) -> Option<DVec3> {
    (v[1] - v[0]).cross(v[2] - v[0]).try_normalize()
}

/// Flips `n` toward the camera: perspective when `dot(n, eye - p) < 0` (`p` any point of the face), orthographic
/// when `dot(n, view_dir) > 0`.
pub fn flip_toward_camera(
    n: DVec3,
    p: DVec3,
    eye: DVec3,
    view_dir: DVec3,
    orthographic: bool,
) -> DVec3 {
    let away = if orthographic {
        n.dot(view_dir) > 0.0
    } else {
        n.dot(eye - p) < 0.0
    };
    if away {
        -n
    } else {
        n
    }
}

/// Shades one face: `clamp(reflectance * (ambient + sum_j color_j max(dot(dir_j, n), 0)), 0, 1)`.
pub fn lambert(n: DVec3, reflectance: [f32; 3], lights: &Lights) -> [f32; 3] {
    let mut s = [
        lights.ambient[0] as f64,
        lights.ambient[1] as f64,
        lights.ambient[2] as f64,
    ];
    for (d, c) in lights.directions.iter().zip(&lights.colors) {
        let dir = DVec3::new(d[0] as f64, d[1] as f64, d[2] as f64)
            .try_normalize()
            .unwrap_or(DVec3::ZERO);
        let k = dir.dot(n).max(0.0);
        for ch in 0..3 {
            s[ch] += c[ch] as f64 * k;
        }
    }
    let mut out = [0f32; 3];
    for ch in 0..3 {
        out[ch] = (reflectance[ch] as f64 * s[ch]).clamp(0.0, 1.0) as f32;
    }
    out
}
