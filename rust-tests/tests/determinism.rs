//! Results are bit-identical for any thread count (forward and backward).

use meshadv_raster::backward::Visibility;
use meshadv_raster::with_threads;
use meshadv_raster_tests::{
    backward, backward_of, forward, params, random_attrs, random_soup, Rng,
};

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn one_and_two_threads_give_identical_bits() {
    let mut rng = Rng::new(9);
    let mut mesh = random_soup(&mut rng, 600, 1.0, 4.0);
    // Batch of two: the second element is the first one shifted.
    let shifted: Vec<f32> = mesh
        .verts
        .chunks(3)
        .flat_map(|p| [p[0] + 0.1, p[1] - 0.05, p[2]])
        .collect();
    mesh.verts.extend(shifted);
    mesh.batch = 2;
    let (h, w, c) = (67, 53, 4);
    let p = params(h, w);
    let attrs = random_attrs(&mut rng, 2 * mesh.num_faces() * c);
    let grad: Vec<f32> = (0..2 * h * w * c).map(|_| rng.uniform(-1.0, 1.0)).collect();
    let run = |threads: usize| {
        with_threads(threads, || {
            let out = forward(&mesh, &attrs, c, &p);
            let g = backward(&mesh, &attrs, c, &p, &out, &grad);
            let local = Visibility::Local { radius: 3 };
            let gl = backward_of(local, &mesh, &attrs, c, &p, &out, &grad);
            (out, g, gl)
        })
        .expect("pool")
    };
    let (o1, g1, l1) = run(1);
    let (o2, g2, l2) = run(2);
    let (o3, g3, l3) = run(3);
    assert!(o1.face_index.iter().filter(|&&f| f >= 0).count() > 1000);
    for (o, g, l) in [(&o2, &g2, &l2), (&o3, &g3, &l3)] {
        assert_eq!(o1.face_index, o.face_index);
        assert_eq!(bits(&o1.depth), bits(&o.depth));
        assert_eq!(bits(&o1.image), bits(&o.image));
        assert_eq!(bits(&g1.grad_verts_screen), bits(&g.grad_verts_screen));
        assert_eq!(bits(&g1.grad_face_attrs), bits(&g.grad_face_attrs));
        assert_eq!(bits(&l1.grad_verts_screen), bits(&l.grad_verts_screen));
    }
    assert!(g1.grad_verts_screen.iter().any(|&x| x != 0.0));
    assert!(l1.grad_verts_screen.iter().any(|&x| x != 0.0));
    assert_ne!(bits(&l1.grad_verts_screen), bits(&g1.grad_verts_screen));
}

/// The backward keeps its buffers between calls and refills them: a call gives the same bits whatever calls ran
/// before it, with larger or smaller images, other channel counts (the generic path above four included) and face
/// counts.
#[test]
fn the_backward_gives_the_same_bits_whatever_ran_before() {
    let mut rng = Rng::new(21);
    let cases: Vec<_> = [(300, 67, 53, 4), (900, 97, 131, 6), (40, 19, 23, 1)]
        .into_iter()
        .map(|(faces, h, w, c)| {
            let mesh = random_soup(&mut rng, faces, 1.0, 4.0);
            let p = params(h, w);
            let attrs = random_attrs(&mut rng, mesh.num_faces() * c);
            let grad: Vec<f32> = (0..h * w * c).map(|_| rng.uniform(-1.0, 1.0)).collect();
            let out = forward(&mesh, &attrs, c, &p);
            (mesh, p, attrs, grad, out, c)
        })
        .collect();
    let run = |k: usize| {
        let (mesh, p, attrs, grad, out, c) = &cases[k];
        let g = with_threads(1, || backward(mesh, attrs, *c, p, out, grad)).expect("pool");
        (bits(&g.grad_verts_screen), bits(&g.grad_face_attrs))
    };
    let first: Vec<_> = (0..cases.len()).map(run).collect();
    assert!(first.iter().all(|(v, _)| v.iter().any(|&x| x != 0)));
    for k in [1, 0, 2, 1, 2, 0] {
        assert_eq!(run(k), first[k], "case {k}");
    }
}

/// Elements with the same vertices are rasterized once and share their fragments: every element of a batch
/// `[A, B, A, A', B]` (A' = A moved by 0.02 in x) gives the bits of rasterizing it alone, each with
/// its own attributes, and its backward too.
#[test]
fn a_batch_with_repeated_geometry_gives_each_element_its_own_bits() {
    let mut rng = Rng::new(33);
    let a = random_soup(&mut rng, 400, 1.0, 4.0);
    let b = random_soup(&mut rng, 400, 1.0, 4.0);
    let a_moved: Vec<f32> = a
        .verts
        .chunks(3)
        .flat_map(|p| [p[0] + 0.02, p[1], p[2]])
        .collect();
    let elements = [&a.verts, &b.verts, &a.verts, &a_moved, &b.verts];
    let (h, w, c) = (61, 47, 4);
    let p = params(h, w);
    let m = a.num_faces();
    let mut batch = a.clone();
    batch.verts = elements.iter().flat_map(|v| v.iter().copied()).collect();
    batch.batch = elements.len();
    let attrs = random_attrs(&mut rng, elements.len() * m * c);
    let grad: Vec<f32> = (0..elements.len() * h * w * c)
        .map(|_| rng.uniform(-1.0, 1.0))
        .collect();
    let (out, g) = with_threads(2, || {
        let out = forward(&batch, &attrs, c, &p);
        let g = backward(&batch, &attrs, c, &p, &out, &grad);
        (out, g)
    })
    .expect("pool");
    let (hw, n) = (h * w, a.verts.len() / 3);
    for (k, verts) in elements.iter().enumerate() {
        let mut one = a.clone();
        one.verts = verts.to_vec();
        let at = &attrs[k * m * c..(k + 1) * m * c];
        let gr = &grad[k * hw * c..(k + 1) * hw * c];
        let alone = forward(&one, at, c, &p);
        let ga = backward(&one, at, c, &p, &alone, gr);
        assert!(alone.face_index.iter().filter(|&&f| f >= 0).count() > 500);
        assert_eq!(
            alone.face_index,
            out.face_index[k * hw..(k + 1) * hw],
            "element {k}"
        );
        assert_eq!(
            bits(&alone.depth),
            bits(&out.depth[k * hw..(k + 1) * hw]),
            "element {k}"
        );
        assert_eq!(
            bits(&alone.image),
            bits(&out.image[k * hw * c..(k + 1) * hw * c]),
            "element {k}"
        );
        assert_eq!(
            bits(&ga.grad_verts_screen),
            bits(&g.grad_verts_screen[k * n * 3..(k + 1) * n * 3]),
            "element {k}"
        );
        assert_eq!(
            bits(&ga.grad_face_attrs),
            bits(&g.grad_face_attrs[k * m * c..(k + 1) * m * c])
        );
    }
    // A and A' differ, and that shows in their fragments.
    assert_ne!(out.face_index[..hw], out.face_index[3 * hw..4 * hw]);
}
