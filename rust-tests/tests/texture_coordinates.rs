//! Huge and non-finite texture coordinates reaching the core: typed errors naming the argument at the entry points,
//! and finite samples (no index overflow) where a per-pixel UV leaves every range because the fragments name a face
//! that is not drawn there.

use meshadv_raster::surface::CornerAttrs;
use meshadv_raster::texture::{Texture, Wrap, MAX_TEXTURE_COORDINATE};
use meshadv_raster::textured::{sample_uv_texture, sample_uv_texture_backward};
use meshadv_raster::{rasterize_fragments, RasterError, ScreenMesh};
use meshadv_raster_tests::params;

const BAD: [f64; 6] = [
    1e30,
    -1e30,
    f64::INFINITY,
    f64::NEG_INFINITY,
    f64::NAN,
    MAX_TEXTURE_COORDINATE * 1.5,
];

fn texture(texels: &[f32], wrap: Wrap) -> Texture<'_> {
    Texture {
        texels,
        batch: 1,
        height: 3,
        width: 4,
        channels: 2,
        wrap,
    }
}

/// 3 x 4 texels of 2 channels.
fn texels() -> Vec<f32> {
    (0..24).map(|i| i as f32 * 0.1).collect()
}

/// The per-corner UVs of the one face `[0, 1, 2]`.
fn uvs(values: &[f32]) -> CornerAttrs<'_> {
    CornerAttrs {
        values,
        corners: &[0, 1, 2],
        batch: 1,
        rows: 3,
        channels: 2,
        arg: "uvs",
    }
}

fn names(e: &RasterError, arg: &str) -> bool {
    e.to_string().starts_with(&format!("{arg}:"))
}

#[test]
fn sampling_at_huge_or_non_finite_uvs_is_an_error_naming_uv() {
    let texels = texels();
    for wrap in [Wrap::Repeat, Wrap::Clamp] {
        let tex = texture(&texels, wrap);
        for bad in BAD {
            for uv in [[bad, 0.5], [0.5, bad]] {
                let e = tex.sample(0, uv).expect_err("bad uv");
                assert!(names(&e, "uv"), "{wrap:?} {uv:?}: {e}");
                let mut grad_texels = vec![0f64; texels.len()];
                let e = tex
                    .sample_backward(0, uv, &[1.0, 1.0], &mut grad_texels)
                    .expect_err("bad uv");
                assert!(names(&e, "uv"), "{wrap:?} {uv:?}: {e}");
                assert!(grad_texels.iter().all(|&g| g == 0.0));
            }
        }
        // The largest accepted coordinate samples the texture like any other.
        let far = tex
            .sample(0, [MAX_TEXTURE_COORDINATE, -MAX_TEXTURE_COORDINATE])
            .expect("far");
        assert!(far.iter().all(|x| (0.0..=2.31).contains(x)), "{far:?}");
    }
}

/// One perspective face, steep in depth, on a 40 x 40 image.
fn steep_face() -> Vec<f32> {
    vec![-0.4, -0.4, 1.0, 0.4, -0.4, 1.0, 0.0, 0.4, 30.0]
}

#[test]
fn huge_or_non_finite_uv_values_are_errors_naming_uvs() {
    let verts = steep_face();
    let mesh = ScreenMesh::new(&verts, &[0, 1, 2], 1, 3).expect("mesh");
    let p = params(40, 40);
    let face_index = rasterize_fragments(&mesh, &p).expect("raster").face_index;
    let texels = texels();
    let tex = texture(&texels, Wrap::Repeat);
    let grad = vec![1f32; face_index.len() * 2];
    for bad in BAD {
        let values = [0.1, 0.2, 0.9, 0.2, bad as f32, 0.8];
        let uvs = uvs(&values);
        let e = sample_uv_texture(&mesh, &p, &face_index, &uvs, &tex).expect_err("forward");
        assert!(names(&e, "uvs"), "{bad}: {e}");
        let e = sample_uv_texture_backward(&mesh, &p, &face_index, &uvs, &tex, &grad)
            .expect_err("backward");
        assert!(names(&e, "uvs"), "{bad}: {e}");
    }
}

#[test]
fn fragments_of_a_face_not_drawn_there_give_finite_samples() {
    // Every pixel claims the face: beyond its horizon the perspective UV's denominator crosses zero, so the
    // per-pixel UVs there are huge, infinite or NaN.
    let verts = steep_face();
    let mesh = ScreenMesh::new(&verts, &[0, 1, 2], 1, 3).expect("mesh");
    let p = params(40, 40);
    let face_index = vec![0i32; 40 * 40];
    let values = [0.0f32, 0.0, MAX_TEXTURE_COORDINATE as f32, 0.0, 0.5, -1e6];
    let uvs = uvs(&values);
    let texels = texels();
    for wrap in [Wrap::Repeat, Wrap::Clamp] {
        let tex = texture(&texels, wrap);
        let out = sample_uv_texture(&mesh, &p, &face_index, &uvs, &tex).expect("forward");
        let bad: Vec<_> = out.iter().filter(|x| !(0.0..=2.31).contains(*x)).collect();
        assert!(bad.is_empty(), "{wrap:?}: {bad:?}");
        let grad = vec![1f32; face_index.len() * 2];
        let g = sample_uv_texture_backward(&mesh, &p, &face_index, &uvs, &tex, &grad)
            .expect("backward");
        // Every pixel adds its bilinear weights (summing to one) to the texel gradient.
        let total: f64 = g.grad_texels.iter().map(|&x| x as f64).sum();
        assert!((total - 2.0 * 1600.0).abs() < 1e-2, "{wrap:?}: {total}");
    }
}
