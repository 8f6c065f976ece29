//! The scene file's tables as serde reads them, before any check: plain
//! records with the spans errors point at (`Spanned`), unknown fields
//! refused. The other files of `parse` check them into a [`crate::scene::Scene`].

use glam::Vec3;
use serde::Deserialize;
use toml::Spanned;

/// A TOML array of exactly `N` values: serde's fixed arrays take the first
/// `N` of a longer one without a word (`position = [1, 1, -2, 0]`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Exact<T, const N: usize>(pub(super) [T; N]);

/// Three numbers: a point, a vector or an RGB triple.
pub(super) type V3 = Exact<f32, 3>;

impl From<V3> for Vec3 {
    fn from(v: V3) -> Vec3 {
        Vec3::from(v.0)
    }
}

impl<T, const N: usize> std::ops::Deref for Exact<T, N> {
    type Target = [T; N];
    fn deref(&self) -> &[T; N] {
        &self.0
    }
}

impl<'de, T: Deserialize<'de>, const N: usize> Deserialize<'de> for Exact<T, N> {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let v = Vec::<T>::deserialize(d)?;
        let n = v.len();
        // Points and colours are lists of 3 numbers, quads of 4 corners.
        let expected = if N == 3 { format!("an array of length {N}") } else { format!("a list of {N} corners") };
        let a: [T; N] = v.try_into().map_err(|_| serde::de::Error::invalid_length(n, &expected.as_str()))?;
        Ok(Self(a))
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawScene {
    pub(super) camera: Option<Spanned<RawCamera>>,
    pub(super) gltf: Option<Spanned<RawGltf>>,
    pub(super) build: Option<Spanned<RawBuild>>,
    #[serde(default)]
    pub(super) material: Vec<Spanned<RawMaterial>>,
    #[serde(default)]
    pub(super) surface: Vec<Spanned<RawSurface>>,
    pub(super) animation: Option<Spanned<RawAnimation>>,
}

/// `[gltf]`: a glTF file whose scene this one starts from.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawGltf {
    pub(super) file: Spanned<String>,
    pub(super) camera: Option<String>,
    pub(super) light_radius: Option<Spanned<f32>>,
    pub(super) fps: Option<Spanned<f32>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawAnimation {
    pub(super) frames: Spanned<u32>,
    #[serde(default = "default_fps")]
    pub(super) fps: Spanned<f32>,
}

fn default_fps() -> Spanned<f32> {
    Spanned::new(0..0, 24.0)
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawKeyframe {
    pub(super) frame: u32,
    pub(super) translate: Option<V3>,
    pub(super) rotate_deg: Option<V3>,
    pub(super) scale: Option<V3>,
}

/// `[camera]`: every field but `up` (default +Y) and `keyframes` is
/// required, except over a `[gltf]` scene, whose camera gives those left
/// out ([`super::camera::camera_of`]).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawCamera {
    pub(super) position: Option<V3>,
    pub(super) look_at: Option<V3>,
    pub(super) up: Option<V3>,
    pub(super) fov_y_deg: Option<Spanned<f32>>,
    pub(super) width: Option<Spanned<u32>>,
    pub(super) height: Option<Spanned<u32>>,
    pub(super) keyframes: Option<Spanned<Vec<RawCameraKey>>>,
}

impl RawCamera {
    /// Whether the table gives a whole camera, needing none from a file.
    pub(super) fn is_whole(&self) -> bool {
        self.position.is_some()
            && self.look_at.is_some()
            && self.fov_y_deg.is_some()
            && self.width.is_some()
            && self.height.is_some()
    }

    /// Whether the table says where the camera is or looks (so that a
    /// file camera's path no longer applies).
    pub(super) fn places(&self) -> bool {
        self.position.is_some() || self.look_at.is_some() || self.up.is_some()
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawCameraKey {
    pub(super) frame: u32,
    pub(super) position: V3,
    pub(super) look_at: V3,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawEmissionKey {
    pub(super) frame: u32,
    pub(super) emission: V3,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawBuild {
    pub(super) patch_size: Option<Spanned<f32>>,
    pub(super) frequency: Option<Spanned<u32>>,
    pub(super) ray_spacing: Option<Spanned<f32>>,
    pub(super) buckets: Option<Spanned<u32>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawMaterial {
    pub(super) name: Spanned<String>,
    #[serde(rename = "type")]
    pub(super) kind: Spanned<String>,
    pub(super) reflectance: Option<Spanned<V3>>,
    pub(super) specular: Option<Spanned<V3>>,
    pub(super) alpha: Option<Spanned<f32>>,
    pub(super) alpha_u: Option<Spanned<f32>>,
    pub(super) alpha_v: Option<Spanned<f32>>,
    pub(super) ior: Option<Spanned<Ior>>,
}

/// An index of refraction: one for all bands or one per band.
#[derive(Deserialize)]
#[serde(untagged)]
pub(super) enum Ior {
    One(f32),
    Bands(V3),
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawSurface {
    pub(super) name: Spanned<String>,
    pub(super) material: Spanned<String>,
    pub(super) emission: Option<Spanned<V3>>,
    pub(super) quad: Option<Spanned<Exact<V3, 4>>>,
    pub(super) quads: Option<Spanned<Vec<Exact<V3, 4>>>>,
    #[serde(rename = "box")]
    pub(super) cuboid: Option<Spanned<RawBox>>,
    pub(super) mesh: Option<Spanned<String>>,
    pub(super) transform: Option<Spanned<RawTransform>>,
    pub(super) keyframes: Option<Spanned<Vec<RawKeyframe>>>,
    pub(super) emission_keyframes: Option<Spanned<Vec<RawEmissionKey>>>,
    pub(super) interpolation: Option<Spanned<String>>,
    pub(super) pivot: Option<Spanned<V3>>,
    pub(super) grain: Option<Spanned<V3>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawBox {
    pub(super) min: V3,
    pub(super) max: V3,
    #[serde(default)]
    pub(super) inward: bool,
    #[serde(default)]
    pub(super) omit: Vec<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawTransform {
    pub(super) scale: Option<V3>,
    pub(super) rotate_deg: Option<V3>,
    pub(super) translate: Option<V3>,
}

/// A file's `[camera]` (with its keyframes and `[animation]` frame count),
/// the rest of the file ignored: a scene file, or a camera file of those
/// two tables alone. With `[gltf]`, a partial or missing `[camera]` is
/// completed from the glTF file's camera, as in a scene.
#[derive(Deserialize)]
pub(super) struct RawCameraFile {
    pub(super) camera: Option<Spanned<RawCamera>>,
    pub(super) animation: Option<Spanned<RawAnimation>>,
    pub(super) gltf: Option<Spanned<RawGltf>>,
}
