//! Quick timing of forward + backward, one thread by default; prints the median and the minimum of 20 runs.
//!
//! * `sphere`: a ~10k-face sphere at 299 x 299 (the sphere fills the image; random cotangent, 4 channels).
//! * `pascal`: an attack's render: a real PASCAL3D+ mesh (`aeroplane/03.ply`, 7,106 faces, as stored: not resampled)
//!   scaled to [-1, 1], 6 views (azimuths 0-300 by 60, elevation 30, distance 2.732) in one batch at 448 x 448 (a
//!   224 px image with 2x antialias), RGB + alpha, random cotangent. Read from `$MESHADV_DATA` or `../shared/data`;
//!   skipped with a message when absent.
//! * `pascal-rgb`: the same render with the coverage (alpha) channel's cotangent zero, as in an attack whose victim
//!   sees only RGB (the backward leaves such a channel out of its sweeps).
//!
//! `cargo run --release -p meshadv-raster --example bench [threads] [fwd|bwd] [sphere|pascal|pascal-rgb]` (a mode
//! runs only that pass of one case, `sphere` by default, for `perf stat` or `valgrind --tool=callgrind`).
//! `BENCH_ISA=portable` (or `avx2`) runs the backward on that instruction set instead of the fastest one the CPU
//! has; `BENCH_REPS=n` runs `n` repetitions instead of 20. The timing runs alternate NMR's backward and the local
//! gradient's (`BENCH_RADIUS=r` pixels, default 2); `bwd` runs NMR's unless `BENCH_VISIBILITY=local`. `bwd` prints a
//! fingerprint of the vertex gradient's bits (to compare builds and instruction sets), `fwd` one of the face index,
//! depth and image.

use std::time::Instant;

use meshadv_raster::backward::{rasterize_backward_on, Isa, Visibility};
use meshadv_raster::camera::{project, world_to_view, SphericalCamera};
use meshadv_raster::{
    bits_hash, rasterize, with_threads, BackwardInputs, FaceAttrs, Gradients, RasterError,
    RasterParams, ScreenMesh,
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

/// Reads a binary little-endian PLY with float `x y z` vertices and `list uchar int` triangles (the shared
/// PASCAL3D+ files), scaled so that the largest extent spans [-1, 1] and turned from Z-up to Y-up.
fn read_ply(path: &std::path::Path) -> Result<(Vec<f32>, Vec<i32>), Box<dyn std::error::Error>> {
    let bytes = std::fs::read(path)?;
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .ok_or("no PLY header")?;
    let header = std::str::from_utf8(&bytes[..end])?;
    let count = |name: &str| -> Result<usize, Box<dyn std::error::Error>> {
        let line = header
            .lines()
            .find(|l| l.starts_with(&format!("element {name} ")))
            .ok_or("missing element")?;
        Ok(line.rsplit(' ').next().unwrap_or("").parse()?)
    };
    let (nv, nf) = (count("vertex")?, count("face")?);
    let mut body = &bytes[end + 11..];
    let mut take = |n: usize| -> Result<&[u8], Box<dyn std::error::Error>> {
        let (head, rest) = body.split_at_checked(n).ok_or("truncated PLY")?;
        body = rest;
        Ok(head)
    };
    let mut v = Vec::with_capacity(nv * 3);
    for _ in 0..nv * 3 {
        v.push(f32::from_le_bytes(take(4)?.try_into()?));
    }
    let mut f = Vec::with_capacity(nf * 3);
    for _ in 0..nf {
        if take(1)?[0] != 3 {
            return Err("not a triangle mesh".into());
        }
        for _ in 0..3 {
            f.push(i32::from_le_bytes(take(4)?.try_into()?));
        }
    }
    let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
    for p in v.chunks_exact(3) {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let scale = 2.0 / (0..3).map(|k| hi[k] - lo[k]).fold(0f32, f32::max);
    let verts = v
        .chunks_exact(3)
        .flat_map(|p| {
            let c: [f32; 3] = std::array::from_fn(|k| (p[k] - (lo[k] + hi[k]) / 2.0) * scale);
            [c[0], c[2], -c[1]]
        })
        .collect();
    Ok((verts, f))
}

/// One benchmark case: a projected batch, its attributes and a cotangent.
struct Case {
    name: String,
    screen: Vec<f32>,
    faces: Vec<i32>,
    batch: usize,
    attrs: Vec<f32>,
    grad: Vec<f32>,
    params: RasterParams,
}

/// The sphere case (see the module docs).
fn sphere_case() -> Result<Case, RasterError> {
    let (verts, faces) = sphere(50, 100);
    let cam = SphericalCamera {
        distance: 2.732,
        elevation: 30.0,
        azimuth: 45.0,
        ..Default::default()
    };
    let view = world_to_view(&verts, &cam.view()?);
    Ok(case(
        format!("{} faces, 299x299", faces.len() / 3),
        project(&view, 30.0, false, 1.0),
        faces,
        1,
        299,
    ))
}

/// The PASCAL3D+ case (see the module docs); `None` when the shared data is absent.
fn pascal_case() -> Result<Option<Case>, Box<dyn std::error::Error>> {
    let root = std::env::var("MESHADV_DATA").unwrap_or_else(|_| {
        concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data").to_string()
    });
    let path = std::path::Path::new(&root).join("pascal3d/aeroplane/03.ply");
    if !path.exists() {
        println!("pascal: skipped, {} not found", path.display());
        return Ok(None);
    }
    let (verts, faces) = read_ply(&path)?;
    let mut screen = Vec::new();
    for view in 0..6 {
        let cam = SphericalCamera {
            distance: 2.732,
            elevation: 30.0,
            azimuth: 60.0 * view as f64,
            ..Default::default()
        };
        screen.extend(project(
            &world_to_view(&verts, &cam.view()?),
            30.0,
            false,
            1.0,
        ));
    }
    Ok(Some(case(
        format!(
            "aeroplane/03 ({} faces) x 6 views, 448x448",
            faces.len() / 3
        ),
        screen,
        faces,
        6,
        448,
    )))
}

/// The PASCAL3D+ case with its last (alpha) channel's cotangent zero; `None` when the shared data is absent.
fn pascal_rgb_case() -> Result<Option<Case>, Box<dyn std::error::Error>> {
    Ok(pascal_case()?.map(|mut c| {
        c.name = format!("{}, alpha cotangent 0", c.name);
        c.grad.chunks_exact_mut(4).for_each(|g| g[3] = 0.0);
        c
    }))
}

/// A case with deterministic attributes and cotangent, 4 channels, `size x size`.
fn case(name: String, screen: Vec<f32>, faces: Vec<i32>, batch: usize, size: usize) -> Case {
    let (m, c) = (faces.len() / 3, 4);
    let attrs = (0..batch * m * c)
        .map(|i| ((i * 7919) % 1000) as f32 / 1000.0)
        .collect();
    let grad = (0..batch * size * size * c)
        .map(|i| ((i * 104729) % 2001) as f32 / 1000.0 - 1.0)
        .collect();
    Case {
        name,
        screen,
        faces,
        batch,
        attrs,
        grad,
        params: RasterParams::new(size, size, 0.1, 100.0),
    }
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
    let mode = std::env::args().nth(2).unwrap_or_default();
    let which = std::env::args().nth(3).unwrap_or_else(|| "sphere".into());
    let isa = match std::env::var("BENCH_ISA").as_deref() {
        Ok("portable") => Isa::Portable,
        Ok("avx2") => Isa::Avx2,
        _ => Isa::detect(),
    };
    let radius: usize = std::env::var("BENCH_RADIUS")
        .ok()
        .and_then(|r| r.parse().ok())
        .unwrap_or(2);
    let visibility = match std::env::var("BENCH_VISIBILITY").as_deref() {
        Ok("local") => Visibility::Local { radius },
        _ => Visibility::Nmr,
    };
    let reps: usize = std::env::var("BENCH_REPS")
        .ok()
        .and_then(|r| r.parse().ok())
        .unwrap_or(20);
    if !mode.is_empty() {
        let c = match which.as_str() {
            "pascal" => pascal_case()?.ok_or("no PASCAL3D+ data")?,
            "pascal-rgb" => pascal_rgb_case()?.ok_or("no PASCAL3D+ data")?,
            _ => sphere_case()?,
        };
        return with_threads(threads, || run_only(&c, &mode, isa, visibility, reps))?
            .map_err(Into::into);
    }
    let mut cases = vec![sphere_case()?];
    cases.extend(pascal_case()?);
    cases.extend(pascal_rgb_case()?);
    println!("backward on {isa:?}");
    for c in &cases {
        with_threads(threads, || time_case(c, threads, isa, radius, reps))??;
    }
    Ok(())
}

/// Attributes of a case as the API wants them.
fn face_attrs(c: &Case) -> FaceAttrs<'_> {
    const BG: [f32; 4] = [1.0, 1.0, 1.0, 0.0];
    FaceAttrs {
        values: &c.attrs,
        background: &BG,
        channels: 4,
    }
}

/// The backward of a case from the forward's outputs.
fn backward(
    c: &Case,
    mesh: &ScreenMesh<'_>,
    out: &meshadv_raster::RasterOutput,
    isa: Isa,
    visibility: Visibility,
) -> Result<Gradients, RasterError> {
    let inputs = BackwardInputs {
        face_index: &out.face_index,
        image: &out.image,
        grad_image: &c.grad,
        vertex_grad: true,
        visibility,
    };
    rasterize_backward_on(isa, mesh, &face_attrs(c), &c.params, &inputs)
}

/// Runs only the forward (`fwd`) or the backward `reps` times.
fn run_only(
    c: &Case,
    mode: &str,
    isa: Isa,
    visibility: Visibility,
    reps: usize,
) -> Result<(), RasterError> {
    let mesh = ScreenMesh::new(&c.screen, &c.faces, c.batch, c.screen.len() / 3 / c.batch)?;
    let out = rasterize(&mesh, &face_attrs(c), &c.params)?;
    let mut last = None;
    for _ in 0..reps {
        if mode == "fwd" {
            std::hint::black_box(rasterize(&mesh, &face_attrs(c), &c.params)?);
        } else {
            last = Some(std::hint::black_box(backward(
                c, &mesh, &out, isa, visibility,
            )?));
        }
    }
    match last {
        Some(g) => println!(
            "grad_verts_screen fingerprint {:016x}",
            bits_hash(g.grad_verts_screen.iter().map(|x| x.to_bits()))
        ),
        None => println!(
            "forward fingerprint {:016x}",
            bits_hash(
                out.face_index
                    .iter()
                    .map(|&f| f as u32)
                    .chain(out.depth.iter().chain(&out.image).map(|x| x.to_bits()))
            )
        ),
    }
    Ok(())
}

/// Times the forward and the backward of a case, NMR's and the local gradient's in alternating runs, and prints
/// the medians and their ratio.
fn time_case(
    c: &Case,
    threads: usize,
    isa: Isa,
    radius: usize,
    reps: usize,
) -> Result<(), RasterError> {
    let mesh = ScreenMesh::new(&c.screen, &c.faces, c.batch, c.screen.len() / 3 / c.batch)?;
    let local = Visibility::Local { radius };
    let (mut tf, mut tb, mut tl) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..reps {
        let t0 = Instant::now();
        let out = rasterize(&mesh, &face_attrs(c), &c.params)?;
        let t1 = Instant::now();
        let g = backward(c, &mesh, &out, isa, Visibility::Nmr)?;
        let t2 = Instant::now();
        std::hint::black_box(&g);
        let g = backward(c, &mesh, &out, isa, local)?;
        let t3 = Instant::now();
        std::hint::black_box(&g);
        tf.push(1e3 * (t1 - t0).as_secs_f64());
        tb.push(1e3 * (t2 - t1).as_secs_f64());
        tl.push(1e3 * (t3 - t2).as_secs_f64());
    }
    let (mf, mb, ml) = (median(&mut tf), median(&mut tb), median(&mut tl));
    println!(
        "{}, {threads} thread(s): forward {mf:.2} ms, backward NMR {mb:.2} ms, local (radius {radius}) {ml:.2} ms, \
         NMR / local {:.2} (medians of {reps}; min {:.2} / {:.2} / {:.2} ms)",
        c.name,
        mb / ml,
        tf[0],
        tb[0],
        tl[0]
    );
    Ok(())
}
