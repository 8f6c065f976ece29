//! Meshes whose triangles are smaller than the patches: grouped into
//! patches of several (format-spec §5.5, `src/patch/mesh.rs`), checked
//! against closed forms and against the same surfaces built as quads.
#![allow(clippy::needless_range_loop)]

mod common;

use std::path::Path;

use common::*;
use glam::Vec3;
use illumnet::archive::layout::{PrimitiveRecord, kind, tag};
use illumnet::archive::{self, Archive, ArchiveError};
use illumnet::distribute::{self, DistributeOptions};
use illumnet::progress::NoProgress;
use illumnet::render::{self, RenderOptions, image_io};
use illumnet::scene::{BuildHints, Scene};

/// Writes an OBJ of `verts` and counter-clockwise `tris` (0-based).
fn write_obj(path: &Path, verts: &[Vec3], tris: &[[u32; 3]]) {
    let mut s = String::new();
    for v in verts {
        s += &format!("v {} {} {}\n", v.x, v.y, v.z);
    }
    for t in tris {
        s += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    std::fs::write(path, s).unwrap();
}

/// The quad `p` (corners counter-clockwise seen from its front) as n × n
/// cells, each split into two triangles.
fn grid_mesh(p: [Vec3; 4], n: u32) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let mut verts = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let (u, v) = (i as f32 / n as f32, j as f32 / n as f32);
            verts.push((1.0 - u) * (1.0 - v) * p[0] + u * (1.0 - v) * p[1] + u * v * p[2] + (1.0 - u) * v * p[3]);
        }
    }
    let at = |i: u32, j: u32| j * (n + 1) + i;
    let mut tris = Vec::new();
    for j in 0..n {
        for i in 0..n {
            tris.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            tris.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    (verts, tris)
}

/// A sphere of radius `r` about `c`: an icosahedron with each face cut
/// into 4^level triangles, projected; faces point inwards.
fn inward_sphere(c: Vec3, r: f32, level: u32) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    let mut verts: Vec<Vec3> = [
        (-1.0, t, 0.0),
        (1.0, t, 0.0),
        (-1.0, -t, 0.0),
        (1.0, -t, 0.0),
        (0.0, -1.0, t),
        (0.0, 1.0, t),
        (0.0, -1.0, -t),
        (0.0, 1.0, -t),
        (t, 0.0, -1.0),
        (t, 0.0, 1.0),
        (-t, 0.0, -1.0),
        (-t, 0.0, 1.0),
    ]
    .iter()
    .map(|&(x, y, z)| Vec3::new(x, y, z).normalize())
    .collect();
    let mut tris: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..level {
        let mut mid = std::collections::HashMap::new();
        let mut midpoint = |a: u32, b: u32, verts: &mut Vec<Vec3>| {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                verts.push(((verts[a as usize] + verts[b as usize]) * 0.5).normalize());
                verts.len() as u32 - 1
            })
        };
        let mut next = Vec::new();
        for [a, b, c] in tris {
            let (ab, bc, ca) = (midpoint(a, b, &mut verts), midpoint(b, c, &mut verts), midpoint(c, a, &mut verts));
            next.extend([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
        }
        tris = next;
    }
    // The icosahedron's faces point outwards: reverse them.
    let tris = tris.into_iter().map(|[a, b, c]| [a, c, b]).collect();
    (verts.into_iter().map(|v| c + r * v).collect(), tris)
}

/// A scene from TOML text whose meshes are in `dir`.
fn scene_in(dir: &Path, toml: &str) -> Scene {
    Scene::from_toml(toml, &dir.join("scene.toml"), dir).unwrap_or_else(|e| panic!("{e}"))
}

fn grouped_count(v: &illumnet::archive::InetView<'_>) -> usize {
    v.primitives.iter().filter(|r| r.kind == kind::GROUPED_TRIANGLE).count()
}

#[test]
fn form_factor_onto_a_mesh_of_small_triangles() {
    // Two directly opposed unit squares 1 m apart (analytic F = 0.19982),
    // the receiver a mesh of 12 800 triangles of 1.25 cm, below the default
    // 2.7 cm patches of this scene.
    let dir = tempfile::tempdir().unwrap();
    let (verts, tris) =
        grid_mesh([Vec3::new(0.0, 0.0, 1.0), Vec3::new(0.0, 1.0, 1.0), Vec3::ONE, Vec3::new(1.0, 0.0, 1.0)], 80);
    write_obj(&dir.path().join("receiver.obj"), &verts, &tris);
    let toml = format!(
        "{CAMERA}[[material]]\nname = 'black'\ntype = 'diffuse'\nreflectance = [0, 0, 0]\n\
         [[surface]]\nname = 'emitter'\nmaterial = 'black'\nemission = [1, 1, 1]\n\
         quad = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]\n\
         [[surface]]\nname = 'receiver'\nmaterial = 'black'\nmesh = 'receiver.obj'\n"
    );
    let archive = build_archive(&scene_in(dir.path(), &toml), BuildHints::default());
    let v = archive.view();
    assert_eq!(grouped_count(&v), 12_800, "every triangle grouped");
    let receiver_patches = patch_surface(&v).iter().filter(|&&s| s == 1).count();
    assert!((1000..6400).contains(&receiver_patches), "{receiver_patches} patches of the receiver");
    let sol = solve(&archive);
    let emitted: f64 = sol.balance.emitted.iter().sum();
    let f = surface_total(&v, &sol.received, 1) / emitted;
    let exact = 0.19982;
    eprintln!("onto a mesh: F = {f:.5}, analytic {exact}, error {:+.2}%", (f / exact - 1.0) * 100.0);
    assert!((f - exact).abs() / exact < 0.02, "F = {f:.5}, analytic {exact}");
}

#[test]
fn a_closed_sphere_of_small_triangles_reaches_e_over_one_minus_rho_everywhere() {
    // 20 480 triangles of about 3.5 cm facing in, all emitting (1, 2, 3),
    // reflecting ρ = 0.5: every patch, whatever mix of normals its
    // triangles have, must reach L_e/(1−ρ) = (2, 4, 6).
    let dir = tempfile::tempdir().unwrap();
    let (verts, tris) = inward_sphere(Vec3::ZERO, 1.0, 5);
    write_obj(&dir.path().join("sphere.obj"), &verts, &tris);
    let toml = format!(
        "{CAMERA}[[material]]\nname = 'grey'\ntype = 'diffuse'\nreflectance = [0.5, 0.5, 0.5]\n\
         [[surface]]\nname = 'sphere'\nmaterial = 'grey'\nemission = [1, 2, 3]\nmesh = 'sphere.obj'\n"
    );
    let archive = build_archive(&scene_in(dir.path(), &toml), BuildHints { buckets: Some(0), ..Default::default() });
    let v = archive.view();
    assert_eq!(grouped_count(&v), tris.len());
    assert!(v.patch_count() < tris.len() / 2, "{} patches of {} triangles", v.patch_count(), tris.len());
    let sol = solve(&archive);
    let mut worst = 0.0f64;
    for l in &sol.radiance {
        for (c, e) in [1.0f64, 2.0, 3.0].iter().enumerate() {
            worst = worst.max((l[c] as f64 / (2.0 * e) - 1.0).abs());
        }
    }
    let b = &sol.balance;
    let absorbed = b.absorbed.iter().sum::<f64>() / b.emitted.iter().sum::<f64>() - 1.0;
    eprintln!(
        "closed sphere of {} patches: worst patch {:.3}% off, absorbed/emitted - 1 = {absorbed:.2e}",
        v.patch_count(),
        worst * 100.0
    );
    // Measured 0.197% and -1.1e-4.
    assert!(worst < 0.005, "worst patch deviates {:.3}% from E/(1-rho)", worst * 100.0);
    assert!(absorbed.abs() < 1e-3, "absorbed/emitted - 1 = {absorbed:.2e}");
}

/// The Cornell box's text with its floor quad replaced by `floor`.
fn cornell_with_floor(floor: &str) -> String {
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell_box.toml")).unwrap();
    let quad = "quad = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.5592], [0.556, 0.0, 0.5592], [0.556, 0.0, 0.0]]";
    assert!(text.contains(quad));
    text.replacen(quad, floor, 1)
}

#[test]
fn a_floor_of_small_triangles_renders_like_the_floor_as_one_quad() {
    // The Cornell box's floor as 56 × 56 cells of 1 cm split in 6 272
    // triangles (1.4 cm hypotenuses, below the 1.5 cm patches): grouped,
    // its light interpolated over the mesh, it must give the picture of
    // the floor as a quad, contact shadows of the blocks included.
    let dir = tempfile::tempdir().unwrap();
    let (verts, tris) = grid_mesh(
        [Vec3::ZERO, Vec3::new(0.0, 0.0, 0.5592), Vec3::new(0.556, 0.0, 0.5592), Vec3::new(0.556, 0.0, 0.0)],
        56,
    );
    write_obj(&dir.path().join("floor.obj"), &verts, &tris);
    let render_of = |scene: &Scene| {
        let archive = build_archive(scene, BuildHints::default());
        let v = archive.view();
        let sol = distribute::distribute(&v, &DistributeOptions::default(), &NoProgress).unwrap();
        let light = render::DirectLight::new(&v, &sol, render::direct::DEFAULT_LIGHT_SAMPLES);
        let indirect = render::indirect_frame_radiance(&v, 0, &sol);
        let direct = render::Renderer::new(&v, RenderOptions::default()).frame_direct(0, &indirect, &light).0;
        let inet = render::render(&v, &sol.radiance, &RenderOptions::default());
        let absorbed: f64 = sol.balance.absorbed.iter().sum();
        (grouped_count(&v), direct, inet, absorbed)
    };
    let (_, quad_direct, quad_inet, quad_absorbed) = render_of(&Scene::cornell_box());
    let meshed = scene_in(dir.path(), &cornell_with_floor("mesh = 'floor.obj'"));
    let (grouped, mesh_direct, mesh_inet, mesh_absorbed) = render_of(&meshed);
    assert_eq!(grouped, tris.len());
    let direct = image_io::relative_l2(&mesh_direct, &quad_direct).unwrap();
    let inet = image_io::relative_l2(&mesh_inet, &quad_inet).unwrap();
    let absorbed = mesh_absorbed / quad_absorbed - 1.0;
    eprintln!("floor as a mesh against a quad: direct {direct:.4}, inet {inet:.4}, absorbed {absorbed:+.2e}");
    // Measured 0.0072, 0.0098 and +5.9e-4.
    assert!(direct < 0.012, "direct shading: relative L2 {direct:.4} between the mesh floor and the quad floor");
    assert!(inet < 0.02, "I-net shading: relative L2 {inet:.4} between the mesh floor and the quad floor");
    assert!(absorbed.abs() < 2e-3, "absorbed power differs by {absorbed:+.2e}");
}

/// Bytes of a small archive (a floor mesh under a lamp) with grouped
/// triangles or one patch per triangle, and its primitives.
fn mesh_archive_bytes(group_triangles: bool) -> (Vec<u8>, Vec<PrimitiveRecord>) {
    let dir = tempfile::tempdir().unwrap();
    let (verts, tris) = grid_mesh([Vec3::ZERO, Vec3::new(0.0, 0.0, 1.0), Vec3::new(1.0, 0.0, 1.0), Vec3::X], 12);
    write_obj(&dir.path().join("floor.obj"), &verts, &tris);
    let toml = format!(
        "{CAMERA}[[material]]\nname = 'grey'\ntype = 'diffuse'\nreflectance = [0.5, 0.5, 0.5]\n\
         [[surface]]\nname = 'lamp'\nmaterial = 'grey'\nemission = [1, 1, 1]\n\
         quad = [[0, 1, 0], [1, 1, 0], [1, 1, 1], [0, 1, 1]]\n\
         [[surface]]\nname = 'floor'\nmaterial = 'grey'\nmesh = 'floor.obj'\n"
    );
    let scene = scene_in(dir.path(), &toml);
    let mut settings = illumnet::bake::BuildSettings::resolve(&scene, BuildHints::default());
    settings.patch_size = 0.2;
    settings.frequency = 4;
    settings.group_triangles = group_triangles;
    let (contents, _) = illumnet::bake::build(&scene, &settings, &NoProgress).unwrap();
    (archive::write_to_vec(&contents).unwrap(), contents.primitives)
}

#[test]
fn grouped_triangles_round_trip_and_forgeries_are_refused() {
    // One patch per triangle: no TVTX.
    let (plain, _) = mesh_archive_bytes(false);
    let a = Archive::from_bytes(&plain).unwrap();
    assert_eq!((a.header().version_write, a.header().version_read), (11, 11), "a spatial patch order");
    assert!(a.sections().iter().all(|e| e.tag != tag::GROUPED_TRIANGLE_VERTICES));
    assert_eq!((grouped_count(&a.view()), a.view().patch_count()), (0, 288 + 25));
    let (good, prims) = mesh_archive_bytes(true);
    let a = Archive::from_bytes(&good).unwrap();
    assert_eq!((a.header().version_write, a.header().version_read), (11, 11));
    let v = a.view();
    let n = grouped_count(&v);
    assert_eq!(n, 288);
    assert_eq!(v.grouped_triangles.len(), n);
    let opened =
        prims.windows(2).filter(|w| w[1].kind == kind::GROUPED_TRIANGLE && w[1].first_patch != w[0].first_patch);
    assert!(opened.count() >= 8, "groups of several triangles");
    // `inspect` counts a group's triangles as one patch.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("floor.inet");
    std::fs::write(&path, &good).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_illumnet"))
        .args(["inspect", "--json", path.to_str().unwrap()])
        .output()
        .unwrap();
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let floor_patches = patch_surface(&v).iter().filter(|&&s| s == 1).count() as u64;
    assert_eq!(json["surface_details"][1]["patches"].as_u64(), Some(floor_patches), "{json}");
    let entry = |t: [u8; 4]| *a.sections().iter().find(|e| e.tag == t).unwrap();
    let (prim, tvtx) = (entry(tag::PRIMITIVES), entry(tag::GROUPED_TRIANGLE_VERTICES));
    let record = std::mem::size_of::<PrimitiveRecord>();
    // The first primitive joining a group.
    let joins = (1..prims.len())
        .find(|&i| prims[i].kind == kind::GROUPED_TRIANGLE && prims[i].first_patch == prims[i - 1].first_patch)
        .unwrap();
    let forge = |what: &str, at: usize, value: u32, says: &str| {
        let mut bad = good.clone();
        bad[at..at + 4].copy_from_slice(&value.to_le_bytes());
        archive::reseal(&mut bad);
        match Archive::from_bytes(&bad) {
            Err(e @ ArchiveError::Corrupt(_)) => assert!(e.to_string().contains(says), "{what}: {e}"),
            Err(e) => panic!("{what}: {e}"),
            Ok(_) => panic!("{what}: accepted"),
        }
    };
    let vertex_count = v.vertex_position.len() as u32;
    forge("a corner beyond the vertices", tvtx.offset as usize + 4, vertex_count, "TVTX[0]");
    forge("a corner among the grid vertices", tvtx.offset as usize + 4, 0, "TVTX[0]");
    let p = prim.offset as usize + joins * record;
    forge("a join of another patch", p + 16, prims[joins].first_patch ^ 1, "grouped triangle");
    forge("a TVTX row out of order", p + 20, prims[joins].first_vertex + 1, "grouped triangle");
    forge("a grouped triangle with a grid", p + 8, 2, "grouped triangle");
    forge("a join across surfaces", p + 4, 0, "grouped triangle");
    forge("a lamp quad taken for a grouped triangle", prim.offset as usize, kind::GROUPED_TRIANGLE, "PRIM");
    forge("an unknown kind", prim.offset as usize, 3, "unknown kind");
}
