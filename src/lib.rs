//! # illumnet: geodesic illumination networks
//!
//! An energy-balance global-illumination renderer after Buckalew & Fussell,
//! *An Energy-Balance Method for Animation* (1990). The pipeline runs one way:
//!
//! ```text
//! scene (TOML, OBJ) ──► patch + geodesic ──► build (trace bundles, links)
//!        ──► archive::write ──► file ──► archive::Archive::open (mmap, validate)
//!        ──► distribute (energy balance over links) ──► render (image)
//! ```
//!
//! * [`scene`] parses scene files into plain data with file/line errors.
//! * [`geometry`] holds the few original primitives (quads, triangles), their
//!   ray intersection and their patch grids; both build and render use it.
//! * [`geodesic`] builds the global direction set (§3.3 of the paper).
//! * [`patch`] cuts primitives into patches with shared vertices.
//! * [`build`] traces one bundle of parallel rays per direction pair and turns
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
//! ```
//! use illumnet::{archive, build, distribute, progress::NoProgress, scene};
//! // A coarse Cornell box: build, store, open, distribute.
//! let scene = scene::Scene::cornell_box();
//! let hints = scene::BuildHints { frequency: Some(4), patch_size: Some(0.1), ..Default::default() };
//! let settings = build::BuildSettings::resolve(&scene, hints);
//! let (contents, _) = build::build(&scene, &settings, &NoProgress).unwrap();
//! let archive = archive::Archive::from_bytes(&archive::write_to_vec(&contents).unwrap()).unwrap();
//! let light = distribute::distribute(&archive.view(), &Default::default(), &NoProgress).unwrap();
//! assert!(light.balance.converged && light.balance.imbalance().abs() < 1e-6);
//! ```
#![deny(missing_docs)]
#![deny(rustdoc::broken_intra_doc_links)]
#![deny(unsafe_op_in_unsafe_fn)]
// Per-band loops `for c in 0..3` over RGB arrays read better than zipped iterators.
#![allow(clippy::needless_range_loop)]

#[cfg(not(target_endian = "little"))]
compile_error!("illumnet archives are little-endian and read zero-copy: big-endian targets are not supported");

pub mod archive;
pub mod build;
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
