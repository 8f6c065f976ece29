//! The two ways a build's rays find their hits (`build --tracer`, issue
//! 41): scan conversion tests each ray against the references whose leaf
//! box it meets, exactly the ones BVH traversal tests, so the archives are
//! the same byte for byte: a still, a sequence (temporal instances and
//! frame deltas), a glossy archive and a mesh. And how many rays slip
//! through the seams of a sealed mesh room (issue 41, item 2).

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
    let (bvh, scan) = (built(&scene, h, TraceMethod::Bvh), built(&scene, h, TraceMethod::Scan));
    assert!(bvh == scan, "the sealed room's archives differ");
    let archive = illumnet::archive::Archive::from_bytes(&bvh).unwrap();
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
    let b = common::solve(&archive).balance;
    let s = |x: &[f64; 3]| x.iter().sum::<f64>();
    eprintln!(
        "sealed mesh room: {escaped_rays} of {rays} rays escaped; emitted {:.4} W, escaped {:.2e} W, back faces {:.4} W",
        s(&b.emitted),
        s(&b.escaped),
        s(&b.back_faces)
    );
    // Measured (2026-12-07): 9 of 39 479 501 rays slip through the seams
    // (2.3·10⁻⁷), the same with either tracer: a ray through a shared edge
    // that both triangles' tests turn down. A watertight scan converter
    // must bring this to 0 (issue 41); until then it is a bound.
    assert!(escaped_rays <= 9, "{escaped_rays} rays escaped the sealed room (9 measured)");
    assert!(s(&b.escaped) < 1e-6 * s(&b.emitted), "{b:?}");
}
