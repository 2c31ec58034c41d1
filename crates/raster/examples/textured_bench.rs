//! A textured render and its backward against the per-face (flat) render and its backward, side by side in one run.
//!
//! Case: a UV sphere of 10,000 faces filling a 299 x 299 image (as `bench`'s `sphere`), RGB + coverage, a random
//! cotangent. Per-face: `rasterize` with per-face RGBA attributes, then `rasterize_backward` (attribute and NMR vertex
//! gradients). Textured, as the Python op runs it: fragments, the drawn faces' UV planes (`UvTexturePlanes::new`),
//! the texture sample at each pixel's perspective-correct UV (per-vertex UVs, a 256 x 256 RGB texture, bilinear;
//! `UvTexturePlanes::sample`), the RGBA image, then the per-pixel NMR vertex gradient and the texel, UV and interior
//! vertex gradients (`UvTexturePlanes::backward`, with the forward's planes). The two alternate, `reps` times each;
//! medians and their ratio are printed. With `stages` as a third argument, each stage of the two is then timed on its
//! own as well (the stages of one repetition in a row, `reps` repetitions; per-stage medians).
//!
//! `cargo run --release -p meshadv-raster --example textured_bench [threads] [reps] [stages]` (1 thread and 21
//! repetitions by default).

use std::time::Instant;

use meshadv_raster::backward::{image_vertex_backward, Isa, Visibility};
use meshadv_raster::camera::{project, world_to_view, SphericalCamera};
use meshadv_raster::surface::CornerAttrs;
use meshadv_raster::texture::{Texture, Wrap};
use meshadv_raster::textured::UvTexturePlanes;
use meshadv_raster::{
    rasterize, rasterize_backward, rasterize_fragments, with_threads, BackwardInputs, FaceAttrs,
    RasterError, RasterParams, ScreenMesh,
};

/// UV sphere (`rings * segs * 2` faces) with per-vertex UVs from its grid (a seam column of vertices at u = 1).
fn sphere(rings: usize, segs: usize) -> (Vec<f32>, Vec<i32>, Vec<f32>) {
    let (mut v, mut uv) = (Vec::new(), Vec::new());
    for r in 0..=rings {
        let th = std::f32::consts::PI * r as f32 / rings as f32;
        for s in 0..=segs {
            let ph = std::f32::consts::TAU * s as f32 / segs as f32;
            v.extend_from_slice(&[th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin()]);
            uv.extend_from_slice(&[s as f32 / segs as f32, 1.0 - r as f32 / rings as f32]);
        }
    }
    let mut f = Vec::new();
    let row = segs + 1;
    for r in 0..rings {
        for s in 0..segs {
            let a = (r * row + s) as i32;
            let (b, c) = (a + 1, a + row as i32);
            f.extend_from_slice(&[a, b, c + 1, a, c + 1, c]);
        }
    }
    (v, f, uv)
}

/// A tiny deterministic generator (SplitMix64) of values in [0, 1).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f32 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// CPU time of this process so far in ms (the sum of its threads' run time from `/proc/self/task/*/schedstat`, ns
/// resolution; less disturbed than wall time by other processes on a busy machine), or NaN where it is not readable.
fn cpu_ms() -> f64 {
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return f64::NAN;
    };
    let mut ns = 0u64;
    for task in tasks.flatten() {
        let stat = std::fs::read_to_string(task.path().join("schedstat")).unwrap_or_default();
        ns += stat
            .split_whitespace()
            .next()
            .and_then(|x| x.parse::<u64>().ok())
            .unwrap_or(0);
    }
    ns as f64 / 1e6
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> Result<(), RasterError> {
    let args: Vec<String> = std::env::args().collect();
    let threads: usize = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(1);
    let reps: usize = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(21);
    let (verts, faces, uvs) = sphere(50, 100);
    let cam = SphericalCamera {
        distance: 2.732,
        elevation: 30.0,
        azimuth: 45.0,
        ..Default::default()
    };
    let screen = project(&world_to_view(&verts, &cam.view()?), 30.0, false, 1.0);
    let n = verts.len() / 3;
    let m = faces.len() / 3;
    let size = 299;
    let mesh = ScreenMesh::new(&screen, &faces, 1, n)?;
    let params = RasterParams::new(size, size, 0.1, 100.0);
    let mut rng = Rng(1);
    let mut face_rgba = Vec::with_capacity(m * 4);
    for _ in 0..m {
        face_rgba.extend_from_slice(&[rng.next(), rng.next(), rng.next(), 1.0]);
    }
    let background = [1.0f32, 1.0, 1.0, 0.0];
    let texels: Vec<f32> = (0..256 * 256 * 3).map(|_| rng.next()).collect();
    let grad: Vec<f32> = (0..size * size * 4).map(|_| rng.next() - 0.5).collect();
    let grad_rgb: Vec<f32> = grad
        .chunks_exact(4)
        .flat_map(|g| [g[0], g[1], g[2]])
        .collect();
    let texture = Texture {
        texels: &texels,
        batch: 1,
        height: 256,
        width: 256,
        channels: 3,
        wrap: Wrap::Repeat,
    };
    let uv_attrs = CornerAttrs {
        values: &uvs,
        corners: &faces,
        batch: 1,
        rows: n,
        channels: 2,
        arg: "uvs",
    };
    let flat = || -> Result<f32, RasterError> {
        let attrs = FaceAttrs {
            values: &face_rgba,
            background: &background,
            channels: 4,
        };
        let out = rasterize(&mesh, &attrs, &params)?;
        let inputs = BackwardInputs {
            face_index: &out.face_index,
            image: &out.image,
            grad_image: &grad,
            vertex_grad: true,
            visibility: Visibility::Nmr,
        };
        let g = rasterize_backward(&mesh, &attrs, &params, &inputs)?;
        Ok(g.grad_verts_screen[0] + g.grad_face_attrs[0])
    };
    let textured = || -> Result<f32, RasterError> {
        let frags = rasterize_fragments(&mesh, &params)?;
        // As the Python op: the planes built once by the forward and kept for the backward.
        let planes = UvTexturePlanes::new(&mesh, &params, &frags.face_index, &uv_attrs, &texture)?;
        let rgb = planes.sample(Isa::detect(), &frags.face_index, &texture)?;
        let mut image = Vec::with_capacity(frags.face_index.len() * 4);
        for (c, &f) in rgb.chunks_exact(3).zip(&frags.face_index) {
            image.extend_from_slice(&match f >= 0 {
                true => [c[0], c[1], c[2], 1.0],
                false => background,
            });
        }
        let gv = image_vertex_backward(
            &mesh,
            &params,
            &frags.face_index,
            &image,
            &grad,
            4,
            Visibility::Nmr,
        )?;
        let gs = planes.backward(Isa::detect(), &frags.face_index, &texture, &grad_rgb)?;
        Ok(gv[0] + gs.grad_verts_screen[0] + gs.grad_texels[0] + gs.grad_uvs[0])
    };
    let (mut tf, mut tt) = (Vec::new(), Vec::new());
    let (mut cf, mut ct) = (Vec::new(), Vec::new());
    with_threads(threads, || -> Result<(), RasterError> {
        flat()?;
        textured()?;
        for _ in 0..reps {
            let (t, c) = (Instant::now(), cpu_ms());
            std::hint::black_box(flat()?);
            tf.push(t.elapsed().as_secs_f64() * 1e3);
            cf.push(cpu_ms() - c);
            let (t, c) = (Instant::now(), cpu_ms());
            std::hint::black_box(textured()?);
            tt.push(t.elapsed().as_secs_f64() * 1e3);
            ct.push(cpu_ms() - c);
        }
        Ok(())
    })??;
    if args.get(3).map(String::as_str) == Some("stages") {
        with_threads(threads, || {
            stages(&mesh, &params, &face_rgba, &uv_attrs, &texture, &grad, reps)
        })??;
    }
    let (f, t) = (median(&mut tf), median(&mut tt));
    let (fc, tc) = (median(&mut cf), median(&mut ct));
    println!(
        "{m} faces, {size}x{size}, {threads} thread(s), {reps} alternating repetitions (medians): per-face render + \
         backward {f:.1} ms wall / {fc:.1} ms CPU, textured render + backward {t:.1} ms wall / {tc:.1} ms CPU; \
         ratio {:.2} wall, {:.2} CPU",
        t / f,
        tc / fc
    );
    Ok(())
}

/// Times each stage of the per-face and the textured render + backward (as in `main`) on its own and prints their
/// medians over `reps` repetitions (after two untimed ones).
fn stages(
    mesh: &ScreenMesh<'_>,
    params: &RasterParams,
    face_rgba: &[f32],
    uv_attrs: &CornerAttrs<'_>,
    texture: &Texture<'_>,
    grad: &[f32],
    reps: usize,
) -> Result<(), RasterError> {
    const NAMES: [&str; 8] = [
        "per-face: rasterize",
        "per-face: rasterize_backward",
        "textured: rasterize_fragments",
        "textured: UvTexturePlanes::new",
        "textured: UvTexturePlanes::sample",
        "textured: RGBA image",
        "textured: image_vertex_backward",
        "textured: UvTexturePlanes::backward",
    ];
    let background = [1.0f32, 1.0, 1.0, 0.0];
    let grad_rgb: Vec<f32> = grad
        .chunks_exact(4)
        .flat_map(|g| [g[0], g[1], g[2]])
        .collect();
    let mut times = vec![Vec::new(); NAMES.len()];
    for rep in 0..reps + 2 {
        let mut t = Instant::now();
        let mut lap = |stage: usize| {
            if rep >= 2 {
                times[stage].push(t.elapsed().as_secs_f64() * 1e3);
            }
            t = Instant::now();
        };
        // Each path's buffers freed before the next starts, as in `main` (the allocator's state, and with it the
        // page faults of fresh buffers, depends on it).
        {
            let attrs = FaceAttrs {
                values: face_rgba,
                background: &background,
                channels: 4,
            };
            let out = rasterize(mesh, &attrs, params)?;
            lap(0);
            let inputs = BackwardInputs {
                face_index: &out.face_index,
                image: &out.image,
                grad_image: grad,
                vertex_grad: true,
                visibility: Visibility::Nmr,
            };
            std::hint::black_box(rasterize_backward(mesh, &attrs, params, &inputs)?);
            lap(1);
        }
        let frags = rasterize_fragments(mesh, params)?;
        lap(2);
        let planes = UvTexturePlanes::new(mesh, params, &frags.face_index, uv_attrs, texture)?;
        lap(3);
        let rgb = planes.sample(Isa::detect(), &frags.face_index, texture)?;
        lap(4);
        let mut image = Vec::with_capacity(frags.face_index.len() * 4);
        for (c, &f) in rgb.chunks_exact(3).zip(&frags.face_index) {
            image.extend_from_slice(&match f >= 0 {
                true => [c[0], c[1], c[2], 1.0],
                false => background,
            });
        }
        lap(5);
        let (fi, nmr) = (&frags.face_index, Visibility::Nmr);
        std::hint::black_box(image_vertex_backward(
            mesh, params, fi, &image, grad, 4, nmr,
        )?);
        lap(6);
        std::hint::black_box(planes.backward(Isa::detect(), fi, texture, &grad_rgb)?);
        lap(7);
    }
    let mut sums = [0.0; 2];
    for (name, t) in NAMES.iter().zip(&mut times) {
        let m = median(t);
        sums[usize::from(name.starts_with("textured"))] += m;
        println!("{name:36} {m:7.3} ms");
    }
    println!(
        "sums of the stage medians: per-face {:.2} ms, textured {:.2} ms; ratio {:.2}",
        sums[0],
        sums[1],
        sums[1] / sums[0]
    );
    Ok(())
}
