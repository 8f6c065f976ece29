//! Prints the flicker measure (src/flicker.rs) of the Cornell box's short
//! block moving in small steps, for geodesic I-nets with and without buckets
//! and the ray-space baseline, as JSON lines. Used by tools/accuracy_study.py.
//!
//! cargo run --release --example flicker -- [FREQUENCY] [PATCH_SIZE] [RAY_SPACING] [FRAMES]

use glam::Vec3;
use illumnet::bake::BuildSettings;
use illumnet::distribute::DistributeOptions;
use illumnet::flicker;
use illumnet::geodesic::DirectionSetKind;
use illumnet::scene::{BuildHints, Scene};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg = |i: usize, d: f32| args.get(i).and_then(|s| s.parse().ok()).unwrap_or(d);
    let hints = BuildHints {
        frequency: Some(arg(0, 16.0) as u32),
        patch_size: Some(arg(1, 0.015)),
        ray_spacing: Some(arg(2, 0.0075)),
        buckets: None,
    };
    let frames = arg(3, 6.0) as u32;
    let scene = Scene::cornell_box();
    let block = scene.surfaces.iter().position(|s| s.name == "short_block").expect("short block");
    let step = Vec3::new(0.002, 0.0, 0.001);
    for (name, kind, buckets, corrected) in [
        ("geodesic + buckets + H_p/H_u", DirectionSetKind::Geodesic, 1, true),
        ("geodesic + H_p/H_u, no buckets", DirectionSetKind::Geodesic, 0, true),
        ("geodesic, no corrections", DirectionSetKind::Geodesic, 0, false),
        ("ray-space baseline", DirectionSetKind::RaySpace, 0, false),
    ] {
        let mut s = BuildSettings::resolve(&scene, hints);
        s.direction_set = kind;
        s.max_bucket = buckets;
        let o = DistributeOptions { patch_size_correction: corrected, ..Default::default() };
        match flicker::measure(&scene, &s, &o, block, step, frames, &[block]) {
            Ok(f) => println!(
                "{{\"config\": \"{name}\", \"mean\": {:.6}, \"p95\": {:.6}, \"link_ends\": {:.0}}}",
                f.mean_relative_change, f.p95_relative_change, f.link_ends
            ),
            Err(e) => {
                eprintln!("flicker: {e}");
                std::process::exit(1);
            }
        }
    }
}
