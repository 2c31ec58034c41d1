//! Bad input returns a typed error naming the argument; nothing panics.

use meshadv_raster::camera::SphericalCamera;
use meshadv_raster::pipeline::{render, Lights, RenderSettings};
use meshadv_raster::raycast::{raycast, RayCamera};
use meshadv_raster::{
    rasterize, rasterize_backward, BackwardInputs, ErrorKind, FaceAttrs, RasterError, RasterParams,
    ScreenMesh,
};

const TRI: [f32; 9] = [-0.5, -0.5, 2.0, 0.5, -0.5, 2.0, 0.0, 0.5, 2.0];

fn fwd(verts: &[f32], faces: &[i32], attrs: &[f32], p: &RasterParams) -> Result<(), RasterError> {
    let mesh = ScreenMesh::new(verts, faces, 1, verts.len() / 3)?;
    rasterize(
        &mesh,
        &FaceAttrs {
            values: attrs,
            background: &[0.0],
            channels: 1,
        },
        p,
    )
    .map(|_| ())
}

fn message(r: Result<(), RasterError>) -> (ErrorKind, String) {
    let e = r.expect_err("must fail");
    (e.kind(), e.to_string())
}

#[test]
fn forward_rejects_bad_input_naming_the_argument() {
    let p = RasterParams::new(8, 8, 0.1, 10.0);
    let cases: Vec<(Result<(), RasterError>, ErrorKind, &str)> = vec![
        (fwd(&TRI, &[0, 1, 3], &[1.0], &p), ErrorKind::Index, "faces"),
        (
            fwd(&TRI, &[0, 1, -1], &[1.0], &p),
            ErrorKind::Index,
            "faces",
        ),
        (fwd(&TRI, &[], &[], &p), ErrorKind::Value, "faces"),
        (
            fwd(&TRI, &[0, 1, 2], &[1.0, 2.0], &p),
            ErrorKind::Value,
            "face_attrs",
        ),
        (
            fwd(&TRI, &[0, 1, 2], &[f32::NAN], &p),
            ErrorKind::Value,
            "face_attrs",
        ),
        (
            fwd(&[f32::INFINITY; 9], &[0, 1, 2], &[1.0], &p),
            ErrorKind::Value,
            "verts_screen",
        ),
        (
            fwd(&TRI[..8], &[0, 1, 2], &[1.0], &p),
            ErrorKind::Value,
            "verts_screen",
        ),
        (
            fwd(
                &TRI,
                &[0, 1, 2],
                &[1.0],
                &RasterParams::new(0, 8, 0.1, 10.0),
            ),
            ErrorKind::Value,
            "height",
        ),
        (
            fwd(
                &TRI,
                &[0, 1, 2],
                &[1.0],
                &RasterParams::new(8, 20000, 0.1, 10.0),
            ),
            ErrorKind::Value,
            "width",
        ),
        (
            fwd(&TRI, &[0, 1, 2], &[1.0], &RasterParams::new(8, 8, 5.0, 5.0)),
            ErrorKind::Value,
            "near",
        ),
        (
            fwd(
                &TRI,
                &[0, 1, 2],
                &[1.0],
                &RasterParams::new(8, 8, -1.0, 5.0),
            ),
            ErrorKind::Value,
            "near",
        ),
        (
            fwd(
                &TRI,
                &[0, 1, 2],
                &[1.0],
                &RasterParams::new(8, 8, 0.1, f64::NAN),
            ),
            ErrorKind::Value,
            "far",
        ),
    ];
    for (r, kind, arg) in cases {
        let (k, msg) = message(r);
        assert_eq!(k, kind, "{msg}");
        assert!(msg.contains(arg), "message {msg:?} should name {arg}");
    }
    let behind = [-0.5, -0.5, -2.0, 0.5, -0.5, -2.0, 0.0, 0.5, -2.0];
    let (k, msg) = message(fwd(&behind, &[0, 1, 2], &[1.0], &p));
    assert_eq!(k, ErrorKind::Value);
    assert!(msg.contains("behind the camera"), "{msg}");
}

#[test]
fn backward_rejects_inconsistent_forward_outputs() {
    let p = RasterParams::new(4, 4, 0.1, 10.0);
    let mesh = ScreenMesh::new(&TRI, &[0, 1, 2], 1, 3).expect("ok");
    let attrs = FaceAttrs {
        values: &[1.0],
        background: &[0.0],
        channels: 1,
    };
    let img = [0f32; 16];
    let run = |fi: &[i32], image: &[f32], grad: &[f32]| {
        rasterize_backward(
            &mesh,
            &attrs,
            &p,
            &BackwardInputs {
                face_index: fi,
                image,
                grad_image: grad,
                vertex_grad: true,
                visibility: Default::default(),
            },
        )
        .map(|_| ())
    };
    let (k, msg) = message(run(&[5; 16], &img, &img));
    assert_eq!(k, ErrorKind::Index);
    assert!(msg.contains("face_index"), "{msg}");
    let (k, msg) = message(run(&[-1; 15], &img, &img));
    assert_eq!(k, ErrorKind::Value);
    assert!(msg.contains("face_index"), "{msg}");
    let mut bad = img;
    bad[3] = f32::NAN;
    assert!(message(run(&[-1; 16], &img, &bad)).1.contains("grad_image"));
    assert!(message(run(&[-1; 16], &img[..8], &img)).1.contains("image"));
}

#[test]
fn raycast_and_render_reject_bad_cameras() {
    let p = RasterParams::new(4, 4, 0.1, 10.0);
    let mesh = ScreenMesh::new(&TRI, &[0, 1, 2], 1, 3).expect("ok");
    for angle in [0.0, 180.0, f64::NAN] {
        let cam = RayCamera {
            viewing_angle: angle,
            orthographic: false,
            ortho_scale: 1.0,
        };
        let e = raycast(&mesh, &cam, &p).expect_err("bad angle");
        assert!(e.to_string().contains("viewing_angle"));
    }
    let settings = RenderSettings {
        height: 8,
        width: 8,
        ..Default::default()
    };
    let lights = Lights::default();
    let verts = [-1.0f32, -1.0, 0.0, 1.0, -1.0, 0.0, 0.0, 1.0, 0.0];
    let bad_cams = [
        (
            SphericalCamera {
                distance: 0.0,
                ..Default::default()
            },
            "distance",
        ),
        (
            SphericalCamera {
                azimuth: f64::INFINITY,
                ..Default::default()
            },
            "azimuth",
        ),
        (
            SphericalCamera {
                ortho_scale: -1.0,
                orthographic: true,
                ..Default::default()
            },
            "ortho_scale",
        ),
    ];
    for (cam, arg) in bad_cams {
        let e = render(&verts, &[0, 1, 2], &[1.0; 3], &cam, &lights, &settings)
            .expect_err("bad camera");
        assert!(e.to_string().contains(arg), "{e}");
    }
    let e = render(
        &verts,
        &[0, 1, 2],
        &[1.0; 6],
        &SphericalCamera::default(),
        &lights,
        &settings,
    )
    .expect_err("shape");
    assert!(e.to_string().contains("face_colors"), "{e}");
}
