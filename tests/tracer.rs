//! The two ways a build's rays find their hits (`build --tracer`, issue
//! 41): the BVH tracer tests each ray against the primitives traversal
//! reaches; the scan converter rasterises each primitive onto a pair's ray
//! grid by a watertight fill rule (primitives smaller than the ray spacing
//! squared it leaves to the rays, through their BVH). They may disagree
//! only for rays within rounding of an edge: counted here and bounded,
//! with the light solved from either archive (energy balance within 10⁻⁴,
//! images within 10⁻³: one ray at an edge can carry a visible share of a
//! patch's light). And how many rays slip through the seams of a sealed
//! mesh room (item 2): none with scan conversion.

mod common;

use std::collections::HashMap;

use illumnet::archive::{self, Archive};
use illumnet::bake::{self, BuildSettings, TraceMethod};
use illumnet::distribute::{self, DistributeOptions};
use illumnet::progress::NoProgress;
use illumnet::render::{self, RenderOptions, image_io};
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

/// Frame 0's link ends of an archive, weight by `(patch, other patch,
/// direction)`, and the total weight.
fn link_ends(a: &Archive) -> (HashMap<(u32, u32, u32), f64>, f64) {
    let v = a.view();
    let all: Vec<u32> = (0..v.patch_count() as u32).collect();
    let rows = v.link_rows(&all).unwrap();
    let (mut ends, mut total) = (HashMap::new(), 0.0);
    for p in 0..all.len() {
        let (other, weight, direction) = rows.ends(p);
        for i in 0..other.len() {
            *ends.entry((p as u32, other[i], direction[i])).or_insert(0.0) += weight[i] as f64;
            total += weight[i] as f64;
        }
    }
    (ends, total)
}

/// How two archives of one scene differ: the share of link-end weight
/// and of `H_p` that moved, and the solved light's worst relative
/// differences (the energy balance's absorbed and back-face power, and
/// each frame's image, relative L2).
struct Difference {
    links: f64,
    hits: f64,
    balance: f64,
    image: f64,
}

fn difference(a: &Archive, b: &Archive) -> Difference {
    let ((ea, wa), (eb, wb)) = (link_ends(a), link_ends(b));
    let moved: f64 = ea.iter().map(|(k, w)| (w - eb.get(k).unwrap_or(&0.0)).abs()).sum::<f64>()
        + eb.iter().filter(|(k, _)| !ea.contains_key(k)).map(|(_, w)| w).sum::<f64>();
    let (va, vb) = (a.view(), b.view());
    assert_eq!(va.patch_count(), vb.patch_count());
    let hits = |v: &illumnet::archive::InetView<'_>| v.patch_hits.iter().map(|&h| h as f64).sum::<f64>();
    let hit_moved: f64 = va.patch_hits.iter().zip(vb.patch_hits).map(|(&x, &y)| (x as f64 - y as f64).abs()).sum();
    let opts = DistributeOptions { tolerance: 1e-7, ..Default::default() };
    let frames = va.sequence.as_ref().map_or(1, |s| s.frames());
    let (mut balance, mut image): (f64, f64) = (0.0, 0.0);
    for k in 0..frames {
        let (sa, sb) = (
            distribute::distribute_frame(&va, k, &opts, &NoProgress).unwrap(),
            distribute::distribute_frame(&vb, k, &opts, &NoProgress).unwrap(),
        );
        let total = |x: &[f64; 3]| x.iter().sum::<f64>();
        for (x, y) in [(sa.balance.absorbed, sb.balance.absorbed), (sa.balance.back_faces, sb.balance.back_faces)] {
            balance = balance.max((total(&x) - total(&y)).abs() / total(&sa.balance.emitted));
        }
        let r = RenderOptions { samples_per_axis: 2, ..Default::default() };
        let (ia, ib) = (render::render_frame(&va, k, &sa.radiance, &r), render::render_frame(&vb, k, &sb.radiance, &r));
        image = image.max(image_io::relative_l2(&ia, &ib).unwrap());
    }
    Difference { links: moved / (wa + wb), hits: hit_moved / hits(&va), balance, image }
}

#[test]
fn scan_conversion_differs_from_the_bvh_tracer_only_at_edges() {
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
    // Rays 1 cm apart: all but 0.2% of the bunny's triangles are smaller
    // than the spacing squared, so the scan converter leaves them to the
    // rays through their BVH (`RASTER_MIN_AREA`) and rasterises the box.
    cases.push(("bunny.toml", hints(0.02, 4, 0.01)));
    cases.push(("cornell_box.toml", hints(0.05, 8, 0.01)));
    for (name, h) in cases {
        let scene = common::scene_file(name);
        let (bvh, scan) = (built(&scene, h, TraceMethod::Bvh), built(&scene, h, TraceMethod::Scan));
        let (bvh, scan) = (Archive::from_bytes(&bvh).unwrap(), Archive::from_bytes(&scan).unwrap());
        let d = difference(&bvh, &scan);
        eprintln!(
            "{name}: link-end weight moved {:.2e}, hits moved {:.2e}, balance {:.2e}, image {:.2e}",
            d.links, d.hits, d.balance, d.image
        );
        // Bounds about twice what was measured (2026-12-07, docs/notebook/
        // 2026-12-07-scan-conversion.md): link ends 2.4·10⁻⁶–4.9·10⁻⁵ of
        // the weight, hits 2.7–7.5·10⁻⁶, balance ≤ 1.3·10⁻⁵. Each moved ray
        // went to a neighbouring patch (within rounding of their edge).
        // Images differ by 1.1–6.0·10⁻⁵ but for the Cornell box at 5 cm
        // patches: 5.3·10⁻⁴, where one ray from the light moved to the
        // ceiling beside it (coplanar, sharing the edge), and a back-wall patch lit by few rays of the
        // light changed by 1.2%: the weight of one ray, not a bias.
        assert!(d.links < 1e-4, "{name}: {:.2e} of the link-end weight differs", d.links);
        assert!(d.hits < 2e-5, "{name}: {:.2e} of the hits differ", d.hits);
        assert!(d.balance < 1e-4, "{name}: the energy balance differs by {:.2e}", d.balance);
        assert!(d.image < 1e-3, "{name}: the images differ by {:.2e}", d.image);
    }
}

/// A closed unit cube of `n × n` squares a face, each two triangles,
/// wound inward, as OBJ text (each face with vertices of its own: the
/// cube's edges meet in equal positions, not shared indices).
fn sealed_cube_obj(n: u32) -> String {
    use std::fmt::Write;
    let (x, y, z) = ([1.0f32, 0.0, 0.0], [0.0f32, 1.0, 0.0], [0.0f32, 0.0, 1.0]);
    // (corner, U, V) with U × V the inward normal.
    let faces = [
        ([0.0, 0.0, 0.0], z, x),
        ([0.0, 1.0, 0.0], x, z),
        ([0.0, 0.0, 0.0], y, z),
        ([1.0, 0.0, 0.0], z, y),
        ([0.0, 0.0, 0.0], x, y),
        ([0.0, 0.0, 1.0], y, x),
    ];
    let mut obj = String::new();
    let mut base = 1;
    for (o, u, v) in faces {
        for j in 0..=n {
            for i in 0..=n {
                let (a, b) = (i as f32 / n as f32, j as f32 / n as f32);
                let p: Vec<f32> = (0..3).map(|c| o[c] + u[c] * a + v[c] * b).collect();
                writeln!(obj, "v {} {} {}", p[0], p[1], p[2]).unwrap();
            }
        }
        let at = |i: u32, j: u32| base + j * (n + 1) + i;
        for j in 0..n {
            for i in 0..n {
                let (p00, p10, p11, p01) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
                writeln!(obj, "f {p00} {p10} {p11}\nf {p00} {p11} {p01}").unwrap();
            }
        }
        base += (n + 1) * (n + 1);
    }
    obj
}

#[test]
fn rays_escaping_a_sealed_mesh_room_are_counted_and_bounded() {
    // A cube room of 6 × 2 · 7² triangles (their seams along the faces'
    // diagonals and the cube's edges) with a lamp hung inside: every ray
    // leaving an inward face should meet another face, so no light should
    // escape (what meets the lamp's back is absorbed there, not escaped).
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("room.obj"), sealed_cube_obj(7)).unwrap();
    let toml = format!(
        "{}[[material]]\nname = 'grey'\ntype = 'diffuse'\nreflectance = [0.5, 0.5, 0.5]\n\
         [[material]]\nname = 'black'\ntype = 'diffuse'\nreflectance = [0, 0, 0]\n\
         [[surface]]\nname = 'room'\nmaterial = 'grey'\nmesh = 'room.obj'\n\
         [[surface]]\nname = 'lamp'\nmaterial = 'black'\nemission = [10, 10, 10]\n\
         quad = [[0.3, 0.9, 0.3], [0.7, 0.9, 0.3], [0.7, 0.9, 0.7], [0.3, 0.9, 0.7]]\n",
        common::CAMERA
    );
    let scene = illumnet::scene::Scene::from_toml(&toml, &dir.path().join("room.toml"), dir.path()).unwrap();
    let h = BuildHints { patch_size: Some(0.1), frequency: Some(8), ray_spacing: Some(0.005), buckets: None };
    for method in [TraceMethod::Bvh, TraceMethod::Scan] {
        let archive = Archive::from_bytes(&built(&scene, h, method)).unwrap();
        let escaped = escaped_rays(&archive);
        // Measured (2026-12-07): 9 of 39 479 501 rays slip through the
        // BVH tracer's seams (2.3·10⁻⁷): a ray through a shared edge that
        // both triangles' tests turn down. The scan converter's fill rule
        // gives every such ray to exactly one of them.
        let most = if method == TraceMethod::Scan { 0 } else { 9 };
        assert!(escaped <= most, "{method:?}: {escaped} rays escaped the sealed room (at most {most})");
    }
}

/// Rays that escaped a closed room (each patch's hits less those that
/// reached a facing patch and those that met a back face), counted
/// exactly from the archive, with the solved energy balance's escaped
/// power checked against them.
fn escaped_rays(archive: &Archive) -> i64 {
    let v = archive.view();
    // Per patch, the rays that left it (its hits) less those that reached a
    // facing patch (its link ends' counts) and those that met a back face:
    // the rays that escaped, counted exactly (the energy balance's escaped
    // power also holds the rounding of the shares, ~10⁻⁷ of the power).
    let all: Vec<u32> = (0..v.patch_count() as u32).collect();
    let rows = v.link_rows(&all).unwrap();
    let back = v.patch_back_hits.unwrap();
    let (mut escaped_rays, mut rays) = (0i64, 0i64);
    for (p, (&hits, &back)) in v.patch_hits.iter().zip(back).enumerate() {
        let linked: f64 = rows.ends(p).1.iter().map(|&w| w as f64).sum();
        let left = hits as i64 - linked.round() as i64 - back as i64;
        assert!(left >= 0, "patch {p}: more rays linked than hit it");
        (escaped_rays, rays) = (escaped_rays + left, rays + hits as i64);
    }
    let b = common::solve(archive).balance;
    let s = |x: &[f64; 3]| x.iter().sum::<f64>();
    eprintln!(
        "sealed mesh room: {escaped_rays} of {rays} rays escaped; emitted {:.4} W, escaped {:.2e} W, back faces {:.4} W",
        s(&b.emitted),
        s(&b.escaped),
        s(&b.back_faces)
    );
    assert!(s(&b.escaped) < 1e-6 * s(&b.emitted), "{b:?}");
    escaped_rays
}
