//! `[gltf]`: the glTF file a TOML scene starts from, and the import
//! options the table gives it.

use std::path::Path;

use toml::Spanned;

use super::errors::Ctx;
use super::raw::{RawAnimation, RawCamera, RawGltf};
use crate::scene::SceneError;
use crate::scene::gltf::{GltfOptions, is_gltf_path};

/// The glTF file a `[gltf]` table names (resolved against `base_dir`) and
/// the import options it gives, checked: a scene over a glTF file takes
/// its frames from the file, so has no `[animation]`; a whole `[camera]`
/// replaces the file's (no camera is looked up by name), a partial one
/// takes the rest from the camera named.
pub(super) fn gltf_source(
    cx: &Ctx<'_>,
    g: &Spanned<RawGltf>,
    animation: &Option<Spanned<RawAnimation>>,
    camera: &Option<Spanned<RawCamera>>,
    base_dir: &Path,
) -> Result<(std::path::PathBuf, GltfOptions), SceneError> {
    let gs = g.get_ref();
    if let Some(a) = animation {
        return Err(cx.err(
            a.span(),
            "animation",
            "a scene with [gltf] takes its frames from the glTF file's animation (set its rate with [gltf] fps)",
        ));
    }
    let positive = |v: &Option<Spanned<f32>>, key: &str| -> Result<Option<f32>, SceneError> {
        match v {
            Some(x) if !(x.get_ref().is_finite() && *x.get_ref() > 0.0) => {
                Err(cx.err(x.span(), format!("gltf.{key}"), "must be a positive number"))
            }
            Some(x) => Ok(Some(*x.get_ref())),
            None => Ok(None),
        }
    };
    let options = GltfOptions {
        camera: if camera.as_ref().is_some_and(|c| c.get_ref().is_whole()) { None } else { gs.camera.clone() },
        light_radius: positive(&gs.light_radius, "light_radius")?,
        fps: positive(&gs.fps, "fps")?,
    };
    let path = base_dir.join(gs.file.get_ref());
    if !is_gltf_path(&path) {
        return Err(cx.err(gs.file.span(), "gltf.file", "must name a .gltf or .glb file"));
    }
    Ok((path, options))
}

/// An error importing the glTF file at `path` that `[gltf]` names: one
/// that cannot be read is named at the field naming it.
pub(super) fn at_gltf_file(cx: &Ctx<'_>, g: &Spanned<RawGltf>, path: &Path, e: SceneError) -> SceneError {
    let file = &g.get_ref().file;
    match e.unreadable {
        true => SceneError {
            unreadable: true,
            ..cx.err(file.span(), "gltf.file", format!("`{}` {}", path.display(), e.message))
        },
        false => e,
    }
}
