//! `meshadv-render`: render an OBJ / OFF / PLY mesh to a PNG with meshadv's Rust core (NMR camera conventions,
//! Lambert shading, two-sided).
//!
//! ```text
//! meshadv-render MESH --azimuth A --elevation E --distance D [--tilt T] [--size N] [--light-dir x,y,z]
//!                [--ambient r,g,b] [--z-up] [--normalize] [--mask | --depth] -o out.png
//! ```
//! Errors (missing or malformed file, bad arguments) print one line and exit with status 1 (2 for usage errors).

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use meshadv_raster::camera::SphericalCamera;
use meshadv_raster::pipeline::{render, Lights, RenderSettings};
use meshadv_raster::RasterError;
use meshadv_render_cli::meshio::{self, MeshError};
use thiserror::Error;

/// Everything that can make the binary fail after its arguments parsed.
#[derive(Debug, Error)]
enum CliError {
    /// A bad argument value.
    #[error("{arg}: {message}")]
    Argument {
        /// The option, e.g. `--size`.
        arg: &'static str,
        /// What is expected.
        message: String,
    },
    /// The mesh file cannot be used.
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// The renderer refused the input.
    #[error("render: {0}")]
    Render(#[from] RasterError),
    /// The PNG cannot be written.
    #[error("{path}: cannot write PNG: {message}")]
    WritePng {
        /// The output path.
        path: PathBuf,
        /// Why.
        message: String,
    },
}

/// Render a triangle mesh (OBJ, OFF or PLY) to a PNG image.
#[derive(Debug, Parser)]
#[command(name = "meshadv-render", version, about)]
struct Args {
    /// Mesh file (.obj, .off or .ply).
    mesh: PathBuf,
    /// Camera azimuth in degrees.
    #[arg(long, allow_negative_numbers = true)]
    azimuth: f64,
    /// Camera elevation in degrees.
    #[arg(long, allow_negative_numbers = true)]
    elevation: f64,
    /// Camera distance from the origin.
    #[arg(long)]
    distance: f64,
    /// Camera roll in degrees (counter-clockwise in the image).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    tilt: f64,
    /// Vertical field of view in degrees.
    #[arg(long, default_value_t = 30.0)]
    viewing_angle: f64,
    /// Image size in pixels (square).
    #[arg(long, default_value_t = 256)]
    size: u32,
    /// Direction toward the light, world space (default: from the camera).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    light_dir: Option<[f32; 3]>,
    /// Ambient light RGB.
    #[arg(long, value_parser = parse_vec3, default_value = "0.5,0.5,0.5")]
    ambient: [f32; 3],
    /// Intensity of the directional light.
    #[arg(long, default_value_t = 0.5)]
    light_intensity: f32,
    /// The mesh is Z-up (e.g. PASCAL3D+): rotate it to Y-up first.
    #[arg(long)]
    z_up: bool,
    /// Centre the mesh at the origin and scale its largest extent to 2 (into [-1, 1]).
    #[arg(long)]
    normalize: bool,
    /// Write the silhouette (white on black) instead of the shaded image.
    #[arg(long, conflicts_with = "depth")]
    mask: bool,
    /// Write the depth map (near = bright, background black) instead of the shaded image.
    #[arg(long)]
    depth: bool,
    /// Output PNG path.
    #[arg(short = 'o', long = "output")]
    output: PathBuf,
}

fn parse_vec3(s: &str) -> Result<[f32; 3], String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(format!("expected three comma-separated numbers, got {s:?}"));
    }
    let mut out = [0f32; 3];
    for (o, p) in out.iter_mut().zip(parts) {
        *o = p
            .parse::<f32>()
            .map_err(|_| format!("bad number {p:?} in {s:?}"))?;
        if !o.is_finite() {
            return Err(format!("non-finite number in {s:?}"));
        }
    }
    Ok(out)
}

/// Rotates Z-up to Y-up: `(x, y, z) -> (x, z, -y)`.
fn z_up_to_y_up(v: &mut [f32]) {
    for p in v.chunks_exact_mut(3) {
        let (y, z) = (p[1], p[2]);
        p[1] = z;
        p[2] = -y;
    }
}

/// Centres the bounding box at the origin and scales the largest extent to 2, in f64 (the extent of float32
/// coordinates may overflow float32), as the Python `normalize_mesh`; a mesh of one point has no extent to scale.
fn normalize(v: &mut [f32]) -> Result<(), CliError> {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in v.chunks_exact(3) {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a] as f64);
            hi[a] = hi[a].max(p[a] as f64);
        }
    }
    let extent = (0..3).map(|a| hi[a] - lo[a]).fold(0f64, f64::max);
    if extent <= 0.0 {
        return Err(CliError::Argument {
            arg: "--normalize",
            message: "the mesh has zero extent (all vertices coincide); it cannot be normalised"
                .into(),
        });
    }
    let scale = 2.0 / extent;
    for p in v.chunks_exact_mut(3) {
        for a in 0..3 {
            p[a] = ((p[a] as f64 - 0.5 * (lo[a] + hi[a])) * scale) as f32;
        }
    }
    Ok(())
}

fn run(args: Args) -> Result<(), CliError> {
    if args.size == 0 || args.size as usize > meshadv_raster::MAX_IMAGE_SIZE {
        return Err(CliError::Argument {
            arg: "--size",
            message: format!(
                "must be in [1, {}], got {}",
                meshadv_raster::MAX_IMAGE_SIZE,
                args.size
            ),
        });
    }
    let mut mesh = meshio::load_mesh(&args.mesh)?;
    if args.z_up {
        z_up_to_y_up(&mut mesh.vertices);
    }
    if args.normalize {
        normalize(&mut mesh.vertices)?;
    }
    let camera = SphericalCamera {
        distance: args.distance,
        azimuth: args.azimuth,
        elevation: args.elevation,
        tilt: args.tilt,
        viewing_angle: args.viewing_angle,
        ..SphericalCamera::default()
    };
    let light_dir = match args.light_dir {
        Some(d) => d,
        None => {
            let e = camera.eye();
            [e.x as f32, e.y as f32, e.z as f32]
        }
    };
    let li = args.light_intensity;
    let lights = Lights {
        directions: vec![light_dir],
        colors: vec![[li, li, li]],
        ambient: args.ambient,
    };
    let colors = mesh
        .face_colors
        .clone()
        .unwrap_or_else(|| vec![0.7; mesh.faces.len()]);
    let size = args.size as usize;
    let settings = RenderSettings {
        height: size,
        width: size,
        background: [1.0, 1.0, 1.0],
        fill_back: true,
    };
    let out = render(
        &mesh.vertices,
        &mesh.faces,
        &colors,
        &camera,
        &lights,
        &settings,
    )?;
    let to_u8 = |x: f32| (x.clamp(0.0, 1.0) * 255.0).round() as u8;
    let (w, h) = (args.size, args.size);
    let result = if args.mask {
        let px: Vec<u8> = out.alpha.iter().map(|&a| to_u8(a)).collect();
        image::GrayImage::from_raw(w, h, px).map(|img| img.save(&args.output))
    } else if args.depth {
        let fg: Vec<f32> = out
            .depth
            .iter()
            .zip(&out.face_index)
            .filter(|(_, &f)| f >= 0)
            .map(|(&d, _)| d)
            .collect();
        let lo = fg.iter().copied().fold(f32::INFINITY, f32::min);
        let hi = fg.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        let span = if hi > lo { hi - lo } else { 1.0 };
        let px: Vec<u8> = out
            .depth
            .iter()
            .zip(&out.face_index)
            .map(|(&d, &f)| {
                if f < 0 {
                    0
                } else {
                    to_u8(1.0 - 0.8 * (d - lo) / span)
                }
            })
            .collect();
        image::GrayImage::from_raw(w, h, px).map(|img| img.save(&args.output))
    } else {
        let px: Vec<u8> = out.image.iter().map(|&c| to_u8(c)).collect();
        image::RgbImage::from_raw(w, h, px).map(|img| img.save(&args.output))
    };
    let write_err = |message: String| CliError::WritePng {
        path: args.output.clone(),
        message,
    };
    match result {
        None => Err(write_err("internal error: image buffer size".into())),
        Some(Err(e)) => Err(write_err(e.to_string())),
        Some(Ok(())) => Ok(()),
    }
}

fn main() -> ExitCode {
    let args = Args::parse();
    match run(args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("meshadv-render: error: {e}");
            ExitCode::FAILURE
        }
    }
}
