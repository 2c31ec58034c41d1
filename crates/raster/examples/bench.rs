//! Quick timing of forward + backward on a ~10k-face sphere at 299 x 299 (the sphere fills the image; random
//! cotangent, 4 channels), one thread by default; prints the median and the minimum of 20 runs.
//!
//! `cargo run --release -p meshadv-raster --example bench [threads] [fwd|bwd]` (the mode runs only that pass, for
//! `perf stat`).

use std::time::Instant;

use meshadv_raster::camera::{project, world_to_view, SphericalCamera};
use meshadv_raster::{
    rasterize, rasterize_backward, with_threads, BackwardInputs, FaceAttrs, RasterParams,
    ScreenMesh,
};

/// UV sphere with `rings * segs * 2` faces (minus the pole duplicates).
fn sphere(rings: usize, segs: usize) -> (Vec<f32>, Vec<i32>) {
    let mut v = Vec::new();
    for r in 0..=rings {
        let th = std::f32::consts::PI * r as f32 / rings as f32;
        for s in 0..segs {
            let ph = std::f32::consts::TAU * s as f32 / segs as f32;
            v.extend_from_slice(&[th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin()]);
        }
    }
    let mut f = Vec::new();
    for r in 0..rings {
        for s in 0..segs {
            let a = (r * segs + s) as i32;
            let b = (r * segs + (s + 1) % segs) as i32;
            let c = a + segs as i32;
            let d = b + segs as i32;
            f.extend_from_slice(&[a, b, d, a, d, c]);
        }
    }
    (v, f)
}

/// Median of `v` (sorts it in place).
fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let threads: usize = std::env::args()
        .nth(1)
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(1);
    let (verts, faces) = sphere(50, 100);
    let m = faces.len() / 3;
    let cam = SphericalCamera {
        distance: 2.732,
        elevation: 30.0,
        azimuth: 45.0,
        ..Default::default()
    };
    let view = world_to_view(&verts, &cam.view()?);
    let screen = project(&view, 30.0, false, 1.0);
    let mesh = ScreenMesh::new(&screen, &faces, 1, verts.len() / 3)?;
    let c = 4;
    let attrs: Vec<f32> = (0..m * c)
        .map(|i| ((i * 7919) % 1000) as f32 / 1000.0)
        .collect();
    let bg = [1.0f32, 1.0, 1.0, 0.0];
    let fa = FaceAttrs {
        values: &attrs,
        background: &bg,
        channels: c,
    };
    let p = RasterParams::new(299, 299, 0.1, 100.0);
    let grad: Vec<f32> = (0..299 * 299 * c)
        .map(|i| ((i * 104729) % 2001) as f32 / 1000.0 - 1.0)
        .collect();
    let reps = 20;
    let mode = std::env::args().nth(2).unwrap_or_default();
    if !mode.is_empty() {
        return with_threads(threads, || -> Result<(), meshadv_raster::RasterError> {
            let out = rasterize(&mesh, &fa, &p)?;
            let inputs = BackwardInputs {
                face_index: &out.face_index,
                image: &out.image,
                grad_image: &grad,
                vertex_grad: true,
            };
            for _ in 0..reps {
                if mode == "fwd" {
                    std::hint::black_box(rasterize(&mesh, &fa, &p)?);
                } else {
                    std::hint::black_box(rasterize_backward(&mesh, &fa, &p, &inputs)?);
                }
            }
            Ok(())
        })?
        .map_err(Into::into);
    }
    with_threads(threads, || -> Result<(), meshadv_raster::RasterError> {
        let (mut tf, mut tb) = (Vec::new(), Vec::new());
        for _ in 0..reps {
            let t0 = Instant::now();
            let out = rasterize(&mesh, &fa, &p)?;
            let t1 = Instant::now();
            let inputs = BackwardInputs {
                face_index: &out.face_index,
                image: &out.image,
                grad_image: &grad,
                vertex_grad: true,
            };
            let g = rasterize_backward(&mesh, &fa, &p, &inputs)?;
            let t2 = Instant::now();
            std::hint::black_box(&g);
            tf.push(1e3 * (t1 - t0).as_secs_f64());
            tb.push(1e3 * (t2 - t1).as_secs_f64());
        }
        let t0 = Instant::now();
        for _ in 0..reps {
            std::hint::black_box(meshadv_raster::rasterize_fragments(&mesh, &p)?);
        }
        println!(
            "fragments only: {:.2} ms",
            1e3 * t0.elapsed().as_secs_f64() / reps as f64
        );
        let t0 = Instant::now();
        for _ in 0..reps {
            std::hint::black_box(meshadv_raster::setup::setup_faces(&mesh, 0, &p));
        }
        println!(
            "setup only: {:.2} ms",
            1e3 * t0.elapsed().as_secs_f64() / reps as f64
        );
        println!(
            "{m} faces, 299x299, {threads} thread(s): forward {:.2} ms, backward {:.2} ms \
             (median of {reps}; min {:.2} / {:.2} ms)",
            median(&mut tf),
            median(&mut tb),
            tf[0],
            tb[0]
        );
        Ok(())
    })??;
    Ok(())
}
