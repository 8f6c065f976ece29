//! Shared helpers: build scenes from TOML text and open the archive in memory.
#![allow(dead_code)]

use std::path::Path;

use illumnet::archive::{self, Archive, InetView};
use illumnet::build::{self, BuildSettings};
use illumnet::distribute::{self, DistributeOptions, Solution};
use illumnet::progress::NoProgress;
use illumnet::scene::{BuildHints, Scene};

/// A camera block for scenes that are never rendered.
pub const CAMERA: &str =
    "[camera]\nposition = [0.5, 0.5, -3.0]\nlook_at = [0.5, 0.5, 0.0]\nfov_y_deg = 40\nwidth = 16\nheight = 16\n";

pub fn scene(toml: &str) -> Scene {
    Scene::from_toml(toml, Path::new("test.toml"), Path::new(".")).unwrap_or_else(|e| panic!("{e}"))
}

/// Builds `scene` with default settings (plus `hints`) and opens the result
/// from memory.
pub fn build_archive(scene: &Scene, hints: BuildHints) -> Archive {
    let mut settings = BuildSettings::resolve(scene, hints);
    settings.prototype_library = None; // tests leave no files behind
    let (contents, _) = build::build(scene, &settings, &NoProgress).unwrap();
    Archive::from_bytes(&archive::write_to_vec(&contents).unwrap()).unwrap()
}

/// Builds `scene` (still or animated: a sequence) with default settings
/// (plus `hints`) and opens the result from memory.
pub fn build_sequence_archive(scene: &Scene, hints: BuildHints) -> Archive {
    let mut settings = BuildSettings::resolve(scene, hints);
    settings.prototype_library = None;
    let seq = build::build_sequence(scene, &settings, &NoProgress).unwrap();
    Archive::from_bytes(&archive::write_to_vec(&seq.contents).unwrap()).unwrap()
}

pub fn solve(archive: &Archive) -> Solution {
    distribute::distribute(&archive.view(), &DistributeOptions { tolerance: 1e-7, ..Default::default() }, &NoProgress)
        .unwrap()
}

/// Surface index of every patch.
pub fn patch_surface(v: &InetView<'_>) -> Vec<u32> {
    v.patch_primitive.iter().map(|&p| v.primitives[p as usize].surface).collect()
}

/// Total of `per_patch` (summed over RGB) over the patches of `surface`.
pub fn surface_total(v: &InetView<'_>, per_patch: &[[f32; 3]], surface: u32) -> f64 {
    patch_surface(v)
        .iter()
        .zip(per_patch)
        .filter(|(s, _)| **s == surface)
        .map(|(_, x)| x.iter().map(|&c| c as f64).sum::<f64>())
        .sum()
}
