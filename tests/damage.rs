//! The damage matrix (issue 14): a still, a glossy, a sequence and a mesh archive,
//! every section in turn flipped, zeroed, given a wrong length, cut at
//! every section boundary, and forged with hostile values under valid
//! checksums; each case must be a clear error or give finite light and a
//! finite image, never a panic or a NaN. Run in CI in a debug build with
//! overflow checks too (`tools/test.sh`).

mod common;

use std::panic::{AssertUnwindSafe, catch_unwind};

use bytemuck::pod_read_unaligned;
use illumnet::archive::layout::{self, HeaderRecord, SectionEntry};
use illumnet::archive::{self, Archive, ArchiveContents, ArchiveError, tag_name};
use illumnet::bake::{self, BuildSettings};
use illumnet::distribute::{DistributeError, DistributeOptions, Distributor, Lighting};
use illumnet::progress::NoProgress;
use illumnet::render::{self, RenderOptions, Renderer};
use illumnet::scene::{BuildHints, Scene};

const ROOM: &str = r#"
[camera]
position = [1, 1, -1.5]
look_at = [1, 1, 1]
fov_y_deg = 60
width = 12
height = 12

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
"#;

const GLOSSY: &str = r#"
[[material]]
name = "metal"
type = "rough_conductor"
specular = [0.9, 0.8, 0.7]
alpha_u = 0.2
alpha_v = 0.4

[[surface]]
name = "plate"
material = "metal"
quad = [[0.5, 0.3, 0.5], [1.5, 0.3, 0.5], [1.5, 0.3, 1.5], [0.5, 0.3, 1.5]]
"#;

const MOVING: &str = r#"
[animation]
frames = 3
fps = 10

[[surface]]
name = "mover"
material = "grey"
box = { min = [0.3, 0.2, 0.3], max = [0.7, 0.6, 0.7] }
keyframes = [{ frame = 0 }, { frame = 2, translate = [0.8, 0.2, 0.6] }]
"#;

fn hints() -> BuildHints {
    BuildHints { patch_size: Some(0.3), frequency: Some(3), ray_spacing: Some(0.06), buckets: None }
}

fn contents(text: &str) -> ArchiveContents {
    let scene = Scene::from_toml(text, std::path::Path::new("damage.toml"), std::path::Path::new(".")).unwrap();
    let mut settings = BuildSettings::resolve(&scene, hints());
    settings.prototype_library = None;
    bake::build_sequence(&scene, &settings, &NoProgress).unwrap().contents
}

fn archives() -> Vec<(&'static str, ArchiveContents)> {
    vec![
        ("still", with_escapes(contents(ROOM))),
        ("glossy", contents(&format!("{ROOM}{GLOSSY}"))),
        ("sequence", contents(&format!("{ROOM}{MOVING}"))),
        ("mesh", mesh_contents()),
    ]
}

/// The room with a bumpy mesh of 128 small triangles on its floor (the
/// OBJ written to `dir`), grouped into patches of several (`PRIM.kind` 2,
/// `TVTX`).
fn bumps(dir: &std::path::Path) -> Scene {
    let obj = common::grid_obj(8, (0.5, 0.5), 1.0, |x, z| 0.05 + 0.03 * (7.0 * x).sin() * (5.0 * z).cos());
    std::fs::write(dir.join("bumps.obj"), obj).unwrap();
    let text = format!("{ROOM}\n[[surface]]\nname = \"bumps\"\nmaterial = \"grey\"\nmesh = \"bumps.obj\"\n");
    Scene::from_toml(&text, &dir.join("damage.toml"), dir).unwrap()
}

/// Mesh detail (§5.15) on `scene`'s bumps, so that PSHD, TXHD and TXPX
/// are damaged too: a 2 × 2 texture, uvs the corners' (x, z), and normals
/// leaning with the bumps.
fn with_detail(scene: &mut Scene) {
    use illumnet::scene::texture::{Shading, TextureImage, Wrap};
    scene.textures.push(TextureImage {
        width: 2,
        height: 2,
        wrap: [Wrap::Repeat; 2],
        nearest: true,
        srgb: vec![200, 40, 40, 40, 200, 40, 40, 40, 200, 200, 200, 200],
    });
    let bumps = scene.surfaces.iter_mut().find(|s| s.name == "bumps").unwrap();
    bumps.shading = bumps
        .primitives
        .iter()
        .map(|p| Shading {
            uv: p.p.map(|c| glam::Vec2::new(c.x, c.z)),
            normal: Shading::to_local(p, p.p.map(|c| glam::Vec3::new(c.x - 1.0, 2.0, c.z - 1.0))),
            texture: 0,
            tint: [1.5, 1.6, 1.7],
        })
        .collect();
}

fn mesh_contents() -> ArchiveContents {
    let dir = tempfile::tempdir().unwrap();
    let mut scene = bumps(dir.path());
    with_detail(&mut scene);
    let mut settings = BuildSettings::resolve(&scene, hints());
    settings.prototype_library = None;
    let c = bake::build_sequence(&scene, &settings, &NoProgress).unwrap().contents;
    let mut groups: Vec<u32> = c.primitives.iter().filter(|r| r.kind == 2).map(|r| r.first_patch).collect();
    groups.dedup();
    assert!(c.grouped_triangles.len() == 128 && groups.len() < 64, "{} groups", groups.len());
    // Each primitive's detail is its own, after grouping reordered them:
    // its uvs are its corners' (x, z).
    let sh = c.shading.as_ref().expect("mesh detail");
    assert_eq!(sh.textures.len(), 1);
    let bumps = c.surfaces.len() as u32 - 1;
    let mut checked = 0;
    for (r, d) in c.primitives.iter().zip(&sh.primitives) {
        if r.surface == bumps {
            for k in 0..3 {
                assert_eq!(d.uvs[k], [r.corners[k][0], r.corners[k][2]], "a primitive's uvs are another's");
            }
            checked += 1;
        }
    }
    assert_eq!(checked, 128);
    c
}

/// `c` with every 97th link-end weight lowered by a half: weights that are
/// not whole numbers go to `LCNX` (§5.10), so that its bytes are damaged
/// too (builds make whole counts, which all fit `LCNT` here).
fn with_escapes(mut c: ArchiveContents) -> ArchiveContents {
    for w in c.link_weight.iter_mut().step_by(97) {
        *w -= 0.5;
    }
    c
}

fn header(bytes: &[u8]) -> HeaderRecord {
    pod_read_unaligned(&bytes[..layout::HEADER_SIZE])
}

fn entries(bytes: &[u8]) -> Vec<SectionEntry> {
    let h = header(bytes);
    let t = h.table_offset as usize;
    bytes[t..t + h.section_count as usize * layout::ENTRY_SIZE]
        .chunks_exact(layout::ENTRY_SIZE)
        .map(pod_read_unaligned)
        .collect()
}

fn set_entry(bytes: &mut [u8], i: usize, f: impl FnOnce(&mut SectionEntry)) {
    let t = header(bytes).table_offset as usize + i * layout::ENTRY_SIZE;
    let mut e: SectionEntry = pod_read_unaligned(&bytes[t..t + layout::ENTRY_SIZE]);
    f(&mut e);
    bytes[t..t + layout::ENTRY_SIZE].copy_from_slice(bytemuck::bytes_of(&e));
}

/// What an archive's bytes led to.
#[derive(Debug)]
enum Outcome {
    /// Refused when opened.
    Refused(ArchiveError),
    /// Opened, then refused by the distribution (a frame's delta, a
    /// non-finite result).
    Stopped(DistributeError),
    /// Every frame distributed and rendered, all finite.
    Finite,
}

/// Opens, distributes every frame and renders it; `Err`
/// for a panic or a non-finite value.
fn outcome(bytes: &[u8]) -> Result<Outcome, String> {
    catch_unwind(AssertUnwindSafe(|| -> Result<Outcome, String> {
        let a = match Archive::from_bytes(bytes) {
            Ok(a) => a,
            Err(e) => return Ok(Outcome::Refused(e)),
        };
        let v = a.view();
        let opts = DistributeOptions { max_iterations: 60, ..Default::default() };
        let d = match Distributor::new(&v, &opts, &Lighting::from_view(&v)) {
            Ok(d) => d,
            Err(e) => return Ok(Outcome::Stopped(e)),
        };
        let last = v.sequence.map_or(0, |s| s.frames() - 1);
        let mut renderer = Renderer::new(&v, RenderOptions { samples_per_axis: 1, ..Default::default() });
        for f in 0..=last {
            let s = match d.frame(f, None, &NoProgress) {
                Ok(s) => s,
                Err(e) => return Ok(Outcome::Stopped(e)),
            };
            let finite = |x: &[[f32; 3]]| x.iter().flatten().all(|c| c.is_finite());
            if !finite(&s.radiance) {
                return Err(format!("frame {f}: a non-finite radiance was handed out"));
            }
            let light = render::DirectLight::new(&v, &s, 1);
            let (image, direct) = renderer.frame_direct(f, &render::indirect_frame_radiance(&v, f, &s), &light);
            if !finite(&image.pixels) || !finite(&direct.pixels) {
                return Err(format!("frame {f}: a non-finite pixel"));
            }
        }
        Ok(Outcome::Finite)
    }))
    .unwrap_or_else(|p| {
        let msg = p.downcast_ref::<String>().cloned().or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()));
        Err(format!("panic: {}", msg.unwrap_or_default()))
    })
}

/// Runs `cases` (name, bytes) and fails listing every panic, non-finite
/// output, or case `must_refuse` yet accepted.
fn run(label: &str, cases: impl Iterator<Item = (String, Vec<u8>, bool)>) -> [usize; 3] {
    let mut failures = Vec::new();
    let mut counts = [0usize; 3];
    for (name, bytes, must_refuse) in cases {
        match outcome(&bytes) {
            Err(e) => failures.push(format!("{label} {name}: {e}")),
            Ok(o) => {
                let k = match &o {
                    Outcome::Refused(e) => {
                        // Each kind of damage has its own, specific error.
                        let (m, tag) = (e.to_string(), name.split(':').next().unwrap_or(""));
                        let want = if name.contains("flipped") || name.contains("zeroed") {
                            Some(format!("section {tag}: checksum mismatch"))
                        } else if name.contains(": cut at") || name.starts_with("cut at") {
                            Some("truncated or appended to".to_string())
                        } else if name.contains("version") {
                            Some("version".to_string())
                        } else {
                            None
                        };
                        if let Some(w) = want
                            && !m.contains(&w)
                        {
                            failures.push(format!("{label} {name}: `{m}` does not say `{w}`"));
                        }
                        0
                    }
                    // An archive that opens distributes to finite light (§7):
                    // a non-finite result is "please report it" (issue 42, §1).
                    Outcome::Stopped(e @ DistributeError::NotFinite { .. }) => {
                        failures.push(format!("{label} {name}: opened, then {e}"));
                        1
                    }
                    Outcome::Stopped(_) => 1,
                    Outcome::Finite => 2,
                };
                counts[k] += 1;
                if must_refuse && k == 2 {
                    failures.push(format!("{label} {name}: accepted"));
                }
            }
        }
    }
    assert!(failures.is_empty(), "{} of the damage cases failed:\n{}", failures.len(), failures.join("\n"));
    eprintln!(
        "{label}: refused at open {}, stopped by the distribution {}, finite {}",
        counts[0], counts[1], counts[2]
    );
    counts
}

#[test]
fn flipped_zeroed_misdeclared_and_cut_archives_are_errors() {
    for (label, c) in archives() {
        let good = archive::write_to_vec(&c).unwrap();
        assert!(matches!(outcome(&good), Ok(Outcome::Finite)), "{label}: the undamaged archive");
        let es = entries(&good);
        let mut cases: Vec<(String, Vec<u8>, bool)> = Vec::new();
        for (i, e) in es.iter().enumerate() {
            let name = tag_name(e.tag);
            let (a, n) = (e.offset as usize, e.stored_length as usize);
            for at in [0, n / 2, n.saturating_sub(1)] {
                if n > 0 {
                    let mut b = good.clone();
                    b[a + at] ^= 0x5a;
                    cases.push((format!("{name}: byte {at} flipped"), b, true));
                }
            }
            let z = n.min(64);
            if good[a..a + z].iter().any(|&x| x != 0) {
                let mut b = good.clone();
                b[a..a + z].fill(0);
                cases.push((format!("{name}: first {z} bytes zeroed"), b, true));
            }
            for (what, f) in [
                ("length + 1", (|e: &mut SectionEntry| e.length += 1) as fn(&mut SectionEntry)),
                ("stored length + 1", |e| e.stored_length += 1),
                ("length - 1", |e| e.length = e.length.saturating_sub(1)),
                ("count + 1", |e| e.count += 1),
                ("count u64::MAX", |e| e.count = u64::MAX),
                ("record size 0", |e| e.record_size = if e.record_size == 0 { 1 } else { 0 }),
                ("offset + 64", |e| e.offset += 64),
            ] {
                let mut b = good.clone();
                set_entry(&mut b, i, f);
                archive::reseal(&mut b);
                if b == good {
                    continue; // "length - 1" of an empty section (LCNX when no weight escapes)
                }
                // A moved section may land on bytes that happen to pass.
                cases.push((format!("{name}: table entry {what}"), b, what != "offset + 64"));
            }
            for cut in [a, a + n] {
                cases.push((format!("{name}: cut at {cut}"), good[..cut].to_vec(), true));
            }
        }
        cases.push(("cut at the table".into(), good[..header(&good).table_offset as usize].to_vec(), true));
        for (what, at, value) in [
            ("version_write 0", 8, 0u32),
            ("version_read 0", 12, 0),
            ("version_read above this reader's", 12, illumnet::archive::layout::READER_VERSION + 1),
            ("version_write 6", 8, 6),
        ] {
            let mut b = good.clone();
            b[at..at + 4].copy_from_slice(&value.to_le_bytes());
            archive::reseal(&mut b);
            cases.push((what.into(), b, true));
        }
        let counts = run(label, cases.into_iter());
        assert!(counts[2] <= es.len(), "{label}: refused / stopped / finite {counts:?}");
    }
}

#[test]
fn hostile_values_under_valid_checksums_never_give_nan() {
    let words: [(&str, u32); 10] = [
        ("u32::MAX", u32::MAX),
        ("i32::MIN", 0x8000_0000),
        ("i32::MAX", 0x7fff_ffff),
        ("NaN", f32::NAN.to_bits()),
        ("inf", f32::INFINITY.to_bits()),
        ("-inf", f32::NEG_INFINITY.to_bits()),
        ("-1.0", (-1.0f32).to_bits()),
        ("zero", 0),
        ("3e38", 3e38f32.to_bits()),
        ("1e-45", 1),
    ];
    let mut total = [0usize; 3];
    for (label, c) in archives() {
        let good = archive::write_to_vec(&c).unwrap();
        let mut cases = Vec::new();
        for e in entries(&good) {
            let name = tag_name(e.tag);
            let (a, n) = (e.offset as usize, e.stored_length as usize / 4 * 4);
            if n == 0 {
                continue;
            }
            for at in [0, (n / 8) * 4, n - 4] {
                for (what, w) in words {
                    let mut b = good.clone();
                    b[a + at..a + at + 4].copy_from_slice(&w.to_le_bytes());
                    if b == good {
                        continue;
                    }
                    archive::reseal(&mut b);
                    cases.push((format!("{name}: word at {at} = {what}"), b, false));
                }
            }
        }
        let counts = run(label, cases.into_iter());
        for k in 0..3 {
            total[k] += counts[k];
        }
    }
    // Most forgeries are refused; the rest must give finite light.
    assert!(total[0] > 2 * total[2], "refused / stopped / finite: {total:?}");
}

/// Frame 1's records of the sequence archive with `f` applied, re-encoded.
fn forged_deltas(c: &ArchiveContents, f: impl FnOnce(&mut Vec<layout::DeltaRecord>, &ArchiveContents)) -> Vec<u8> {
    let a = Archive::from_bytes(&archive::write_to_vec(c).unwrap()).unwrap();
    let s = a.view().sequence.unwrap();
    let mut frames: Vec<Vec<layout::DeltaRecord>> = (0..s.frames()).map(|k| s.frame_delta(k).unwrap()).collect();
    f(&mut frames[1], c);
    let mut c = c.clone();
    c.sequence.as_mut().unwrap().deltas = archive::deltas::EncodedDeltas::from_frames(&frames).unwrap();
    archive::write_to_vec(&c).unwrap()
}

fn stopped_with(bytes: &[u8], want: &str) {
    match outcome(bytes) {
        Ok(Outcome::Stopped(e)) => assert!(e.to_string().contains(want), "{e}"),
        other => panic!("expected the distribution to stop with `{want}`, got {other:?}"),
    }
}

#[test]
fn deltas_that_drive_a_weight_negative_or_huge_are_refused_naming_frame_and_record() {
    let c = contents(&format!("{ROOM}{MOVING}"));
    for count in [i32::MIN, i32::MAX, -(1 << 20), 1 << 20] {
        let b = forged_deltas(&c, |r, _| r[0].count = count);
        stopped_with(&b, "DELT frame 1, record 0: count");
    }
    // A removal one ray larger than frame 0 gave the link, at either end.
    let a = Archive::from_bytes(&archive::write_to_vec(&c).unwrap()).unwrap();
    let v = a.view();
    let records = v.sequence.unwrap().frame_delta(1).unwrap();
    let l = *v.links.resident().unwrap();
    let w = l.window();
    let base = |q: u32, direction: u32, other: u32, bucket: u8| -> f64 {
        w.ends_of(q as usize)
            .filter(|&(e, o, k)| l.direction[e] == direction && o == other && k == bucket)
            .map(|(e, _, _)| l.weight.get(e) as f64)
            .sum()
    };
    let k = records
        .iter()
        .position(|d| {
            let most = v.patch_hits[d.a as usize].min(v.patch_hits[d.b as usize]) as f64;
            d.count < 0 && base(d.a, 2 * d.pair, d.b, d.bucket_a) < most
        })
        .expect("frame 1 removes rays somewhere");
    let d = records[k];
    let held = base(d.a, 2 * d.pair, d.b, d.bucket_a) as i32;
    let b = forged_deltas(&c, |r, _| r[k].count = -held - 1);
    stopped_with(&b, &format!("DELT frame 1, record {k}: removes {} rays from patch {}'s end", held + 1, d.a));
    // A removal from a link frame 0 does not have (a patch and itself).
    let b = forged_deltas(&c, |r, _| {
        r[k].b = r[k].a;
        r.sort_by_key(|d| (d.pair, d.a, d.b, d.bucket_a, d.bucket_b));
    });
    stopped_with(&b, "which frame 0 gave 0: a negative weight");
}

fn refused_with(c: &ArchiveContents, want: &str) {
    let bytes = archive::write_to_vec(c).unwrap();
    match Archive::from_bytes(&bytes) {
        Err(e) => assert!(e.to_string().contains(want), "expected `{want}`, got: {e}"),
        Ok(_) => panic!("accepted; expected `{want}`"),
    }
}

#[test]
fn values_within_old_rules_that_made_nan_are_refused_at_open() {
    let c = contents(ROOM);
    let linked = (0..c.patch_hits.len()).find(|&p| c.link_offsets[p + 1] > c.link_offsets[p] + 1).unwrap();
    let mut x = c.clone();
    x.patch_hits[linked] = 1;
    refused_with(&x, "more than the 1 that cross it");
    let mut x = c.clone();
    x.link_weight[c.link_offsets[linked] as usize] = 3e38;
    refused_with(&x, "LCNT");
    let mut x = c.clone();
    x.surfaces[1].emission = [1e38; 3];
    refused_with(&x, "SURF[1]: emission");
    let mut x = c.clone();
    x.patch_area[linked] = 1e-45;
    refused_with(&x, &format!("PARE[{linked}]"));
    let mut x = c.clone();
    x.patch_area[linked] = 1e30;
    refused_with(&x, &format!("PARE[{linked}]"));
    let mut x = c.clone();
    x.materials[0].params[13] = f32::NAN;
    refused_with(&x, "MATL[0]: non-finite");
    // Found by fuzzing (archive_forge): an `up` of 2e-38 made NaN rays.
    let mut x = c.clone();
    x.camera.up = [0.0, 2e-38, 0.0];
    refused_with(&x, "CAMR");
    // Found by fuzzing too: a view vector whose squares underflow in f32.
    let mut x = c.clone();
    (x.camera.position, x.camera.look_at) = ([0.0, 1e-30, 0.0], [0.0, 0.0, 1e-30]);
    refused_with(&x, "CAMR");
    let mut g = contents(&format!("{ROOM}{GLOSSY}"));
    g.reflectance.as_mut().unwrap().prototypes[0].ior = [f32::NEG_INFINITY; 3];
    refused_with(&g, "PTAB[0]");
}

#[test]
fn a_delt_entry_with_a_wrong_count_is_refused() {
    let good = archive::write_to_vec(&contents(&format!("{ROOM}{MOVING}"))).unwrap();
    let i = entries(&good).iter().position(|e| e.tag == layout::tag::DELTAS).unwrap();
    for count in [4, u64::MAX] {
        let mut b = good.clone();
        set_entry(&mut b, i, |e| e.count = count);
        archive::reseal(&mut b);
        let e = Archive::from_bytes(&b).err().expect("accepted");
        assert!(e.to_string().contains("DELT: count"), "{e}");
    }
}

#[test]
fn an_unused_glossy_material_builds_an_archive_that_opens() {
    let text = ROOM.to_string()
        + "\n[[material]]\nname = \"spare\"\ntype = \"rough_conductor\"\nspecular = [0.9, 0.9, 0.9]\nalpha = 0.3\n";
    let c = contents(&text);
    assert!(c.reflectance.is_none());
    let a = Archive::from_bytes(&archive::write_to_vec(&c).unwrap()).unwrap();
    assert!(matches!(outcome(&archive::write_to_vec(&c).unwrap()), Ok(Outcome::Finite)));
    assert_eq!(a.view().materials.len(), 2);
}

/// Writes the fuzzers' seed corpus (`fuzz/corpus/`, committed): the
/// archives of this file's scenes (built coarsely, to stay small), their
/// frames' delta bytes, the scene files, and a few OBJ meshes. Run by hand:
/// `cargo test --release --test damage -- --ignored write_fuzz_seed_corpus`.
#[test]
#[ignore]
fn write_fuzz_seed_corpus() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/corpus");
    let put = |target: &str, name: &str, bytes: &[u8]| {
        std::fs::create_dir_all(root.join(target)).unwrap();
        std::fs::write(root.join(target).join(name), bytes).unwrap();
    };
    let coarse = |text: &str| {
        let scene = Scene::from_toml(text, std::path::Path::new("seed.toml"), std::path::Path::new(".")).unwrap();
        let hints = BuildHints { patch_size: Some(0.4), frequency: Some(2), ray_spacing: Some(0.08), buckets: None };
        let mut settings = BuildSettings::resolve(&scene, hints);
        settings.prototype_library = None;
        archive::write_to_vec(&bake::build_sequence(&scene, &settings, &NoProgress).unwrap().contents).unwrap()
    };
    for (name, text) in
        [("still", ROOM.to_string()), ("glossy", format!("{ROOM}{GLOSSY}")), ("sequence", format!("{ROOM}{MOVING}"))]
    {
        let bytes = coarse(&text);
        assert!(bytes.len() <= 262_144, "{name}: {} bytes, above the fuzzers' -max_len", bytes.len());
        put("archive_open", &format!("{name}-archive"), &bytes);
        put("scene_toml", &format!("{name}.toml"), text.as_bytes());
        if name == "sequence" {
            let a = Archive::from_bytes(&bytes).unwrap();
            let s = a.view().sequence.unwrap();
            for (f, ix) in s.index.iter().enumerate() {
                let stored = s.frame_stored(f as u32).unwrap();
                let mut input = vec![1u8];
                input.extend_from_slice(&(ix.count as u32).to_le_bytes());
                input.extend_from_slice(&stored);
                put("frame_delta", &format!("frame{f}"), &input);
            }
        }
    }
    // Grouped triangles (format version 8): PRIM kind 2 and TVTX; with
    // mesh detail since version 9 (PSHD, TXHD, TXPX).
    let dir = tempfile::tempdir().unwrap();
    let mut scene = bumps(dir.path());
    with_detail(&mut scene);
    let hints = BuildHints { patch_size: Some(0.4), frequency: Some(2), ray_spacing: Some(0.08), buckets: None };
    let mut settings = BuildSettings::resolve(&scene, hints);
    settings.prototype_library = None;
    let (mesh, _) = bake::build(&scene, &settings, &NoProgress).unwrap();
    assert!(!mesh.grouped_triangles.is_empty());
    let bytes = archive::write_to_vec(&mesh).unwrap();
    assert!(bytes.len() <= 262_144, "mesh: {} bytes, above the fuzzers' -max_len", bytes.len());
    put("archive_open", "mesh-archive", &bytes);
    for (i, script) in [&[0u8][..], &[1], &[2], &[2, 5, 0, 0, 0, 0, 3, 0xff, 0xff, 0xff, 0x7f]].iter().enumerate() {
        put("archive_forge", &format!("script{i}"), script);
    }
    for f in std::fs::read_dir(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes")).unwrap() {
        let p = f.unwrap().path();
        if p.extension().is_some_and(|e| e == "toml") {
            put("scene_toml", &p.file_name().unwrap().to_string_lossy(), &std::fs::read(&p).unwrap());
        }
    }
    put("scene_obj", "triangle.obj", b"v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\n");
    put("scene_obj", "quad.obj", b"# a quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//1 4//1\n");
    put("scene_obj", "groups.obj", b"o a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\ng b\nv 0 0 1\nf -1 -2 -3\n");
}

/// Opens `bytes`, distributes every frame and renders: refused at open
/// with `want` in its message, never a non-finite result.
fn refused_bytes_with(bytes: &[u8], want: &str) {
    match outcome(bytes) {
        Ok(Outcome::Refused(e)) => assert!(e.to_string().contains(want), "expected `{want}`, got: {e}"),
        other => panic!("expected a refusal at open with `{want}`, got {other:?}"),
    }
}

/// Issue 42, §1: the forgeries of the probe that opened and verified yet
/// made non-finite light (exit 7) are refused at open naming the section
/// and record; products of fields at their bounds give finite light.
#[test]
fn forged_products_and_denormals_that_made_infinite_light_are_refused_at_open() {
    let c = contents(ROOM);
    let linked = (0..c.patch_hits.len()).find(|&p| c.link_offsets[p + 1] > c.link_offsets[p] + 1).unwrap();
    // PEXP's bound (§7): A·N/δ².
    fn bound(c: &ArchiveContents, p: usize) -> f32 {
        (c.patch_area[p] as f64 * c.directions.len() as f64 / (c.build.ray_spacing_m as f64).powi(2)) as f32
    }
    // A denormal area, its expected exposure within its (old) bound.
    for exposure in [0.0, 1e-3] {
        let mut x = c.clone();
        x.patch_area[linked] = 1e-45;
        x.patch_expected_hits[linked] = exposure;
        refused_with(&x, &format!("PARE[{linked}]: area 1e-45 m² neither 0 nor at least 1e-18"));
    }
    // No absolute slack: a zero area has no expected hits.
    let mut x = c.clone();
    x.patch_area[linked] = 0.0;
    x.patch_expected_hits[linked] = 1e-3;
    refused_with(&x, &format!("PEXP[{linked}]"));
    // The exposure bound lifted by a tiny ray spacing, in a sequence.
    let mut s = contents(&format!("{ROOM}{MOVING}"));
    s.build.ray_spacing_m = 1e-20;
    s.patch_expected_hits[linked] = 3e38;
    refused_with(&s, "BILD: ray spacing 1e-20 m below 1e-6 m");
    // Solid angles: one of 3e38 (verify flagged it, open did not), and
    // each doubled (every one within 4π, the sum 8π).
    let mut x = c.clone();
    x.directions[0].solid_angle_sr = 3e38;
    refused_with(&x, "DIRS[0]: solid angle 3e38 sr outside (1e-9, 4π]");
    let mut x = c.clone();
    x.directions.iter_mut().for_each(|d| d.solid_angle_sr *= 2.0);
    refused_with(&x, "DIRS: solid angles sum to 25.13");
    // Products at their bounds: the least area with the most exposure,
    // the least spacing, a patch crossed by one ray: finite light.
    for (what, f) in [
        (
            "least area, most exposure",
            (|x: &mut ArchiveContents, p: usize| {
                x.patch_area[p] = 1e-18;
                x.patch_expected_hits[p] = bound(x, p);
            }) as fn(&mut ArchiveContents, usize),
        ),
        ("one ray, the most exposure", |x, p| {
            x.patch_expected_hits[p] = bound(x, p);
        }),
        ("least spacing, most exposure", |x, p| {
            x.build.ray_spacing_m = 1e-6;
            x.patch_expected_hits[p] = bound(x, p);
        }),
    ] {
        let mut x = c.clone();
        f(&mut x, linked);
        let bytes = archive::write_to_vec(&x).unwrap();
        match outcome(&bytes) {
            Ok(Outcome::Finite | Outcome::Refused(_)) => {}
            Ok(Outcome::Stopped(e @ DistributeError::NotFinite { .. })) => panic!("{what}: opened, then {e}"),
            Ok(Outcome::Stopped(_)) => {}
            Err(e) => panic!("{what}: {e}"),
        }
    }
}

/// Issue 42, §8: one energy rule (k_d + k_s ≤ 1 + 10⁻⁶, `limits::
/// conserves_energy`) at open and in `render`: 1.0000009 opens and
/// renders (it exited 3 in `render`), 1.00001 is refused at open.
#[test]
fn reflectance_plus_specular_has_one_tolerance_at_open_and_render() {
    let glossy = GLOSSY
        .replace("rough_conductor", "broad_specular")
        .replace("specular = [0.9, 0.8, 0.7]", "reflectance = [0.1, 0.1, 0.1]\nspecular = [0.9, 0.8, 0.7]");
    let c = contents(&format!("{ROOM}{glossy}"));
    let m = c.materials.iter().position(|m| m.model == layout::model::BROAD_SPECULAR).unwrap();
    let mut x = c.clone();
    (x.materials[m].params[0], x.materials[m].params[3]) = (0.5, 0.500_000_9);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("edge.inet");
    std::fs::write(&path, archive::write_to_vec(&x).unwrap()).unwrap();
    Archive::open(&path).expect("1.0000009 is within the rule");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_illumnet"))
        .args(["render", "-q", path.to_str().unwrap(), "-o", dir.path().join("edge.png").to_str().unwrap()])
        .output()
        .unwrap();
    assert!(out.status.success(), "{:?}: {}", out.status, String::from_utf8_lossy(&out.stderr));
    let mut x = c.clone();
    (x.materials[m].params[0], x.materials[m].params[3]) = (0.5, 0.50001);
    refused_with(&x, &format!("MATL[{m}]: reflectance + specular above 1"));
}

/// `bytes` with its `BILD` changed by `f`, resealed.
fn forged_build(bytes: &[u8], f: impl FnOnce(&mut layout::BuildRecord)) -> Vec<u8> {
    let mut b = bytes.to_vec();
    let e = entries(&b).into_iter().find(|e| e.tag == layout::tag::BUILD).unwrap();
    let size = std::mem::size_of::<layout::BuildRecord>();
    let at = e.offset as usize;
    let mut r: layout::BuildRecord = pod_read_unaligned(&b[at..at + size]);
    f(&mut r);
    b[at..at + size].copy_from_slice(bytemuck::bytes_of(&r));
    archive::reseal(&mut b);
    b
}

/// Issue 42, §5: counts the file cannot hold are corruption before a
/// render plans memory from them: 2³¹ patches in `BILD` (exit 6, "needs
/// 1.40 TiB", where open said exit 4) and a `DIDX` count of 2³² − 1
/// (passed open, planned 736 GiB).
#[test]
fn counts_the_file_cannot_hold_are_corrupt_before_memory_is_planned() {
    let dir = tempfile::tempdir().unwrap();
    let bin = env!("CARGO_BIN_EXE_illumnet");
    let still = archive::write_to_vec(&contents(ROOM)).unwrap();
    let patches = forged_build(&still, |b| b.patch_count = 1 << 31);
    let seq = archive::write_to_vec(&contents(&format!("{ROOM}{MOVING}"))).unwrap();
    let mut didx = seq.clone();
    let e = entries(&seq).into_iter().find(|e| e.tag == layout::tag::DELTA_INDEX).unwrap();
    let size = std::mem::size_of::<layout::DeltaIndexRecord>();
    let at = e.offset as usize + size;
    let mut r: layout::DeltaIndexRecord = pod_read_unaligned(&didx[at..at + size]);
    r.count = u32::MAX as u64;
    didx[at..at + size].copy_from_slice(bytemuck::bytes_of(&r));
    archive::reseal(&mut didx);
    for (name, bytes, want) in [
        ("patches.inet", &patches, "section PCEN: "),
        ("didx.inet", &didx, "DIDX[1]: 4294967295 records, more than its"),
    ] {
        refused_bytes_with(bytes, want);
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).unwrap();
        let e = Archive::summary(&path).err().unwrap_or_else(|| panic!("{name}: the summary accepted it"));
        assert!(e.to_string().contains(want), "{name}: {e}");
        for args in [vec!["render", "-q", path.to_str().unwrap(), "-o"], vec!["verify"], vec!["inspect"]] {
            let mut args = args.clone();
            let png = dir.path().join("x.png");
            if args[0] == "render" {
                args.push(png.to_str().unwrap());
            } else {
                args.push(path.to_str().unwrap());
            }
            let out = std::process::Command::new(bin).args(&args).output().unwrap();
            let text = String::from_utf8_lossy(&out.stderr).into_owned() + &String::from_utf8_lossy(&out.stdout);
            assert_eq!(out.status.code(), Some(4), "{name} {}: {text}", args[0]);
            assert!(!text.contains("TiB") && !text.contains("GiB"), "{name} {}: {text}", args[0]);
        }
    }
}

/// Issue 42, §1: `render --set` obeys the scene reader's bound on
/// emission (10⁹): 10³⁸ was accepted and the error then blamed the
/// archive; now a usage error naming the option (exit 3), and 10⁹ renders.
#[test]
fn set_emission_beyond_the_scene_readers_bound_is_refused_naming_the_option() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("room.inet");
    std::fs::write(&path, archive::write_to_vec(&contents(ROOM)).unwrap()).unwrap();
    let render = |set: &str| {
        std::process::Command::new(env!("CARGO_BIN_EXE_illumnet"))
            .args(["render", "-q", path.to_str().unwrap(), "-o", dir.path().join("x.png").to_str().unwrap()])
            .args(["--set", set])
            .output()
            .unwrap()
    };
    let out = render("lamp.emission=1e38,1e38,1e38");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{err}");
    assert!(err.contains("--set `lamp.emission=1e38,1e38,1e38`: emission must be in [0, 1e9]"), "{err}");
    assert!(!err.contains("corrupt") && !err.contains("report"), "{err}");
    let out = render("lamp.emission=1e9,1e9,1e9");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
}

/// Issue 42, §1: a glossy patch with a single ray in one direction pair
/// and none in the others (`NDHC`): refused at open, or finite light.
/// Reproduces the probe's case (NaN and 5e35 at patch 0): the entry scale
/// `c_i` is now held so that no ray carries more than arrived.
#[test]
fn a_glossy_patch_with_one_ray_in_one_pair_gives_finite_light_or_is_refused() {
    let c = contents(&format!("{ROOM}{GLOSSY}"));
    let r = c.reflectance.as_ref().unwrap();
    let half = c.directions.len() / 2;
    let mut outcomes = Vec::new();
    for k in [0, r.patches.len() / 2, r.patches.len() - 1] {
        let q = r.patches[k].patch as usize;
        let sum: u64 = r.hits[k * half..(k + 1) * half].iter().map(|&h| h as u64).sum();
        eprintln!("patch {q}: PHIT {}, NDHC sum {sum}", c.patch_hits[q]);
        for pair in [0, half / 3, half - 1] {
            let mut x = c.clone();
            let xr = x.reflectance.as_mut().unwrap();
            xr.hits[k * half..(k + 1) * half].fill(0);
            xr.hits[k * half + pair] = 1;
            if !xr.back_hits.is_empty() {
                xr.back_hits[k * half..(k + 1) * half].fill(0);
            }
            let bytes = archive::write_to_vec(&x).unwrap();
            match outcome(&bytes) {
                Ok(Outcome::Stopped(e @ DistributeError::NotFinite { .. })) => {
                    panic!("patch {q}, pair {pair}: opened, then {e}")
                }
                Ok(o @ (Outcome::Finite | Outcome::Refused(_))) => {
                    outcomes.push(format!("{o:?}").chars().take(60).collect::<String>())
                }
                Ok(o) => panic!("patch {q}, pair {pair}: {o:?}"),
                Err(e) => panic!("patch {q}, pair {pair}: {e}"),
            }
        }
    }
    eprintln!("{outcomes:#?}");
}
