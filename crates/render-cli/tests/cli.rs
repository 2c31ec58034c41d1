//! Runs the built `meshadv-render` binary on small generated files and on a shared PASCAL3D+ mesh when present.

use std::path::{Path, PathBuf};
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_meshadv-render"))
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("meshadv-render-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir.join(name)
}

const CAMERA: [&str; 6] = ["--azimuth", "30", "--elevation", "20", "--distance", "4"];

/// A unit cube as ASCII OFF with quad faces.
fn cube_off() -> String {
    let v = "-1 -1 -1\n1 -1 -1\n1 1 -1\n-1 1 -1\n-1 -1 1\n1 -1 1\n1 1 1\n-1 1 1\n";
    let f = "4 0 1 2 3\n4 4 5 6 7\n4 0 1 5 4\n4 2 3 7 6\n4 1 2 6 5\n4 0 3 7 4\n";
    format!("OFF\n# a cube\n8 6 0\n{v}{f}")
}

fn png_size(path: &Path) -> (u32, u32) {
    let bytes = std::fs::read(path).expect("png written");
    assert_eq!(&bytes[1..4], b"PNG");
    let w = u32::from_be_bytes([bytes[16], bytes[17], bytes[18], bytes[19]]);
    let h = u32::from_be_bytes([bytes[20], bytes[21], bytes[22], bytes[23]]);
    (w, h)
}

#[test]
fn renders_a_generated_off_cube_in_all_modes() {
    let mesh = tmp("cube.off");
    std::fs::write(&mesh, cube_off()).expect("write");
    for (mode, name) in [
        (None, "rgb.png"),
        (Some("--mask"), "mask.png"),
        (Some("--depth"), "depth.png"),
    ] {
        let out = tmp(name);
        let mut cmd = bin();
        cmd.arg(&mesh)
            .args(CAMERA)
            .args(["--size", "40", "-o"])
            .arg(&out);
        if let Some(m) = mode {
            cmd.arg(m);
        }
        let res = cmd.output().expect("run");
        assert!(
            res.status.success(),
            "{mode:?}: {}",
            String::from_utf8_lossy(&res.stderr)
        );
        assert_eq!(png_size(&out), (40, 40));
    }
}

#[test]
fn renders_an_obj_and_an_ascii_ply() {
    let obj = tmp("tri.obj");
    std::fs::write(&obj, "v -1 -1 0\nv 1 -1 0\nv 0 1 0\nf 1 2 3\n").expect("write");
    let ply = tmp("tri.ply");
    std::fs::write(
        &ply,
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
         element face 1\nproperty list uchar int vertex_indices\nproperty uchar red\nproperty uchar green\n\
         property uchar blue\nend_header\n-1 -1 0\n1 -1 0\n0 1 0\n3 0 1 2 255 0 0\n",
    )
    .expect("write");
    for mesh in [obj, ply] {
        let out = tmp("tri.png");
        let res = bin()
            .arg(&mesh)
            .args(CAMERA)
            .args(["--size", "24", "-o"])
            .arg(&out)
            .output()
            .expect("run");
        assert!(
            res.status.success(),
            "{}",
            String::from_utf8_lossy(&res.stderr)
        );
        assert_eq!(png_size(&out), (24, 24));
    }
}

#[test]
fn missing_and_malformed_files_fail_cleanly() {
    let out = tmp("never.png");
    let bad_off = tmp("bad.off");
    std::fs::write(&bad_off, "OFF\n3 1 0\n0 0 0\n1 0 0\n").expect("write");
    let bad_ply = tmp("bad.ply");
    std::fs::write(&bad_ply, "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n\x01\x02").expect("write");
    let bad_index = tmp("bad_index.obj");
    std::fs::write(&bad_index, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n").expect("write");
    let cases: [(PathBuf, &str); 4] = [
        (tmp("missing.ply"), "no such file"),
        (bad_off, "malformed OFF"),
        (bad_ply, "truncated"),
        (bad_index, "bad_index.obj"),
    ];
    for (mesh, needle) in cases {
        let res = bin()
            .arg(&mesh)
            .args(CAMERA)
            .arg("-o")
            .arg(&out)
            .output()
            .expect("run");
        let err = String::from_utf8_lossy(&res.stderr);
        assert_eq!(res.status.code(), Some(1), "{}: {err}", mesh.display());
        assert!(
            err.contains(needle),
            "{}: {err:?} should contain {needle:?}",
            mesh.display()
        );
        assert!(!err.contains("panicked"), "{err}");
    }
    // Usage errors (missing required option) exit with clap's status 2.
    let res = bin().arg("x.ply").output().expect("run");
    assert_eq!(res.status.code(), Some(2));
}

#[test]
fn renders_the_shared_pascal_chair_when_present() {
    let chair =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/pascal3d/chair/01.ply");
    if !chair.exists() {
        eprintln!("skipping: shared data not found at {}", chair.display());
        return;
    }
    let out = tmp("chair_mask.png");
    let res = bin()
        .arg(&chair)
        .args(CAMERA)
        .args(["--z-up", "--normalize", "--mask", "--size", "64", "-o"])
        .arg(&out)
        .output()
        .expect("run");
    assert!(
        res.status.success(),
        "{}",
        String::from_utf8_lossy(&res.stderr)
    );
    assert_eq!(png_size(&out), (64, 64));
    // The silhouette is neither empty nor full: count white pixels via a mask decode with the image crate.
    let img = image::open(&out).expect("decode").to_luma8();
    let white = img.pixels().filter(|p| p.0[0] > 127).count();
    assert!(
        white > 200 && white < 64 * 64 - 200,
        "{white} foreground pixels"
    );
}

/// Runs the binary on `mesh_text` (written as `name`) with `extra` options (after [`CAMERA`] unless they give
/// an azimuth of their own) and returns (exit code, stderr).
fn run_on(name: &str, mesh_text: &[u8], extra: &[&str]) -> (Option<i32>, String) {
    let mesh = tmp(name);
    std::fs::write(&mesh, mesh_text).expect("write");
    let camera: &[&str] = if extra.contains(&"--azimuth") {
        &[]
    } else {
        &CAMERA
    };
    let res = bin()
        .arg(&mesh)
        .args(camera)
        .args(["--size", "16"])
        .args(extra)
        .arg("-o")
        .arg(tmp(&format!("{name}.png")))
        .output()
        .expect("run");
    (
        res.status.code(),
        String::from_utf8_lossy(&res.stderr).into_owned(),
    )
}

const TRIANGLE: &[u8] = b"v -1 -1 0\nv 1 -1 0\nv 0 1 0\nf 1 2 3\n";

#[test]
fn inputs_the_python_api_refuses_are_errors_naming_what_is_wrong() {
    let ply_double_list = |count: &str, index: &str| {
        format!(
            "ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\nproperty double z\n\
             element face 1\nproperty list double double vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n\
             {count} 0 {index} 2\n"
        )
        .into_bytes()
    };
    let cases: Vec<(&str, Vec<u8>, Vec<&str>, &str)> = vec![
        (
            "nan_index.ply",
            ply_double_list("3", "nan"),
            vec![],
            "not an integer",
        ),
        (
            "fraction_count.ply",
            ply_double_list("3.9", "1"),
            vec![],
            "bad list length 3.9",
        ),
        (
            "flat.obj",
            b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n".to_vec(),
            vec!["--normalize"],
            "every face is degenerate",
        ),
        (
            "point.obj",
            b"v 1 1 1\nv 1 1 1\nv 1 1 1\nf 1 2 3\n".to_vec(),
            vec!["--normalize"],
            "degenerate",
        ),
        (
            "narrow.obj",
            TRIANGLE.to_vec(),
            vec!["--viewing-angle", "1e-40"],
            "viewing_angle",
        ),
        (
            "tall.obj",
            // far out along the view's x axis, in front of the camera
            b"v -1 -1 0\nv 1 -1 0\nv 1e37 0 0\nf 1 2 3\n".to_vec(),
            vec![
                "--azimuth",
                "0",
                "--elevation",
                "0",
                "--distance",
                "4",
                "--viewing-angle",
                "0.001",
            ],
            "projects beyond float32",
        ),
        (
            "dark.obj",
            TRIANGLE.to_vec(),
            vec!["--light-dir", "0,0,0"],
            "light_directions",
        ),
    ];
    for (name, text, extra, needle) in cases {
        let (code, err) = run_on(name, &text, &extra);
        assert_eq!(code, Some(1), "{name}: {err}");
        assert!(err.contains(needle), "{name}: {err:?} lacks {needle:?}");
        assert!(!err.contains("panicked"), "{err}");
    }
}

#[test]
fn normalize_scales_float32_extremes_without_overflow() {
    // The extent 6e38 overflows float32; normalised in f64 the triangle fills the view as at unit scale.
    let huge = b"v -3e38 -3e38 0\nv 3e38 -3e38 0\nv 0 3e38 0\nf 1 2 3\n";
    let mut coverage = Vec::new();
    for (name, text) in [("huge.obj", &huge[..]), ("unit.obj", TRIANGLE)] {
        let (code, err) = run_on(name, text, &["--normalize", "--mask"]);
        assert_eq!(code, Some(0), "{name}: {err}");
        let img = std::fs::read(tmp(&format!("{name}.png"))).expect("png");
        coverage.push(img);
    }
    assert_eq!(
        coverage[0], coverage[1],
        "the huge triangle renders as the unit one"
    );
}
