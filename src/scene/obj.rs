//! Wavefront OBJ scenes with their MTL materials (`illumnet build
//! model.obj`): one surface per OBJ object or group and material, the
//! materials mapped as `format-spec/scene.md` ("OBJ + MTL scenes") states:
//!
//! * `Kd` → diffuse reflectance (0.8 grey without), times the mean albedo
//!   of `map_Kd`, whose texels are kept for the render;
//! * `vn` → shading normals;
//! * `Ks` with `Ns` → a GGX lobe of `α = √(2 / (Ns + 2))` (the Phong exponent
//!   whose lobe has the same width, Walter et al. 2007), at least 0.01:
//!   `rough_conductor` without `Kd`, else `broad_specular` (both scaled down
//!   together where `Kd + Ks` exceeds 1);
//! * `Ke` → emitted radiance (W·sr⁻¹·m⁻²).
//!
//! OBJ has no camera: one frames the scene along −Z (change it with
//! `render --camera-*`).

use std::path::Path;

use glam::{Vec2, Vec3};

use super::check::check_primitive;
use super::error::error;
use super::import::{Notes, merge_quads_indexed, unique_name, unique_names};
use super::texture::{MAX_TEXEL_BYTES, Shading, Texture, TextureImage, Wrap, srgb_to_linear};
use super::{BuildHints, Material, ReflectanceModel, Scene, SceneError, Surface};
use crate::reflectance::Lobe;

/// Default image width of the framing camera.
const DEFAULT_WIDTH: u32 = 640;

/// Whether `path` names an OBJ file (`.obj`, any case).
pub(super) fn is_obj_path(path: &Path) -> bool {
    path.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("obj"))
}

/// The reflectance model of an MTL material's `Kd`, `Ks`, `Ns`, and whether
/// `Kd + Ks` had to be scaled down to conserve energy.
pub fn mtl_model(kd: [f32; 3], ks: [f32; 3], ns: f32) -> (ReflectanceModel, bool) {
    let kd = kd.map(|x| if x.is_finite() { x.clamp(0.0, 1.0) } else { 0.0 });
    let ks = ks.map(|x| if x.is_finite() { x.clamp(0.0, 1.0) } else { 0.0 });
    if ks.iter().all(|&x| x <= 1e-3) {
        return (ReflectanceModel::Diffuse { reflectance: kd }, false);
    }
    let ns = if ns.is_finite() { ns.max(0.0) } else { 0.0 };
    let alpha = (2.0 / (ns + 2.0)).sqrt().clamp(0.01, 1.0);
    let lobe = Lobe { alpha_u: alpha, alpha_v: alpha, ior: None };
    if kd.iter().all(|&x| x <= 1e-3) {
        return (ReflectanceModel::RoughConductor { specular: ks, lobe }, false);
    }
    let worst = (0..3).map(|c| kd[c] + ks[c]).fold(0.0f32, f32::max);
    let scale = if worst > 1.0 { 1.0 / worst } else { 1.0 };
    (
        ReflectanceModel::BroadSpecular { reflectance: kd.map(|x| x * scale), specular: ks.map(|x| x * scale), lobe },
        worst > 1.0,
    )
}

/// Reads the OBJ at `path` and the MTL files it names.
pub(super) fn import(path: &Path) -> Result<Scene, SceneError> {
    match std::fs::metadata(path) {
        Err(e) => return Err(SceneError::io(path, e)),
        Ok(m) if m.is_dir() => return Err(error(path, "", "is a directory, not an OBJ file")),
        Ok(_) => {}
    }
    let opts = tobj::LoadOptions { triangulate: true, single_index: true, ..Default::default() };
    let (models, mtl) = tobj::load_obj(path, &opts).map_err(|e| error(path, "", format!("cannot load OBJ: {e}")))?;
    let mut notes = Notes::default();
    let mtl = match mtl {
        Ok(m) => m,
        Err(e) => {
            notes.add(format!("cannot read its MTL file ({e}): every surface is a diffuse grey of 0.8"));
            Vec::new()
        }
    };
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut materials: Vec<Material> = Vec::new();
    let mut by_mtl: Vec<Option<u32>> = vec![None; mtl.len()];
    let mut surfaces: Vec<Surface> = Vec::new();
    let mut textured = 0u32;
    let (mut textures, mut kept_textures, mut texel_bytes) = (Vec::new(), Vec::<std::path::PathBuf>::new(), 0usize);
    for (k, model) in models.iter().enumerate() {
        let mesh = &model.mesh;
        let field = format!("object `{}`", model.name);
        let positions: Vec<Vec3> = mesh.positions.chunks_exact(3).map(|p| Vec3::new(p[0], p[1], p[2])).collect();
        if mesh.indices.iter().any(|&i| i as usize >= positions.len()) {
            return Err(error(path, field, "a face index is out of range"));
        }
        let mut tri: Vec<[u32; 3]> = Vec::with_capacity(mesh.indices.len() / 3);
        let mut degenerate = 0usize;
        for f in mesh.indices.chunks_exact(3) {
            let t = [f[0], f[1], f[2]];
            let p = crate::geometry::Primitive::triangle(
                positions[t[0] as usize],
                positions[t[1] as usize],
                positions[t[2] as usize],
            );
            if check_primitive(&p).is_ok() {
                tri.push(t);
            } else {
                degenerate += 1;
            }
        }
        if degenerate > 0 {
            notes.add(format!("{field}: {degenerate} degenerate (zero-area or non-finite) triangles left out"));
        }
        if tri.is_empty() {
            continue;
        }
        let source = mesh.material_id.filter(|&m| m < mtl.len());
        // The texture the render applies, and one over its mean.
        let mut kept: Option<(u32, [f32; 3])> = None;
        let (material, emission) = match source {
            None => {
                notes.add("a face group has no material: a diffuse grey of 0.8 is used");
                let i = match materials.iter().position(|m| m.name == "default") {
                    Some(i) => i as u32,
                    None => {
                        materials.push(Material {
                            name: "default".into(),
                            model: ReflectanceModel::Diffuse { reflectance: [0.8; 3] },
                        });
                        (materials.len() - 1) as u32
                    }
                };
                (i, [0.0; 3])
            }
            Some(m) => {
                let src = &mtl[m];
                let emission = src
                    .emissive
                    .unwrap_or([0.0; 3])
                    .map(|e| if e.is_finite() { e.clamp(0.0, crate::limits::MAX_RADIANCE) } else { 0.0 });
                for (present, what) in [
                    (src.specular_texture.is_some(), "map_Ks"),
                    (src.shininess_texture.is_some(), "map_Ns"),
                    (src.normal_texture.is_some(), "a normal or bump map"),
                    (
                        src.dissolve.is_some_and(|d| d < 1.0) || src.dissolve_texture.is_some(),
                        "transparency (d, map_d)",
                    ),
                ] {
                    if present {
                        notes.add(format!("material `{}`: {what} is not supported and was ignored", src.name));
                    }
                }
                let mut kd = src.diffuse.unwrap_or([0.8; 3]);
                let mut own = false;
                if let Some(map) = &src.diffuse_texture {
                    // Options (`-s 1 1 1 file.png`) come first: the file is the last word.
                    let file = map.split_whitespace().last().unwrap_or(map);
                    let uvs: Vec<[Vec2; 3]> = if mesh.texcoords.len() == 2 * positions.len() {
                        let uv = |i: u32| {
                            let i = i as usize * 2;
                            // OBJ's v runs up from the bottom row; images start at the top.
                            Vec2::new(mesh.texcoords[i], 1.0 - mesh.texcoords[i + 1])
                        };
                        tri.iter().map(|t| t.map(uv)).collect()
                    } else {
                        Vec::new()
                    };
                    if uvs.is_empty() {
                        notes.add(format!("{field}: no texture coordinates for map_Kd; its Kd alone is used"));
                    } else {
                        let image = image::open(dir.join(file)).map_err(|e| {
                            error(path, format!("material `{}`.map_Kd", src.name), format!("cannot read `{file}`: {e}"))
                        })?;
                        let rgb = image.to_rgb8();
                        let lut: Vec<f32> = (0..256).map(|v| srgb_to_linear(v as f32 / 255.0)).collect();
                        let raw = rgb.as_raw();
                        let fetch = |i: usize| [0, 1, 2].map(|c| raw.get(3 * i + c).map_or(0.0, |&b| lut[b as usize]));
                        let texture = Texture { width: rgb.width(), height: rgb.height(), texel: &fetch };
                        let areas = tri.iter().map(|t| {
                            let p = t.map(|i| positions[i as usize]);
                            (p[1] - p[0]).cross(p[2] - p[0]).length() / 2.0
                        });
                        let mean = texture.mean_albedo((Wrap::Repeat, Wrap::Repeat), &uvs, areas);
                        for c in 0..3 {
                            kd[c] *= mean[c];
                        }
                        own = true;
                        let tint = mean.map(|m| if m > 0.0 { 1.0 / m } else { 0.0 });
                        let key = dir.join(file);
                        let id = match kept_textures.iter().position(|k| *k == key) {
                            Some(i) => Some(i as u32),
                            None if texel_bytes + raw.len() <= MAX_TEXEL_BYTES => {
                                texel_bytes += raw.len();
                                kept_textures.push(key);
                                textures.push(TextureImage {
                                    width: rgb.width(),
                                    height: rgb.height(),
                                    wrap: [Wrap::Repeat, Wrap::Repeat],
                                    nearest: false,
                                    srgb: raw.clone(),
                                });
                                Some((textures.len() - 1) as u32)
                            }
                            None => {
                                notes.add(format!(
                                    "material `{}`: the scene's textures exceed {} MiB; map_Kd enters as its mean",
                                    src.name,
                                    MAX_TEXEL_BYTES >> 20
                                ));
                                None
                            }
                        };
                        kept = id.map(|i| (i, tint));
                    }
                }
                let (model, scaled) = mtl_model(kd, src.specular.unwrap_or([0.0; 3]), src.shininess.unwrap_or(0.0));
                if scaled {
                    notes.add(format!(
                        "material `{}`: Kd + Ks exceeds 1; both scaled down to conserve energy",
                        src.name
                    ));
                }
                let index = match (own, by_mtl[m]) {
                    (false, Some(i)) => i,
                    _ => {
                        let name = if own {
                            textured += 1;
                            format!("{}@{textured}", src.name)
                        } else {
                            src.name.clone()
                        };
                        let name = unique_name(&name, |n| materials.iter().any(|x| x.name == n));
                        materials.push(Material { name, model });
                        let i = (materials.len() - 1) as u32;
                        if !own {
                            by_mtl[m] = Some(i);
                        }
                        i
                    }
                };
                (index, emission)
            }
        };
        let name = if model.name.is_empty() { format!("object{k}") } else { model.name.clone() };
        let (primitives, corners) = merge_quads_indexed(&positions, &tri);
        // Emitters show their own radiance: a texture would not change it.
        let texture = kept.filter(|_| emission.iter().all(|&e| e <= 0.0));
        let normals = (mesh.normals.len() == 3 * positions.len())
            .then(|| mesh.normals.chunks_exact(3).map(|n| Vec3::new(n[0], n[1], n[2])).collect::<Vec<_>>());
        let uv = |i: u32| {
            let i = i as usize * 2;
            mesh.texcoords.get(i..i + 2).map_or(Vec2::ZERO, |t| Vec2::new(t[0], 1.0 - t[1]))
        };
        let shading = if normals.is_some() || texture.is_some() {
            primitives
                .iter()
                .zip(&corners)
                .map(|(p, c)| Shading {
                    uv: c.map(uv),
                    normal: Shading::to_local(
                        p,
                        normals.as_ref().map_or([Vec3::ZERO; 4], |n| c.map(|i| n[i as usize])),
                    ),
                    texture: texture.map_or(u32::MAX, |t| t.0),
                    tint: texture.map_or([1.0; 3], |t| t.1),
                })
                .collect()
        } else {
            Vec::new()
        };
        surfaces.push(Surface {
            name,
            material,
            emission,
            primitives,
            motion: None,
            emission_keys: Vec::new(),
            grain: None,
            moved: false,
            shading,
        });
    }
    unique_names(&mut surfaces);
    if surfaces.is_empty() {
        return Err(error(path, "", "the OBJ has no faces"));
    }
    if surfaces.iter().all(|s| s.emission.iter().all(|&e| e <= 0.0)) {
        return Err(error(
            path,
            "",
            "the scene emits no light: give a material of its MTL an emission (`Ke r g b`, radiance in \
             W·sr⁻¹·m⁻²), or write a TOML scene with a `mesh = ` surface and an emitter",
        ));
    }
    let bounds = crate::geometry::bounds_of(surfaces.iter().flat_map(|s| &s.primitives));
    notes.add("OBJ has no camera: one looks at the scene along -Z (give one with render --camera-*)");
    Ok(Scene {
        name: path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default(),
        materials,
        surfaces,
        camera: super::framing_camera(bounds, DEFAULT_WIDTH),
        build: BuildHints::default(),
        animation: None,
        camera_keys: Vec::new(),
        notes: notes.into_vec(),
        textures,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mtl_maps_onto_our_models() {
        assert_eq!(mtl_model([0.5; 3], [0.0; 3], 10.0).0, ReflectanceModel::Diffuse { reflectance: [0.5; 3] });
        // Ns = 48: α = √(2/50) = 0.2.
        let ReflectanceModel::RoughConductor { specular, lobe } = mtl_model([0.0; 3], [0.9; 3], 48.0).0 else {
            panic!()
        };
        assert_eq!(specular, [0.9; 3]);
        assert!((lobe.alpha_u - 0.2).abs() < 1e-6 && lobe.alpha_u == lobe.alpha_v);
        // Kd + Ks = 1.5: both scaled by 1/1.5, and said.
        let (m, scaled) = mtl_model([0.9, 0.5, 0.5], [0.6; 3], 0.0);
        let ReflectanceModel::BroadSpecular { reflectance, specular, lobe } = m else { panic!() };
        assert!(scaled);
        assert!((reflectance[0] - 0.6).abs() < 1e-6 && (specular[0] - 0.4).abs() < 1e-6);
        assert_eq!(lobe.alpha_u, 1.0, "Ns = 0: the widest lobe");
        // A mirror-like exponent is clamped to α = 0.01.
        let ReflectanceModel::RoughConductor { lobe, .. } = mtl_model([0.0; 3], [1.0; 3], 1e9).0 else { panic!() };
        assert_eq!(lobe.alpha_u, 0.01);
    }
}
