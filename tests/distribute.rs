//! The distribution's fast path against the plain reference solver, its
//! errors, and its images pinned bit for bit.
//!
//! The pinned hashes were first those of the images the single-function
//! distribution made before `distribute/` was split into its pieces
//! (setup, warm starts, the iteration step, kernels); the split was also
//! checked bit for bit on the glossy floor and the brushed plate, which
//! are not pinned here (their table kernel depends on the CPU's AVX2).
//! Format version 7's one-byte weights kept them bit for bit; its tiled
//! patch numbering changed the order of the gather's sums and re-pinned
//! them (`patches_in_tiles_give_the_light_of_patches_in_rows` holds the
//! two orders within 1e-6). Format version 11's spatial patch order
//! re-pinned the Cornell box's (the fan room moves, so keeps primitive
//! order): `a_spatial_patch_order_gives_the_light_of_primitive_order`
//! holds the two within 1e-6. Anderson's secant pairs stored as bfloat16
//! (issue 39 §0: they only steer the step) re-pinned the accelerated
//! images; the plain one (no buckets, no acceleration) kept its hash, and
//! the same iterations and energy balance held on the Cornell box at 4, 2
//! and 1 mm and the top ladder rung. The scan-converting tracer becoming
//! the default (issue 41) re-pinned both: its archives differ from the BVH
//! tracer's in rays at edges (`tests/tracer.rs` bounds the difference).
//! Closest hits that break ties by primitive order (of primitives met at
//! one distance, the first; it was whichever the traversal met first)
//! re-pinned the fan room's frame 41, with the binary BVH as with the
//! render's eight-wide one. A change that means to change the numbers
//! re-pins them: run this test with `ILLUMNET_PIN=1` and copy the printed
//! hashes, and say why in the commit.

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
fn weights_kept_apart_give_the_reference_light_resident_and_streamed() {
    // Patches of 0.24 m crossed by rays 3 mm apart: links of up to ~6 400
    // rays, whose weights do not fit LCNT's byte and go to LCNX (§5.10),
    // mixed with small ones; the gather adds them in a pass of their own.
    let hints =
        BuildHints { frequency: Some(3), patch_size: Some(0.24), ray_spacing: Some(0.003), ..Default::default() };
    let scene = Scene::cornell_box();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("coarse.inet");
    let mut settings = illumnet::bake::BuildSettings::resolve(&scene, hints);
    settings.prototype_library = None;
    let (contents, _) = illumnet::bake::build(&scene, &settings, &NoProgress).unwrap();
    illumnet::archive::write(&path, &contents).unwrap();
    let big = contents.link_weight.iter().filter(|&&w| w > 255.0).count();
    assert!(big > 100 && big < contents.link_weight.len(), "{big} of {} ends escaped", contents.link_weight.len());
    let lighting = {
        let a = Archive::open(&path).unwrap();
        Lighting::from_view(&a.view())
    };
    for streamed in [false, true] {
        let a = if streamed { Archive::open_streamed(&path, 300).unwrap() } else { Archive::open(&path).unwrap() };
        let v = a.view();
        assert_eq!(v.links.resident().map(|l| l.weight.escapes().len()).unwrap_or(big), big);
        for buckets in [true, false] {
            let opts = DistributeOptions { tolerance: 1e-7, buckets, ..Default::default() };
            let fast = distribute::distribute(&v, &opts, &NoProgress).unwrap();
            let want = reference::solve(&v, 0, &lighting, &DistributeOptions { tolerance: 1e-10, ..opts }).unwrap();
            let err = worst_relative(&fast.radiance, &want.radiance);
            assert!(err < 1e-5, "streamed {streamed}, buckets {buckets}: worst patch {err:.2e} off the reference");
        }
    }
}

/// The default Cornell box built with `tweak` applied to its settings.
fn cornell_with(tweak: impl FnOnce(&mut illumnet::bake::BuildSettings)) -> Archive {
    let scene = Scene::cornell_box();
    let mut settings = illumnet::bake::BuildSettings::resolve(&scene, BuildHints::default());
    tweak(&mut settings);
    let (contents, _) = illumnet::bake::build(&scene, &settings, &NoProgress).unwrap();
    Archive::from_bytes(&illumnet::archive::write_to_vec(&contents).unwrap()).unwrap()
}

/// Holds two builds of the same links between renumbered patches to the
/// same light: 12 iterations of each, and every patch `p` of `a` against
/// patch `q_of(p)` of `b` (which also checks what else they must share)
/// within 1e-6 relative, only the order of the gather's sums changed;
/// most patches must be renumbered, or the test would show nothing.
fn same_light_renumbered(what: &str, a: &Archive, b: &Archive, q_of: impl Fn(usize) -> usize) {
    let opts = DistributeOptions { tolerance: 0.0, max_iterations: 12, ..Default::default() };
    let solve = |x: &Archive| distribute::distribute(&x.view(), &opts, &NoProgress).unwrap();
    let (r, t) = (solve(a), solve(b));
    assert_eq!(r.balance.iterations, t.balance.iterations);
    let (va, vb) = (a.view(), b.view());
    assert_eq!(va.link_end_count(), vb.link_end_count());
    let (mut worst, mut moved) = (0.0f64, 0);
    for p in 0..va.patch_count() {
        let q = q_of(p);
        moved += usize::from(q != p);
        assert_eq!(va.patch_hits[p], vb.patch_hits[q]);
        for c in 0..3 {
            let (x, y) = (r.radiance[p][c] as f64, t.radiance[q][c] as f64);
            worst = worst.max((x - y).abs() / x.abs().max(1e-3));
        }
    }
    assert!(moved > va.patch_count() / 2, "{what}: most patches renumbered ({moved})");
    eprintln!("{what}: worst patch {worst:.2e} apart, {moved} patches renumbered");
    assert!(worst < 1e-6, "{what}: worst patch {worst:.2e} apart");
}

#[test]
fn patches_in_tiles_give_the_light_of_patches_in_rows() {
    // Version 7 numbers a quad's patches in tiles (§5.5).
    use illumnet::geometry::PrimitiveKind;
    use illumnet::geometry::grid::{CellOrder, PatchGrid};
    let rows = cornell_with(|s| s.cell_order = CellOrder::Rows);
    let tiles = cornell_with(|s| s.cell_order = CellOrder::Tiles);
    let (vr, vt) = (rows.view(), tiles.view());
    same_light_renumbered("tiles against rows", &rows, &tiles, |p| {
        let prim = vr.patch_primitive[p] as usize;
        let (a, b) = (&vr.primitives[prim], &vt.primitives[prim]);
        assert_eq!((a.cell_order, b.cell_order), (0, 1));
        let grid = |order| PatchGrid { kind: PrimitiveKind::Quad, n_u: a.grid_u, n_v: a.grid_v, order };
        let (i, j) = grid(CellOrder::Rows).quad_ij(p as u32 - a.first_patch);
        (b.first_patch + grid(CellOrder::Tiles).quad_cell(i, j)) as usize
    });
}

#[test]
fn a_spatial_patch_order_gives_the_light_of_primitive_order() {
    // Version 11 may number primitives' patch blocks along a Morton curve
    // (§5.5); only the reordered file needs a version 11 reader.
    use illumnet::bake::PatchOrder;
    let plain = cornell_with(|s| s.patch_order = PatchOrder::Primitives);
    let spatial = cornell_with(|s| s.patch_order = PatchOrder::Spatial);
    assert_eq!((plain.header().version_read, spatial.header().version_read), (10, 11));
    let (vr, vs) = (plain.view(), spatial.view());
    same_light_renumbered("spatial against primitive order", &plain, &spatial, |p| {
        let prim = vr.patch_primitive[p];
        let (a, b) = (&vr.primitives[prim as usize], &vs.primitives[prim as usize]);
        let q = (b.first_patch + (p as u32 - a.first_patch)) as usize;
        assert_eq!(vs.patch_primitive[q], prim);
        assert_eq!(vr.patch_area[p], vs.patch_area[q]);
        q
    });
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
    check_pins("cornell", &got, &[0x9717b76660efbe06, 0x6fbad8bd5180eac4]);
    let hints = BuildHints { frequency: Some(8), patch_size: Some(0.2), ray_spacing: Some(0.05), ..Default::default() };
    let a = common::build_sequence_archive(&scene_file("fan_room.toml"), hints);
    let v = a.view();
    let got = [render_frames(&v, &default, &[0, 1, 2, 3, 4, 5], true), render_frames(&v, &default, &[40, 41], false)]
        .concat();
    let want = [
        0x904a880e1eba3793,
        0x716b0f2078f8f174,
        0x3527fbd76e94fe46,
        0x5a5ea9be7a81ef29,
        0xf18335981b8984f6,
        0xd1c1b2520b9bc63a,
        0x915957de6881a999,
        0x15e526ddfccd00a0,
    ];
    check_pins("fan room", &got, &want);
}
