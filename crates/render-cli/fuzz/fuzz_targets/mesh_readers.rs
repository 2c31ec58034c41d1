//! Fuzz target: the render binary's OBJ, OFF and PLY readers must return a mesh or a `MeshError` for any bytes,
//! never panic, hang or allocate without bound. A mesh they return must pass `check_mesh`'s invariants when
//! `check_mesh` accepts it.
#![no_main]

use libfuzzer_sys::fuzz_target;
use meshadv_render_cli::meshio::{check_mesh, parse_obj, parse_off, parse_ply};

fuzz_target!(|data: &[u8]| {
    for parse in [parse_obj, parse_off, parse_ply] {
        if let Ok(mesh) = parse(data) {
            if check_mesh(&mesh).is_ok() {
                let n = (mesh.vertices.len() / 3) as i32;
                assert!(mesh.faces.iter().all(|&f| (0..n).contains(&f)));
                assert!(mesh.vertices.iter().all(|v| v.is_finite()));
            }
        }
    }
});
