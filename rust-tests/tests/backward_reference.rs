//! The backward pass against the plain implementation in `meshadv_raster_tests::nmr_reference`: equal
//! within 1e-5 relative on randomized scenes and on the scenes of the other tests, and bit-identical on every
//! instruction set this CPU offers.

use meshadv_raster::backward::{rasterize_backward_on, Isa, Visibility};
use meshadv_raster::camera::{project, world_to_view, SphericalCamera};
use meshadv_raster::{BackwardInputs, FaceAttrs, Gradients, RasterParams};
use meshadv_raster_tests::nmr_reference::reference_backward;
use meshadv_raster_tests::{
    forward, ortho_params, params, project30, random_attrs, random_soup, random_view_soup,
    soup_faces, OwnedMesh, Rng,
};

/// Backward (NMR's vertex gradient) of `mesh` on `isa` (or the reference when `None`), with background 0.
fn grads(
    mesh: &OwnedMesh,
    attrs: &[f32],
    c: usize,
    p: &RasterParams,
    grad: &[f32],
    isa: Option<Isa>,
) -> Gradients {
    grads_of(Visibility::Nmr, mesh, attrs, c, p, grad, isa)
}

/// [`grads`] with the vertex gradient `visibility`.
fn grads_of(
    visibility: Visibility,
    mesh: &OwnedMesh,
    attrs: &[f32],
    c: usize,
    p: &RasterParams,
    grad: &[f32],
    isa: Option<Isa>,
) -> Gradients {
    let out = forward(mesh, attrs, c, p);
    let bg = vec![0.0f32; c];
    let a = FaceAttrs {
        values: attrs,
        background: &bg,
        channels: c,
    };
    let inputs = BackwardInputs {
        face_index: &out.face_index,
        image: &out.image,
        grad_image: grad,
        vertex_grad: true,
        visibility,
    };
    match isa {
        Some(isa) => rasterize_backward_on(isa, &mesh.view(), &a, p, &inputs),
        None => reference_backward(&mesh.view(), &a, p, &inputs),
    }
    .expect("valid test input")
}

/// Compares the backward (NMR's vertex gradient) with the reference; returns the largest relative error (to the
/// largest gradient).
fn check(name: &str, mesh: &OwnedMesh, c: usize, p: &RasterParams, rng: &mut Rng) -> f64 {
    check_of(Visibility::Nmr, name, mesh, c, p, rng)
}

/// [`check`] for the vertex gradient `visibility`.
fn check_of(
    visibility: Visibility,
    name: &str,
    mesh: &OwnedMesh,
    c: usize,
    p: &RasterParams,
    rng: &mut Rng,
) -> f64 {
    let grads =
        |attrs: &[f32], grad: &[f32], isa| grads_of(visibility, mesh, attrs, c, p, grad, isa);
    let attrs = random_attrs(rng, mesh.batch * mesh.num_faces() * c);
    let n = mesh.batch * p.pixels() * c;
    let grad: Vec<f32> = (0..n).map(|_| rng.uniform(-1.0, 1.0)).collect();
    let want = grads(&attrs, &grad, None);
    let got = grads(&attrs, &grad, Some(Isa::Portable));
    for isa in Isa::all_available().into_iter().skip(1) {
        let fast = grads(&attrs, &grad, Some(isa));
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(
            bits(&fast.grad_verts_screen),
            bits(&got.grad_verts_screen),
            "{name}: {isa:?} and Portable differ"
        );
    }
    assert_eq!(got.grad_face_attrs, want.grad_face_attrs, "{name}");
    let (g, w) = (&got.grad_verts_screen, &want.grad_verts_screen);
    let scale = w.iter().fold(0f64, |m, &x| m.max((x as f64).abs()));
    assert!(scale > 0.0, "{name}: the scene has no vertex gradient");
    let mut worst = 0f64;
    for (k, (&x, &y)) in g.iter().zip(w).enumerate() {
        let err = (x as f64 - y as f64).abs();
        // 1e-5 relative to the element, or to the scene's largest gradient for elements that are sums cancelling to
        // (nearly) nothing.
        assert!(
            err <= 1e-5 * (y as f64).abs().max(1e-2 * scale),
            "{name}: element {k}: {x} vs reference {y} (largest gradient {scale})"
        );
        worst = worst.max(err / scale);
    }
    worst
}

#[test]
fn random_soups_match_the_reference() {
    let mut rng = Rng::new(11);
    for case in 0..24 {
        let count = 1 + rng.below(300);
        let mut mesh = random_soup(&mut rng, count, 1.0, 5.0);
        if case % 3 == 0 {
            let shifted: Vec<f32> = mesh
                .verts
                .chunks(3)
                .flat_map(|q| [q[0] * 0.9 + 0.05, q[1] - 0.03, q[2] + 0.5])
                .collect();
            mesh.verts.extend(shifted);
            mesh.batch = 2;
        }
        let (h, w) = (8 + rng.below(90), 8 + rng.below(90));
        let c = 1 + rng.below(6);
        let p = if case % 4 == 1 {
            ortho_params(h, w)
        } else {
            RasterParams {
                cull_backfaces: case % 5 == 2,
                near: if case % 6 == 3 { 2.0 } else { 0.1 },
                far: if case % 6 == 3 { 4.0 } else { 100.0 },
                ..params(h, w)
            }
        };
        check(&format!("soup {case}"), &mesh, c, &p, &mut rng);
    }
}

#[test]
fn the_local_gradient_matches_the_reference() {
    let mut rng = Rng::new(15);
    for case in 0..18 {
        let radius = [1, 2, 3, 7][case % 4];
        let visibility = Visibility::Local { radius };
        let count = 1 + rng.below(300);
        let mesh = if case % 3 == 0 {
            OwnedMesh::new(
                project30(&random_view_soup(&mut rng, count)),
                soup_faces(count),
            )
        } else {
            random_soup(&mut rng, count, 1.0, 5.0)
        };
        let (h, w) = (8 + rng.below(70), 8 + rng.below(70));
        let c = 1 + rng.below(6);
        let p = match case % 5 {
            1 => ortho_params(h, w),
            2 => RasterParams {
                cull_backfaces: true,
                near: 2.0,
                far: 4.0,
                ..params(h, w)
            },
            _ => params(h, w),
        };
        check_of(
            visibility,
            &format!("local soup {case}, radius {radius}"),
            &mesh,
            c,
            &p,
            &mut rng,
        );
    }
}

#[test]
fn the_local_gradient_is_nmr_s_with_a_radius_of_the_image_and_differs_below() {
    let mut rng = Rng::new(16);
    for case in 0..8 {
        let count = 20 + rng.below(200);
        let mesh = random_soup(&mut rng, count, 1.0, 5.0);
        let (h, w) = (16 + rng.below(50), 16 + rng.below(50));
        let p = params(h, w);
        let c = 3;
        let attrs = random_attrs(&mut rng, mesh.num_faces() * c);
        let grad: Vec<f32> = (0..p.pixels() * c)
            .map(|_| rng.uniform(-1.0, 1.0))
            .collect();
        let bits = |g: &Gradients| {
            g.grad_verts_screen
                .iter()
                .map(|x| x.to_bits())
                .collect::<Vec<_>>()
        };
        for isa in Isa::all_available() {
            let nmr = grads(&mesh, &attrs, c, &p, &grad, Some(isa));
            let whole = Visibility::Local { radius: h.max(w) };
            let wide = grads_of(whole, &mesh, &attrs, c, &p, &grad, Some(isa));
            assert_eq!(bits(&wide), bits(&nmr), "case {case}, {isa:?}");
            let local = grads_of(
                Visibility::Local { radius: 2 },
                &mesh,
                &attrs,
                c,
                &p,
                &grad,
                Some(isa),
            );
            assert_ne!(
                bits(&local),
                bits(&nmr),
                "case {case}, {isa:?}: the truncation changed nothing"
            );
            assert_eq!(
                local.grad_face_attrs, nmr.grad_face_attrs,
                "case {case}, {isa:?}"
            );
        }
    }
}

#[test]
fn view_soups_and_a_sphere_match_the_reference() {
    let mut rng = Rng::new(12);
    for case in 0..6 {
        let count = 50 + rng.below(400);
        let verts = project30(&random_view_soup(&mut rng, count));
        let mesh = OwnedMesh::new(verts, soup_faces(count));
        check(
            &format!("view soup {case}"),
            &mesh,
            3 + case % 2,
            &params(64, 80),
            &mut rng,
        );
    }
    // The Rust bench's sphere at a smaller size: mostly long OUT sweeps over a curved surface.
    let (rings, segs) = (20i32, 40i32);
    let mut verts = Vec::new();
    for r in 0..=rings {
        let th = std::f32::consts::PI * r as f32 / rings as f32;
        for s in 0..segs {
            let ph = std::f32::consts::TAU * s as f32 / segs as f32;
            verts.extend_from_slice(&[th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin()]);
        }
    }
    let mut faces = Vec::new();
    for r in 0..rings {
        for s in 0..segs {
            let (a, b) = (r * segs + s, r * segs + (s + 1) % segs);
            faces.extend_from_slice(&[a, b, b + segs, a, b + segs, a + segs]);
        }
    }
    let cam = SphericalCamera {
        distance: 2.732,
        elevation: 30.0,
        azimuth: 45.0,
        ..Default::default()
    };
    let view = world_to_view(&verts, &cam.view().expect("camera"));
    let mesh = OwnedMesh::new(project(&view, 30.0, false, 1.0), faces);
    let worst = check("sphere", &mesh, 4, &params(97, 101), &mut rng);
    assert!(worst < 1e-5, "sphere: {worst}");
}

#[test]
fn coplanar_and_tied_faces_match_the_reference() {
    // A grid of coplanar quads (exact depth ties along the shared edges) in perspective and orthographic views.
    let mut rng = Rng::new(13);
    let n = 12i32;
    let mut verts = Vec::new();
    for i in 0..=n {
        for j in 0..=n {
            let (x, y) = (
                -0.9 + 1.8 * j as f32 / n as f32,
                -0.9 + 1.8 * i as f32 / n as f32,
            );
            verts.extend_from_slice(&[x, y, 2.0 + 0.3 * x]);
        }
    }
    let mut faces = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let a = i * (n + 1) + j;
            faces.extend_from_slice(&[a, a + 1, a + n + 2, a, a + n + 2, a + n + 1]);
        }
    }
    // The same grid once more, exactly on top (every pixel a tie between two faces).
    let half = faces.clone();
    faces.extend(half);
    let mesh = OwnedMesh::new(verts, faces);
    for c in [1, 3, 4] {
        check("grid", &mesh, c, &params(70, 61), &mut rng);
        check("grid ortho", &mesh, c, &ortho_params(70, 61), &mut rng);
    }
}

/// `values` (`c` channels, interleaved) restricted to the channels `keep`.
fn channels_of(values: &[f32], c: usize, keep: &[usize]) -> Vec<f32> {
    values
        .chunks_exact(c)
        .flat_map(|row| keep.iter().map(move |&k| row[k]))
        .collect()
}

#[test]
fn zero_cotangent_channels_are_left_out_with_the_same_bits() {
    // A channel whose cotangent is zero everywhere (the coverage channel of an RGB victim's render) is left out of
    // the sweeps: the vertex gradient must have the bits of the same render without that channel (which sweeps every
    // channel it has), on every instruction set, and agree with the reference; its attribute gradient is zero.
    let mut rng = Rng::new(14);
    let cases: [(usize, &[usize]); 6] = [
        (4, &[3]),       // the last (alpha): the kept channels are a prefix
        (4, &[1]),       // one in the middle: a list of channels
        (5, &[0, 2, 4]), // more than four channels, several zero
        (2, &[0]),
        (3, &[0, 1, 2]), // all zero: no vertex gradient at all
        (1, &[0]),
    ];
    for (case, &(c, zero)) in cases.iter().enumerate() {
        let count = 40 + rng.below(200);
        let mesh = random_soup(&mut rng, count, 1.0, 5.0);
        let p = params(40 + rng.below(40), 40 + rng.below(40));
        let attrs = random_attrs(&mut rng, mesh.num_faces() * c);
        let mut grad: Vec<f32> = (0..p.pixels() * c)
            .map(|_| rng.uniform(-1.0, 1.0))
            .collect();
        for px in grad.chunks_exact_mut(c) {
            for &k in zero {
                px[k] = if k % 2 == 0 { 0.0 } else { -0.0 };
            }
        }
        let keep: Vec<usize> = (0..c).filter(|k| !zero.contains(k)).collect();
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let want = grads(&mesh, &attrs, c, &p, &grad, None);
        for isa in Isa::all_available() {
            let got = grads(&mesh, &attrs, c, &p, &grad, Some(isa));
            assert_eq!(
                got.grad_face_attrs, want.grad_face_attrs,
                "case {case}, {isa:?}"
            );
            if keep.is_empty() {
                assert!(
                    got.grad_verts_screen.iter().all(|x| x.to_bits() == 0),
                    "case {case}, {isa:?}: a zero cotangent has a vertex gradient"
                );
                assert!(
                    want.grad_verts_screen.iter().all(|&x| x == 0.0),
                    "case {case}"
                );
                continue;
            }
            let without = grads(
                &mesh,
                &channels_of(&attrs, c, &keep),
                keep.len(),
                &p,
                &channels_of(&grad, c, &keep),
                Some(isa),
            );
            assert_eq!(
                bits(&got.grad_verts_screen),
                bits(&without.grad_verts_screen),
                "case {case}, {isa:?}: not the bits of the render without the zero channels"
            );
            let scale = want
                .grad_verts_screen
                .iter()
                .fold(0f64, |m, &x| m.max((x as f64).abs()));
            assert!(scale > 0.0, "case {case}: the scene has no vertex gradient");
            for (&x, &y) in got.grad_verts_screen.iter().zip(&want.grad_verts_screen) {
                let err = (x as f64 - y as f64).abs();
                assert!(
                    err <= 1e-5 * (y as f64).abs().max(1e-2 * scale),
                    "case {case}, {isa:?}: {x} vs reference {y}"
                );
            }
        }
    }
}
