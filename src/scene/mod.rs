//! Scene descriptions: what the user wrote, resolved into plain data.
//!
//! A scene is materials, surfaces (each a list of [`Primitive`]s with one
//! material and an optional emission), a pinhole camera and optional build
//! settings. The text format is TOML, specified field by field in
//! `format-spec/scene.md`; `parse` turns text into a [`Scene`] or a
//! [`SceneError`] naming the file, line, column and field. Scenes made in
//! other tools come in through [`gltf`] (glTF 2.0) and `obj` (Wavefront OBJ
//! with its MTL), which map what they can and say the rest in
//! [`Scene::notes`].
//!
//! [`Scene::from_file`] is the one constructor for files: it reads each
//! kind by its own reader (`parse`, [`gltf`], `obj`). Below them lie what
//! they share, so that no reader imports another: `error` ([`SceneError`]),
//! `check` (the rule every primitive is held to) and `import` (the
//! importers' notes, unique names and quads re-merged from triangle pairs).

mod check;
mod error;
pub mod gltf;
mod import;
pub mod motion;
mod mtl;
mod obj;
mod parse;
pub mod texture;

use std::path::Path;

use glam::Vec3;

pub use error::SceneError;
pub use gltf::GltfOptions;

use crate::geometry::Primitive;

/// How a material reflects light (`format-spec/scene.md`; the formulas are
/// in [`crate::reflectance::model`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ReflectanceModel {
    /// Lambertian: `f = ρ/π`, with `ρ` the linear-RGB reflectance in `[0, 1]`.
    Diffuse {
        /// Linear RGB reflectance.
        reflectance: [f32; 3],
    },
    /// Rough conductor (brushed metal): `k_s` times the GGX lobe.
    RoughConductor {
        /// `k_s`, linear RGB in `[0, 1]`.
        specular: [f32; 3],
        /// The lobe's roughness and Fresnel term.
        lobe: crate::reflectance::Lobe,
    },
    /// Broad specular: `k_d/π` plus `k_s` times the GGX lobe.
    BroadSpecular {
        /// `k_d`, linear RGB.
        reflectance: [f32; 3],
        /// `k_s`, linear RGB; `k_d + k_s ≤ 1` per band.
        specular: [f32; 3],
        /// The lobe's roughness and Fresnel term.
        lobe: crate::reflectance::Lobe,
    },
}

impl ReflectanceModel {
    /// The diffuse reflectance `k_d` (zero for a rough conductor).
    pub fn diffuse(&self) -> [f32; 3] {
        match self {
            ReflectanceModel::Diffuse { reflectance } | ReflectanceModel::BroadSpecular { reflectance, .. } => {
                *reflectance
            }
            ReflectanceModel::RoughConductor { .. } => [0.0; 3],
        }
    }

    /// The specular colour `k_s` and lobe, for models that have one.
    pub fn lobe(&self) -> Option<([f32; 3], crate::reflectance::Lobe)> {
        match self {
            ReflectanceModel::Diffuse { .. } => None,
            ReflectanceModel::RoughConductor { specular, lobe }
            | ReflectanceModel::BroadSpecular { specular, lobe, .. } => Some((*specular, *lobe)),
        }
    }
}

/// A named material.
#[derive(Debug, Clone, PartialEq)]
pub struct Material {
    /// Name used by surfaces to refer to it.
    pub name: String,
    /// Its reflectance function.
    pub model: ReflectanceModel,
}

/// A named surface: primitives sharing a material and an emission.
#[derive(Debug, Clone, PartialEq)]
pub struct Surface {
    /// Name, for messages and inspection.
    pub name: String,
    /// Index into [`Scene::materials`].
    pub material: u32,
    /// Emitted radiance (W·sr⁻¹·m⁻², linear RGB) from the front face.
    pub emission: [f32; 3],
    /// The surface's primitives, in world space (for a moving surface, before
    /// its motion is applied).
    pub primitives: Vec<Primitive>,
    /// Keyframed motion; `None` for a surface that never moves.
    pub motion: Option<motion::Motion>,
    /// Keyframed emission (linear between keys); empty: `emission` always.
    pub emission_keys: Vec<motion::EmissionKey>,
    /// The grain (tangent) direction in world space, for anisotropic
    /// reflectance; `None`: each primitive's first edge.
    pub grain: Option<Vec3>,
    /// Whether the surface moves in the sequence this still was taken
    /// from ([`Scene::at_frame`]): a still of one frame then builds it as
    /// the sequence does (its small triangles each a patch, not grouped:
    /// `patch::mesh`), so that its links equal the sequence's at that frame.
    pub moved: bool,
    /// Per primitive, texture coordinates, shading normals and texture
    /// (imported meshes); empty: every primitive shades as its face.
    pub shading: Vec<texture::Shading>,
}

impl Surface {
    /// Emitted radiance at `frame`.
    pub fn emission_at(&self, frame: u32) -> [f32; 3] {
        motion::interpolate(
            &self.emission_keys,
            frame,
            |k| k.frame,
            |a, b, t| motion::EmissionKey { frame, emission: a.emission.lerp(b.emission, t) },
        )
        .map_or(self.emission, |k| k.emission.to_array())
    }
}

/// A pinhole camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Eye position (m).
    pub position: Vec3,
    /// Point looked at (m).
    pub look_at: Vec3,
    /// Up vector (need not be orthogonal to the view direction).
    pub up: Vec3,
    /// Vertical field of view in degrees.
    pub fov_y_deg: f32,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
}

/// `camera` moved along `keys` (linear between keys, held outside them) at
/// `frame`.
fn camera_at(camera: &Camera, keys: &[motion::CameraKey], frame: u32) -> Camera {
    let key = motion::interpolate(
        keys,
        frame,
        |k| k.frame,
        |a, b, t| motion::CameraKey {
            frame,
            position: a.position.lerp(b.position, t),
            look_at: a.look_at.lerp(b.look_at, t),
            up: a.up.lerp(b.up, t),
        },
    );
    match key {
        Some(k) => Camera { position: k.position, look_at: k.look_at, up: k.up, ..*camera },
        None => *camera,
    }
}

/// A camera looking along −Z at the middle of `bounds` and framing it, for
/// imported scenes that bring none: 40°, `width` × ¾·`width` pixels.
fn framing_camera((lo, hi): (Vec3, Vec3), width: u32) -> Camera {
    let centre = (lo + hi) / 2.0;
    let fov = 40.0f32;
    let half = (hi - lo).length() / 2.0;
    let distance = hi.z - centre.z + half / (fov.to_radians() / 2.0).tan();
    Camera {
        position: centre + Vec3::Z * distance.max(1e-3),
        look_at: centre,
        up: Vec3::Y,
        fov_y_deg: fov,
        width,
        height: (width * 3 / 4).max(1),
    }
}

/// A camera read from a file on its own (`render --camera-from`,
/// `--camera-path`): a scene file's `[camera]`, or a file holding just
/// `[camera]` and, for a path, `[animation] frames` and the camera's
/// `keyframes` (`format-spec/scene.md`); over a glTF file (`[gltf]`), a
/// partial or missing `[camera]` completed from the file's camera, as a
/// scene would be.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraPath {
    /// The camera (position and look_at as keyed at each frame).
    pub camera: Camera,
    /// Keyframes of position and look_at, by increasing frame.
    pub keys: Vec<motion::CameraKey>,
    /// Frames of the path (the file's `[animation] frames`; 1 without).
    pub frames: u32,
}

impl CameraPath {
    /// Reads the camera of the TOML file at `path`: errors name the file,
    /// line and field, as for scenes.
    ///
    /// A glTF file (`.gltf`, `.glb`) gives its first camera and the
    /// frames of its animation. In a TOML file with a `[gltf]` table, a
    /// `[camera]` that leaves fields out (or none) takes them from the
    /// glTF file's camera, its path and its animation's frames; only the
    /// camera is read from the glTF file, unless it has none (then the
    /// scene is read whole, for the camera that frames its geometry).
    pub fn from_file(path: &Path) -> Result<Self, SceneError> {
        if gltf::is_gltf_path(path) {
            return gltf::import_camera(path, &GltfOptions::default());
        }
        let text = read_text(path)?;
        parse::parse_camera(&text, path, path.parent().unwrap_or(Path::new(".")))
    }

    /// The camera at `frame`.
    pub fn at(&self, frame: u32) -> Camera {
        camera_at(&self.camera, &self.keys, frame)
    }
}

/// The text of the scene or camera file at `path`, read by
/// [`crate::limits::read_regular_text`]'s rule: a regular file of at most
/// [`crate::limits::MAX_INPUT_FILE`] bytes, else an I/O error naming it.
fn read_text(path: &Path) -> Result<String, SceneError> {
    crate::limits::read_regular_text(path, crate::limits::MAX_INPUT_FILE).map_err(|e| SceneError::io(path, e))
}

/// Build settings given in the scene file; `None` means "use the default".
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct BuildHints {
    /// Target patch edge length (m).
    pub patch_size: Option<f32>,
    /// Geodesic subdivision frequency.
    pub frequency: Option<u32>,
    /// Distance between parallel rays (m).
    pub ray_spacing: Option<f32>,
    /// Widest bucket (§3.4); 0 turns buckets off.
    pub buckets: Option<u32>,
}

/// A parsed, validated scene.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    /// Name (the file stem), recorded in archives.
    pub name: String,
    /// Materials, referred to by index.
    pub materials: Vec<Material>,
    /// Surfaces.
    pub surfaces: Vec<Surface>,
    /// The camera.
    pub camera: Camera,
    /// Build settings from the `[build]` table.
    pub build: BuildHints,
    /// Sequence length and rate; `None` for a still.
    pub animation: Option<motion::Animation>,
    /// Camera keyframes (position and look-at, linear); empty: a still camera.
    pub camera_keys: Vec<motion::CameraKey>,
    /// What an importer could not map (a glTF file's skins, directional
    /// lights, ignored textures, …), each said once, by name: printed as
    /// warnings, never dropped silently. Empty for TOML scenes.
    pub notes: Vec<String>,
    /// Base-colour textures the surfaces' [`Surface::shading`] refers to.
    pub textures: Vec<texture::TextureImage>,
}

impl Scene {
    /// Reads and parses a scene file, by its extension: glTF 2.0 (`.gltf`,
    /// `.glb`, with default [`GltfOptions`]), Wavefront OBJ with its MTL
    /// (`.obj`), else TOML (OBJ meshes it names resolve relative to it).
    pub fn from_file(path: &Path) -> Result<Self, SceneError> {
        Self::from_file_with(path, &GltfOptions::default())
    }

    /// [`Scene::from_file`] with the choices a glTF file does not make.
    pub fn from_file_with(path: &Path, gltf_options: &GltfOptions) -> Result<Self, SceneError> {
        if gltf::is_gltf_path(path) {
            return gltf::import(path, gltf_options);
        }
        if obj::is_obj_path(path) {
            return obj::import(path);
        }
        let text = read_text(path)?;
        let name = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        parse::parse(&text, path, path.parent().unwrap_or(Path::new(".")), name)
    }

    /// Parses scene text; `origin` names it in errors and `base_dir` resolves
    /// OBJ paths.
    pub fn from_toml(text: &str, origin: &Path, base_dir: &Path) -> Result<Self, SceneError> {
        let name = origin.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        parse::parse(text, origin, base_dir, name)
    }

    /// The embedded Cornell box (`scenes/cornell_box.toml`).
    pub fn cornell_box() -> Self {
        Self::from_toml(crate::CORNELL_BOX_TOML, Path::new("cornell_box.toml"), Path::new("."))
            .expect("the embedded Cornell box parses")
    }

    /// Frames in the sequence (1 for a still).
    pub fn frame_count(&self) -> u32 {
        self.animation.map_or(1, |a| a.frames)
    }

    /// The camera at `frame`.
    pub fn camera_at(&self, frame: u32) -> Camera {
        camera_at(&self.camera, &self.camera_keys, frame)
    }

    /// Whether anything changes over the sequence (geometry, light or camera).
    pub fn is_animated(&self) -> bool {
        self.animation.is_some()
            && (!self.camera_keys.is_empty()
                || self.surfaces.iter().any(|s| s.motion.is_some() || !s.emission_keys.is_empty()))
    }

    /// The still scene of frame `frame`: moving surfaces placed where their
    /// motion puts them, emission and camera as keyed, and no keys left.
    pub fn at_frame(&self, frame: u32) -> Scene {
        let mut s = self.clone();
        for surf in &mut s.surfaces {
            if let Some(m) = surf.motion.take() {
                surf.moved = true;
                let moved = m.apply(frame, &surf.primitives);
                surf.shading = m.apply_shading(frame, &surf.primitives, &moved, &surf.shading);
                surf.primitives = moved;
                surf.grain = surf.grain.map(|g| m.apply_direction(frame, g));
            }
            surf.emission = surf.emission_at(frame);
            surf.emission_keys.clear();
        }
        s.camera = self.camera_at(frame);
        s.camera_keys.clear();
        s.animation = None;
        s
    }

    /// Turns the surface named `name` about its normal, through the centre
    /// of its vertices, by `degrees` (counter-clockwise seen from the front):
    /// the brushed plate's orientations (§4, Images 3–4) without editing the
    /// scene. The surface must be planar and static.
    pub fn turn_surface(&mut self, name: &str, degrees: f32) -> Result<(), String> {
        let known = || self.surfaces.iter().map(|s| s.name.as_str()).collect::<Vec<_>>().join(", ");
        let i = self
            .surfaces
            .iter()
            .position(|s| s.name == name)
            .ok_or_else(|| format!("no surface named `{name}` (known: {})", known()))?;
        let s = &mut self.surfaces[i];
        if s.motion.is_some() {
            return Err(format!("surface `{name}` moves; only a static surface can be turned"));
        }
        let n = s.primitives[0].normal();
        if s.primitives.iter().any(|p| p.normal().dot(n) < 1.0 - 1e-5) {
            return Err(format!("surface `{name}` is not planar"));
        }
        let verts: Vec<Vec3> = s.primitives.iter().flat_map(|p| p.p[..p.corner_count()].iter().copied()).collect();
        let centre = verts.iter().copied().sum::<Vec3>() / verts.len() as f32;
        let r = glam::Quat::from_axis_angle(n, degrees.to_radians());
        for p in &mut s.primitives {
            let q = p.p.map(|v| centre + r * (v - centre));
            *p = match p.kind {
                crate::geometry::PrimitiveKind::Quad => Primitive::quad(q),
                crate::geometry::PrimitiveKind::Triangle => Primitive::triangle(q[0], q[1], q[2]),
            };
        }
        s.grain = s.grain.map(|g| r * g);
        Ok(())
    }

    /// Every primitive with its surface index, in surface order.
    pub fn primitives(&self) -> impl Iterator<Item = (u32, &Primitive)> {
        self.surfaces.iter().enumerate().flat_map(|(s, surf)| surf.primitives.iter().map(move |p| (s as u32, p)))
    }

    /// Axis-aligned bounds of all primitives over all frames.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let (mut lo, mut hi) =
            crate::geometry::bounds_of(self.surfaces.iter().filter(|s| s.motion.is_none()).flat_map(|s| &s.primitives));
        for s in &self.surfaces {
            if let Some(m) = &s.motion {
                for f in 0..self.frame_count() {
                    let (a, b) = crate::geometry::bounds_of(&m.apply(f, &s.primitives));
                    lo = lo.min(a);
                    hi = hi.max(b);
                }
            }
        }
        (lo, hi)
    }

    /// Total surface area (m²).
    pub fn total_area(&self) -> f64 {
        self.primitives().map(|(_, p)| p.area() as f64).sum()
    }
}
