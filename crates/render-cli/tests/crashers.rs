//! Regression tests: every file in `tests/crashers/` is an input that can make a mesh reader panic, hang or load
//! garbage (found by hand or by the fuzz targets in `crates/render-cli/fuzz`). Each must give a `MeshError`.
//! Files whose name starts with `ok_` must load.

use std::fs;
use std::path::{Path, PathBuf};

use meshadv_render_cli::meshio::{self, MeshError};

fn corpus() -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/crashers");
    let mut files: Vec<PathBuf> = fs::read_dir(&dir)
        .expect("tests/crashers exists")
        .map(|e| e.expect("entry").path())
        .filter(|p| {
            matches!(
                p.extension().and_then(|e| e.to_str()),
                Some("obj" | "off" | "ply")
            )
        })
        .collect();
    files.sort();
    files
}

#[test]
fn every_crasher_is_a_mesh_error_and_never_a_panic() {
    let files = corpus();
    assert!(files.len() >= 10, "corpus has only {} files", files.len());
    for path in files {
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
        let result = meshio::load_mesh(&path);
        if name.starts_with("ok_") {
            assert!(result.is_ok(), "{name}: {result:?}");
        } else {
            let err = result.expect_err(name);
            assert!(
                err.to_string().contains(name),
                "{name}: the message names the file: {err}"
            );
        }
    }
}

#[test]
fn parsers_take_arbitrary_bytes_of_each_crasher() {
    for path in corpus() {
        let bytes = fs::read(&path).expect("read");
        // Every prefix of every crasher: truncations must be errors too, never panics.
        for end in 0..bytes.len() {
            let _ = meshio::parse_obj(&bytes[..end]);
            let _ = meshio::parse_off(&bytes[..end]);
            let _ = meshio::parse_ply(&bytes[..end]);
        }
    }
}

#[test]
fn huge_indices_and_counts_are_malformed_errors() {
    let off = b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n18446744073709551615 0 1 2\n";
    assert!(matches!(
        meshio::parse_off(off),
        Err(MeshError::Malformed { format: "OFF", .. })
    ));
    let off = b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 18446744073709551615\n";
    assert!(matches!(
        meshio::parse_off(off),
        Err(MeshError::Malformed { format: "OFF", .. })
    ));
}

#[cfg(unix)]
#[test]
fn fifos_and_devices_are_refused_without_reading() {
    let dir = std::env::temp_dir().join(format!("meshadv-crashers-{}", std::process::id()));
    fs::create_dir_all(&dir).expect("tmp dir");
    let link = dir.join("zero.ply");
    let _ = fs::remove_file(&link);
    std::os::unix::fs::symlink("/dev/zero", &link).expect("symlink");
    assert!(matches!(
        meshio::load_mesh(&link),
        Err(MeshError::NotRegularFile {
            kind: "a character device",
            ..
        })
    ));
    let fifo = dir.join("x.off");
    let _ = fs::remove_file(&fifo);
    let made = std::process::Command::new("mkfifo").arg(&fifo).status();
    if made.map(|s| s.success()).unwrap_or(false) {
        assert!(matches!(
            meshio::load_mesh(&fifo),
            Err(MeshError::NotRegularFile { kind: "a FIFO", .. })
        ));
    }
    assert!(matches!(
        meshio::load_mesh(&dir.join("missing.obj")),
        Err(MeshError::NotFound { .. })
    ));
    let _ = fs::remove_dir_all(&dir);
}

#[test]
fn reads_are_bounded() {
    let dir = std::env::temp_dir().join(format!("meshadv-bounded-{}", std::process::id()));
    fs::create_dir_all(&dir).expect("tmp dir");
    let path = dir.join("big.off");
    fs::write(&path, vec![b' '; 4096]).expect("write");
    assert!(matches!(
        meshio::read_regular_file(&path, 1024),
        Err(MeshError::TooLarge { limit: 1024, .. })
    ));
    let _ = fs::remove_dir_all(&dir);
}
