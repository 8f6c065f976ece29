//! The TOML reader's unit tests: errors that name line and field, camera
//! tables over a file camera, boxes.

use std::path::Path;

use glam::Vec3;

use super::camera::{camera_of, parse_camera};
use super::errors::Ctx;
use super::parse;
use super::raw::RawCameraFile;
use crate::scene::motion::CameraKey;
use crate::scene::{Camera, Scene, SceneError};

fn parse_str(s: &str) -> Result<Scene, SceneError> {
    parse(s, Path::new("t.toml"), Path::new("."), "t".into())
}

const CAM: &str = "[camera]\nposition=[0,0,-1]\nlook_at=[0,0,0]\nfov_y_deg=40\nwidth=8\nheight=8\n";

/// A `[camera]` table read over a file camera (640 × 480, keyed at
/// frames 0 and 9), or alone.
fn camera_over(table: &str, file: bool) -> Result<(Camera, Vec<CameraKey>), SceneError> {
    let cx = Ctx { text: table, file: Path::new("c.toml") };
    let raw: RawCameraFile = cx.deserialize()?;
    // Rolled a little: its `up` is not the default.
    let cam = Camera {
        position: Vec3::new(0.0, 1.0, 5.0),
        look_at: Vec3::new(0.0, 1.0, 0.0),
        up: Vec3::new(0.1, 1.0, 0.0),
        fov_y_deg: 50.0,
        width: 640,
        height: 480,
    };
    let keys = [0, 9].map(|frame| CameraKey {
        frame,
        position: Vec3::new(frame as f32, 1.0, 5.0),
        look_at: Vec3::new(0.0, 1.0, 0.0),
        up: Vec3::Y,
    });
    camera_of(
        &cx,
        raw.camera.as_ref().expect("a [camera] table"),
        &raw.animation,
        file.then_some((&cam, &keys[..])),
        true,
    )
}

#[test]
fn a_partial_camera_table_takes_the_rest_from_the_file_camera() {
    // The width alone: the height keeps the file's 4:3; the path stays.
    let (c, keys) = camera_over("[camera]\nwidth = 1000\n", true).unwrap();
    assert_eq!((c.width, c.height, c.fov_y_deg, c.position), (1000, 750, 50.0, Vec3::new(0.0, 1.0, 5.0)));
    assert_eq!(c.up, Vec3::new(0.1, 1.0, 0.0), "the file's up, with its view");
    assert_eq!(keys.len(), 2);
    // The height alone, and the field of view.
    let (c, keys) = camera_over("[camera]\nheight = 240\nfov_y_deg = 30\n", true).unwrap();
    assert_eq!((c.width, c.height, c.fov_y_deg, keys.len()), (320, 240, 30.0, 2));
    // Both sides as given, whatever the file's ratio.
    let (c, _) = camera_over("[camera]\nwidth = 64\nheight = 64\n", true).unwrap();
    assert_eq!((c.width, c.height), (64, 64));
    // Placing the camera drops the file's path; the rest is the file's.
    let (c, keys) = camera_over("[camera]\nposition = [3, 1, 3]\n", true).unwrap();
    assert_eq!((c.position, c.look_at, c.width, c.height), (Vec3::new(3.0, 1.0, 3.0), Vec3::Y, 640, 480));
    assert!(keys.is_empty());
    // A view of the table's own has the default up, not the file's.
    assert_eq!(c.up, Vec3::Y);
    let whole = camera_over(CAM, true).unwrap().0;
    assert_eq!((whole.up, whole.width), (Vec3::Y, 8), "a whole table owes the file nothing");
    // Over a file camera the values given are still checked.
    let e = camera_over("[camera]\nfov_y_deg = 190\n", true).unwrap_err();
    assert_eq!((e.line, e.field.as_str()), (2, "camera.fov_y_deg"), "{e}");
    let e = camera_over("[camera]\nlook_at = [0, 1, 5]\n", true).unwrap_err();
    assert_eq!(e.field, "camera.up", "{e}");
    // Without one, every field but `up` is needed, each named.
    let (c, _) = camera_over(CAM, false).unwrap();
    assert_eq!(c.up, Vec3::Y);
    for field in ["position", "look_at", "fov_y_deg", "width", "height"] {
        let table: String = CAM.lines().filter(|l| !l.starts_with(field)).map(|l| format!("{l}\n")).collect();
        let e = camera_over(&table, false).unwrap_err();
        assert_eq!((e.line, e.field.clone()), (1, format!("camera.{field}")), "{e}");
        assert!(e.message.contains(&format!("missing field `{field}`")) && e.message.contains("[gltf]"), "{e}");
    }
    // A camera file (`render --camera-from`) is read alone.
    let e = parse_camera("[camera]\nwidth = 8\n", Path::new("c.toml"), Path::new(".")).unwrap_err();
    assert!(e.field == "camera.position" && e.message.contains("read alone"), "{e}");
}

#[test]
fn errors_name_line_and_field() {
    let s = format!(
        "{CAM}[[material]]\nname='w'\ntype='diffuse'\nreflectance=[0.5,0.5,0.5]\n[[surface]]\nname='a'\nmaterial='nope'\nquad=[[0,0,0],[1,0,0],[1,1,0],[0,1,0]]\n"
    );
    let e = parse_str(&s).unwrap_err();
    assert_eq!(e.line, 13, "{e}");
    assert_eq!(e.field, "surface[0].material");
    assert!(e.to_string().starts_with("t.toml:13:"), "{e}");

    let e = parse_str(&s.replace("reflectance=[0.5,0.5,0.5]", "reflectance=[1.5,0.5,0.5]")).unwrap_err();
    assert_eq!((e.line, e.field.as_str()), (10, "material[0].reflectance"), "{e}");

    let e = parse_str(&s.replace("'nope'", "'w'").replace("[0,1,0]]", "[0,1,0.5]]")).unwrap_err();
    assert!(e.message.contains("not planar"), "{e}");

    let e = parse_str(&s.replace("fov_y_deg=40", "fov_y_deg=400")).unwrap_err();
    assert_eq!((e.line, e.field.as_str()), (4, "camera.fov_y_deg"), "{e}");

    // Syntax errors carry a position too.
    let e = parse_str(&s.replace("name='a'", "name=")).unwrap_err();
    assert!(e.line >= 11, "{e}");
}

#[test]
fn boxes_face_outwards_or_inwards() {
    let s = format!(
        "{CAM}[[material]]\nname='w'\ntype='diffuse'\nreflectance=[0.5,0.5,0.5]\n[[surface]]\nname='b'\nmaterial='w'\nbox={{min=[0,0,0],max=[1,2,3],omit=['-y']}}\n"
    );
    let sc = parse_str(&s).unwrap();
    let prims = &sc.surfaces[0].primitives;
    assert_eq!(prims.len(), 5);
    let centre = Vec3::new(0.5, 1.0, 1.5);
    for p in prims {
        let mid = (p.p[0] + p.p[2]) / 2.0;
        assert!(p.normal().dot(mid - centre) > 0.0);
    }
    assert!((sc.total_area() - (2.0 * (2.0 + 6.0 + 3.0) - 3.0)).abs() < 1e-5);
    let sc = parse_str(&s.replace("omit=['-y']", "inward=true")).unwrap();
    for p in &sc.surfaces[0].primitives {
        let mid = (p.p[0] + p.p[2]) / 2.0;
        assert!(p.normal().dot(mid - centre) < 0.0);
    }
}

#[test]
fn cornell_box_parses() {
    let sc = Scene::cornell_box();
    assert_eq!(sc.surfaces.len(), 8);
    assert_eq!(sc.materials.len(), 4);
    assert_eq!(sc.primitives().count(), 1 + 4 + 1 + 3 + 10);
}
