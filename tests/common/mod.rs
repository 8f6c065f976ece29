//! Shared helpers: build scenes from TOML text and open the archive in memory.
#![allow(dead_code)]

use std::path::Path;

use illumnet::archive::{self, Archive, InetView};
use illumnet::bake::{self, BuildSettings};
use illumnet::distribute::{self, DistributeOptions, Solution};
use illumnet::progress::NoProgress;
use illumnet::scene::{BuildHints, Scene};

/// A camera block for scenes that are never rendered.
pub const CAMERA: &str =
    "[camera]\nposition = [0.5, 0.5, -3.0]\nlook_at = [0.5, 0.5, 0.0]\nfov_y_deg = 40\nwidth = 16\nheight = 16\n";

/// A scene of `scenes/`, read from its file.
pub fn scene_file(name: &str) -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes").join(name);
    Scene::from_file(&path).unwrap()
}

/// Builds `scene` (a sequence when animated) at `hints` into
/// `dir/scene.inet`.
pub fn write_scene(scene: &Scene, hints: BuildHints, dir: &Path) -> std::path::PathBuf {
    let mut settings = BuildSettings::resolve(scene, hints);
    settings.prototype_library = None;
    let contents = match scene.frame_count() > 1 {
        true => bake::build_sequence(scene, &settings, &NoProgress).unwrap().contents,
        false => bake::build(scene, &settings, &NoProgress).unwrap().0,
    };
    let path = dir.join("scene.inet");
    archive::write(&path, &contents).unwrap();
    path
}

pub fn scene(toml: &str) -> Scene {
    Scene::from_toml(toml, Path::new("test.toml"), Path::new(".")).unwrap_or_else(|e| panic!("{e}"))
}

/// Builds `scene` with default settings (plus `hints`) and opens the result
/// from memory.
pub fn build_archive(scene: &Scene, hints: BuildHints) -> Archive {
    let mut settings = BuildSettings::resolve(scene, hints);
    settings.prototype_library = None; // tests leave no files behind
    let (contents, _) = bake::build(scene, &settings, &NoProgress).unwrap();
    Archive::from_bytes(&archive::write_to_vec(&contents).unwrap()).unwrap()
}

/// Builds `scene` (still or animated: a sequence) with default settings
/// (plus `hints`) and opens the result from memory.
pub fn build_sequence_archive(scene: &Scene, hints: BuildHints) -> Archive {
    build_sequence_archive_traced(scene, hints, bake::TraceMethod::default())
}

/// [`build_sequence_archive`] with the rays traced by `method`.
pub fn build_sequence_archive_traced(scene: &Scene, hints: BuildHints, method: bake::TraceMethod) -> Archive {
    let mut settings = BuildSettings::resolve(scene, hints);
    settings.prototype_library = None;
    settings.trace_method = method;
    let seq = bake::build_sequence(scene, &settings, &NoProgress).unwrap();
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

/// A Wavefront OBJ of `n × n` square cells over `[x0, x0 + size] × [z0,
/// z0 + size]`, each cut into two triangles facing +y, at heights
/// `height(x, z)`: a mesh of small triangles (grouped into patches when
/// smaller than them, format-spec/archive.md §5.5).
pub fn grid_obj(n: u32, (x0, z0): (f32, f32), size: f32, height: impl Fn(f32, f32) -> f32) -> String {
    let mut obj = String::new();
    for j in 0..=n {
        for i in 0..=n {
            let (x, z) = (x0 + size * i as f32 / n as f32, z0 + size * j as f32 / n as f32);
            obj += &format!("v {x} {} {z}\n", height(x, z));
        }
    }
    let at = |i: u32, j: u32| j * (n + 1) + i + 1;
    for j in 0..n {
        for i in 0..n {
            obj += &format!("f {} {} {}\n", at(i, j), at(i, j + 1), at(i + 1, j + 1));
            obj += &format!("f {} {} {}\n", at(i, j), at(i + 1, j + 1), at(i + 1, j));
        }
    }
    obj
}

/// Writes the Cornell box at a coarse setting (frequency 6, patches of
/// 5 cm: about 1 000 patches) to `out`, for tests of the command line.
pub fn coarse_box_archive(out: &Path) {
    let scene = Scene::cornell_box();
    let hints = BuildHints { frequency: Some(6), patch_size: Some(0.05), ..Default::default() };
    let mut settings = BuildSettings::resolve(&scene, hints);
    settings.prototype_library = None;
    let (contents, _) = bake::build(&scene, &settings, &NoProgress).unwrap();
    std::fs::write(out, archive::write_to_vec(&contents).unwrap()).unwrap();
}

/// Three scenes at coarse settings whose link ends span several 2¹⁶-end
/// chunks (a still, a glossy scene, a sequence), for tests that cut the
/// ends into windows or ranges.
pub fn coarse_scenes() -> [(&'static str, BuildHints); 3] {
    let hints = |p: f32, f: u32, r: f32| BuildHints {
        patch_size: Some(p),
        frequency: Some(f),
        ray_spacing: Some(r),
        buckets: None,
    };
    [
        ("cornell_box.toml", hints(0.1, 6, 0.02)),
        ("glossy_floor.toml", hints(0.25, 5, 0.03)),
        ("fan_room.toml", hints(0.4, 4, 0.06)),
    ]
}

/// Every frame of `a`, each warm-started from the last, as one
/// distributor does them (tolerance 1e-5); given `spill`, its secant
/// pairs and totals kept in scratch files there.
pub fn solve_all_frames(a: &Archive, spill: Option<&Path>) -> Vec<Solution> {
    let v = a.view();
    let opts = DistributeOptions { tolerance: 1e-5, ..Default::default() };
    let mut d = distribute::Distributor::new(&v, &opts, &distribute::Lighting::from_view(&v)).unwrap();
    if let Some(dir) = spill {
        d = d.spill_in(dir);
    }
    let frames = v.sequence.map_or(1, |s| s.frames());
    let mut out: Vec<Solution> = Vec::new();
    for k in 0..frames {
        let s = d.frame(k, out.last(), &NoProgress).unwrap();
        out.push(s);
    }
    out
}

/// Asserts two runs of frames reached the same light bit for bit: energy
/// balance (iterations and ends gathered included), radiance, received
/// power, residual, first bounce and directional radiance.
pub fn assert_same_light(want: &[Solution], got: &[Solution], what: &str) {
    assert_eq!(want.len(), got.len(), "{what}: frames");
    for (k, (m, s)) in want.iter().zip(got).enumerate() {
        assert_eq!(m.balance, s.balance, "{what} frame {k}: energy balance differs");
        assert!(m.radiance == s.radiance, "{what} frame {k}: radiance differs");
        assert!(m.received == s.received, "{what} frame {k}: received power differs");
        assert!(m.residual == s.residual, "{what} frame {k}: residual differs");
        assert!(m.direct == s.direct, "{what} frame {k}: first bounce differs");
        assert!(m.directional == s.directional, "{what} frame {k}: directional radiance differs");
    }
}
