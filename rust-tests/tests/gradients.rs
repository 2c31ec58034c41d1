//! Gradients: the exact attribute gradient against finite differences, and NMR's vertex gradient against a
//! hand-computed case, signs on a square, and the occlusion rule of the OUT sweep.

use meshadv_raster::backward::EPS;
use meshadv_raster_tests::{backward, forward, params, random_attrs, random_soup, OwnedMesh, Rng};

#[test]
fn attribute_gradient_matches_finite_differences() {
    let mut rng = Rng::new(5);
    let mesh = random_soup(&mut rng, 40, 1.0, 5.0);
    let (h, w, c) = (24, 20, 3);
    let p = params(h, w);
    let attrs = random_attrs(&mut rng, mesh.num_faces() * c);
    let out = forward(&mesh, &attrs, c, &p);
    let g: Vec<f32> = (0..h * w * c).map(|_| rng.uniform(-1.0, 1.0)).collect();
    let loss = |a: &[f32]| -> f64 {
        let o = forward(&mesh, a, c, &p);
        o.image
            .iter()
            .zip(&g)
            .map(|(&x, &y)| x as f64 * y as f64)
            .sum()
    };
    let grads = backward(&mesh, &attrs, c, &p, &out, &g);
    let base = loss(&attrs);
    let step = 0.25f32;
    for k in 0..attrs.len() {
        let mut a = attrs.clone();
        a[k] += step;
        let fd = (loss(&a) - base) / step as f64;
        let an = grads.grad_face_attrs[k] as f64;
        assert!(
            (fd - an).abs() <= 1e-3 * (1.0 + fd.abs()),
            "attr {k}: fd {fd} vs analytic {an}"
        );
    }
}

#[test]
fn vertex_gradient_matches_a_hand_computed_case() {
    // 1 x 4 image, pixel centres x = -0.75, -0.25, 0.25, 0.75. Triangle with a vertical right edge at x = 0 covers
    // columns 0 and 1. One channel, attribute 1, background 0, cotangent -1 everywhere (loss = -sum(image)).
    // Only the OUT sweep of the right edge contributes (see docs/NMR_GRADIENT.md): pixels 2 and 3 at 0.5 and 1.5
    // pixels beyond the edge, i.e. 0.5 and 1.5 NDC units of motion of each endpoint.
    let mesh = OwnedMesh::new(
        vec![0.0, -2.0, 2.0, 0.0, 2.0, 2.0, -3.0, 0.0, 2.0],
        vec![0, 1, 2],
    );
    let p = params(1, 4);
    let out = forward(&mesh, &[1.0], 1, &p);
    assert_eq!(out.face_index, vec![0, 0, -1, -1]);
    let g = backward(&mesh, &[1.0], 1, &p, &out, &[-1.0; 4]);
    let want = -(1.0 / (0.5 + EPS) + 1.0 / (1.5 + EPS));
    for v in 0..2 {
        assert!(
            (g.grad_verts_screen[3 * v] as f64 - want).abs() < 1e-5,
            "{:?}",
            g.grad_verts_screen
        );
        assert_eq!(g.grad_verts_screen[3 * v + 1], 0.0);
    }
    assert_eq!(&g.grad_verts_screen[6..9], &[0.0, 0.0, 0.0]);
    assert!(
        g.grad_verts_screen
            .iter()
            .skip(2)
            .step_by(3)
            .all(|&z| z == 0.0),
        "no z gradient"
    );
}

fn square(extra: &[f32]) -> OwnedMesh {
    // Corners off the pixel grid: a pixel centre exactly on an edge gives NMR's delta / EPS spike.
    let mut v = vec![
        -0.47, -0.41, 2.0, 0.43, -0.41, 2.0, 0.43, 0.45, 2.0, -0.47, 0.45, 2.0,
    ];
    v.extend_from_slice(extra);
    let mut faces = vec![0, 1, 2, 0, 2, 3];
    if !extra.is_empty() {
        faces.extend_from_slice(&[4, 5, 6]);
    }
    OwnedMesh::new(v, faces)
}

#[test]
fn growing_a_silhouette_gets_the_expected_signs() {
    // loss = -sum(alpha): every vertex gradient points inward (moving outward lowers the loss).
    let mesh = square(&[]);
    let (h, w) = (20, 20);
    let p = params(h, w);
    let attrs = [1.0f32, 1.0];
    let out = forward(&mesh, &attrs, 1, &p);
    let g = backward(&mesh, &attrs, 1, &p, &out, &vec![-1.0; h * w]);
    let gv = &g.grad_verts_screen;
    let corners = [(-1.0f32, -1.0f32), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)];
    for (k, (sx, sy)) in corners.iter().enumerate() {
        assert!(
            gv[3 * k] * sx < 0.0,
            "vertex {k} x gradient {} should point inward",
            gv[3 * k]
        );
        assert!(
            gv[3 * k + 1] * sy < 0.0,
            "vertex {k} y gradient {} should point inward",
            gv[3 * k + 1]
        );
    }
    // Only decreasing contributions are kept: with cotangent +1 (loss = sum(alpha)) shrinking helps, so the signs flip.
    let g2 = backward(&mesh, &attrs, 1, &p, &out, &vec![1.0; h * w]);
    for k in 0..4 {
        assert!(
            g2.grad_verts_screen[3 * k] * gv[3 * k] < 0.0,
            "{:?} vs {:?}",
            g2.grad_verts_screen,
            gv
        );
    }
}

#[test]
fn out_sweep_respects_occlusion() {
    // A wall at x >= 0.6 with attribute 0, either in front of (z = 1) or behind (z = 3) the square (z = 2).
    let (h, w) = (20, 20);
    let p = params(h, w);
    let attrs = [1.0f32, 1.0, 0.0];
    let right_x = |z: f32| {
        let mesh = square(&[0.6, -5.0, z, 5.0, -5.0, z, 0.6, 5.0, z]);
        let out = forward(&mesh, &attrs, 1, &p);
        let g = backward(&mesh, &attrs, 1, &p, &out, &vec![-1.0; h * w]);
        g.grad_verts_screen[3]
    };
    let (front, behind) = (right_x(1.0), right_x(3.0));
    assert!(
        front < 0.0,
        "the free column between square and wall still counts: {front}"
    );
    assert!(
        behind < front,
        "wall pixels count only when the wall is behind: front {front}, behind {behind}"
    );
}

#[test]
fn invisible_faces_get_no_vertex_gradient() {
    // A small triangle fully hidden behind the square gets exactly zero gradient.
    let mesh = square(&[-0.1, -0.1, 5.0, 0.1, -0.1, 5.0, 0.0, 0.1, 5.0]);
    let (h, w) = (16, 16);
    let p = params(h, w);
    let attrs = [1.0f32, 1.0, 0.3];
    let out = forward(&mesh, &attrs, 1, &p);
    assert!(!out.face_index.contains(&2));
    let mut rng = Rng::new(1);
    let grad: Vec<f32> = (0..h * w).map(|_| rng.uniform(-1.0, 1.0)).collect();
    let g = backward(&mesh, &attrs, 1, &p, &out, &grad);
    assert!(g.grad_verts_screen[12..21].iter().all(|&x| x == 0.0));
    assert_eq!(g.grad_face_attrs[2], 0.0);
}
