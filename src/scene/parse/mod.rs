//! TOML scene text → [`Scene`], with errors that name file, line and field.
//!
//! * `raw`: the tables as serde reads them (spans kept for errors);
//! * `errors`: line, column and field name of a position, the TOML
//!   parser's messages in plain words;
//! * `camera`: `[camera]` and its keys, and camera files read alone;
//! * `gltf_table`: `[gltf]`, the glTF file a scene starts from;
//! * `material`, `surface`, `motion`: `[[material]]`, `[[surface]]` (its
//!   primitives, boxes, OBJ meshes) and keyframes with `[animation]`.
//!
//! [`parse`] checks `[gltf]`, `[camera]`, `[build]`, the materials, the
//! surfaces (each whole, in file order) and then `[animation]`: the first
//! mistake in that order is the one reported.

mod camera;
mod errors;
mod gltf_table;
mod material;
mod motion;
mod raw;
mod surface;
#[cfg(test)]
mod tests;

use std::path::Path;

use toml::Spanned;

use camera::camera_of;
pub(super) use camera::parse_camera;
use errors::Ctx;
use gltf_table::{at_gltf_file, gltf_source};
use raw::{RawBuild, RawScene};

use super::{BuildHints, Material, Scene, SceneError, Surface};

/// Reads the scene text `text` of `file` (OBJ meshes and a `[gltf]` file
/// resolve against `base_dir`) into a scene named `name`.
pub(super) fn parse(text: &str, file: &Path, base_dir: &Path, name: String) -> Result<Scene, SceneError> {
    let cx = Ctx { text, file };
    let raw: RawScene = cx.deserialize()?;

    // A glTF file to start from: its materials and surfaces come first; this
    // file's override materials of the same name and add the rest.
    let imported = match &raw.gltf {
        None => None,
        Some(g) => {
            let (path, options) = gltf_source(&cx, g, &raw.animation, &raw.camera, base_dir)?;
            Some(super::gltf::import_unchecked(&path, &options).map_err(|e| at_gltf_file(&cx, g, &path, e))?)
        }
    };
    let (camera, camera_keys) = match (&raw.camera, &imported) {
        (Some(c), g) => camera_of(&cx, c, &raw.animation, g.as_ref().map(|g| (&g.camera, &g.camera_keys[..])), true)?,
        (None, Some(g)) => (g.camera, g.camera_keys.clone()),
        (None, None) => return Err(cx.err(0..0, "camera", "the scene has no [camera] table")),
    };

    let build = build_hints(&cx, &raw.build)?;

    // Materials.
    let mut materials: Vec<Material> = imported.as_ref().map_or_else(Vec::new, |g| g.materials.clone());
    let from_gltf = materials.len();
    for (i, m) in raw.material.iter().enumerate() {
        material::add_material(&cx, i, m.get_ref(), &mut materials, from_gltf)?;
    }

    // Surfaces.
    let mut surfaces: Vec<Surface> = imported.as_ref().map_or_else(Vec::new, |g| g.surfaces.clone());
    for (i, s) in raw.surface.iter().enumerate() {
        let surface = surface::surface_of(&cx, i, s, &materials, &surfaces, &raw.animation, base_dir)?;
        surfaces.push(surface);
    }
    if surfaces.is_empty() {
        return Err(cx.err(0..0, "surface", "the scene has no surfaces"));
    }
    if imported.is_some() {
        material::check_overrides(&cx, &raw.material, &materials, from_gltf, &surfaces)?;
    }
    let animation = match &raw.animation {
        None if imported.is_some() => imported.as_ref().and_then(|g| g.animation),
        Some(a) => Some(motion::animation_of(&cx, a)?),
        None => None,
    };
    let (notes, textures) = imported.map_or_else(Default::default, |g| (g.notes, g.textures));
    let scene = Scene { name, materials, surfaces, camera, build, animation, camera_keys, notes, textures };
    Ok(scene)
}

/// `[build]`: the build settings the scene asks for, checked.
fn build_hints(cx: &Ctx<'_>, raw: &Option<Spanned<RawBuild>>) -> Result<BuildHints, SceneError> {
    let mut build = BuildHints::default();
    if let Some(b) = raw {
        let b = b.get_ref();
        if let Some(p) = &b.patch_size {
            if !(p.get_ref().is_finite() && *p.get_ref() > 0.0) {
                return Err(cx.err(p.span(), "build.patch_size", "must be a positive length in metres"));
            }
            build.patch_size = Some(*p.get_ref());
        }
        if let Some(r) = &b.ray_spacing {
            if !(r.get_ref().is_finite() && *r.get_ref() >= crate::limits::MIN_RAY_SPACING) {
                return Err(cx.err(r.span(), "build.ray_spacing", "must be a length of at least 1e-6 metres"));
            }
            build.ray_spacing = Some(*r.get_ref());
        }
        if let Some(k) = &b.buckets {
            if *k.get_ref() > crate::limits::MAX_BUCKET {
                return Err(cx.err(k.span(), "build.buckets", format!("must be in 0..={}", crate::limits::MAX_BUCKET)));
            }
            build.buckets = Some(*k.get_ref());
        }
        if let Some(f) = &b.frequency {
            if !(1..=crate::limits::MAX_FREQUENCY).contains(f.get_ref()) {
                return Err(cx.err(
                    f.span(),
                    "build.frequency",
                    format!("must be in 1..={}", crate::limits::MAX_FREQUENCY),
                ));
            }
            build.frequency = Some(*f.get_ref());
        }
    }
    Ok(build)
}
