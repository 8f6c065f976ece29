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

/// An OBJ file's models, its materials (an error when its MTL could not be
/// read), and what [`super::mtl::scan`] found in its MTL files.
pub(super) type ObjFile = (Vec<tobj::Model>, Result<Vec<tobj::Material>, tobj::LoadError>, Vec<super::mtl::MtlFinding>);

/// The OBJ at `path` as `tobj` reads it, with the MTL files it names
/// (a result, since a missing MTL file is not an error), every file read
/// through [`crate::limits::read_regular`]: the OBJ or an MTL that is not a
/// regular file of at most [`crate::limits::MAX_INPUT_FILE`] bytes (a FIFO,
/// `/dev/zero`, a directory) is an I/O error naming it (exit 5), never a
/// hang or a read without end. Each MTL's values are scanned first (its
/// findings returned for OBJ scenes to refuse or say; `mesh` surfaces,
/// which use no material, ignore them); one `tobj` would panic on is not
/// given to it. Shared by OBJ scenes and `mesh` surfaces.
pub(super) fn load_obj_file(path: &Path) -> Result<ObjFile, SceneError> {
    let bytes =
        crate::limits::read_regular(path, crate::limits::MAX_INPUT_FILE).map_err(|e| SceneError::io(path, e))?;
    let dir = path.parent().unwrap_or(Path::new("."));
    let refused: std::cell::RefCell<Option<SceneError>> = Default::default();
    let findings: std::cell::RefCell<Vec<super::mtl::MtlFinding>> = Default::default();
    let opts = tobj::LoadOptions { triangulate: true, single_index: true, ..Default::default() };
    let loaded = tobj::load_obj_buf(&mut &bytes[..], &opts, |mtl_path| {
        let full = dir.join(mtl_path);
        match crate::limits::read_regular(&full, crate::limits::MAX_INPUT_FILE) {
            Ok(text) => {
                let scan = super::mtl::scan(&full, &text);
                findings.borrow_mut().extend(scan.findings);
                if scan.malformed {
                    return Err(tobj::LoadError::MaterialParseError);
                }
                tobj::load_mtl_buf(&mut &text[..])
            }
            Err(e) => {
                // A file that is there but cannot be read (not a regular
                // file, too large) is refused; a missing one is said.
                if std::fs::metadata(&full).is_ok() {
                    refused.borrow_mut().get_or_insert_with(|| SceneError::io(&full, e));
                }
                Err(tobj::LoadError::OpenFileFailed)
            }
        }
    });
    if let Some(e) = refused.into_inner() {
        return Err(e);
    }
    let (models, materials) = loaded.map_err(|e| error(path, "", format!("cannot load OBJ: {e}")))?;
    Ok((models, materials, findings.into_inner()))
}

/// Reads the OBJ at `path` and the MTL files it names.
pub(super) fn import(path: &Path) -> Result<Scene, SceneError> {
    let (models, mtl, findings) = load_obj_file(path)?;
    let mut notes = Notes::default();
    // An MTL value beyond the TOML reader's bounds: refused, or (a
    // reflectance above 1) clamped and said, naming file, line and field.
    for f in findings {
        if f.refused {
            return Err(f.error);
        }
        notes.add(f.error.to_string());
    }
    let mtl = match mtl {
        Ok(m) => m,
        Err(e) => {
            notes.add(format!("cannot read its MTL file ({e}): every surface is a diffuse grey of 0.8"));
            Vec::new()
        }
    };
    let mut materials = MtlMaterials::new(path, &mtl);
    let mut surfaces: Vec<Surface> = Vec::new();
    for (k, model) in models.iter().enumerate() {
        if let Some(surface) = object_surface(path, k, model, &mut materials, &mut notes)? {
            surfaces.push(surface);
        }
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
        materials: materials.materials,
        surfaces,
        camera: super::framing_camera(bounds, DEFAULT_WIDTH),
        build: BuildHints::default(),
        animation: None,
        camera_keys: Vec::new(),
        notes: notes.into_vec(),
        textures: materials.textures,
    })
}

/// The image at `path` (PNG, EXR, GIF, by its bytes), read through
/// [`crate::limits::read_regular`] and decoded by
/// [`super::texture::decode_image`] (a size a texture cannot hold is
/// refused before decoding); failing, the error and whether it is an I/O
/// failure (`true`) rather than a bad image.
fn read_image(path: &Path) -> Result<image::DynamicImage, (String, bool)> {
    let bytes = crate::limits::read_regular(path, crate::limits::MAX_INPUT_FILE).map_err(|e| (e.to_string(), true))?;
    super::texture::decode_image(&bytes).map_err(|e| (e, false))
}

/// The surface of the `k`-th OBJ object (`model`): its non-degenerate
/// triangles (pairs re-merged into quads), its material, emission and
/// shading; `None` when it has no triangles left.
fn object_surface(
    path: &Path,
    k: usize,
    model: &tobj::Model,
    materials: &mut MtlMaterials<'_>,
    notes: &mut Notes,
) -> Result<Option<Surface>, SceneError> {
    let mesh = &model.mesh;
    let field = format!("object `{}`", model.name);
    let positions: Vec<Vec3> = mesh.positions.chunks_exact(3).map(|p| Vec3::new(p[0], p[1], p[2])).collect();
    if mesh.indices.iter().any(|&i| i as usize >= positions.len()) {
        return Err(error(path, field, "a face index is out of range"));
    }
    let (tri, degenerate) = kept_triangles(&positions, &mesh.indices);
    if degenerate > 0 {
        notes.add(format!("{field}: {degenerate} degenerate (zero-area or non-finite) triangles left out"));
    }
    if tri.is_empty() {
        return Ok(None);
    }
    let source = mesh.material_id.filter(|&m| m < materials.mtl.len());
    // The texture the render applies, and one over its mean.
    let (material, emission, kept) = match source {
        None => {
            notes.add("a face group has no material: a diffuse grey of 0.8 is used");
            (materials.default_material(), [0.0; 3], None)
        }
        Some(m) => materials.of_mtl(m, &field, mesh, &positions, &tri, notes)?,
    };
    let name = if model.name.is_empty() { format!("object{k}") } else { model.name.clone() };
    let (primitives, corners) = merge_quads_indexed(&positions, &tri);
    // Emitters show their own radiance: a texture would not change it.
    let texture = kept.filter(|_| emission.iter().all(|&e| e <= 0.0));
    let shading = shading_of(mesh, positions.len(), &primitives, &corners, texture);
    Ok(Some(Surface {
        name,
        material,
        emission,
        primitives,
        motion: None,
        emission_keys: Vec::new(),
        grain: None,
        moved: false,
        shading,
    }))
}

/// The triangles of `indices` that pass [`check_primitive`], and how many
/// did not.
fn kept_triangles(positions: &[Vec3], indices: &[u32]) -> (Vec<[u32; 3]>, usize) {
    let mut tri: Vec<[u32; 3]> = Vec::with_capacity(indices.len() / 3);
    let mut degenerate = 0usize;
    for f in indices.chunks_exact(3) {
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
    (tri, degenerate)
}

/// Per primitive, its shading detail: the mesh's vertex normals and the
/// texture (its index, and one over its mean) with its coordinates; empty
/// when it has neither.
fn shading_of(
    mesh: &tobj::Mesh,
    vertices: usize,
    primitives: &[crate::geometry::Primitive],
    corners: &[[u32; 4]],
    texture: Option<(u32, [f32; 3])>,
) -> Vec<Shading> {
    let normals = (mesh.normals.len() == 3 * vertices)
        .then(|| mesh.normals.chunks_exact(3).map(|n| Vec3::new(n[0], n[1], n[2])).collect::<Vec<_>>());
    let uv = |i: u32| {
        let i = i as usize * 2;
        mesh.texcoords.get(i..i + 2).map_or(Vec2::ZERO, |t| Vec2::new(t[0], 1.0 - t[1]))
    };
    if normals.is_some() || texture.is_some() {
        primitives
            .iter()
            .zip(corners)
            .map(|(p, c)| Shading {
                uv: c.map(uv),
                normal: Shading::to_local(p, normals.as_ref().map_or([Vec3::ZERO; 4], |n| c.map(|i| n[i as usize]))),
                texture: texture.map_or(u32::MAX, |t| t.0),
                tint: texture.map_or([1.0; 3], |t| t.1),
            })
            .collect()
    } else {
        Vec::new()
    }
}

/// The materials made from an OBJ's MTL so far, and the textures kept for
/// the render: the state every object's surface adds to.
struct MtlMaterials<'a> {
    /// The OBJ file, for errors.
    path: &'a Path,
    /// Its folder, which `map_Kd` paths are relative to.
    dir: &'a Path,
    /// The MTL's materials, as `tobj` read them.
    mtl: &'a [tobj::Material],
    /// Our materials.
    materials: Vec<Material>,
    /// Our index of each untextured MTL material, once made.
    by_mtl: Vec<Option<u32>>,
    /// Textured materials made (each surface gets its own: `name@k`).
    textured: u32,
    /// Textures kept for the render, the files they came from, and their
    /// texels' bytes.
    textures: Vec<TextureImage>,
    kept_textures: Vec<std::path::PathBuf>,
    texel_bytes: usize,
}

impl<'a> MtlMaterials<'a> {
    fn new(path: &'a Path, mtl: &'a [tobj::Material]) -> Self {
        Self {
            path,
            dir: path.parent().unwrap_or(Path::new(".")),
            mtl,
            materials: Vec::new(),
            by_mtl: vec![None; mtl.len()],
            textured: 0,
            textures: Vec::new(),
            kept_textures: Vec::new(),
            texel_bytes: 0,
        }
    }

    /// The diffuse grey 0.8 of faces without a material, made once.
    fn default_material(&mut self) -> u32 {
        match self.materials.iter().position(|m| m.name == "default") {
            Some(i) => i as u32,
            None => {
                self.materials.push(Material {
                    name: "default".into(),
                    model: ReflectanceModel::Diffuse { reflectance: [0.8; 3] },
                });
                (self.materials.len() - 1) as u32
            }
        }
    }

    /// Our material for MTL material `m` on the triangles `tri` of `mesh`
    /// (a textured one gets its own: its mean albedo is the surface's), its
    /// emission, and its texture as the render applies it.
    #[allow(clippy::type_complexity)]
    fn of_mtl(
        &mut self,
        m: usize,
        field: &str,
        mesh: &tobj::Mesh,
        positions: &[Vec3],
        tri: &[[u32; 3]],
        notes: &mut Notes,
    ) -> Result<(u32, [f32; 3], Option<(u32, [f32; 3])>), SceneError> {
        let src = &self.mtl[m];
        let emission = src
            .emissive
            .unwrap_or([0.0; 3])
            .map(|e| if e.is_finite() { e.clamp(0.0, crate::limits::MAX_RADIANCE) } else { 0.0 });
        for (present, what) in [
            (src.specular_texture.is_some(), "map_Ks"),
            (src.shininess_texture.is_some(), "map_Ns"),
            (src.normal_texture.is_some(), "a normal or bump map"),
            (src.dissolve.is_some_and(|d| d < 1.0) || src.dissolve_texture.is_some(), "transparency (d, map_d)"),
        ] {
            if present {
                notes.add(format!("material `{}`: {what} is not supported and was ignored", src.name));
            }
        }
        let mut kd = src.diffuse.unwrap_or([0.8; 3]);
        let mut own = false;
        let mut kept: Option<(u32, [f32; 3])> = None;
        if let Some(map) = &src.diffuse_texture
            && let Some((mean, id)) = self.diffuse_texture(src, map, field, mesh, positions, tri, notes)?
        {
            for c in 0..3 {
                kd[c] *= mean[c];
            }
            own = true;
            let tint = mean.map(|m| if m > 0.0 { 1.0 / m } else { 0.0 });
            kept = id.map(|i| (i, tint));
        }
        let (model, scaled) = mtl_model(kd, src.specular.unwrap_or([0.0; 3]), src.shininess.unwrap_or(0.0));
        if scaled {
            notes.add(format!("material `{}`: Kd + Ks exceeds 1; both scaled down to conserve energy", src.name));
        }
        let index = match (own, self.by_mtl[m]) {
            (false, Some(i)) => i,
            _ => {
                let name = if own {
                    self.textured += 1;
                    format!("{}@{}", src.name, self.textured)
                } else {
                    src.name.clone()
                };
                let name = unique_name(&name, |n| self.materials.iter().any(|x| x.name == n));
                self.materials.push(Material { name, model });
                let i = (self.materials.len() - 1) as u32;
                if !own {
                    self.by_mtl[m] = Some(i);
                }
                i
            }
        };
        Ok((index, emission, kept))
    }

    /// `map_Kd` (`map`) of `src` over the triangles `tri`: its mean linear
    /// albedo over them and the index of its texels kept for the render
    /// (`None` past [`MAX_TEXEL_BYTES`]); `None` without texture
    /// coordinates (said).
    #[allow(clippy::too_many_arguments, clippy::type_complexity)]
    fn diffuse_texture(
        &mut self,
        src: &tobj::Material,
        map: &str,
        field: &str,
        mesh: &tobj::Mesh,
        positions: &[Vec3],
        tri: &[[u32; 3]],
        notes: &mut Notes,
    ) -> Result<Option<([f32; 3], Option<u32>)>, SceneError> {
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
            return Ok(None);
        }
        let image = read_image(&self.dir.join(file)).map_err(|(e, unreadable)| SceneError {
            unreadable,
            ..error(self.path, format!("material `{}`.map_Kd", src.name), format!("cannot read `{file}`: {e}"))
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
        let key = self.dir.join(file);
        let id = match self.kept_textures.iter().position(|k| *k == key) {
            Some(i) => Some(i as u32),
            None if self.texel_bytes + raw.len() <= MAX_TEXEL_BYTES => {
                self.texel_bytes += raw.len();
                self.kept_textures.push(key);
                self.textures.push(TextureImage {
                    width: rgb.width(),
                    height: rgb.height(),
                    wrap: [Wrap::Repeat, Wrap::Repeat],
                    nearest: false,
                    srgb: raw.clone(),
                });
                Some((self.textures.len() - 1) as u32)
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
        Ok(Some((mean, id)))
    }
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
