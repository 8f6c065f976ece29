//! The distribution's fast path against the plain reference solver, its
//! errors, and its images pinned bit for bit.
//!
//! The pinned hashes are those of the images the single-function
//! distribution made before `distribute/` was split into its pieces
//! (setup, warm starts, the iteration step, kernels); the split was also
//! checked bit for bit on the glossy floor and the brushed plate, which
//! are not pinned here (their table kernel depends on the CPU's AVX2). A change that means to change
//! the numbers re-pins them: run this test with `ILLUMNET_PIN=1` and copy
//! the printed hashes, and say why in the commit.

mod common;

use illumnet::archive::{Archive, InetView};
use illumnet::distribute::{self, DistributeError, DistributeOptions, Distributor, Lighting, Solution, reference};
use illumnet::progress::NoProgress;
use illumnet::render::{self, RenderOptions, Renderer};
use illumnet::scene::{BuildHints, Scene};

fn scene_file(name: &str) -> Scene {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes").join(name);
    Scene::from_file(&path).unwrap_or_else(|e| panic!("{e}"))
}

/// Relative difference of radiance, over patches brighter than 1e-3 of the
/// brightest (dimmer ones: absolute against that floor).
fn worst_relative(fast: &[[f32; 3]], reference: &[[f64; 3]]) -> f64 {
    let top = reference.iter().flatten().fold(0.0f64, |m, &x| m.max(x));
    let floor = 1e-3 * top;
    fast.iter()
        .zip(reference)
        .flat_map(|(a, b)| (0..3).map(move |c| (a[c] as f64 - b[c]).abs() / b[c].abs().max(floor)))
        .fold(0.0, f64::max)
}

fn coarse_cornell() -> Archive {
    let hints =
        BuildHints { frequency: Some(6), patch_size: Some(0.08), ray_spacing: Some(0.01), ..Default::default() };
    common::build_archive(&Scene::cornell_box(), hints)
}

fn coarse_fan_room() -> Archive {
    let hints = BuildHints { frequency: Some(6), patch_size: Some(0.3), ray_spacing: Some(0.06), ..Default::default() };
    common::build_sequence_archive(&scene_file("fan_room.toml"), hints)
}

#[test]
fn fast_distribution_agrees_with_the_reference_solver_on_a_still() {
    let a = coarse_cornell();
    let v = a.view();
    let lighting = Lighting::from_view(&v);
    for (buckets, anderson_depth) in [(true, 5), (false, 0), (true, 0), (false, 3)] {
        let opts = DistributeOptions { tolerance: 1e-7, buckets, anderson_depth, ..Default::default() };
        let fast = distribute::distribute(&v, &opts, &NoProgress).unwrap();
        let reference_opts = DistributeOptions { tolerance: 1e-10, ..opts };
        let want = reference::solve(&v, 0, &lighting, &reference_opts).unwrap();
        assert!(fast.balance.converged && want.converged);
        let err = worst_relative(&fast.radiance, &want.radiance);
        // f32 sums against f64: about 1e-6 (measured 0.7–1.6e-6).
        assert!(err < 1e-5, "buckets {buckets}, anderson {anderson_depth}: worst patch {err:.2e} off the reference");
        // The reference is plain Jacobi: the fast path takes fewer steps.
        assert!(fast.balance.iterations < want.iterations, "{} vs {}", fast.balance.iterations, want.iterations);
    }
    // The check can fail: the uncorrected method is a different answer.
    let opts = DistributeOptions { tolerance: 1e-7, patch_size_correction: false, ..Default::default() };
    let other = distribute::distribute(&v, &opts, &NoProgress).unwrap();
    let want =
        reference::solve(&v, 0, &lighting, &DistributeOptions { tolerance: 1e-10, ..Default::default() }).unwrap();
    assert!(worst_relative(&other.radiance, &want.radiance) > 1e-3);
}

#[test]
fn warm_and_sparse_frames_agree_with_the_reference_solver() {
    let a = coarse_fan_room();
    let v = a.view();
    let frames = v.sequence.unwrap().frames();
    let lighting = Lighting::from_view(&v);
    let opts = DistributeOptions { tolerance: 1e-7, ..Default::default() };
    let d = Distributor::new(&v, &opts, &lighting).unwrap();
    let mut previous: Option<Solution> = None;
    let mut worst = 0.0f64;
    // Every frame warm-started from the one before (sparse jumps), and a
    // jump back to frame 0 and forward again (full guesses).
    let order: Vec<u32> = (0..12).chain([0, frames - 1, 30]).collect();
    for &k in &order {
        let fast = d.frame(k, previous.as_ref(), &NoProgress).unwrap();
        let want = reference::solve(&v, k, &lighting, &DistributeOptions { tolerance: 1e-10, ..opts }).unwrap();
        assert!(fast.balance.converged && want.converged, "frame {k}");
        let present = v.presence(k);
        for p in (0..v.patch_count()).filter(|&p| !present.patch(p)) {
            assert_eq!(fast.radiance[p], [0.0; 3], "absent patch {p} of frame {k} has light");
        }
        worst = worst.max(worst_relative(&fast.radiance, &want.radiance));
        previous = Some(fast);
    }
    assert!(worst < 1e-5, "worst patch {worst:.2e} off the reference");
}

#[test]
fn caller_mistakes_are_distribute_errors() {
    let still = coarse_cornell();
    let v = still.view();
    let opts = DistributeOptions::default();
    let err = distribute::distribute_frame(&v, 1, &opts, &NoProgress).unwrap_err();
    assert!(matches!(err, DistributeError::NotASequence { frame: 1 }), "{err}");
    let mut lighting = Lighting::from_view(&v);
    lighting.emission.pop();
    let err = Distributor::new(&v, &opts, &lighting).err().unwrap();
    assert!(matches!(err, DistributeError::LightingMismatch { given, surfaces } if given + 1 == surfaces), "{err}");
    let seq = coarse_fan_room();
    let v = seq.view();
    let frames = v.sequence.unwrap().frames();
    let err = distribute::distribute_frame(&v, frames, &opts, &NoProgress).unwrap_err();
    assert!(matches!(err, DistributeError::FrameOutOfRange { frame, frames: f } if frame == f), "{err}");
    assert!(err.to_string().contains("outside the sequence"), "{err}");
}

/// xxh3 of an image's f32 bits.
fn image_hash(image: &render::Image) -> u64 {
    xxhash_rust::xxh3::xxh3_64(bytemuck::cast_slice(&image.pixels))
}

fn check_pins(name: &str, got: &[u64], want: &[u64]) {
    if std::env::var_os("ILLUMNET_PIN").is_some() {
        println!("{name}: {got:#018x?}");
        return;
    }
    assert_eq!(got, want, "{name}: images changed (see the module docs to re-pin)");
}

fn render_frames(v: &InetView<'_>, opts: &DistributeOptions, frames: &[u32], warm: bool) -> Vec<u64> {
    let d = Distributor::new(v, opts, &Lighting::from_view(v)).unwrap();
    let mut renderer = Renderer::new(v, RenderOptions::default());
    let mut previous: Option<Solution> = None;
    let mut out = Vec::new();
    for &k in frames {
        let s = d.frame(k, if warm { previous.as_ref() } else { None }, &NoProgress).unwrap();
        out.push(image_hash(&renderer.frame(k, &render::frame_radiance(v, k, &s))));
        previous = Some(s);
    }
    out
}

#[test]
fn images_are_pinned_bit_for_bit() {
    // The Cornell box at default settings, and the fan room as
    // `--patch-size 0.2 --ray-spacing 0.05 --frequency 8`.
    let a = common::build_archive(&Scene::cornell_box(), BuildHints::default());
    let v = a.view();
    let default = DistributeOptions::default();
    let plain = DistributeOptions { buckets: false, anderson_depth: 0, ..default };
    let got = [render_frames(&v, &default, &[0], false), render_frames(&v, &plain, &[0], false)].concat();
    check_pins("cornell", &got, &[0x6a11deb05932108a, 0xd2856f2ba9186d61]);
    let hints = BuildHints { frequency: Some(8), patch_size: Some(0.2), ray_spacing: Some(0.05), ..Default::default() };
    let a = common::build_sequence_archive(&scene_file("fan_room.toml"), hints);
    let v = a.view();
    let got = [render_frames(&v, &default, &[0, 1, 2, 3, 4, 5], true), render_frames(&v, &default, &[40, 41], false)]
        .concat();
    let want = [
        0x6760f39322abb3f1,
        0xf4b59e9cb1ccf1d4,
        0x7308fdc6971256de,
        0xcad4ab8ce1f5bc9b,
        0xd90a306e3459ae29,
        0xf0fb0014b074db8e,
        0x01b081ea8a415605,
        0x44e6c159f51d4bd4,
    ];
    check_pins("fan room", &got, &want);
}
