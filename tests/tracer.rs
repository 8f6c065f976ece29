//! The two ways a build's rays find their hits (`build --tracer`, issue
//! 41): scan conversion tests each ray against the references whose leaf
//! box it meets, exactly the ones BVH traversal tests, so the archives are
//! the same byte for byte: a still, a sequence (temporal instances and
//! frame deltas), a glossy archive and a mesh.

mod common;

use illumnet::archive;
use illumnet::bake::{self, BuildSettings, TraceMethod};
use illumnet::progress::NoProgress;
use illumnet::scene::BuildHints;

/// The archive's bytes of `scene` built at `hints` with `method`.
fn built(scene: &illumnet::scene::Scene, hints: BuildHints, method: TraceMethod) -> Vec<u8> {
    let mut settings = BuildSettings::resolve(scene, hints);
    settings.prototype_library = None;
    settings.trace_method = method;
    let contents = match scene.frame_count() > 1 {
        true => bake::build_sequence(scene, &settings, &NoProgress).unwrap().contents,
        false => bake::build(scene, &settings, &NoProgress).unwrap().0,
    };
    archive::write_to_vec(&contents).unwrap()
}

#[test]
fn scan_conversion_builds_the_bvh_tracers_archive_byte_for_byte() {
    let mut cases: Vec<(&str, BuildHints)> = common::coarse_scenes().to_vec();
    // A mesh (grouped triangles), and the Cornell box at the default
    // frequency's ray spacing (many rays through edges and corners).
    let hints = |p: f32, f: u32, r: f32| BuildHints {
        patch_size: Some(p),
        frequency: Some(f),
        ray_spacing: Some(r),
        buckets: None,
    };
    cases.push(("bunny.toml", hints(0.02, 4, 0.004)));
    cases.push(("cornell_box.toml", hints(0.05, 8, 0.01)));
    for (name, h) in cases {
        let scene = common::scene_file(name);
        let (bvh, scan) = (built(&scene, h, TraceMethod::Bvh), built(&scene, h, TraceMethod::Scan));
        assert!(bvh == scan, "{name}: the archives differ ({} and {} bytes)", bvh.len(), scan.len());
        eprintln!("{name}: {} bytes, the same", bvh.len());
    }
}
