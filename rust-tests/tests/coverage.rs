//! Coverage rules: pixel centres, the top-left tie rule, watertight shared edges.

use meshadv_raster::rasterize_fragments;
use meshadv_raster_tests::{params, OwnedMesh, Rng};

/// Coverage count per pixel when each face is rasterized alone.
fn coverage_counts(mesh: &OwnedMesh, h: usize, w: usize) -> Vec<u32> {
    let mut counts = vec![0u32; h * w];
    for f in 0..mesh.num_faces() {
        let tri = &mesh.faces[3 * f..3 * f + 3];
        let verts: Vec<f32> = tri
            .iter()
            .flat_map(|&k| mesh.verts[3 * k as usize..3 * k as usize + 3].to_vec())
            .collect();
        let single = OwnedMesh::new(verts, vec![0, 1, 2]);
        let fr = rasterize_fragments(&single.view(), &params(h, w)).expect("valid");
        for (c, &fi) in counts.iter_mut().zip(&fr.face_index) {
            if fi >= 0 {
                *c += 1;
            }
        }
    }
    counts
}

#[test]
fn two_triangles_sharing_a_diagonal_cover_each_pixel_once() {
    for (h, w) in [(8, 8), (7, 9), (16, 5)] {
        // Quad slightly larger than the image, split along a diagonal that passes through pixel centres.
        let verts = vec![
            -1.5, -1.5, 1.0, 1.5, -1.5, 1.0, 1.5, 1.5, 1.0, -1.5, 1.5, 1.0,
        ];
        for faces in [
            vec![0, 1, 2, 0, 2, 3],
            vec![0, 1, 3, 1, 2, 3],
            vec![2, 1, 0, 3, 2, 0],
        ] {
            let mesh = OwnedMesh::new(verts.clone(), faces);
            let counts = coverage_counts(&mesh, h, w);
            assert!(counts.iter().all(|&c| c == 1), "{h}x{w}: counts {counts:?}");
        }
    }
}

#[test]
fn triangle_fans_on_the_pixel_grid_are_watertight() {
    let mut rng = Rng::new(7);
    let (h, w) = (12, 12);
    for _ in 0..30 {
        // Corners snapped to pixel centres and pixel-centre midpoints so that edges hit many centres exactly.
        let snap = |x: f32| ((x * w as f32).round()) / w as f32;
        let centre = [
            snap(rng.uniform(-0.5, 0.5)),
            snap(rng.uniform(-0.5, 0.5)),
            1.0,
        ];
        let k = 6 + rng.below(6); // enough spokes for the fan to contain the whole image
        let mut verts = centre.to_vec();
        for i in 0..k {
            let a = i as f32 / k as f32 * std::f32::consts::TAU + rng.uniform(0.0, 0.3);
            let r = 2.5 + rng.uniform(0.0, 0.5);
            verts.extend_from_slice(&[snap(r * a.cos()), snap(r * a.sin()), 1.0]);
        }
        let mut faces = Vec::new();
        for i in 0..k {
            let (a, b) = (1 + i as i32, 1 + ((i + 1) % k) as i32);
            // Random winding per face: two-sided rasterization must not care.
            if rng.below(2) == 0 {
                faces.extend_from_slice(&[0, a, b]);
            } else {
                faces.extend_from_slice(&[b, a, 0]);
            }
        }
        let mesh = OwnedMesh::new(verts, faces);
        let counts = coverage_counts(&mesh, h, w);
        assert!(
            counts.iter().all(|&c| c == 1),
            "fan with {k} faces: counts {counts:?}"
        );
    }
}

#[test]
fn pixel_centre_rule_on_an_axis_aligned_triangle() {
    // 4x4 image: pixel centres at x, y in {-0.75, -0.25, 0.25, 0.75}. Right triangle with legs on x = -0.25 and
    // y = -0.25 (through pixel centres) and hypotenuse from (-0.25, 0.75) to (0.75, -0.25).
    let verts = vec![-0.25, -0.25, 1.0, 0.75, -0.25, 1.0, -0.25, 0.75, 1.0];
    let mesh = OwnedMesh::new(verts, vec![0, 1, 2]);
    let fr = rasterize_fragments(&mesh.view(), &params(4, 4)).expect("valid");
    let covered: Vec<(usize, usize)> = (0..16)
        .filter(|&p| fr.face_index[p] == 0)
        .map(|p| (p / 4, p % 4))
        .collect();
    // Left edge x = -0.25 (column 1) is a left edge: included. Bottom edge y = -0.25 (row 2) is a bottom edge:
    // excluded. Hypotenuse x + y = 0.5 passes through (0.25, 0.25) = (row 1, col 2) and the corner (row 0, col 1):
    // a right edge, excluded. Only (row 1, col 1) is strictly inside or on owned edges.
    assert_eq!(covered, vec![(1, 1)]);
    // Mirrored horizontally, the vertical leg becomes a right edge and the hypotenuse a left edge.
    let verts = vec![0.25, -0.25, 1.0, -0.75, -0.25, 1.0, 0.25, 0.75, 1.0];
    let mesh = OwnedMesh::new(verts, vec![0, 1, 2]);
    let fr = rasterize_fragments(&mesh.view(), &params(4, 4)).expect("valid");
    let covered: Vec<(usize, usize)> = (0..16)
        .filter(|&p| fr.face_index[p] == 0)
        .map(|p| (p / 4, p % 4))
        .collect();
    // (row 1, col 1) lies only on the hypotenuse, now a left edge: included; (row 1, col 2) and the corner
    // (row 0, col 2) lie on the vertical leg x = 0.25, now a right edge: excluded.
    assert_eq!(covered, vec![(1, 1)]);
}

#[test]
fn pixel_centres_strictly_inside_are_covered() {
    let mut rng = Rng::new(11);
    let (h, w) = (20, 24);
    for _ in 0..50 {
        let v: Vec<f32> = (0..3)
            .flat_map(|_| [rng.uniform(-1.2, 1.2), rng.uniform(-1.2, 1.2), 1.0])
            .collect();
        let mesh = OwnedMesh::new(v.clone(), vec![0, 1, 2]);
        let fr = rasterize_fragments(&mesh.view(), &params(h, w)).expect("valid");
        // Independent inside test in f64 with a margin: strictly inside => covered, strictly outside => not.
        let e = |a: usize, b: usize, x: f64, y: f64| {
            let (ax, ay, bx, by) = (
                v[3 * a] as f64,
                v[3 * a + 1] as f64,
                v[3 * b] as f64,
                v[3 * b + 1] as f64,
            );
            (bx - ax) * (y - ay) - (by - ay) * (x - ax)
        };
        let area = e(0, 1, v[6] as f64, v[7] as f64);
        if area.abs() < 1e-3 {
            continue;
        }
        for i in 0..h {
            for j in 0..w {
                let x = (2 * j + 1) as f64 / w as f64 - 1.0;
                let y = 1.0 - (2 * i + 1) as f64 / h as f64;
                let s = [e(1, 2, x, y), e(2, 0, x, y), e(0, 1, x, y)].map(|t| t * area.signum());
                let covered = fr.face_index[i * w + j] == 0;
                if s.iter().all(|&t| t > 1e-6) {
                    assert!(covered, "pixel ({i}, {j}) strictly inside but not covered");
                }
                if s.iter().any(|&t| t < -1e-6) {
                    assert!(!covered, "pixel ({i}, {j}) strictly outside but covered");
                }
            }
        }
    }
}
