//! glTF 2.0 scenes (`.gltf`, `.glb`) → [`Scene`]: what modelling tools
//! export, mapped onto our surfaces, materials, emitters, camera and
//! keyframes. The mapping and its limits are stated in
//! `format-spec/scene.md` ("glTF 2.0 scenes"); whatever cannot be mapped is
//! listed by name in [`Scene::notes`], never dropped silently.
//!
//! * `triangles`: a mesh primitive's triangles in world space, pairs that
//!   make a planar convex quad merged back into quads;
//! * `material`: metallic-roughness, emission and anisotropy onto our
//!   reflectance models; base-colour textures (their mean for the
//!   distribution, their texels kept for the render);
//! * `light`: `KHR_lights_punctual` lamps as small area emitters;
//! * `animation`: node channels sampled at the frame rate.
//!
//! Errors name the file and a JSON pointer into it
//! (`/materials/3/pbrMetallicRoughness`).

mod animation;
mod light;
mod load;
mod material;
mod triangles;

use std::path::Path;

use glam::{Mat4, Vec3};

use super::error::error;
use super::import::{Notes, unique_names};
use super::motion::{Animation, CameraKey, Interpolation, Keyframe, Motion};
use super::texture::Shading;
use super::{BuildHints, Camera, Scene, SceneError, Surface};
use crate::geometry::Primitive;

/// Choices a glTF file does not make; `Default` is what `illumnet build
/// model.glb` uses.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GltfOptions {
    /// The camera node (or camera) to use by name; `None`: the first one met
    /// walking the scene's nodes in order.
    pub camera: Option<String>,
    /// Radius (m) of the small emitters standing in for point and spot
    /// lights; `None`: the meshes' bounding diagonal / 64, the default patch
    /// size, so a default build links every lamp in every direction.
    pub light_radius: Option<f32>,
    /// Frames per second at which node animations are sampled (default 24).
    pub fps: Option<f32>,
}

/// Whether `path` names a glTF file (`.gltf` or `.glb`, any case).
pub fn is_gltf_path(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("gltf") || e.eq_ignore_ascii_case("glb"))
}

/// Default image width for a glTF camera (glTF states only an aspect ratio).
const DEFAULT_WIDTH: u32 = 640;
/// Default frame rate for sampling animations.
const DEFAULT_FPS: f32 = 24.0;
/// Most surfaces (node × mesh-primitive instances) one file may make.
const MAX_SURFACES: usize = 1_000_000;
/// Most triangles one file may make, over all instances.
const MAX_TRIANGLES: usize = 50_000_000;

/// A node met walking the scene, with its place in the hierarchy.
struct Placed<'a> {
    node: gltf::Node<'a>,
    /// Index into the placed list of the parent (None for a root).
    parent: Option<usize>,
}

/// Reads the glTF or GLB file at `path` into a scene; a scene that emits no
/// light is an error saying how to add a lamp.
pub fn import(path: &Path, options: &GltfOptions) -> Result<Scene, SceneError> {
    let scene = import_unchecked(path, options)?;
    if scene.surfaces.iter().all(|s| s.emission.iter().all(|&e| e <= 0.0)) {
        return Err(error(
            path,
            "/materials",
            "the scene emits no light: give a material an emissiveFactor (with \
             KHR_materials_emissive_strength for radiance above 1) or add a KHR_lights_punctual \
             point or spot light",
        ));
    }
    Ok(scene)
}

/// [`import`] without the emitter check: a TOML scene that starts from a
/// glTF file may add its lamps itself.
pub(super) fn import_unchecked(path: &Path, options: &GltfOptions) -> Result<Scene, SceneError> {
    let load::Loaded { doc, buffers, mut images } = open(path)?;
    let mut notes = Notes::default();
    let mut scene = guarded(path, || convert(path, &doc, &buffers, &mut images, options, &mut notes))?;
    scene.notes = notes.into_vec();
    Ok(scene)
}

/// `work`, with a panic inside the `gltf` crate on data our checks did not
/// foresee turned into an error (the checks in `load` come first).
fn guarded<T>(path: &Path, work: impl FnOnce() -> Result<T, SceneError>) -> Result<T, SceneError> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(work))
        .map_err(|_| error(path, "", "the glTF reader failed on malformed data"))?
}

/// The camera of a glTF file alone (`render --camera-from model.glb`),
/// with its keyframes and frame count.
pub fn import_camera(path: &Path, options: &GltfOptions) -> Result<super::CameraPath, SceneError> {
    import_camera_if_any(path, options)?.ok_or_else(|| error(path, "/cameras", "the file has no camera"))
}

/// [`import_camera`], or `None` when the file has no camera (without
/// reading its meshes: a scene over it frames its geometry instead).
pub fn import_camera_if_any(path: &Path, options: &GltfOptions) -> Result<Option<super::CameraPath>, SceneError> {
    let load::Loaded { doc, buffers, .. } = open(path)?;
    guarded(path, || {
        let placed = walk(path, &doc)?;
        let nodes = placed_nodes(&placed);
        let anim = animation::Sampled::new(path, &doc, &buffers, options, &mut Notes::default())?;
        let worlds = anim.world_matrices(path, &placed_parents(&placed), &nodes)?;
        let found = camera_of(path, &doc, &placed, &worlds, options)?;
        Ok(found.map(|(camera, keys)| super::CameraPath { camera, keys, frames: anim.frames }))
    })
}

/// The glTF file at `path`, read and checked (a regular file only: see
/// `load`).
fn open(path: &Path) -> Result<load::Loaded, SceneError> {
    load::Loaded::open(path)
}

/// A gltf-json path (`meshes[0].primitives[1].attributes["POSITION"]`) as a
/// JSON pointer (`/meshes/0/primitives/1/attributes/POSITION`).
fn pointer(path: &str) -> String {
    let mut out = String::from("/");
    for c in path.chars() {
        match c {
            '.' | '[' => {
                if !out.ends_with('/') {
                    out.push('/')
                }
            }
            ']' | '"' => {}
            c => out.push(c),
        }
    }
    out
}

/// Every node reachable from the default scene (the first scene without
/// one), depth first, parents before children. A node met twice is an
/// error: glTF gives a node at most one parent and no cycles (a file that
/// breaks the rule could otherwise make exponentially many instances).
fn walk<'a>(path: &Path, doc: &'a gltf::Document) -> Result<Vec<Placed<'a>>, SceneError> {
    let Some(root) = doc.default_scene().or_else(|| doc.scenes().next()) else {
        return Err(error(path, "/scenes", "the file has no scene"));
    };
    let mut placed = Vec::new();
    let mut stack: Vec<(gltf::Node<'a>, Option<usize>)> = root.nodes().map(|n| (n, None)).collect();
    stack.reverse();
    let mut seen = vec![false; doc.nodes().len()];
    while let Some((node, parent)) = stack.pop() {
        if std::mem::replace(&mut seen[node.index()], true) {
            return Err(error(
                path,
                format!("/nodes/{}", node.index()),
                "the node is reached twice: glTF allows a node one parent and no cycles (share its mesh instead)",
            ));
        }
        if placed.len() >= MAX_SURFACES {
            return Err(error(path, "/nodes", format!("more than {MAX_SURFACES} node instances")));
        }
        let me = placed.len();
        placed.push(Placed { node: node.clone(), parent });
        for child in node.children().collect::<Vec<_>>().into_iter().rev() {
            stack.push((child, Some(me)));
        }
    }
    Ok(placed)
}

fn placed_nodes<'a>(placed: &[Placed<'a>]) -> Vec<gltf::Node<'a>> {
    placed.iter().map(|p| p.node.clone()).collect()
}

fn placed_parents(placed: &[Placed<'_>]) -> Vec<Option<usize>> {
    placed.iter().map(|p| p.parent).collect()
}

/// A node's name for messages and surface names.
fn node_name(node: &gltf::Node<'_>) -> String {
    node.name().map_or_else(|| format!("node{}", node.index()), str::to_string)
}

/// The scene of a parsed glTF file: its meshes and lamps as surfaces,
/// its camera (or one framing the meshes) and animation; what cannot be
/// mapped goes to `notes`.
fn convert(
    path: &Path,
    doc: &gltf::Document,
    buffers: &[gltf::buffer::Data],
    images: &mut load::Images,
    options: &GltfOptions,
    notes: &mut Notes,
) -> Result<Scene, SceneError> {
    const HANDLED: [&str; 3] = ["KHR_lights_punctual", "KHR_materials_emissive_strength", "KHR_materials_anisotropy"];
    for ext in doc.extensions_used() {
        if !HANDLED.contains(&ext) {
            notes.add(format!("extension {ext} is not supported and was ignored"));
        }
    }
    let placed = walk(path, doc)?;
    let nodes = placed_nodes(&placed);
    let parents = placed_parents(&placed);
    let anim = animation::Sampled::new(path, doc, buffers, options, notes)?;
    let worlds = anim.world_matrices(path, &parents, &nodes)?;
    let moving: Vec<bool> = worlds.iter().map(|w| w.iter().any(|m| *m != w[0])).collect();
    let posed = Posed { nodes, worlds, moving };

    let mut materials = material::Materials::new(path, doc, buffers, images);
    let mut surfaces = mesh_surfaces(path, &posed, buffers, &mut materials, notes)?;
    let mesh_bounds = crate::geometry::bounds_of(surfaces.iter().flat_map(|s| &s.primitives));
    lamp_surfaces(path, &posed, options, mesh_bounds, &mut materials, notes, &mut surfaces)?;
    unique_names(&mut surfaces);
    if surfaces.is_empty() {
        return Err(error(path, "/meshes", "the scene has no triangles to build"));
    }

    let camera = match camera_of(path, doc, &placed, &posed.worlds, options)? {
        Some(c) => c,
        None => {
            notes.add("the file has no camera: one looks at the scene along -Z (give one with render --camera-*)");
            (super::framing_camera(mesh_bounds, DEFAULT_WIDTH), Vec::new())
        }
    };
    let name = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let animation = (anim.frames > 1).then_some(Animation { frames: anim.frames, fps: anim.fps });
    let (materials, textures) = materials.into_materials();
    Ok(Scene {
        name,
        materials,
        surfaces,
        camera: camera.0,
        build: BuildHints::default(),
        animation,
        camera_keys: camera.1,
        notes: Vec::new(),
        textures,
    })
}

/// The placed nodes with their world matrices over the frames: what the
/// mesh and lamp steps of [`convert`] share.
struct Posed<'a> {
    /// Every node reachable from the scene, parents first ([`walk`]).
    nodes: Vec<gltf::Node<'a>>,
    /// Per node, its world matrix at each frame (one for a node that no
    /// animation moves).
    worlds: Vec<Vec<Mat4>>,
    /// Per node, whether its world matrix changes over the frames.
    moving: Vec<bool>,
}

impl Posed<'_> {
    /// The motion of node `i` (keyed at every frame), if it moves.
    fn motion(&self, path: &Path, i: usize) -> Result<Option<Motion>, SceneError> {
        if self.moving[i] { Ok(Some(motion_of(path, &self.nodes[i], &self.worlds[i])?)) } else { Ok(None) }
    }
}

/// Meshes: one surface per (node instance, mesh primitive), degenerate
/// triangles left out (and counted in one note).
fn mesh_surfaces(
    path: &Path,
    posed: &Posed<'_>,
    buffers: &[gltf::buffer::Data],
    materials: &mut material::Materials<'_>,
    notes: &mut Notes,
) -> Result<Vec<Surface>, SceneError> {
    let mut degenerate = (0usize, 0usize);
    let mut surfaces: Vec<Surface> = Vec::new();
    let mut triangle_count = 0usize;
    for (i, node) in posed.nodes.iter().enumerate() {
        if node.skin().is_some() {
            notes.add(format!(
                "node `{}`: skinning is not supported; the mesh is used in its bind pose",
                node_name(node)
            ));
        }
        let Some(mesh) = node.mesh() else { continue };
        let w0 = posed.worlds[i][0];
        let motion = posed.motion(path, i)?;
        for (k, prim) in mesh.primitives().enumerate() {
            let at = format!("/meshes/{}/primitives/{k}", mesh.index());
            if prim.morph_targets().len() > 0 {
                notes.add(format!(
                    "mesh `{}`: morph targets are not supported; the base shape is used",
                    mesh_name(&mesh)
                ));
            }
            let tri = triangles::read(path, &at, &prim, buffers, w0, notes)?;
            if tri.degenerate > 0 {
                degenerate = (degenerate.0 + tri.degenerate, degenerate.1 + 1);
            }
            if tri.primitives.is_empty() {
                continue;
            }
            triangle_count += tri.primitives.len();
            if triangle_count > MAX_TRIANGLES {
                return Err(error(path, at, format!("the scene has more than {MAX_TRIANGLES} triangles")));
            }
            let (material_index, grain, texture) = materials.surface_material(&prim, (mesh.index(), k), &tri, notes)?;
            let emission = materials.emission(&prim, notes);
            // Emitters show their own radiance: a texture would not change it.
            let texture = texture.filter(|_| emission.iter().all(|&e| e <= 0.0));
            let mut shading = shading_of(&tri, texture.as_ref());
            let mut primitives = tri.primitives;
            if prim.material().double_sided() && !tri.closed {
                add_back_faces(&mut primitives, &mut shading);
            }
            let base = node_name(node);
            let name = if mesh.primitives().len() > 1 { format!("{base}#{k}") } else { base };
            surfaces.push(Surface {
                name,
                material: material_index,
                emission,
                primitives,
                motion: motion.clone(),
                emission_keys: Vec::new(),
                grain,
                moved: false,
                shading,
            });
            if surfaces.len() > MAX_SURFACES {
                return Err(error(path, "/nodes", format!("more than {MAX_SURFACES} mesh instances")));
            }
        }
    }
    if degenerate.0 > 0 {
        notes.add(format!(
            "{} degenerate (zero-area or non-finite) triangles in {} mesh instances were left out",
            degenerate.0, degenerate.1
        ));
    }
    Ok(surfaces)
}

/// A double-sided open mesh: each primitive also with its back as a front
/// (surfaces are one-sided), and its shading (if any) flipped to match.
fn add_back_faces(primitives: &mut Vec<Primitive>, shading: &mut Vec<Shading>) {
    let back: Vec<Primitive> = primitives.iter().map(triangles::flipped).collect();
    if !shading.is_empty() {
        let flipped: Vec<Shading> = primitives
            .iter()
            .zip(&back)
            .zip(shading.iter())
            .map(|((front, back), s)| {
                let [x, y, z] = front.own_frame();
                let world = s.normal.map(|n| -(x * n.x + y * n.y + z * n.z));
                Shading {
                    uv: triangles::flipped_corners(front.kind, s.uv),
                    normal: Shading::to_local(back, triangles::flipped_corners(front.kind, world)),
                    ..*s
                }
            })
            .collect();
        shading.extend(flipped);
    }
    primitives.extend(back);
}

/// Lamps: each `KHR_lights_punctual` light as a small emitter of radius
/// `options.light_radius` (default the meshes' bounding diagonal / 64),
/// appended to `surfaces`.
fn lamp_surfaces(
    path: &Path,
    posed: &Posed<'_>,
    options: &GltfOptions,
    mesh_bounds: (Vec3, Vec3),
    materials: &mut material::Materials<'_>,
    notes: &mut Notes,
    surfaces: &mut Vec<Surface>,
) -> Result<(), SceneError> {
    let radius = match options.light_radius {
        Some(r) => r,
        None if mesh_bounds.0.x <= mesh_bounds.1.x => (mesh_bounds.1 - mesh_bounds.0).length() / 64.0,
        None => 0.01,
    };
    for (i, node) in posed.nodes.iter().enumerate() {
        let Some(lamp) = node.light() else { continue };
        let at = format!("/extensions/KHR_lights_punctual/lights/{}", lamp.index());
        let Some((primitives, emission)) = light::emitter(path, &at, &lamp, radius, posed.worlds[i][0], notes)? else {
            continue;
        };
        let material = materials.lamp_material();
        let motion = posed.motion(path, i)?;
        surfaces.push(Surface {
            name: format!("{}:{}", node_name(node), lamp.name().unwrap_or("light")),
            material,
            emission,
            primitives,
            motion,
            emission_keys: Vec::new(),
            grain: None,
            moved: false,
            shading: Vec::new(),
        });
    }
    Ok(())
}

/// Per primitive of `tri`, its shading detail: the mesh's vertex normals
/// and `texture`'s coordinates; empty when it has neither.
fn shading_of(tri: &triangles::Triangles, texture: Option<&material::TextureUse>) -> Vec<Shading> {
    let uvs = texture.and_then(|t| tri.vertex_uv.get(t.set).and_then(|u| u.as_ref()));
    if tri.vertex_normal.is_none() && uvs.is_none() {
        return Vec::new();
    }
    tri.primitives
        .iter()
        .zip(&tri.vertices)
        .map(|(p, v)| {
            let world = match &tri.vertex_normal {
                Some(n) => v.map(|i| n[i as usize]),
                None => [Vec3::ZERO; 4],
            };
            Shading {
                uv: match uvs {
                    Some(u) => v.map(|i| u[i as usize]),
                    None => [glam::Vec2::ZERO; 4],
                },
                normal: Shading::to_local(p, world),
                texture: match (texture, uvs) {
                    (Some(t), Some(_)) => t.texture,
                    _ => u32::MAX,
                },
                tint: texture.map_or([1.0; 3], |t| t.tint),
            }
        })
        .collect()
}

fn mesh_name(mesh: &gltf::Mesh<'_>) -> String {
    mesh.name().map_or_else(|| format!("mesh{}", mesh.index()), str::to_string)
}

/// Keyframes moving a surface from its frame-0 world placement (where its
/// primitives are) to each frame's: one key per frame, `M(f)·M(0)⁻¹`
/// decomposed into translation, rotation and scale about the origin. A node
/// scaled to (nearly) nothing at some frame is an error: a surface keeps its
/// area in every frame.
fn motion_of(path: &Path, node: &gltf::Node<'_>, worlds: &[Mat4]) -> Result<Motion, SceneError> {
    let flat = |f: usize| {
        error(
            path,
            format!("/nodes/{}", node.index()),
            format!(
                "node `{}`: at frame {f} its animation scales it to (nearly) nothing or moves it beyond ±1e9 m; \
                 a surface must keep its area in every frame",
                node_name(node)
            ),
        )
    };
    let det0 = worlds[0].determinant();
    if !(det0.is_finite() && det0.abs() > 1e-18) {
        return Err(flat(0));
    }
    let inv0 = worlds[0].inverse();
    let mut keyframes = Vec::with_capacity(worlds.len());
    for (f, w) in worlds.iter().enumerate() {
        let (scale, rotation, translate) = if f == 0 {
            (Vec3::ONE, glam::Quat::IDENTITY, Vec3::ZERO)
        } else {
            (*w * inv0).to_scale_rotation_translation()
        };
        let usable = scale.is_finite()
            && scale.abs().min_element() > 1e-6
            && rotation.is_finite()
            && translate.abs().max_element() <= crate::limits::MAX_COORDINATE;
        if !usable {
            return Err(flat(f));
        }
        keyframes.push(Keyframe { frame: f as u32, translate, rotation, scale });
    }
    Ok(Motion { pivot: Vec3::ZERO, interpolation: Interpolation::Linear, keyframes })
}

/// The chosen camera node: its camera at frame 0 and, when it moves, one key
/// per frame.
#[allow(clippy::type_complexity)]
fn camera_of(
    path: &Path,
    doc: &gltf::Document,
    placed: &[Placed<'_>],
    worlds: &[Vec<Mat4>],
    options: &GltfOptions,
) -> Result<Option<(Camera, Vec<CameraKey>)>, SceneError> {
    let with_camera = || placed.iter().enumerate().filter(|(_, p)| p.node.camera().is_some());
    let chosen = match &options.camera {
        Some(name) => {
            let found = with_camera().find(|(_, p)| {
                p.node.name() == Some(name.as_str())
                    || p.node.camera().and_then(|c| c.name().map(str::to_string)).as_deref() == Some(name)
            });
            match found {
                Some(f) => Some(f),
                None => {
                    let known: Vec<String> = with_camera()
                        .map(|(_, p)| {
                            p.node
                                .camera()
                                .and_then(|c| c.name().map(str::to_string))
                                .unwrap_or_else(|| node_name(&p.node))
                        })
                        .collect();
                    return Err(error(
                        path,
                        "/cameras",
                        format!(
                            "no camera named `{name}` (known: {})",
                            if known.is_empty() { "none".into() } else { known.join(", ") }
                        ),
                    ));
                }
            }
        }
        None => with_camera().next(),
    };
    let Some((i, p)) = chosen else {
        if doc.cameras().len() > 0 {
            return Err(error(path, "/cameras", "no node of the scene uses the file's cameras"));
        }
        return Ok(None);
    };
    let cam = p.node.camera().expect("filtered on camera");
    let at = format!("/cameras/{}", cam.index());
    let (fov, aspect) = match cam.projection() {
        gltf::camera::Projection::Perspective(q) => (q.yfov().to_degrees(), q.aspect_ratio().unwrap_or(1.0)),
        gltf::camera::Projection::Orthographic(_) => {
            return Err(error(path, at, "orthographic cameras are not supported (a pinhole camera is)"));
        }
    };
    if !(fov.is_finite() && fov > 0.0 && fov < 180.0) {
        return Err(error(path, format!("{at}/perspective/yfov"), "the field of view must be in (0, π) radians"));
    }
    if !(aspect.is_finite() && (1e-3..=1e3).contains(&aspect)) {
        return Err(error(path, format!("{at}/perspective/aspectRatio"), "the aspect ratio must be in [0.001, 1000]"));
    }
    let width = DEFAULT_WIDTH;
    let height = ((width as f32 / aspect).round() as u32).clamp(1, 16384);
    let pose = |m: &Mat4| {
        let position = m.transform_point3(Vec3::ZERO);
        let forward = m.transform_vector3(Vec3::NEG_Z).normalize_or_zero();
        let up = m.transform_vector3(Vec3::Y).normalize_or_zero();
        (position, forward, up)
    };
    let degenerate = |f: usize| {
        error(
            path,
            format!("/nodes/{}", p.node.index()),
            format!("the camera node's transform is degenerate (or beyond ±1e9 m) at frame {f}"),
        )
    };
    let usable = |(position, forward, up): (Vec3, Vec3, Vec3)| {
        forward != Vec3::ZERO
            && up != Vec3::ZERO
            && crate::limits::camera_is_usable(position.to_array(), (position + forward).to_array(), up.to_array())
    };
    let first = pose(&worlds[i][0]);
    if !usable(first) {
        return Err(degenerate(0));
    }
    let (position, forward, up) = first;
    let camera = Camera { position, look_at: position + forward, up, fov_y_deg: fov, width, height };
    let mut keys = Vec::new();
    if worlds[i].iter().any(|m| *m != worlds[i][0]) {
        for (f, m) in worlds[i].iter().enumerate() {
            let pose = pose(m);
            if !usable(pose) {
                return Err(degenerate(f));
            }
            let (position, forward, up) = pose;
            keys.push(CameraKey { frame: f as u32, position, look_at: position + forward, up });
        }
    }
    Ok(Some((camera, keys)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_paths_become_pointers() {
        assert_eq!(
            pointer("meshes[0].primitives[1].attributes[\"POSITION\"]"),
            "/meshes/0/primitives/1/attributes/POSITION"
        );
        assert_eq!(pointer("materials[3].pbrMetallicRoughness"), "/materials/3/pbrMetallicRoughness");
    }
}
