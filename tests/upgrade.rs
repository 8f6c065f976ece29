//! `illumnet upgrade`: archives of format versions 6 and 9 (written by
//! those versions of illumnet, `tests/data/v6/README.md`,
//! `tests/data/v9/README.md`) rewritten as version 10 keep every section
//! but the link ends byte for byte, the same link ends in each row (by
//! bucket, then sender chunk, stably), and render what a fresh build
//! renders.

mod common;

use std::path::{Path, PathBuf};

use illumnet::archive::layout::{self, SectionEntry, tag};
use illumnet::archive::{Archive, ArchiveError, upgrade};
use illumnet::distribute::{self, DistributeOptions, Solution};
use illumnet::progress::NoProgress;
use illumnet::render::{self, RenderOptions, Renderer};
use illumnet::scene::{BuildHints, Scene};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/v6").join(name)
}

/// The stored bytes of every section of the file at `path`, by tag (the
/// table parsed by hand: the reader refuses version 6 files).
fn sections(bytes: &[u8]) -> Vec<(SectionEntry, &[u8])> {
    let header: layout::HeaderRecord = bytemuck::pod_read_unaligned(&bytes[..128]);
    (0..header.section_count as usize)
        .map(|i| {
            let at = header.table_offset as usize + 64 * i;
            let e: SectionEntry = bytemuck::pod_read_unaligned(&bytes[at..at + 64]);
            (e, &bytes[e.offset as usize..(e.offset + e.stored_length) as usize])
        })
        .collect()
}

/// Per patch, its link ends as the file at `bytes` (version 6 to 9)
/// stores them: (other, weight, direction, bucket), in row order.
fn old_rows(bytes: &[u8]) -> Vec<Vec<(u32, f32, u32, u8)>> {
    let s = sections(bytes);
    let find = |t: layout::Tag| s.iter().find(|(e, _)| e.tag == t).map(|(_, b)| *b);
    let u32s =
        |b: &[u8]| -> Vec<u32> { b.chunks_exact(4).map(|x| u32::from_le_bytes(x.try_into().unwrap())).collect() };
    let offsets: Vec<u64> =
        find(tag::LINK_OFFSETS).unwrap().chunks_exact(8).map(|x| u64::from_le_bytes(x.try_into().unwrap())).collect();
    let other = u32s(find(tag::LINK_OTHER).unwrap());
    let direction = u32s(find(tag::LINK_DIRECTION).unwrap());
    let weight: Vec<f32> = match find(tag::LINK_WEIGHT_V6) {
        Some(w) => u32s(w).into_iter().map(f32::from_bits).collect(),
        None => {
            let mut w: Vec<f32> = find(tag::LINK_COUNT).unwrap().iter().map(|&c| c as f32).collect();
            for x in find(tag::LINK_ESCAPES).unwrap().chunks_exact(16) {
                let end = u64::from_le_bytes(x[..8].try_into().unwrap()) as usize;
                w[end] = f32::from_le_bytes(x[8..12].try_into().unwrap());
            }
            w
        }
    };
    let bucket = find(tag::LINK_BUCKET_V9).map_or_else(|| vec![0; other.len()], <[u8]>::to_vec);
    (0..offsets.len() - 1)
        .map(|q| {
            (offsets[q] as usize..offsets[q + 1] as usize)
                .map(|e| (other[e], weight[e], direction[e], bucket[e]))
                .collect()
        })
        .collect()
}

/// Per patch, the link ends of the version 10 archive `a`, decoded.
fn new_rows(a: &Archive) -> Vec<Vec<(u32, f32, u32, u8)>> {
    let v = a.view();
    let l = *v.links.resident().unwrap();
    let w = l.window();
    (0..v.patch_count())
        .map(|q| w.ends_of(q).map(|(e, o, k)| (o, l.weight.get(e), l.direction[e], k)).collect())
        .collect()
}

/// Checks that the upgraded `new` (open as `a`) holds `old`'s sections but
/// the link ends byte for byte, and its link ends re-ordered by (bucket,
/// sender chunk) within each row, stably.
fn same_but_link_order(name: &str, old: &[u8], new: &[u8], a: &Archive) {
    let links = upgrade::OLD_LINK_COLUMNS;
    let (old_s, new_s) = (sections(old), sections(new));
    for (e, bytes) in old_s.iter().filter(|(e, _)| !links.contains(&e.tag)) {
        let (_, b) = new_s.iter().find(|(n, _)| n.tag == e.tag).unwrap();
        assert_eq!(bytes, b, "{name}: section {}", illumnet::archive::tag_name(e.tag));
    }
    let mut want = old_rows(old);
    for row in &mut want {
        row.sort_by_key(|&(o, _, _, k)| (k, o as usize / layout::CHUNK_PATCHES));
    }
    let got = new_rows(a);
    assert_eq!(got.len(), want.len());
    for (q, (g, w)) in got.iter().zip(&want).enumerate() {
        assert!(g == w, "{name}: patch {q}'s link ends differ");
    }
    assert!(got.iter().map(Vec::len).sum::<usize>() > 100, "{name}: links");
}

fn images(a: &Archive) -> Vec<Vec<f32>> {
    let v = a.view();
    let opts = DistributeOptions { tolerance: 1e-7, ..Default::default() };
    let frames = v.sequence.map_or(1, |s| s.frames());
    let mut renderer = Renderer::new(&v, RenderOptions { samples_per_axis: 2, ..Default::default() });
    (0..frames)
        .map(|k| {
            let s: Solution = distribute::distribute_frame(&v, k, &opts, &NoProgress).unwrap();
            renderer.frame(k, &render::frame_radiance(&v, k, &s)).pixels.iter().flat_map(|p| *p).collect()
        })
        .collect()
}

fn relative_l2(a: &[f32], b: &[f32]) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
    let den: f64 = b.iter().map(|y| (*y as f64).powi(2)).sum();
    (num / den).sqrt()
}

#[test]
fn version_6_archives_upgrade_to_the_same_sections_and_light() {
    let cases = [
        ("v6_glossy_floor.inet", Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/glossy_floor.toml"), 0.25, 0.06),
        ("v6_moving_box.inet", data("moving_box.toml"), 0.4, 0.1),
    ];
    let dir = tempfile::tempdir().unwrap();
    for (name, scene, patch, rays) in cases {
        let old = std::fs::read(data(name)).unwrap();
        // The reader refuses it, saying what to do.
        let err = Archive::open(&data(name)).err().unwrap();
        assert!(matches!(err, ArchiveError::Outdated { written: 6 }), "{err}");
        assert!(err.to_string().contains("illumnet upgrade"), "{err}");

        let out = dir.path().join(name);
        let done = upgrade::upgrade(&data(name), &out).unwrap();
        assert_eq!(done.bytes_before, old.len() as u64);
        let new = std::fs::read(&out).unwrap();
        assert_eq!(done.bytes_after, new.len() as u64);
        let a = Archive::open(&out).unwrap();
        // Patches stay in primitive order: readable by version 10.
        assert_eq!((a.header().version_write, a.header().version_read), (11, 10));
        assert_eq!(done.version_before, 6);
        same_but_link_order(name, &old, &new, &a);
        assert!(new.len() < old.len(), "{name}: 6 bytes fewer per link end");

        // The light of a fresh build of the same scene (whose
        // patches are numbered in tiles, so sums run in another order),
        // its rays traced as version 6 traced them (by the BVH).
        let scene = Scene::from_file(&scene).unwrap();
        let hints = BuildHints { patch_size: Some(patch), ray_spacing: Some(rays), frequency: Some(3), buckets: None };
        let fresh = common::build_sequence_archive_traced(&scene, hints, illumnet::bake::TraceMethod::Bvh);
        for (k, (got, want)) in images(&a).iter().zip(images(&fresh)).enumerate() {
            assert!(want.iter().any(|&x| x > 0.0), "{name} frame {k}: black");
            let e = relative_l2(got, &want);
            assert!(e < 1e-4, "{name} frame {k}: relative L2 {e:e} against a fresh build");
        }
    }
}

#[test]
fn version_9_archives_upgrade_to_the_bytes_of_a_fresh_build() {
    // Written by the version 9 illumnet (`tests/data/v9/README.md`): a
    // still of 120 253 patches (two sender chunks: rows re-ordered) and a
    // 4-frame sequence with buckets.
    use illumnet::archive::{self, layout::CHUNK_PATCHES};
    use illumnet::bake::{self, BuildSettings};
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let v9 = |name: &str| root.join("tests/data/v9").join(name);
    let dir = tempfile::tempdir().unwrap();
    let chunks = dir.path().join("v9_chunks.inet");
    let packed = std::fs::File::open(v9("v9_chunks.inet.zst")).unwrap();
    std::fs::write(&chunks, zstd::decode_all(packed).unwrap()).unwrap();
    let hints = |patch, rays, frequency| BuildHints {
        patch_size: Some(patch),
        ray_spacing: Some(rays),
        frequency: Some(frequency),
        buckets: None,
    };
    let cases = [
        ("chunks", chunks, root.join("scenes/cornell_box.toml"), hints(0.004, 0.012, 2)),
        ("moving box", v9("v9_moving_box.inet"), data("moving_box.toml"), hints(0.4, 0.1, 3)),
    ];
    for (name, path, scene, hints) in cases {
        let old = std::fs::read(&path).unwrap();
        let err = Archive::open(&path).err().unwrap();
        assert!(matches!(err, ArchiveError::Outdated { written: 9 }), "{err}");
        assert!(err.to_string().contains("illumnet upgrade"), "{err}");
        let out = dir.path().join("up.inet");
        let done = upgrade::upgrade(&path, &out).unwrap();
        assert_eq!((done.version_before, done.already_current), (9, false));
        let new = std::fs::read(&out).unwrap();
        let a = Archive::open(&out).unwrap();
        same_but_link_order(name, &old, &new, &a);
        // What a build of the same scene in primitive order writes (the
        // upgrade keeps the file's patch numbers), its rays traced as
        // version 9 traced them (by the BVH), byte for byte.
        let scene = Scene::from_file(&scene).unwrap();
        let mut settings = BuildSettings::resolve(&scene, hints);
        settings.prototype_library = None;
        settings.trace_method = bake::TraceMethod::Bvh;
        settings.patch_order = illumnet::patch::order::PatchOrder::Primitives;
        let fresh = match scene.animation.is_some() {
            true => bake::build_sequence(&scene, &settings, &NoProgress).unwrap().contents,
            false => bake::build(&scene, &settings, &NoProgress).unwrap().0,
        };
        assert!(archive::write_to_vec(&fresh).unwrap() == new, "{name}: not the bytes of a fresh build");
        if name == "chunks" {
            // Rows with ends in both chunks, re-ordered by the upgrade.
            let v = a.view();
            assert!(v.patch_count() > CHUNK_PATCHES);
            let runs = v.links.resident().unwrap().runs;
            let both = (0..v.patch_count()).filter(|&q| {
                let r = runs.of(q);
                r.iter().any(|x| x.chunk == 0) && r.iter().any(|x| x.chunk == 1)
            });
            assert!(both.count() > 100, "{name}: rows across chunks");
            let moved = old_rows(&old).iter().zip(new_rows(&a)).filter(|(o, n)| **o != *n).count();
            assert!(moved > 100, "{name}: {moved} rows re-ordered");
        }
    }
}

#[test]
fn upgrades_replace_in_place_refuse_the_wrong_files_and_leave_damage_alone() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("a.inet");
    std::fs::copy(data("v6_glossy_floor.inet"), &path).unwrap();
    upgrade::upgrade(&path, &path).unwrap();
    Archive::open(&path).unwrap();
    // Once is enough: again, nothing happens.
    let before = std::fs::read(&path).unwrap();
    assert!(upgrade::upgrade(&path, &path).unwrap().already_current);
    assert_eq!(std::fs::read(&path).unwrap(), before);
    // To another file, a current archive is copied (and checked), its
    // folder made.
    let copy = dir.path().join("copies/copy.inet");
    assert!(upgrade::upgrade(&path, &copy).unwrap().already_current);
    assert_eq!(std::fs::read(&copy).unwrap(), before);
    // A damaged current archive is not copied.
    let mut bad = before.clone();
    let (e, _) = sections(&before).into_iter().find(|(e, _)| e.tag == tag::PATCH_CENTRE).unwrap();
    bad[e.offset as usize + 4] ^= 0x40;
    let damaged_current = dir.path().join("damaged_current.inet");
    std::fs::write(&damaged_current, &bad).unwrap();
    // Folders made for a write that fails are removed again.
    let copy2 = dir.path().join("fresh/copy2.inet");
    let err = upgrade::upgrade(&damaged_current, &copy2).unwrap_err().to_string();
    assert!(
        err.contains("damaged_current.inet") && err.contains("nothing was written") && err.contains("PCEN"),
        "{err}"
    );
    assert!(!copy2.exists());
    // The same file spelt another way: nothing to do, nothing written.
    let spelt = dir.path().join(".").join("a.inet");
    assert!(upgrade::same_file(&path, &spelt) && !upgrade::same_file(&path, &copy));
    assert!(upgrade::upgrade(&path, &spelt).unwrap().already_current);
    assert_eq!(std::fs::read(&path).unwrap(), before);
    // A flipped byte in LWGT: refused, nothing written, nothing left.
    let mut bytes = std::fs::read(data("v6_glossy_floor.inet")).unwrap();
    let (e, _) = sections(&bytes.clone()).into_iter().find(|(e, _)| e.tag == tag::LINK_WEIGHT_V6).unwrap();
    bytes[e.offset as usize + 8] ^= 0x10;
    let damaged = dir.path().join("damaged.inet");
    std::fs::write(&damaged, &bytes).unwrap();
    let out = dir.path().join("made/for/out.inet");
    let err = upgrade::upgrade(&damaged, &out).unwrap_err().to_string();
    assert!(err.contains("LWGT") && err.contains("checksum"), "{err}");
    assert!(!out.exists());
    let mut left: Vec<_> =
        std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    left.sort();
    assert_eq!(left, ["a.inet", "copies", "damaged.inet", "damaged_current.inet"], "no temporaries left");
}

#[test]
fn the_cli_says_to_upgrade_and_upgrades() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("box.inet");
    std::fs::copy(data("v6_moving_box.inet"), &path).unwrap();
    let bin = env!("CARGO_BIN_EXE_illumnet");
    let png = dir.path().join("f_%d.png");
    let render = || {
        std::process::Command::new(bin)
            .args(["render", "-q", path.to_str().unwrap(), "-o", png.to_str().unwrap()])
            .output()
            .unwrap()
    };
    let out = render();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(4), "{err}");
    assert!(err.contains("format version 6") && err.contains("illumnet upgrade"), "{err}");
    // `verify` says the same, as a finding: the file is sound, not corrupt.
    let out = std::process::Command::new(bin).args(["verify", path.to_str().unwrap()]).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(4), "{text}");
    assert!(text.contains("illumnet upgrade") && !text.contains("corrupt"), "{text}");
    let out = std::process::Command::new(bin).args(["upgrade", path.to_str().unwrap()]).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success() && text.contains("to format version 11"), "{text}");
    let out = render();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(dir.path().join("f_3.png").exists());
}

/// Issue 42, §8: a file that claims version 12 over a version-9 layout
/// was "nothing to do" in place (exit 0) though it does not open; now
/// refused as corrupt (exit 4), the file left as it was.
#[test]
fn an_in_place_upgrade_of_a_current_version_that_does_not_open_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("claims_12.inet");
    let mut bytes =
        std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/v9/v9_moving_box.inet")).unwrap();
    let mut h: layout::HeaderRecord = bytemuck::pod_read_unaligned(&bytes[..layout::HEADER_SIZE]);
    (h.version_write, h.version_read) = (12, layout::VERSION_READ);
    bytes[..layout::HEADER_SIZE].copy_from_slice(bytemuck::bytes_of(&h));
    illumnet::archive::reseal(&mut bytes);
    std::fs::write(&path, &bytes).unwrap();
    let err = upgrade::upgrade(&path, &path).unwrap_err();
    assert!(matches!(err, ArchiveError::Corrupt(_)), "{err}");
    let text = err.to_string();
    assert!(text.contains("claims_12.inet") && text.contains("does not validate"), "{text}");
    assert_eq!(std::fs::read(&path).unwrap(), bytes, "left as it was");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_illumnet"))
        .args(["upgrade", path.to_str().unwrap()])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(4), "{text}");
    assert!(!text.contains("nothing to do"), "{text}");
}
