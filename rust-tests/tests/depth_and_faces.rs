//! Depth order, ties, perspective-correct and orthographic depth, near/far clipping, culling, degenerate faces.

use meshadv_raster::{rasterize_fragments, RasterParams};
use meshadv_raster_tests::{ortho_params, params, project30, OwnedMesh};

/// A big triangle covering the image at view depth `z` (screen space).
fn big(z: f32) -> Vec<f32> {
    vec![-3.0, -3.0, z, 3.0, -3.0, z, 0.0, 3.0, z]
}

#[test]
fn nearest_face_wins_regardless_of_order() {
    for (z0, z1, want) in [(2.0, 3.0, 0), (3.0, 2.0, 1)] {
        let mut v = big(z0);
        v.extend(big(z1));
        let mesh = OwnedMesh::new(v, vec![0, 1, 2, 3, 4, 5]);
        let fr = rasterize_fragments(&mesh.view(), &params(6, 6)).expect("valid");
        assert!(fr.face_index.iter().all(|&f| f == want));
        let zmin = z0.min(z1);
        assert!(fr.depth.iter().all(|&d| d == zmin));
    }
}

#[test]
fn exact_depth_tie_goes_to_the_lower_index() {
    let mut v = big(2.0);
    v.extend(big(2.0));
    for faces in [vec![0, 1, 2, 3, 4, 5], vec![3, 4, 5, 0, 1, 2]] {
        let mesh = OwnedMesh::new(v.clone(), faces);
        let fr = rasterize_fragments(&mesh.view(), &params(5, 7)).expect("valid");
        assert!(fr.face_index.iter().all(|&f| f == 0));
    }
}

#[test]
fn perspective_depth_matches_the_view_ray_hit() {
    // A tilted plane z = 3 + 0.5 x_view in view space, projected with a 30 degree field of view.
    let view = vec![-1.0f32, -1.0, 2.5, 1.0, -1.0, 3.5, 0.0, 1.2, 3.0];
    let screen = project30(&view);
    let mesh = OwnedMesh::new(screen, vec![0, 1, 2]);
    let (h, w) = (32, 32);
    let fr = rasterize_fragments(&mesh.view(), &params(h, w)).expect("valid");
    let tw = (15f64).to_radians().tan();
    let mut checked = 0;
    for i in 0..h {
        for j in 0..w {
            if fr.face_index[i * w + j] != 0 {
                continue;
            }
            let x = (2 * j + 1) as f64 / w as f64 - 1.0;
            // Ray (x tw, y tw, 1) t hits z = 3 + 0.5 * x_view: t = 3 + 0.5 * x tw t.
            let z = 3.0 / (1.0 - 0.5 * x * tw);
            let d = fr.depth[i * w + j] as f64;
            assert!(
                (d - z).abs() < 1e-4 * z,
                "pixel ({i}, {j}): depth {d} vs {z}"
            );
            checked += 1;
        }
    }
    assert!(checked > 50);
}

#[test]
fn orthographic_depth_is_linear_in_screen_space() {
    // Ortho screen = view / scale with scale 1: plane z = 3 + 0.5 x.
    let v = vec![-1.0f32, -1.0, 2.5, 1.0, -1.0, 3.5, 0.0, 1.2, 3.0];
    let mesh = OwnedMesh::new(v, vec![0, 1, 2]);
    let (h, w) = (16, 16);
    let fr = rasterize_fragments(&mesh.view(), &ortho_params(h, w)).expect("valid");
    let mut checked = 0;
    for i in 0..h {
        for j in 0..w {
            if fr.face_index[i * w + j] == 0 {
                let x = (2 * j + 1) as f64 / w as f64 - 1.0;
                assert!((fr.depth[i * w + j] as f64 - (3.0 + 0.5 * x)).abs() < 1e-5);
                checked += 1;
            }
        }
    }
    assert!(checked > 20);
}

#[test]
fn near_and_far_clip_per_pixel() {
    // Orthographic plane z = 3 + 2 x crossing near = 2.5 and far = 3.5: only |x| <= 0.25 is kept.
    let v = vec![-3.0f32, -3.0, -3.0, 3.0, -3.0, 9.0, 0.0, 3.0, 3.0];
    let mesh = OwnedMesh::new(v, vec![0, 1, 2]);
    let (h, w) = (8, 16);
    let p = RasterParams {
        near: 2.5,
        far: 3.5,
        ..ortho_params(h, w)
    };
    let fr = rasterize_fragments(&mesh.view(), &p).expect("valid");
    for i in 0..h {
        for j in 0..w {
            let x = (2 * j + 1) as f64 / w as f64 - 1.0;
            let z = 3.0 + 2.0 * x;
            let inside = (2.5..=3.5).contains(&z);
            assert_eq!(
                fr.face_index[i * w + j] == 0,
                inside,
                "pixel ({i}, {j}), z = {z}"
            );
            if !inside {
                assert_eq!(fr.depth[i * w + j], 3.5, "background depth is far");
            }
        }
    }
}

#[test]
fn back_faces_are_drawn_two_sided_and_dropped_when_culling() {
    // Counter-clockwise in y-up NDC = back-facing under NMR's mirrored view frame.
    let ccw = vec![-0.8f32, -0.8, 2.0, 0.8, -0.8, 2.0, 0.0, 0.8, 2.0];
    for (faces, back) in [(vec![0, 1, 2], true), (vec![0, 2, 1], false)] {
        let mesh = OwnedMesh::new(ccw.clone(), faces);
        let two = rasterize_fragments(&mesh.view(), &params(8, 8)).expect("valid");
        assert!(two.face_index.contains(&0));
        let culled = rasterize_fragments(
            &mesh.view(),
            &RasterParams {
                cull_backfaces: true,
                ..params(8, 8)
            },
        )
        .expect("valid");
        assert_eq!(culled.face_index.contains(&0), !back);
    }
}

#[test]
fn degenerate_and_behind_camera_faces_are_not_drawn() {
    let v = vec![
        -0.5, -0.5, 2.0, 0.5, 0.5, 2.0, 0.0, 0.0, 2.0, // collinear: zero area
        -0.9, -0.9, 2.0, 0.9, -0.9, -1.0, 0.0, 0.9, 2.0, // a vertex behind the camera
        -0.2, -0.2, 3.0, 0.2, -0.2, 3.0, 0.0, 0.2, 3.0, // normal
    ];
    let mesh = OwnedMesh::new(v, (0..9).collect());
    let fr = rasterize_fragments(&mesh.view(), &params(16, 16)).expect("valid");
    assert!(!fr.face_index.contains(&0));
    assert!(!fr.face_index.contains(&1));
    assert!(fr.face_index.contains(&2));
}
