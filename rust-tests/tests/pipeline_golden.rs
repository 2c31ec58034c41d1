//! The full pipeline against hand-computed Lambert shading and projection on a single triangle.

use meshadv_raster::camera::SphericalCamera;
use meshadv_raster::pipeline::{render, Lights, RenderSettings};

#[test]
fn single_triangle_lambert_shading_by_hand() {
    // Triangle in the z = 0 plane; the azimuth-0 camera sits at (0, 0, -d) looking toward +z.
    // Its normal (v1 - v0) x (v2 - v0) = (0, 0, 4) -> (0, 0, 1) points away from the eye, so two-sided shading flips it
    // to (0, 0, -1). Light toward (0, 1, -1)/sqrt(2): cos = 1/sqrt(2).
    let verts = [-1.0f32, -1.0, 0.0, 1.0, -1.0, 0.0, 0.0, 1.0, 0.0];
    let refl = [0.8f32, 0.6, 0.4];
    let lights = Lights {
        directions: vec![[0.0, 1.0, -1.0]],
        colors: vec![[0.5, 0.4, 0.3]],
        ambient: [0.3, 0.2, 0.1],
    };
    let cam = SphericalCamera {
        distance: 5.0,
        ..Default::default()
    };
    let settings = RenderSettings {
        height: 33,
        width: 33,
        background: [0.1, 0.2, 0.3],
        fill_back: true,
    };
    let out = render(&verts, &[0, 1, 2], &refl, &cam, &lights, &settings).expect("valid");
    let k = std::f64::consts::FRAC_1_SQRT_2;
    let want: Vec<f32> = (0..3)
        .map(|c| {
            (refl[c] as f64 * (lights.ambient[c] as f64 + lights.colors[0][c] as f64 * k))
                .clamp(0.0, 1.0) as f32
        })
        .collect();
    let centre = 16 * 33 + 16;
    assert_eq!(out.face_index[centre], 0);
    assert_eq!(out.alpha[centre], 1.0);
    for c in 0..3 {
        assert!(
            (out.image[3 * centre + c] - want[c]).abs() < 1e-6,
            "{:?} vs {want:?}",
            &out.image[3 * centre..]
        );
    }
    assert!((out.depth[centre] - 5.0).abs() < 1e-5);
    // Corners are background.
    assert_eq!(out.face_index[0], -1);
    assert_eq!(&out.image[..3], &[0.1, 0.2, 0.3]);
    assert_eq!(out.alpha[0], 0.0);
    assert_eq!(out.depth[0], 100.0);
    // Projection by hand: the bottom edge y = -1 lies at y_ndc = -1 / (5 tan 15deg) = -0.7464; pixel rows whose centre
    // is above it are covered in the centre column, rows below are not.
    let y_edge = -1.0 / (5.0 * 15f64.to_radians().tan());
    for i in 0..33 {
        let y = 1.0 - (2 * i + 1) as f64 / 33.0;
        let covered = out.face_index[i * 33 + 16] == 0;
        if y < y_edge - 1e-6 {
            assert!(!covered, "row {i} below the bottom edge");
        }
        if y > y_edge + 1e-6 && y < 0.0 {
            assert!(covered, "row {i} above the bottom edge");
        }
    }
    // One-sided: the face looks away from the camera and is culled.
    let culled = render(
        &verts,
        &[0, 1, 2],
        &refl,
        &cam,
        &lights,
        &RenderSettings {
            fill_back: false,
            ..settings
        },
    )
    .expect("valid");
    assert!(culled.face_index.iter().all(|&f| f == -1));
    let front = render(
        &verts,
        &[0, 2, 1],
        &refl,
        &cam,
        &lights,
        &RenderSettings {
            fill_back: false,
            ..settings
        },
    )
    .expect("valid");
    assert_eq!(front.face_index[centre], 0);
    assert_eq!(&front.image[3 * centre..3 * centre + 3], &want[..]);
}
