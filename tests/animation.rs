//! Animation exactness (issue #5): the links active at frame k after
//! applying the deltas of one sequence build equal, bit for bit, the links of
//! a from-scratch build of frame k's geometry with the same ray grid.
#![allow(clippy::needless_range_loop)]

mod common;

use illumnet::bake::{self, BuildSettings};
use illumnet::progress::NoProgress;
use illumnet::scene::{BuildHints, Scene};

/// A closed room with a moving light whose colour changes, a moving camera,
/// and three movers: two whose paths cross (overlapping in space at frame
/// 3), one that enters the space another has just left, and one static for
/// the first half.
const ADVERSARIAL: &str = r#"
[camera]
position = [1, 1, -2]
look_at = [1, 1, 1]
fov_y_deg = 50
width = 16
height = 16
keyframes = [{ frame = 0, position = [1, 1, -2], look_at = [1, 1, 1] }, { frame = 6, position = [0.5, 1.2, -2], look_at = [1.2, 0.8, 1] }]

[animation]
frames = 7
fps = 10

[[material]]
name = "grey"
type = "diffuse"
reflectance = [0.6, 0.5, 0.4]

[[surface]]
name = "room"
material = "grey"
box = { min = [0, 0, 0], max = [2, 2, 2], inward = true }

[[surface]]
name = "lamp"
material = "grey"
emission = [5, 5, 5]
quad = [[0.8, 1.9, 0.8], [1.2, 1.9, 0.8], [1.2, 1.9, 1.2], [0.8, 1.9, 1.2]]
pivot = [1, 1.9, 1]
keyframes = [{ frame = 0, translate = [-0.5, 0, 0] }, { frame = 6, translate = [0.5, 0, 0.3], rotate_deg = [0, 90, 0] }]
emission_keyframes = [{ frame = 0, emission = [5, 5, 5] }, { frame = 6, emission = [1, 3, 9] }]

[[surface]]
name = "mover_a"
material = "grey"
box = { min = [0.2, 0.2, 0.2], max = [0.6, 0.6, 0.6] }
keyframes = [{ frame = 0 }, { frame = 6, translate = [1.2, 0.3, 1.0] }]

[[surface]]
name = "mover_b"
material = "grey"
box = { min = [1.4, 0.2, 1.4], max = [1.8, 0.7, 1.8] }
keyframes = [{ frame = 0 }, { frame = 6, translate = [-1.2, 0.2, -1.0] }]

[[surface]]
name = "late_starter"
material = "grey"
box = { min = [0.2, 1.0, 1.4], max = [0.5, 1.3, 1.7] }
interpolation = "hold"
keyframes = [{ frame = 0 }, { frame = 3, translate = [0.3, 0, -0.2], rotate_deg = [0, 30, 0] }, { frame = 5, translate = [0.9, -0.4, -0.6] }]
"#;

fn adversarial() -> Scene {
    Scene::from_toml(ADVERSARIAL, std::path::Path::new("adversarial.toml"), std::path::Path::new(".")).unwrap()
}

/// The adversarial scene with its movers glossy (one anisotropic, one with
/// per-band Fresnel) over a still glossy panel.
fn glossy_adversarial() -> Scene {
    let text = ADVERSARIAL.replace(
        "[[surface]]\nname = \"mover_a\"\nmaterial = \"grey\"",
        "[[material]]\nname = \"gloss\"\ntype = \"broad_specular\"\nreflectance = [0.3, 0.2, 0.1]\nspecular = [0.5, 0.5, 0.5]\nalpha = 0.3\n\n[[material]]\nname = \"metal\"\ntype = \"rough_conductor\"\nspecular = [0.9, 0.9, 0.9]\nalpha_u = 0.2\nalpha_v = 0.5\nior = [1.4, 1.6, 1.8]\n\n[[surface]]\nname = \"mover_a\"\nmaterial = \"gloss\"",
    )
    .replace("name = \"mover_b\"\nmaterial = \"grey\"", "name = \"mover_b\"\nmaterial = \"metal\"\ngrain = [1, 0, 1]")
    // A still glossy panel under the movers: glossy patches present in
    // every frame with frame 0 links to instances that leave.
    + "\n[[surface]]\nname = \"panel\"\nmaterial = \"gloss\"\nquad = [[0.1, 0.01, 0.1], [0.1, 0.01, 1.9], [1.9, 0.01, 1.9], [1.9, 0.01, 0.1]]\n";
    Scene::from_toml(&text, std::path::Path::new("glossy.toml"), std::path::Path::new(".")).unwrap()
}

/// The sequence build of `scene` at `hints`, keeping its links, and its settings.
fn sequence(scene: &Scene, hints: BuildHints) -> (bake::Sequence, BuildSettings) {
    sequence_traced(scene, hints, bake::TraceMethod::default())
}

/// [`sequence`] with the rays traced by `method`.
fn sequence_traced(scene: &Scene, hints: BuildHints, method: bake::TraceMethod) -> (bake::Sequence, BuildSettings) {
    let settings = BuildSettings { trace_method: method, ..BuildSettings::resolve(scene, hints) };
    (bake::build_sequence_with_links(scene, &settings, &NoProgress).unwrap(), settings)
}

/// A from-scratch build of frame `k` alone, with the sequence's ray grids.
fn from_scratch(scene: &Scene, seq: &bake::Sequence, settings: &BuildSettings, k: u32) -> bake::Sequence {
    let still_settings = BuildSettings { grid_bounds: Some(seq.bounds), ..settings.clone() };
    bake::build_sequence_with_links(&scene.at_frame(k), &still_settings, &NoProgress).unwrap()
}

#[test]
fn sequence_links_equal_from_scratch_links_at_every_frame() {
    // With either tracer (issue 41, item 3).
    for method in [bake::TraceMethod::Bvh, bake::TraceMethod::Scan] {
        eprintln!("{method:?}:");
        links_equal_from_scratch_at_every_frame(method);
    }
}

fn links_equal_from_scratch_at_every_frame(method: bake::TraceMethod) {
    let scene = adversarial();
    let hints = BuildHints { patch_size: Some(0.2), frequency: Some(5), ray_spacing: Some(0.03), buckets: Some(1) };
    let (seq, settings) = sequence_traced(&scene, hints, method);
    let index = &seq.contents.sequence.as_ref().unwrap().deltas.index;
    assert!(index.iter().any(|d| d.count > 0), "movers must change links");
    // `hold` makes the late starter one instance per held run: 3 instances.
    let late = scene.surfaces.iter().position(|s| s.name == "late_starter").unwrap() as u32;
    assert_eq!(seq.instances.iter().filter(|i| i.surface == late).count(), 3);
    let mut total_links = 0;
    for k in 0..scene.frame_count() {
        let still = from_scratch(&scene, &seq, &settings, k);
        let want = still.active_links(0).unwrap();
        let got = seq.active_links(k).unwrap();
        let missing = want.iter().filter(|(key, n)| got.get(key) != Some(n)).count();
        let extra = got.iter().filter(|(key, n)| want.get(key) != Some(n)).count();
        assert!(
            missing == 0 && extra == 0,
            "frame {k}: {missing} links differ from scratch, {extra} extra ({} vs {})",
            got.len(),
            want.len()
        );
        total_links += want.len();
        // Hit counts H_p of the patches present at frame k agree too.
        let present = |p: usize| {
            let prim = seq.contents.patch_primitive[p] as usize;
            let mut first = 0;
            seq.instances.iter().any(|i| {
                let inside = prim >= first && prim < first + i.primitives.len();
                first += i.primitives.len();
                inside && i.frames.contains(k)
            })
        };
        let mut seq_hits = std::collections::BTreeMap::new();
        for p in (0..seq.patch_identity.len()).filter(|&p| present(p)) {
            seq_hits.insert(seq.patch_identity[p], seq.contents.patch_hits[p]);
        }
        let still_hits: std::collections::BTreeMap<_, _> =
            still.patch_identity.iter().copied().zip(still.contents.patch_hits.iter().copied()).collect();
        assert_eq!(seq_hits, still_hits, "frame {k}: hit counts differ");
    }
    eprintln!(
        "{} frames, {} active links checked, {} delta entries",
        scene.frame_count(),
        total_links,
        index.iter().map(|d| d.count).sum::<u64>()
    );
}

#[test]
fn bad_animation_input_is_a_clear_error() {
    let bad = ADVERSARIAL.replace(
        "keyframes = [{ frame = 0 }, { frame = 6, translate = [1.2, 0.3, 1.0] }]",
        "keyframes = [{ frame = 6, translate = [1.2, 0.3, 1.0] }, { frame = 0 }]",
    );
    let e = Scene::from_toml(&bad, std::path::Path::new("a.toml"), std::path::Path::new(".")).unwrap_err();
    assert!(e.message.contains("out of order") && e.field.contains("keyframes[1]"), "{e}");
    let line = ADVERSARIAL.lines().position(|l| l.contains("translate = [1.2, 0.3, 1.0]")).unwrap() + 1;
    assert_eq!(e.line, line, "the line of mover_a's keyframes: {e}");
    let bad = ADVERSARIAL.replace("{ frame = 6, translate = [1.2, 0.3, 1.0] }", "{ frame = 9 }");
    let e = Scene::from_toml(&bad, std::path::Path::new("a.toml"), std::path::Path::new(".")).unwrap_err();
    assert!(e.message.contains("outside the sequence 0..7"), "{e}");
    // A still build of an animated scene says what to do instead.
    let scene = adversarial();
    let err = bake::build(&scene, &BuildSettings::resolve(&scene, BuildHints::default()), &NoProgress).unwrap_err();
    assert!(err.contains("animated"), "{err}");
}

#[test]
fn frame_radiance_from_the_sequence_archive_equals_from_scratch() {
    use illumnet::archive::{self, Archive};
    use illumnet::distribute::{self, DistributeOptions};
    let scene = adversarial();
    let hints = BuildHints { patch_size: Some(0.25), frequency: Some(4), ray_spacing: Some(0.04), buckets: Some(1) };
    let (seq, settings) = sequence(&scene, hints);
    let bytes = archive::write_to_vec(&seq.contents).unwrap();
    let arch = Archive::from_bytes(&bytes).unwrap();
    assert_eq!(arch.header().version_read, 10, "archives need a reader of version 10");
    let v = arch.view();
    let opts = DistributeOptions { tolerance: 1e-7, ..Default::default() };
    let mut worst = 0.0f64;
    for k in 0..scene.frame_count() {
        let sol = distribute::distribute_frame(&v, k, &opts, &NoProgress).unwrap();
        let present = v.presence(k).primitives;
        let still = from_scratch(&scene, &seq, &settings, k);
        let still_arch = Archive::from_bytes(&archive::write_to_vec(&still.contents).unwrap()).unwrap();
        let want = distribute::distribute(&still_arch.view(), &opts, &NoProgress).unwrap();
        let want_by_id: std::collections::BTreeMap<_, _> = still.patch_identity.iter().zip(&want.radiance).collect();
        let mut compared = 0;
        for p in 0..v.patch_count() {
            if !present[v.patch_primitive[p] as usize] {
                // Absent patches take no part: exactly nothing arrives.
                assert_eq!(sol.received[p], [0.0; 3], "frame {k}: absent patch {p} received light");
                continue;
            }
            let w = want_by_id[&seq.patch_identity[p]];
            for c in 0..3 {
                let d = (sol.radiance[p][c] - w[c]).abs() as f64 / (w[c].abs() as f64).max(1e-3);
                worst = worst.max(d);
            }
            compared += 1;
        }
        assert_eq!(compared, want_by_id.len(), "frame {k}: every present patch compared");
        let (e1, e2): (f64, f64) = (sol.balance.emitted.iter().sum(), want.balance.emitted.iter().sum());
        assert!((e1 / e2 - 1.0).abs() < 1e-6, "frame {k}: emitted {e1} vs {e2}");
        // The frame's image (keyed camera, present geometry) matches too.
        let opts_r = illumnet::render::RenderOptions { samples_per_axis: 2, ..Default::default() };
        let img = illumnet::render::render_frame(&v, k, &sol.radiance, &opts_r);
        let want_img = illumnet::render::render(&still_arch.view(), &want.radiance, &opts_r);
        let err = illumnet::render::image_io::relative_l2(&img, &want_img).unwrap();
        assert!(err < 1e-4, "frame {k}: image differs from scratch by {err}");
    }
    eprintln!("worst relative radiance difference sequence vs from scratch: {worst:.2e}");
    assert!(worst < 1e-3, "worst relative difference {worst}");
    // Frames outside the sequence are errors, not panics.
    assert!(v.sequence.unwrap().frame_delta(scene.frame_count()).is_err());
    assert!(distribute::distribute_frame(&v, scene.frame_count(), &opts, &NoProgress).is_err());
}

#[test]
fn corrupt_sequence_sections_are_errors() {
    use illumnet::archive::{self, Archive, tag_name};
    let scene = adversarial();
    let hints = BuildHints { patch_size: Some(0.4), frequency: Some(3), ray_spacing: Some(0.08), buckets: Some(1) };
    let seq = bake::build_sequence(&scene, &BuildSettings::resolve(&scene, hints), &NoProgress).unwrap();
    let bytes = archive::write_to_vec(&seq.contents).unwrap();
    let good = Archive::from_bytes(&bytes).unwrap();
    let mut checked = 0;
    for e in good.sections().iter().filter(|e| ["ANIM", "INST", "DIDX", "DELT"].contains(&tag_name(e.tag).as_str())) {
        for at in [e.offset, e.offset + e.stored_length / 2, e.offset + e.stored_length - 1] {
            let mut bad = bytes.clone();
            bad[at as usize] ^= 0x10;
            assert!(Archive::from_bytes(&bad).is_err(), "{} byte {at} flipped, archive still opened", tag_name(e.tag));
            checked += 1;
        }
    }
    assert_eq!(checked, 12);
}

#[test]
fn sequence_archive_bytes_do_not_depend_on_thread_count() {
    // Each frame's changes are compressed in blocks by chunks of direction
    // pairs traced in parallel: the chunking must not follow the threads.
    use illumnet::archive;
    let scene = adversarial();
    let hints = BuildHints { patch_size: Some(0.4), frequency: Some(4), ray_spacing: Some(0.08), buckets: Some(1) };
    let settings = BuildSettings::resolve(&scene, hints);
    let build_with = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| archive::write_to_vec(&bake::build_sequence(&scene, &settings, &NoProgress).unwrap().contents))
            .unwrap()
    };
    let one = build_with(1);
    assert!(build_with(2) == one && build_with(3) == one, "sequence archives differ between thread counts");
}

#[test]
fn archives_of_older_formats_are_refused_with_what_to_do() {
    // See: format-spec/archive.md §6, §8. A reader of version 7 reads
    // version 7 files; version 6 files are rewritten by `illumnet upgrade`
    // (tests/upgrade.rs), older ones built again.
    use illumnet::archive::{self, Archive, ArchiveError};
    use xxhash_rust::xxh3::xxh3_64;
    let scene = adversarial();
    let hints = BuildHints { patch_size: Some(0.4), frequency: Some(3), ray_spacing: Some(0.08), buckets: Some(1) };
    let seq = bake::build_sequence(&scene, &BuildSettings::resolve(&scene, hints), &NoProgress).unwrap();
    let bytes = archive::write_to_vec(&seq.contents).unwrap();
    for (written, read, says) in [(6u32, 6u32, "illumnet upgrade"), (5, 5, "build it again"), (4, 3, "build it again")]
    {
        let mut b = bytes.clone();
        b[8..12].copy_from_slice(&written.to_le_bytes()); // version_write
        b[12..16].copy_from_slice(&read.to_le_bytes()); // version_read
        let header_sum = xxh3_64(&b[..120]);
        b[120..128].copy_from_slice(&header_sum.to_le_bytes());
        let err = Archive::from_bytes(&b).err().unwrap();
        assert!(matches!(err, ArchiveError::Outdated { written: w } if w == written), "{err}");
        assert!(err.to_string().contains(says), "{err}");
    }
}

#[test]
fn warm_start_converges_to_the_same_light_in_fewer_iterations() {
    use illumnet::archive::{self, Archive};
    use illumnet::distribute::{self, DistributeOptions};
    let scene = adversarial();
    let hints = BuildHints { patch_size: Some(0.25), frequency: Some(4), ray_spacing: Some(0.04), buckets: Some(1) };
    let seq = bake::build_sequence(&scene, &BuildSettings::resolve(&scene, hints), &NoProgress).unwrap();
    let arch = Archive::from_bytes(&archive::write_to_vec(&seq.contents).unwrap()).unwrap();
    let v = arch.view();
    // Plain iteration (depth 0) and Anderson acceleration (the default).
    let mut iterations = Vec::new();
    for depth in [0, 5] {
        let opts = DistributeOptions { tolerance: 1e-5, anderson_depth: depth, ..Default::default() };
        let (mut cold_iterations, mut warm_iterations, mut worst) = (0, 0, 0.0f64);
        let mut previous = distribute::distribute_frame(&v, 0, &opts, &NoProgress).unwrap();
        for k in 1..scene.frame_count() {
            let cold = distribute::distribute_frame(&v, k, &opts, &NoProgress).unwrap();
            let warm = distribute::distribute_frame_from(&v, k, &opts, Some(&previous), &NoProgress).unwrap();
            cold_iterations += cold.balance.iterations;
            warm_iterations += warm.balance.iterations;
            assert!(warm.balance.imbalance().abs() < 1e-5, "frame {k}: {:?}", warm.balance);
            for (a, b) in cold.radiance.iter().zip(&warm.radiance) {
                for c in 0..3 {
                    worst = worst.max((a[c] - b[c]).abs() as f64 / (a[c].abs() as f64).max(1e-2));
                }
            }
            previous = warm;
        }
        eprintln!(
            "Anderson depth {depth}: iterations over frames 1..7: cold {cold_iterations}, warm {warm_iterations}; \
             worst difference {worst:.1e}"
        );
        assert!(worst < 1e-3, "depth {depth}: warm and cold solutions differ by {worst}");
        assert!(warm_iterations <= cold_iterations, "depth {depth}: warm {warm_iterations} vs cold {cold_iterations}");
        iterations.push((cold_iterations, warm_iterations));
    }
    let ((plain_cold, plain_warm), (fast_cold, fast_warm)) = (iterations[0], iterations[1]);
    assert!(plain_warm < plain_cold, "plain: warm {plain_warm} vs cold {plain_cold}");
    assert!(fast_cold < plain_cold && fast_warm < plain_warm, "Anderson {iterations:?}");
}

#[test]
fn fan_room_links_are_exact_at_every_frame() {
    // See: issue #5 acceptance. The paper's scene, at a coarse resolution to
    // keep the 60 from-scratch builds quick.
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/fan_room.toml");
    let scene = Scene::from_file(&path).unwrap();
    assert_eq!((scene.frame_count(), scene.animation.unwrap().fps), (60, 15.0));
    let hints = BuildHints { patch_size: Some(0.4), frequency: Some(4), ray_spacing: Some(0.12), buckets: Some(1) };
    let (seq, settings) = sequence(&scene, hints);
    for k in 0..scene.frame_count() {
        let still = from_scratch(&scene, &seq, &settings, k);
        let (want, got) = (still.active_links(0).unwrap(), seq.active_links(k).unwrap());
        assert!(want == got, "frame {k}: {} links vs {} from scratch", got.len(), want.len());
    }
}

#[test]
fn glossy_movers_radiance_from_the_sequence_equals_from_scratch() {
    // The adversarial scene with its movers glossy (one anisotropic, one
    // with per-band Fresnel): the reflectance sections of a sequence
    // (per-instance orientations and ray counts) and the overlay's glossy
    // senders must give each frame the light of a from-scratch build.
    use illumnet::archive::{self, Archive};
    use illumnet::distribute::{self, DistributeOptions};
    let scene = glossy_adversarial();
    let hints = BuildHints { patch_size: Some(0.25), frequency: Some(4), ray_spacing: Some(0.04), buckets: Some(1) };
    let mut settings = BuildSettings::resolve(&scene, hints);
    settings.prototype_library = None;
    let seq = bake::build_sequence_with_links(&scene, &settings, &NoProgress).unwrap();
    let arch = Archive::from_bytes(&archive::write_to_vec(&seq.contents).unwrap()).unwrap();
    let v = arch.view();
    assert_eq!(arch.header().version_read, 10, "every archive needs a reader of version 10");
    let r = v.reflectance.unwrap();
    assert!(r.orientations.len() > 6, "moving glossy boxes have one orientation per face and turn");
    let opts = DistributeOptions { tolerance: 1e-7, ..Default::default() };
    let (mut worst, mut worst_dir) = (0.0f64, 0.0f64);
    let mut previous: Option<distribute::Solution> = None;
    for k in 0..scene.frame_count() {
        // Warm-started from the previous frame, as `render --frames` does.
        let sol = distribute::distribute_frame_from(&v, k, &opts, previous.as_ref(), &NoProgress).unwrap();
        assert!(sol.balance.imbalance().abs() < 1e-5, "frame {k}: {:?}", sol.balance);
        let present = v.presence(k).primitives;
        // Absent patches take no part, glossy senders notwithstanding.
        for p in (0..v.patch_count()).filter(|&p| !present[v.patch_primitive[p] as usize]) {
            assert_eq!(sol.received[p], [0.0; 3], "frame {k}: absent patch {p} received light");
        }
        let still = from_scratch(&scene, &seq, &settings, k);
        let still_arch = Archive::from_bytes(&archive::write_to_vec(&still.contents).unwrap()).unwrap();
        let want = distribute::distribute(&still_arch.view(), &opts, &NoProgress).unwrap();
        let want_by_id: std::collections::BTreeMap<_, _> = still.patch_identity.iter().zip(&want.radiance).collect();
        for p in (0..v.patch_count()).filter(|&p| present[v.patch_primitive[p] as usize]) {
            let w = want_by_id[&seq.patch_identity[p]];
            for c in 0..3 {
                worst = worst.max((sol.radiance[p][c] - w[c]).abs() as f64 / (w[c].abs() as f64).max(1e-3));
            }
        }
        // Where the power went, too: absent glossy patches must not count
        // light found along their frame 0 ends as reflected. (What leaves
        // unlinked is compared whole: a sequence splits it between back
        // faces and escape by each patch's first frame, §5.7.)
        for c in 0..3 {
            let (e, b, a) = (want.balance.emitted[c], &sol.balance, &want.balance);
            let (lost, lost_want) = (b.escaped[c] + b.back_faces[c], a.escaped[c] + a.back_faces[c]);
            assert!(
                (b.absorbed[c] - a.absorbed[c]).abs() < 1e-4 * e && (lost - lost_want).abs() < 1e-4 * e,
                "frame {k}, band {c}: absorbed {} vs {}, escaped or met back faces {lost} vs {lost_want} from scratch",
                b.absorbed[c],
                a.absorbed[c],
            );
        }
        // Directional radiance of the glossy patches present, by identity.
        let (d, wd) = (sol.directional.as_ref().unwrap(), want.directional.as_ref().unwrap());
        let want_dir: std::collections::BTreeMap<_, _> =
            wd.patches.iter().enumerate().map(|(j, &q)| (still.patch_identity[q as usize], wd.of(j))).collect();
        let mut compared = 0;
        for (j, &q) in d.patches.iter().enumerate() {
            if !present[v.patch_primitive[q as usize] as usize] {
                continue;
            }
            let w = want_dir[&seq.patch_identity[q as usize]];
            let scale = w.iter().flatten().fold(1e-3f32, |m, &x| m.max(x)) as f64;
            for (a, b) in d.of(j).iter().zip(w) {
                for c in 0..3 {
                    worst_dir = worst_dir.max((a[c] - b[c]).abs() as f64 / scale);
                }
            }
            compared += 1;
        }
        assert_eq!(compared, want_dir.len(), "frame {k}: every present glossy patch compared");
        previous = Some(sol);
    }
    eprintln!("glossy movers: worst relative difference {worst:.2e} (radiance), {worst_dir:.2e} (directional)");
    assert!(worst < 1e-3 && worst_dir < 1e-3, "radiance {worst}, directional {worst_dir}");
}

#[test]
fn cached_visibility_renders_the_same_images_and_retraces_only_near_movers() {
    use illumnet::archive::{self, Archive};
    use illumnet::distribute::{self, DistributeOptions};
    use illumnet::render::{self, RenderOptions, Renderer};
    // The adversarial scene with a still camera: later frames reuse what
    // the samples saw, except near the movers.
    let text = ADVERSARIAL.replace("keyframes = [{ frame = 0, position = [1, 1, -2], look_at = [1, 1, 1] }, { frame = 6, position = [0.5, 1.2, -2], look_at = [1.2, 0.8, 1] }]\n", "");
    let scene = Scene::from_toml(&text, std::path::Path::new("still_camera.toml"), std::path::Path::new(".")).unwrap();
    let hints = BuildHints { patch_size: Some(0.25), frequency: Some(4), ray_spacing: Some(0.04), buckets: Some(1) };
    let seq = bake::build_sequence(&scene, &BuildSettings::resolve(&scene, hints), &NoProgress).unwrap();
    let arch = Archive::from_bytes(&archive::write_to_vec(&seq.contents).unwrap()).unwrap();
    let v = arch.view();
    let opts = RenderOptions { samples_per_axis: 3, ..Default::default() };
    let mut cached = Renderer::new(&v, opts);
    let mut uncached = Renderer::new(&v, opts).with_cache_budget(0);
    let total = (v.camera.width * v.camera.height * 9) as usize;
    for k in 0..scene.frame_count() {
        let sol = distribute::distribute_frame(&v, k, &DistributeOptions::default(), &NoProgress).unwrap();
        let radiance = render::frame_radiance(&v, k, &sol);
        let a = cached.frame(k, &radiance);
        let b = render::render_frame(&v, k, &radiance, &opts);
        assert!(a == b, "frame {k}: the cached render differs");
        assert!(uncached.frame(k, &radiance) == b, "frame {k}: the render without cache differs");
        assert_eq!(uncached.retraced, total);
        if k == 0 {
            assert_eq!(cached.retraced, total);
        } else {
            assert!(cached.retraced < total, "frame {k}: all {total} samples retraced");
        }
    }
}

#[test]
fn explicit_removals_of_links_to_absent_patches_give_the_same_light() {
    // See: format-spec/archive.md §5.13, step 2. Version 6 writers omit the
    // records that remove frame 0's links to patches absent from a frame;
    // files before version 6 list them. Both must give the same links, so
    // the same light, diffuse and glossy (whose escaped power is counted
    // per direction).
    use illumnet::archive::layout::DeltaRecord;
    use illumnet::archive::{self, Archive};
    use illumnet::distribute::{self, DistributeOptions};
    for scene in [adversarial(), glossy_adversarial()] {
        let hints = BuildHints { patch_size: Some(0.3), frequency: Some(4), ray_spacing: Some(0.05), buckets: Some(1) };
        let mut settings = BuildSettings::resolve(&scene, hints);
        settings.prototype_library = None;
        let seq = bake::build_sequence_with_links(&scene, &settings, &NoProgress).unwrap();
        let deltas = &seq.contents.sequence.as_ref().unwrap().deltas;
        let present_at = |k: u32| {
            let mut present = Vec::new();
            for i in &seq.instances {
                present.extend(std::iter::repeat_n(i.frames.contains(k), i.primitives.len()));
            }
            seq.contents.patch_primitive.iter().map(|&p| present[p as usize]).collect::<Vec<bool>>()
        };
        let (mut omitted, mut listed) = (0, 0);
        let explicit: Vec<Vec<DeltaRecord>> = (0..scene.frame_count())
            .map(|k| {
                let present = present_at(k);
                let mut records = deltas.frame(k as usize).unwrap();
                assert!(records.iter().all(|d| present[d.a as usize] && present[d.b as usize]), "frame {k}");
                listed += records.len();
                for l in seq.base.as_ref().unwrap() {
                    if !(present[l.a as usize] && present[l.b as usize]) {
                        records.push(DeltaRecord {
                            pair: l.pair,
                            a: l.a,
                            b: l.b,
                            count: -(l.weight as i32),
                            bucket_a: l.bucket_a,
                            bucket_b: l.bucket_b,
                            reserved: 0,
                        });
                        omitted += 1;
                    }
                }
                records.sort_by_key(|d| (d.pair, d.a, d.b, d.bucket_a, d.bucket_b));
                records
            })
            .collect();
        assert!(omitted > listed / 10, "the movers' frame 0 links must matter: {omitted} omitted, {listed} listed");
        let mut with_removals = seq.contents.clone();
        with_removals.sequence.as_mut().unwrap().deltas =
            archive::deltas::EncodedDeltas::from_frames(&explicit).unwrap();
        let (a, b) = (archive::write_to_vec(&seq.contents).unwrap(), archive::write_to_vec(&with_removals).unwrap());
        let (a, b) = (Archive::from_bytes(&a).unwrap(), Archive::from_bytes(&b).unwrap());
        let opts = DistributeOptions { tolerance: 1e-7, ..Default::default() };
        let mut worst = 0.0f64;
        for k in 0..scene.frame_count() {
            let x = distribute::distribute_frame(&a.view(), k, &opts, &NoProgress).unwrap();
            let y = distribute::distribute_frame(&b.view(), k, &opts, &NoProgress).unwrap();
            assert!(x.balance.imbalance().abs() < 1e-5 && y.balance.imbalance().abs() < 1e-5, "frame {k}");
            for c in 0..3 {
                let (ex, ey) = (x.balance.escaped[c], y.balance.escaped[c]);
                assert!((ex - ey).abs() <= 1e-6 * x.balance.emitted[c], "frame {k}: escaped {ex} vs {ey}");
            }
            for (p, q) in x.radiance.iter().zip(&y.radiance) {
                for c in 0..3 {
                    worst = worst.max((p[c] - q[c]).abs() as f64 / (p[c].abs() as f64).max(1e-3));
                }
            }
        }
        assert!(worst < 1e-5, "radiance with and without explicit removals differs by {worst}");
    }
}

#[test]
fn warm_frames_of_one_distributor_start_with_a_sparse_gather_and_reach_the_cold_light() {
    // See: distribute::Distributor::frame. Frames warm-started from the
    // same distributor's previous frame gather only the two frames' overlay
    // ends in their first step (G_f(X) = G_e(S) + overlay_f(X) −
    // overlay_e(S)); frames where a patch with frame 0 links leaves (1 and
    // 3 here) take the full gather. Either way the light must be the cold
    // start's.
    use illumnet::archive::{self, Archive};
    use illumnet::distribute::{DistributeOptions, Distributor, Lighting};
    let scene = adversarial();
    let hints = BuildHints { patch_size: Some(0.25), frequency: Some(4), ray_spacing: Some(0.04), buckets: Some(1) };
    let seq = bake::build_sequence(&scene, &BuildSettings::resolve(&scene, hints), &NoProgress).unwrap();
    let arch = Archive::from_bytes(&archive::write_to_vec(&seq.contents).unwrap()).unwrap();
    let v = arch.view();
    let opts = DistributeOptions { tolerance: 1e-5, ..Default::default() };
    let d = Distributor::new(&v, &opts, &Lighting::from_view(&v)).unwrap();
    let mut previous = d.frame(0, None, &NoProgress).unwrap();
    let (mut sparse, mut worst) = (Vec::new(), 0.0f64);
    for k in 1..scene.frame_count() {
        let warm = d.frame(k, Some(&previous), &NoProgress).unwrap();
        let cold = d.frame(k, None, &NoProgress).unwrap();
        assert!(warm.balance.imbalance().abs() < 1e-5, "frame {k}: {:?}", warm.balance);
        let full = cold.balance.ends_gathered / cold.balance.iterations as u64;
        if warm.balance.ends_gathered < warm.balance.iterations as u64 * full {
            sparse.push(k);
        }
        for (a, b) in cold.radiance.iter().zip(&warm.radiance) {
            for c in 0..3 {
                worst = worst.max((a[c] - b[c]).abs() as f64 / (a[c].abs() as f64).max(1e-2));
            }
        }
        previous = warm;
    }
    eprintln!("sparse first steps at frames {sparse:?}; worst warm/cold difference {worst:.1e}");
    assert_eq!(sparse, vec![2, 4, 5, 6], "frames 1 and 3 lose frame 0 instances, the others need no full gather");
    assert!(worst < 1e-3, "warm and cold solutions differ by {worst}");
}

#[test]
fn a_long_chain_of_sparse_warm_starts_keeps_the_cold_light() {
    // See: distribute::Carry. The fan room's 60 frames warm-started one from
    // the next: totals carried from sparse jump to sparse jump must not
    // drift from the cold-start light (a full gather every 32nd jump bounds
    // the rounding carried along).
    use illumnet::archive::{self, Archive};
    use illumnet::distribute::{DistributeOptions, Distributor, Lighting};
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/fan_room.toml");
    let scene = Scene::from_file(&path).unwrap();
    let hints = BuildHints { patch_size: Some(0.4), frequency: Some(4), ray_spacing: Some(0.12), buckets: Some(1) };
    let seq = bake::build_sequence(&scene, &BuildSettings::resolve(&scene, hints), &NoProgress).unwrap();
    let arch = Archive::from_bytes(&archive::write_to_vec(&seq.contents).unwrap()).unwrap();
    let v = arch.view();
    let opts = DistributeOptions { tolerance: 1e-7, ..Default::default() };
    let d = Distributor::new(&v, &opts, &Lighting::from_view(&v)).unwrap();
    let mut previous = d.frame(0, None, &NoProgress).unwrap();
    let mut sparse = 0;
    for k in 1..scene.frame_count() {
        let warm = d.frame(k, Some(&previous), &NoProgress).unwrap();
        let cold = d.frame(k, None, &NoProgress).unwrap();
        let full = cold.balance.ends_gathered / cold.balance.iterations as u64;
        sparse += (warm.balance.ends_gathered < full * warm.balance.iterations as u64) as u32;
        assert!(warm.balance.imbalance().abs() < 1e-6, "frame {k}: {:?}", warm.balance);
        if k % 29 == 0 || k == scene.frame_count() - 1 {
            let mut worst = 0.0f64;
            for (a, b) in cold.radiance.iter().zip(&warm.radiance) {
                for c in 0..3 {
                    worst = worst.max((a[c] - b[c]).abs() as f64 / (a[c].abs() as f64).max(1e-2));
                }
            }
            eprintln!("frame {k}: warm vs cold {worst:.1e}");
            assert!(worst < 1e-4, "frame {k}: warm and cold differ by {worst}");
        }
        previous = warm;
    }
    // Frame 1 loses frame 0's instances, frame 33 ends a chain of 32.
    assert_eq!(sparse, scene.frame_count() - 3, "sparse first steps in all but frames 1 and 33");
}

#[test]
fn meshes_still_and_moving_keep_links_exact_at_every_frame() {
    // A still mesh of small triangles (grouped into patches in the
    // sequence and in every still of one frame alike) and a moving one
    // (a patch per triangle in both: a still of frame k builds the mover
    // as the sequence does, so the links agree).
    let dir = tempfile::tempdir().unwrap();
    let obj = common::grid_obj(6, (0.0, 0.0), 0.6, |x, z| 0.04 * (9.0 * x).sin() * (7.0 * z).cos());
    std::fs::write(dir.path().join("bumps.obj"), obj).unwrap();
    let text = ADVERSARIAL.to_string()
        + "\n[[surface]]\nname = \"still_mesh\"\nmaterial = \"grey\"\nmesh = \"bumps.obj\"\n\
           transform = { translate = [1.2, 0.05, 0.2] }\n\
           \n[[surface]]\nname = \"moving_mesh\"\nmaterial = \"grey\"\nmesh = \"bumps.obj\"\n\
           transform = { translate = [0.2, 1.2, 0.2] }\n\
           keyframes = [{ frame = 0 }, { frame = 6, translate = [0.8, -0.2, 0.9] }]\n";
    let scene = Scene::from_toml(&text, &dir.path().join("meshes.toml"), dir.path()).unwrap();
    let hints = BuildHints { patch_size: Some(0.2), frequency: Some(5), ray_spacing: Some(0.03), buckets: Some(1) };
    let (seq, settings) = sequence(&scene, hints);
    let grouped = |c: &illumnet::archive::ArchiveContents| c.primitives.iter().filter(|r| r.kind == 2).count();
    assert_eq!(grouped(&seq.contents), 72, "the still mesh's 72 triangles are grouped, the mover's are not");
    for k in 0..scene.frame_count() {
        let still = from_scratch(&scene, &seq, &settings, k);
        assert_eq!(grouped(&still.contents), 72, "frame {k}");
        let (want, got) = (still.active_links(0).unwrap(), seq.active_links(k).unwrap());
        assert!(want == got, "frame {k}: links differ ({} vs {})", got.len(), want.len());
    }
}
