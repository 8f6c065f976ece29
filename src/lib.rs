//! # illumnet: geodesic illumination networks
//!
//! An energy-balance global-illumination renderer after Buckalew & Fussell,
//! *An Energy-Balance Method for Animation* (1990). The pipeline runs one way:
//!
//! ```text
//! scene (TOML, OBJ) ──► patch + geodesic ──► bake (trace bundles, links)
//!        ──► archive::write ──► file ──► archive::Archive::open (mmap, validate)
//!        ──► distribute (energy balance over links) ──► render (image)
//! ```
//!
//! * [`scene`] parses scene files into plain data with file/line errors.
//! * [`geometry`] holds the few original primitives (quads, triangles), their
//!   ray intersection and their patch grids; both build and render use it.
//! * [`geodesic`] builds the global direction set (§3.3 of the paper).
//! * [`patch`] cuts primitives into patches with shared vertices.
//! * [`bake`] (the build stage) traces one bundle of parallel rays per direction pair and turns
//!   consecutive facing hits into links (§2, §3.3).
//! * [`archive`] is the versioned, checksummed, memory-mapped file format
//!   (specified byte by byte in `format-spec/archive.md`). It is the only
//!   interface between build and render.
//! * [`distribute`] spreads light along links until the energy balance
//!   converges (§3.1, §3.4).
//! * [`render`] turns patch radiance into images (§3.5).
//!
//! `ARCHITECTURE.md` at the repository root states what may depend on what.
//!
//! # Library use
//!
//! The `illumnet` binary is a thin layer over this library: everything it
//! does can be done from code. A Cornell box from its embedded scene file,
//! built at a coarse setting, stored in memory, opened and solved:
//!
//! ```
//! use illumnet::{archive, bake, distribute, progress::NoProgress, scene};
//! // A coarse Cornell box: build, store, open, distribute.
//! let scene = scene::Scene::cornell_box();
//! let hints = scene::BuildHints { frequency: Some(4), patch_size: Some(0.1), ..Default::default() };
//! let settings = bake::BuildSettings::resolve(&scene, hints);
//! let (contents, _) = bake::build(&scene, &settings, &NoProgress).unwrap();
//! let archive = archive::Archive::from_bytes(&archive::write_to_vec(&contents).unwrap()).unwrap();
//! let light = distribute::distribute(&archive.view(), &Default::default(), &NoProgress).unwrap();
//! assert!(light.balance.converged && light.balance.imbalance().abs() < 1e-6);
//! ```
//!
//! A scene made in code (a grey floor under a square lamp), built, and a
//! frame rendered into an in-memory [`render::Image`] with the default
//! shading (direct light per pixel, the I-net's indirect light); then
//! relit without a rebuild, since the archive holds geometry only:
//!
//! ```
//! use glam::Vec3;
//! use illumnet::geometry::Primitive;
//! use illumnet::scene::{BuildHints, Camera, Material, ReflectanceModel, Scene, Surface};
//! use illumnet::{archive, bake, distribute, progress::NoProgress, render};
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! // A quad's normal is (p1 − p0) × (p2 − p0): the floor faces up, the lamp down.
//! let surface = |name: &str, emission: f32, corners: [[f32; 3]; 4]| Surface {
//!     name: name.into(),
//!     material: 0,
//!     emission: [emission; 3],
//!     primitives: vec![Primitive::quad(corners.map(Vec3::from))],
//!     motion: None,
//!     emission_keys: Vec::new(),
//!     grain: None,
//!     moved: false,
//!     shading: Vec::new(),
//! };
//! let scene = Scene {
//!     name: "floor".into(),
//!     materials: vec![Material { name: "grey".into(), model: ReflectanceModel::Diffuse { reflectance: [0.5; 3] } }],
//!     surfaces: vec![
//!         surface("floor", 0.0, [[-1.0, 0.0, 1.0], [1.0, 0.0, 1.0], [1.0, 0.0, -1.0], [-1.0, 0.0, -1.0]]),
//!         surface("lamp", 10.0, [[-0.2, 1.0, -0.2], [0.2, 1.0, -0.2], [0.2, 1.0, 0.2], [-0.2, 1.0, 0.2]]),
//!     ],
//!     camera: Camera {
//!         position: Vec3::new(0.0, 0.8, -2.0),
//!         look_at: Vec3::ZERO,
//!         up: Vec3::Y,
//!         fov_y_deg: 40.0,
//!         width: 32,
//!         height: 24,
//!     },
//!     build: BuildHints { frequency: Some(4), patch_size: Some(0.25), ..Default::default() },
//!     animation: None,
//!     camera_keys: Vec::new(),
//!     notes: Vec::new(),
//!     textures: Vec::new(),
//! };
//! let settings = bake::BuildSettings::resolve(&scene, scene.build);
//! let (contents, _) = bake::build(&scene, &settings, &NoProgress)?;
//! let archive = archive::Archive::from_bytes(&archive::write_to_vec(&contents)?)?;
//! let view = archive.view();
//!
//! // Solve the light and render the archive's camera into memory.
//! let solution = distribute::distribute(&view, &Default::default(), &NoProgress)?;
//! let mut renderer = render::Renderer::new(&view, render::RenderOptions::default());
//! let shade = |renderer: &mut render::Renderer, s: &distribute::Solution| {
//!     let light = render::DirectLight::new(&view, s, render::direct::DEFAULT_LIGHT_SAMPLES);
//!     renderer.frame_direct(0, &render::indirect_frame_radiance(&view, 0, s), &light).0
//! };
//! let image = shade(&mut renderer, &solution);
//! assert_eq!((image.width, image.height), (32, 24));
//! // The floor under the lamp (the image's centre): ρ/π · E = ρ · L · F,
//! // with F ≈ 0.05 the form factor of a 0.4 m square 1 m above.
//! let under = image.at(16, 12)[0];
//! assert!(under > 0.5 * 10.0 * 0.03 && under < 0.5 * 10.0 * 0.07, "{under}");
//!
//! // Relight: twice the lamp's radiance, the same archive; light is linear.
//! let mut lighting = distribute::Lighting::from_view(&view);
//! lighting.emission[1] = [20.0; 3];
//! lighting.emission_fixed[1] = true;
//! let brighter = distribute::Distributor::new(&view, &Default::default(), &lighting)?.frame(0, None, &NoProgress)?;
//! let relit = shade(&mut renderer, &brighter);
//! assert!((relit.at(16, 12)[0] / under - 2.0).abs() < 1e-3);
//! # Ok(())
//! # }
//! ```
#![deny(missing_docs)]
#![deny(rustdoc::broken_intra_doc_links)]
#![deny(unsafe_op_in_unsafe_fn)]
// Per-band loops `for c in 0..3` over RGB arrays read better than zipped iterators.
#![allow(clippy::needless_range_loop)]

#[cfg(not(target_endian = "little"))]
compile_error!("illumnet archives are little-endian and read zero-copy: big-endian targets are not supported");

pub mod archive;
pub mod bake;
pub mod distribute;
pub mod flicker;
pub mod geodesic;
pub mod geometry;
pub mod limits;
pub mod memory;
pub mod patch;
pub mod progress;
pub mod reflectance;
pub mod render;
pub mod scene;
pub mod scratch;

/// The Cornell box scene embedded in the binary (`scenes/cornell_box.toml`),
/// used by `illumnet demo` and the tests.
pub const CORNELL_BOX_TOML: &str = include_str!("../scenes/cornell_box.toml");
