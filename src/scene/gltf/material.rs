//! glTF materials onto our reflectance models (`format-spec/scene.md`,
//! "glTF 2.0 scenes", states the mapping and its limits):
//!
//! * roughness `r` → GGX `α = r²`, clamped to `[0.01, 1]`;
//! * metallic `m = 1` → rough conductor with `k_s` = base colour;
//! * `m = 0` and `r ≥ 0.8` (matte) → diffuse with `ρ` = base colour;
//! * otherwise broad specular, `k_d = 0.96·(1−m)·c`, `k_s = 0.04·(1−m) + m·c`
//!   (the specification's blend of a 4% dielectric layer and a metal);
//! * `KHR_materials_anisotropy`: `α` along the anisotropy direction becomes
//!   `α + (1−α)·s²` (the extension's rule), that direction the grain;
//! * emissive factor × `KHR_materials_emissive_strength` → emitted radiance;
//! * a base-colour texture multiplies the factor by its mean (linear) albedo
//!   over the surface's triangles, and its texels are kept for the render
//!   (`TextureUse`: per-texel detail around that mean).

use std::collections::HashMap;
use std::path::Path;

use glam::Vec3;

use super::triangles::Triangles;
use crate::reflectance::Lobe;
use crate::scene::error::error;
use crate::scene::import::Notes;
use crate::scene::texture::{MAX_TEXEL_BYTES, Texture, TextureImage, Wrap, linear_to_srgb_byte, srgb_to_linear};
use crate::scene::{Material, ReflectanceModel, SceneError};

/// Roughness at or above which a non-metal without anisotropy is taken as
/// diffuse (its 4% specular layer is then nearly Lambertian).
const MATTE_ROUGHNESS: f32 = 0.8;

/// The reflectance model of a glTF material's factors (base colour already
/// multiplied by any texture's mean); `anisotropy` is the strength `s`.
/// Returns the model and whether the roughness had to be clamped.
pub fn model_of(base: [f32; 3], metallic: f32, roughness: f32, anisotropy: f32) -> (ReflectanceModel, bool) {
    let c = base.map(|x| x.clamp(0.0, 1.0));
    let m = metallic.clamp(0.0, 1.0);
    let r = roughness.clamp(0.0, 1.0);
    let alpha = r * r;
    let clamped = alpha < 0.01;
    let alpha = alpha.clamp(0.01, 1.0);
    let s = anisotropy.clamp(0.0, 1.0);
    let lobe = Lobe { alpha_u: alpha + (1.0 - alpha) * s * s, alpha_v: alpha, ior: None };
    let model = if m >= 0.999 {
        ReflectanceModel::RoughConductor { specular: c, lobe }
    } else if m <= 0.001 && r >= MATTE_ROUGHNESS && s == 0.0 {
        ReflectanceModel::Diffuse { reflectance: c }
    } else {
        ReflectanceModel::BroadSpecular {
            reflectance: c.map(|x| 0.96 * (1.0 - m) * x),
            specular: c.map(|x| 0.04 * (1.0 - m) + m * x),
            lobe,
        }
    };
    (model, clamped)
}

/// The materials made so far, and the glTF materials they came from.
pub(super) struct Materials<'a> {
    path: &'a Path,
    doc: &'a gltf::Document,
    buffers: &'a [gltf::buffer::Data],
    images: &'a mut super::load::Images,
    /// A textured mesh primitive's mean albedo, by (mesh, primitive): every
    /// instance of it shares the first one's.
    means: HashMap<(usize, usize), [f32; 3]>,
    out: Vec<Material>,
    /// Our index of each untextured glTF material (`None`: the default).
    by_source: HashMap<Option<usize>, u32>,
    lamp: Option<u32>,
    textured: u32,
    /// Textures kept for the render, and their index by (image, wraps).
    textures: Vec<TextureImage>,
    texture_ids: HashMap<(usize, [Wrap; 2], bool), u32>,
    texel_bytes: usize,
}

/// A surface's base-colour texture as the render applies it.
pub(super) struct TextureUse {
    /// Index into the scene's textures.
    pub(super) texture: u32,
    /// Its `TEXCOORD_n` set.
    pub(super) set: usize,
    /// One over the texture's mean over the surface (per band; 0 where the
    /// mean is 0).
    pub(super) tint: [f32; 3],
}

impl<'a> Materials<'a> {
    pub(super) fn new(
        path: &'a Path,
        doc: &'a gltf::Document,
        buffers: &'a [gltf::buffer::Data],
        images: &'a mut super::load::Images,
    ) -> Self {
        Self {
            path,
            doc,
            buffers,
            images,
            means: HashMap::new(),
            out: Vec::new(),
            by_source: HashMap::new(),
            lamp: None,
            textured: 0,
            textures: Vec::new(),
            texture_ids: HashMap::new(),
            texel_bytes: 0,
        }
    }

    /// The materials, in index order, and the textures kept for the render.
    pub(super) fn into_materials(self) -> (Vec<Material>, Vec<TextureImage>) {
        (self.out, self.textures)
    }

    /// Our texture of glTF image `index` with `wrap`, its texels kept as
    /// 8-bit sRGB; `None` once [`MAX_TEXEL_BYTES`] are kept.
    fn keep_texture(
        &mut self,
        index: usize,
        wrap: [Wrap; 2],
        nearest: bool,
        notes: &mut Notes,
    ) -> Result<Option<u32>, SceneError> {
        if let Some(&i) = self.texture_ids.get(&(index, wrap, nearest)) {
            return Ok(Some(i));
        }
        let image = self.images.get(self.path, self.doc, self.buffers, index)?;
        let n = image.width as usize * image.height as usize;
        if self.texel_bytes + 3 * n > MAX_TEXEL_BYTES {
            notes.add(format!(
                "image {index}: the scene's textures exceed {} MiB; it enters as its surfaces' mean albedo only",
                MAX_TEXEL_BYTES >> 20
            ));
            return Ok(None);
        }
        let mut srgb = Vec::with_capacity(3 * n);
        for i in 0..n {
            srgb.extend(texel(image, i).map(linear_to_srgb_byte));
        }
        self.texel_bytes += srgb.len();
        self.textures.push(TextureImage { width: image.width, height: image.height, wrap, nearest, srgb });
        let id = (self.textures.len() - 1) as u32;
        self.texture_ids.insert((index, wrap, nearest), id);
        Ok(Some(id))
    }

    fn push(&mut self, name: String, model: ReflectanceModel) -> u32 {
        let name = crate::scene::import::unique_name(&name, |n| self.out.iter().any(|m| m.name == n));
        self.out.push(Material { name, model });
        (self.out.len() - 1) as u32
    }

    /// The black material of lamps' stand-in emitters.
    pub(super) fn lamp_material(&mut self) -> u32 {
        if let Some(i) = self.lamp {
            return i;
        }
        let i = self.push("lamp".into(), ReflectanceModel::Diffuse { reflectance: [0.0; 3] });
        self.lamp = Some(i);
        i
    }

    /// Emitted radiance of a primitive's material: factor × strength.
    pub(super) fn emission(&self, prim: &gltf::Primitive<'_>, notes: &mut Notes) -> [f32; 3] {
        let m = prim.material();
        let strength = m.emissive_strength().unwrap_or(1.0);
        let e = m.emissive_factor().map(|e| e * strength);
        if !e.iter().all(|x| x.is_finite() && (0.0..=crate::limits::MAX_RADIANCE).contains(x)) {
            let name = m.name().map_or_else(|| format!("material{}", m.index().unwrap_or(0)), str::to_string);
            notes.add(format!("material `{name}`: its emission is not in [0, 1e9] W·sr⁻¹·m⁻² and was clamped there"));
        }
        e.map(|x| if x.is_nan() { 0.0 } else { x.clamp(0.0, crate::limits::MAX_RADIANCE) })
    }

    /// Our material for a surface made of `tri` (a textured material gets
    /// one per surface: its mean albedo is the surface's), the surface's
    /// grain for an anisotropic one, and its base-colour texture as the
    /// render applies it (for models with a diffuse part).
    pub(super) fn surface_material(
        &mut self,
        prim: &gltf::Primitive<'_>,
        key: (usize, usize),
        tri: &Triangles,
        notes: &mut Notes,
    ) -> Result<(u32, Option<Vec3>, Option<TextureUse>), SceneError> {
        let m = prim.material();
        let Some(index) = m.index() else {
            notes.add("a primitive has no material: a diffuse grey of 0.8 is used");
            return Ok((self.default_material(), None, None));
        };
        let at = format!("/materials/{index}");
        let name = m.name().map_or_else(|| format!("material{index}"), str::to_string);
        let pbr = m.pbr_metallic_roughness();
        let [r, g, b, a] = pbr.base_color_factor();
        note_ignored(&m, &pbr, a, &name, notes);
        let (strength, rotation) = anisotropy(self.path, &at, &m, &name, notes)?;
        let texture = pbr.base_color_texture();
        let mut base = [r, g, b];
        if texture.is_none()
            && strength == 0.0
            && let Some(&i) = self.by_source.get(&Some(index))
        {
            return Ok((i, None, None));
        }
        let mut kept: Option<(usize, [Wrap; 2], bool, [f32; 3])> = None;
        if let Some(info) = &texture {
            let (image, wraps, nearest, mean) = self.base_colour_mean(info, &at, key, tri)?;
            for (c, m) in base.iter_mut().zip(mean) {
                *c *= m;
            }
            kept = Some((image, wraps, nearest, mean));
        }
        let (model, clamped) = model_of(base, pbr.metallic_factor(), pbr.roughness_factor(), strength);
        let texture_use = self.texture_use(kept, &model, &pbr, &name, notes)?;
        if clamped {
            notes.add(format!("material `{name}`: roughness below 0.1 is taken as 0.1 (GGX α ≥ 0.01)"));
        }
        let grain = if strength > 0.0 && model.lobe().is_some() { grain_of(tri, rotation, &name, notes) } else { None };
        let i = if texture.is_some() || grain.is_some() {
            self.textured += 1;
            self.push(format!("{name}@{}", self.textured), model)
        } else {
            let i = self.push(name, model);
            self.by_source.insert(Some(index), i);
            i
        };
        Ok((i, grain, texture_use))
    }

    /// The diffuse grey 0.8 of primitives without a material, made once.
    fn default_material(&mut self) -> u32 {
        if let Some(&i) = self.by_source.get(&None) {
            return i;
        }
        let i = self.push("default".into(), ReflectanceModel::Diffuse { reflectance: [0.8; 3] });
        self.by_source.insert(None, i);
        i
    }

    /// A base-colour texture (`info`, of the material at `at`) over the
    /// surface `tri` of mesh primitive `key`: its image, wraps, whether
    /// sampled nearest, and its mean linear albedo over the surface (every
    /// instance of a mesh primitive shares the first one's).
    #[allow(clippy::type_complexity)]
    fn base_colour_mean(
        &mut self,
        info: &gltf::texture::Info<'_>,
        at: &str,
        key: (usize, usize),
        tri: &Triangles,
    ) -> Result<(usize, [Wrap; 2], bool, [f32; 3]), SceneError> {
        let set = info.tex_coord() as usize;
        let Some(Some(uvs)) = tri.uvs.get(set) else {
            return Err(error(
                self.path,
                format!("{at}/pbrMetallicRoughness/baseColorTexture/texCoord"),
                format!("the mesh has no TEXCOORD_{set} for the base-colour texture"),
            ));
        };
        let tex = info.texture();
        let sampler = tex.sampler();
        let wrap = |m: gltf::texture::WrappingMode| match m {
            gltf::texture::WrappingMode::ClampToEdge => Wrap::Clamp,
            gltf::texture::WrappingMode::Repeat => Wrap::Repeat,
            gltf::texture::WrappingMode::MirroredRepeat => Wrap::Mirror,
        };
        let wraps = [wrap(sampler.wrap_s()), wrap(sampler.wrap_t())];
        let nearest = sampler.mag_filter() == Some(gltf::texture::MagFilter::Nearest);
        let mean = match self.means.get(&key) {
            Some(m) => *m,
            None => {
                let image = self.images.get(self.path, self.doc, self.buffers, tex.source().index())?;
                let fetch = |i: usize| texel(image, i);
                let texture = Texture { width: image.width, height: image.height, texel: &fetch };
                let m = texture.mean_albedo((wraps[0], wraps[1]), uvs, tri.corners.iter().map(|c| c.area));
                self.means.insert(key, m);
                m
            }
        };
        Ok((tex.source().index(), wraps, nearest, mean))
    }

    /// The base-colour texture as the render applies it: its texels times
    /// one over its mean on diffuse reflection. A metal's base colour is
    /// its specular colour, which keeps the mean (said).
    #[allow(clippy::type_complexity)]
    fn texture_use(
        &mut self,
        kept: Option<(usize, [Wrap; 2], bool, [f32; 3])>,
        model: &ReflectanceModel,
        pbr: &gltf::material::PbrMetallicRoughness<'_>,
        name: &str,
        notes: &mut Notes,
    ) -> Result<Option<TextureUse>, SceneError> {
        // The render applies the texels to diffuse reflection; a metal's
        // base colour is its specular colour, which keeps the mean.
        let texture_use = match (kept, model) {
            (Some(_), ReflectanceModel::RoughConductor { .. }) => {
                notes.add(format!(
                    "material `{name}`: a metal's base-colour texture enters as its mean colour (no per-texel detail)"
                ));
                None
            }
            (Some((image, wraps, nearest, mean)), _) => {
                self.keep_texture(image, wraps, nearest, notes)?.map(|texture| TextureUse {
                    texture,
                    set: tex_coord_set(pbr),
                    tint: mean.map(|m| if m > 0.0 { 1.0 / m } else { 0.0 }),
                })
            }
            (None, _) => None,
        };
        Ok(texture_use)
    }
}

/// Notes what of material `m` (named `name`, base colour alpha `alpha`) is
/// not mapped: transparency, and the textures whose factors are used.
fn note_ignored(
    m: &gltf::Material<'_>,
    pbr: &gltf::material::PbrMetallicRoughness<'_>,
    alpha: f32,
    name: &str,
    notes: &mut Notes,
) {
    if alpha < 1.0 || m.alpha_mode() != gltf::material::AlphaMode::Opaque {
        notes.add(format!("material `{name}`: transparency is not supported; it is opaque"));
    }
    for (present, what) in [
        (pbr.metallic_roughness_texture().is_some(), "metallicRoughnessTexture (its factors are used)"),
        (m.normal_texture().is_some(), "normalTexture"),
        (m.occlusion_texture().is_some(), "occlusionTexture"),
        (m.emissive_texture().is_some(), "emissiveTexture (its factor is used)"),
    ] {
        if present {
            notes.add(format!("material `{name}`: {what} is ignored"));
        }
    }
}

/// An anisotropic surface's grain: the anisotropy direction (the tangent
/// turned by `rotation` toward the bitangent) averaged over `tri` by
/// area; `None` without tangents or texture coordinates (said).
fn grain_of(tri: &Triangles, rotation: f32, name: &str, notes: &mut Notes) -> Option<Vec3> {
    let (s, c) = rotation.sin_cos();
    let mut sum = Vec3::ZERO;
    for k in &tri.corners {
        sum += (k.tangent * c + k.bitangent * s) * k.area;
    }
    let dir = sum.normalize_or_zero();
    if dir == Vec3::ZERO {
        notes.add(format!(
            "material `{name}`: anisotropic without TANGENT or TEXCOORD_0; each triangle's first edge is its grain"
        ));
        None
    } else {
        let spread =
            tri.corners.iter().filter(|k| k.area > 0.0).any(|k| (k.tangent * c + k.bitangent * s).dot(dir) < 0.95);
        if spread {
            notes.add(format!(
                "material `{name}`: the anisotropy direction varies over a surface; its mean direction is used"
            ));
        }
        Some(dir)
    }
}

/// The `TEXCOORD_n` set of a base-colour texture.
fn tex_coord_set(pbr: &gltf::material::PbrMetallicRoughness<'_>) -> usize {
    pbr.base_color_texture().map_or(0, |t| t.tex_coord() as usize)
}

/// `KHR_materials_anisotropy`'s strength and rotation (0, 0 without it).
fn anisotropy(
    path: &Path,
    at: &str,
    m: &gltf::Material<'_>,
    name: &str,
    notes: &mut Notes,
) -> Result<(f32, f32), SceneError> {
    let Some(ext) = m.extension_value("KHR_materials_anisotropy") else { return Ok((0.0, 0.0)) };
    let at = format!("{at}/extensions/KHR_materials_anisotropy");
    let number = |key: &str, default: f32| -> Result<f32, SceneError> {
        match ext.get(key) {
            None => Ok(default),
            Some(v) => v
                .as_f64()
                .map(|x| x as f32)
                .filter(|x| x.is_finite())
                .ok_or_else(|| error(path, format!("{at}/{key}"), "must be a finite number")),
        }
    };
    let strength = number("anisotropyStrength", 0.0)?;
    if !(0.0..=1.0).contains(&strength) {
        return Err(error(path, format!("{at}/anisotropyStrength"), "must be in [0, 1]"));
    }
    if ext.get("anisotropyTexture").is_some() {
        notes.add(format!("material `{name}`: anisotropyTexture is ignored (its factors are used)"));
    }
    Ok((strength, number("anisotropyRotation", 0.0)?))
}

/// Linear RGB of texel `i` (sRGB-encoded integer formats decoded; grey
/// formats repeat their one channel).
fn texel(image: &gltf::image::Data, i: usize) -> [f32; 3] {
    use gltf::image::Format::*;
    let px = &image.pixels;
    let srgb = srgb_to_linear;
    let u8s = |ch: usize, take: usize| -> [f32; 3] {
        let o = i * ch;
        let g = |k: usize| px.get(o + k.min(take - 1)).map_or(0.0, |&b| srgb(b as f32 / 255.0));
        [g(0), g(1), g(2)]
    };
    let u16s = |ch: usize, take: usize| -> [f32; 3] {
        let o = 2 * i * ch;
        let g = |k: usize| {
            let j = o + 2 * k.min(take - 1);
            px.get(j..j + 2).map_or(0.0, |b| srgb(u16::from_le_bytes([b[0], b[1]]) as f32 / 65535.0))
        };
        [g(0), g(1), g(2)]
    };
    let f32s = |ch: usize| -> [f32; 3] {
        let o = 4 * i * ch;
        let g = |k: usize| {
            let j = o + 4 * k;
            px.get(j..j + 4).map_or(0.0, |b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]).clamp(0.0, 1.0))
        };
        [g(0), g(1), g(2)]
    };
    match image.format {
        R8 => u8s(1, 1),
        R8G8 => u8s(2, 1),
        R8G8B8 => u8s(3, 3),
        R8G8B8A8 => u8s(4, 3),
        R16 => u16s(1, 1),
        R16G16 => u16s(2, 1),
        R16G16B16 => u16s(3, 3),
        R16G16B16A16 => u16s(4, 3),
        R32G32B32FLOAT => f32s(3),
        R32G32B32A32FLOAT => f32s(4),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn metallic_roughness_maps_onto_our_models() {
        // Matte dielectric: diffuse, the base colour as ρ.
        assert_eq!(
            model_of([0.5, 0.4, 0.3], 0.0, 1.0, 0.0).0,
            ReflectanceModel::Diffuse { reflectance: [0.5, 0.4, 0.3] }
        );
        // Metal: k_s = base colour, α = r².
        let (m, clamped) = model_of([0.9, 0.6, 0.3], 1.0, 0.5, 0.0);
        assert!(!clamped);
        let ReflectanceModel::RoughConductor { specular, lobe } = m else { panic!("{m:?}") };
        assert_eq!(specular, [0.9, 0.6, 0.3]);
        assert!((lobe.alpha_u - 0.25).abs() < 1e-7 && (lobe.alpha_v - 0.25).abs() < 1e-7);
        // Glossy dielectric: the 4% layer over 96% of the base colour.
        let ReflectanceModel::BroadSpecular { reflectance, specular, .. } = model_of([1.0, 0.5, 0.0], 0.0, 0.3, 0.0).0
        else {
            panic!()
        };
        assert_eq!(reflectance, [0.96, 0.48, 0.0]);
        assert_eq!(specular, [0.04; 3]);
        // Half metal: energy stays ≤ 1 in every band.
        let ReflectanceModel::BroadSpecular { reflectance, specular, .. } = model_of([1.0; 3], 0.5, 0.5, 0.0).0 else {
            panic!()
        };
        assert!(reflectance.iter().zip(specular).all(|(d, s)| d + s <= 1.0 + 1e-6));
        // Anisotropy: α along the direction grows by s², across it stays.
        let ReflectanceModel::RoughConductor { lobe, .. } = model_of([1.0; 3], 1.0, 0.4, 0.5).0 else { panic!() };
        assert!((lobe.alpha_u - (0.16 + 0.84 * 0.25)).abs() < 1e-6 && (lobe.alpha_v - 0.16).abs() < 1e-7);
        // Mirror-smooth roughness is clamped (and said).
        assert!(model_of([1.0; 3], 1.0, 0.0, 0.0).1);
    }
}
