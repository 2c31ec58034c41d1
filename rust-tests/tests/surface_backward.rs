//! The vertex gradient of images with per-pixel colours (`image_vertex_backward`): on an image drawn with per-face
//! colours it is `rasterize_backward`'s vertex gradient bit for bit, in perspective and orthographic projection, for
//! any thread count; on a textured image it differs from the flat one only through the colours it reads.

use meshadv_raster::backward::{image_vertex_backward, Visibility};
use meshadv_raster::surface::CornerAttrs;
use meshadv_raster::texture::{Texture, Wrap};
use meshadv_raster::textured::sample_uv_texture;
use meshadv_raster::{
    rasterize_backward, rasterize_fragments, with_threads, BackwardInputs, FaceAttrs,
};
use meshadv_raster_tests::{
    backward, forward, ortho_params, params, random_attrs, random_soup, Rng,
};

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn per_pixel_colours_of_a_flat_image_give_the_flat_vertex_gradient_bit_for_bit() {
    let mut rng = Rng::new(17);
    for (case, c) in [(0, 1), (1, 3), (2, 4), (3, 5)] {
        let mesh = random_soup(&mut rng, 60, 1.0, 5.0);
        let p = if case == 2 {
            ortho_params(29, 33)
        } else {
            params(29, 33)
        };
        let attrs = random_attrs(&mut rng, mesh.num_faces() * c);
        let out = forward(&mesh, &attrs, c, &p);
        let g: Vec<f32> = (0..29 * 33 * c).map(|_| rng.uniform(-1.0, 1.0)).collect();
        let flat = backward(&mesh, &attrs, c, &p, &out, &g);
        for threads in [1, 3] {
            let got = with_threads(threads, || {
                image_vertex_backward(
                    &mesh.view(),
                    &p,
                    &out.face_index,
                    &out.image,
                    &g,
                    c,
                    Visibility::Nmr,
                )
            })
            .expect("pool")
            .expect("backward");
            assert_eq!(
                bits(&got),
                bits(&flat.grad_verts_screen),
                "case {case}, {threads} threads"
            );
        }
        assert!(flat.grad_verts_screen.iter().any(|&x| x != 0.0));
        // The local (truncated) sweeps too.
        let local = Visibility::Local { radius: 3 };
        let inputs = BackwardInputs {
            face_index: &out.face_index,
            image: &out.image,
            grad_image: &g,
            vertex_grad: true,
            visibility: local,
        };
        let face_attrs = FaceAttrs {
            values: &attrs,
            background: &vec![0.0; c],
            channels: c,
        };
        let want = rasterize_backward(&mesh.view(), &face_attrs, &p, &inputs).expect("flat local");
        let got =
            image_vertex_backward(&mesh.view(), &p, &out.face_index, &out.image, &g, c, local)
                .expect("local");
        assert_eq!(
            bits(&got),
            bits(&want.grad_verts_screen),
            "case {case}, local"
        );
    }
}

#[test]
fn a_textured_image_gets_a_vertex_gradient_from_the_colours_at_its_edges() {
    // One texture sampled over the soup: the vertex gradient is finite, non-zero and deterministic across threads.
    let mut rng = Rng::new(3);
    let mesh = random_soup(&mut rng, 40, 1.0, 5.0);
    let p = params(31, 37);
    let view = mesh.view();
    let frags = rasterize_fragments(&view, &p).expect("fragments");
    let uvs: Vec<f32> = (0..mesh.num_faces() * 6)
        .map(|_| rng.uniform(0.0, 1.0))
        .collect();
    let corners: Vec<i32> = (0..mesh.num_faces() as i32 * 3).collect();
    let attrs = CornerAttrs {
        values: &uvs,
        corners: &corners,
        batch: 1,
        rows: corners.len(),
        channels: 2,
        arg: "uvs",
    };
    let texels: Vec<f32> = (0..8 * 8 * 3).map(|_| rng.uniform(0.0, 1.0)).collect();
    let tex = Texture {
        texels: &texels,
        batch: 1,
        height: 8,
        width: 8,
        channels: 3,
        wrap: Wrap::Repeat,
    };
    let image = sample_uv_texture(&view, &p, &frags.face_index, &attrs, &tex).expect("sample");
    let g: Vec<f32> = (0..image.len()).map(|_| rng.uniform(-1.0, 1.0)).collect();
    let one = with_threads(1, || {
        image_vertex_backward(&view, &p, &frags.face_index, &image, &g, 3, Visibility::Nmr)
    })
    .expect("pool")
    .expect("1");
    let four = with_threads(4, || {
        image_vertex_backward(&view, &p, &frags.face_index, &image, &g, 3, Visibility::Nmr)
    })
    .expect("pool")
    .expect("4");
    assert_eq!(bits(&one), bits(&four));
    assert!(one.iter().all(|x| x.is_finite()) && one.iter().any(|&x| x != 0.0));
    let e = image_vertex_backward(
        &view,
        &p,
        &frags.face_index,
        &image[1..],
        &g,
        3,
        Visibility::Nmr,
    )
    .expect_err("short image");
    assert!(e.to_string().starts_with("image"), "{e}");
}
