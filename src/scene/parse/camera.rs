//! `[camera]`: the scene's camera and its keyframes, checked so that every
//! frame's camera can make rays; over a `[gltf]` scene, the fields left
//! out taken from the file's camera. Camera files (`render
//! --camera-from`) are read here too.

use std::path::Path;

use glam::Vec3;
use toml::Spanned;

use super::errors::Ctx;
use super::gltf_table::{at_gltf_file, gltf_source};
use super::motion::check_key_frames;
use super::raw::{RawAnimation, RawCamera, RawCameraFile, V3};
use crate::scene::motion::CameraKey;
use crate::scene::{Camera, CameraPath, Scene, SceneError};

/// Finite and within ±[`crate::limits::MAX_COORDINATE`].
fn finite3(v: &[f32; 3]) -> bool {
    v.iter().all(|x| x.abs() <= crate::limits::MAX_COORDINATE)
}

/// The `[camera]` table (and its keyframes, which need `[animation]`),
/// checked: every frame's camera, between keys too, can make rays (the
/// archive reader's rule). Over a glTF scene (`file`: its camera and
/// keys) the fields the table leaves out are the file camera's: the width
/// alone sets the height by the file camera's aspect ratio (and the height
/// alone the width), `up` is the file's only with its position and
/// look_at, and the file camera's path stays unless the table places the
/// camera (`position`, `look_at` or `up`). `scene`: read from a scene
/// (else a camera file, read alone), for what a missing field's error
/// says.
pub(super) fn camera_of(
    cx: &Ctx<'_>,
    raw: &Spanned<RawCamera>,
    animation: &Option<Spanned<RawAnimation>>,
    file: Option<(&Camera, &[CameraKey])>,
    scene: bool,
) -> Result<(Camera, Vec<CameraKey>), SceneError> {
    // Camera.
    let c = raw.get_ref();
    let cspan = raw.span();
    // Only without a file camera, which gives every field.
    let missing = |field: &str| {
        let why = format!(
            "missing field `{field}` (a [camera] needs position, look_at, fov_y_deg, width and height{})",
            match file {
                Some(_) => "",
                None if scene => "; over a [gltf] scene, the file's camera gives those left out",
                None => "; a camera file is read alone, so its [camera] gives them all",
            }
        );
        cx.err(cspan.clone(), format!("camera.{field}"), why)
    };
    let pick = |v: &Option<V3>, of_file: fn(&Camera) -> Vec3, field: &str| match (v, file) {
        (Some(v), _) => Ok(Vec3::from(*v)),
        (None, Some((f, _))) => Ok(of_file(f)),
        (None, None) if field == "up" => Ok(Vec3::Y),
        (None, None) => Err(missing(field)),
    };
    let position = pick(&c.position, |f| f.position, "position")?;
    let look_at = pick(&c.look_at, |f| f.look_at, "look_at")?;
    // The file's `up` goes with its view only: a table that says where
    // the camera is or looks has `up`'s default.
    let up = match (&c.up, c.position.is_some() || c.look_at.is_some()) {
        (None, true) => Vec3::Y,
        _ => pick(&c.up, |f| f.up, "up")?,
    };
    if !finite3(&position.to_array()) || !finite3(&look_at.to_array()) || !finite3(&up.to_array()) {
        return Err(cx.err(cspan, "camera", "position, look_at and up must be finite and within ±1e9 m"));
    }
    let forward = look_at - position;
    if forward.length() <= 0.0 || forward.normalize().cross(up).length() < 1e-6 {
        return Err(cx.err(
            cspan,
            "camera.up",
            "look_at must differ from position, and up must not be parallel to the view direction",
        ));
    }
    let fov = match (&c.fov_y_deg, file) {
        (Some(v), _) => {
            let fov = *v.get_ref();
            if !(fov > 0.0 && fov < 180.0) {
                return Err(cx.err(v.span(), "camera.fov_y_deg", format!("must be in (0, 180) degrees, got {fov}")));
            }
            fov
        }
        (None, Some((f, _))) => f.fov_y_deg,
        (None, None) => return Err(missing("fov_y_deg")),
    };
    for (v, f) in [(&c.width, "camera.width"), (&c.height, "camera.height")] {
        if let Some(v) = v
            && !(1..=16384).contains(v.get_ref())
        {
            return Err(cx.err(v.span(), f, format!("must be in 1..=16384 pixels, got {}", v.get_ref())));
        }
    }
    // One side given over a file camera: the other keeps its aspect ratio.
    let scaled = |n: u32, ratio: f64| ((n as f64 * ratio).round() as u32).clamp(1, 16384);
    let (width, height) = match (c.width.as_ref().map(|v| *v.get_ref()), c.height.as_ref().map(|v| *v.get_ref()), file)
    {
        (Some(w), Some(h), _) => (w, h),
        (Some(w), None, Some((f, _))) => (w, scaled(w, f.height as f64 / f.width as f64)),
        (None, Some(h), Some((f, _))) => (scaled(h, f.width as f64 / f.height as f64), h),
        (None, None, Some((f, _))) => (f.width, f.height),
        (None, _, None) => return Err(missing("width")),
        (_, None, None) => return Err(missing("height")),
    };
    let camera = Camera { position, look_at, up, fov_y_deg: fov, width, height };

    let camera_keys = camera_keys(cx, raw, animation, file, &camera)?;
    Ok((camera, camera_keys))
}

/// The camera's keys: the table's `keyframes`, else a file camera's path
/// unless the table places the camera; checked so that every frame's
/// camera can make rays.
fn camera_keys(
    cx: &Ctx<'_>,
    raw: &Spanned<RawCamera>,
    animation: &Option<Spanned<RawAnimation>>,
    file: Option<(&Camera, &[CameraKey])>,
    camera: &Camera,
) -> Result<Vec<CameraKey>, SceneError> {
    let c = raw.get_ref();
    // A file camera's path, unless the table places the camera.
    let mut camera_keys = match (file, &c.keyframes) {
        (Some((_, keys)), None) if !c.places() => keys.to_vec(),
        _ => Vec::new(),
    };
    if let Some(keys) = &raw.get_ref().keyframes {
        check_key_frames(cx, keys.get_ref().iter().map(|k| k.frame), keys.span(), "camera.keyframes", animation)?;
        for k in keys.get_ref() {
            let (p, l) = (Vec3::from(k.position), Vec3::from(k.look_at));
            if !(finite3(&p.to_array()) && finite3(&l.to_array()))
                || (l - p).normalize_or_zero().cross(camera.up).length() < 1e-6
            {
                return Err(cx.err(
                    keys.span(),
                    "camera.keyframes",
                    "position and look_at must be finite (within ±1e9 m), distinct and not along `up`",
                ));
            }
            camera_keys.push(CameraKey { frame: k.frame, position: p, look_at: l, up: camera.up });
        }
    }
    let frames = animation.as_ref().map_or(1, |a| *a.get_ref().frames.get_ref());
    if let Some(f) = (0..frames).find(|&f| {
        let c = crate::scene::camera_at(camera, &camera_keys, f);
        !crate::limits::camera_is_usable(c.position.to_array(), c.look_at.to_array(), c.up.to_array())
    }) {
        let (span, field) = match &raw.get_ref().keyframes {
            Some(k) => (k.span(), "camera.keyframes"),
            None => (raw.span(), "camera"),
        };
        return Err(cx.err(
            span,
            field,
            format!(
                "at frame {f} the camera looks along `up`, or from its look_at point (or beyond ±1e9 m): \
                 no rays can be made"
            ),
        ));
    }
    Ok(camera_keys)
}

/// Reads the `[camera]` of a camera file (`render --camera-from`): see
/// [`crate::scene::CameraPath::from_file`].
pub(in crate::scene) fn parse_camera(text: &str, file: &Path, base_dir: &Path) -> Result<CameraPath, SceneError> {
    let cx = Ctx { text, file };
    let raw: RawCameraFile = cx.deserialize()?;
    let whole = raw.camera.as_ref().is_some_and(|c| c.get_ref().is_whole());
    if let (Some(g), false) = (&raw.gltf, whole) {
        // Only the camera is read from the glTF file, not its meshes.
        let (path, options) = gltf_source(&cx, g, &raw.animation, &raw.camera, base_dir)?;
        let Some(f) =
            crate::scene::gltf::import_camera_if_any(&path, &options).map_err(|e| at_gltf_file(&cx, g, &path, e))?
        else {
            // No camera in the file: the scene's, which frames its geometry.
            let s = Scene::from_toml(text, file, base_dir)?;
            return Ok(CameraPath { frames: s.frame_count(), camera: s.camera, keys: s.camera_keys });
        };
        let (camera, keys) = match &raw.camera {
            Some(c) => camera_of(&cx, c, &None, Some((&f.camera, &f.keys[..])), true)?,
            None => (f.camera, f.keys),
        };
        return Ok(CameraPath { camera, keys, frames: f.frames });
    }
    let Some(c) = &raw.camera else {
        return Err(cx.err(0..0, "camera", "the file has no [camera] table (nor a [gltf] file to take one from)"));
    };
    let (camera, keys) = camera_of(&cx, c, &raw.animation, None, false)?;
    let frames = raw.animation.as_ref().map_or(1, |a| *a.get_ref().frames.get_ref());
    Ok(CameraPath { camera, keys, frames })
}
