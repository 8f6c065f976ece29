//! `illumnet upgrade`: version 6 archives (written by the version 6
//! illumnet, `tests/data/v6/README.md`) rewritten as version 7 keep every
//! section but the weights byte for byte, the same weights exactly, and
//! render what a fresh build renders.

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
        assert_eq!((a.header().version_write, a.header().version_read), (9, 7));
        // Every section but the weights byte for byte; the weights exact.
        let (old_s, new_s) = (sections(&old), sections(&new));
        for (e, bytes) in &old_s {
            if e.tag == tag::LINK_WEIGHT_V6 {
                let want: Vec<f32> =
                    bytes.chunks_exact(4).map(|x| f32::from_le_bytes([x[0], x[1], x[2], x[3]])).collect();
                let got = a.view().links.resident().unwrap().weight.to_vec();
                assert_eq!(got, want, "{name}: weights");
                continue;
            }
            let (_, b) = new_s.iter().find(|(n, _)| n.tag == e.tag).unwrap();
            assert_eq!(bytes, b, "{name}: section {}", illumnet::archive::tag_name(e.tag));
        }
        assert!(new.len() < old.len(), "{name}: 3 bytes fewer per link end");

        // The light of a fresh version 7 build of the same scene (whose
        // patches are numbered in tiles, so sums run in another order).
        let scene = Scene::from_file(&scene).unwrap();
        let hints = BuildHints { patch_size: Some(patch), ray_spacing: Some(rays), frequency: Some(3), buckets: None };
        let fresh = common::build_sequence_archive(&scene, hints);
        for (k, (got, want)) in images(&a).iter().zip(images(&fresh)).enumerate() {
            assert!(want.iter().any(|&x| x > 0.0), "{name} frame {k}: black");
            let e = relative_l2(got, &want);
            assert!(e < 1e-4, "{name} frame {k}: relative L2 {e:e} against a fresh build");
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
    // A flipped byte in LWGT: refused, nothing written, nothing left.
    let mut bytes = std::fs::read(data("v6_glossy_floor.inet")).unwrap();
    let (e, _) = sections(&bytes.clone()).into_iter().find(|(e, _)| e.tag == tag::LINK_WEIGHT_V6).unwrap();
    bytes[e.offset as usize + 8] ^= 0x10;
    let damaged = dir.path().join("damaged.inet");
    std::fs::write(&damaged, &bytes).unwrap();
    let out = dir.path().join("out.inet");
    let err = upgrade::upgrade(&damaged, &out).unwrap_err().to_string();
    assert!(err.contains("LWGT") && err.contains("checksum"), "{err}");
    assert!(!out.exists());
    let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(left.len(), 2, "no temporaries left: {left:?}");
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
    let out = std::process::Command::new(bin).args(["upgrade", path.to_str().unwrap()]).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success() && text.contains("to format version 9"), "{text}");
    let out = render();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(dir.path().join("f_3.png").exists());
}
