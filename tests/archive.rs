//! Archive format: round trip, corruption and truncation give errors (never
//! panics), mmap and in-memory readers agree, builds are deterministic.

mod common;

use common::*;
use illumnet::archive::{self, Archive, ArchiveError, layout};
use illumnet::bake::{self, BuildSettings};
use illumnet::progress::NoProgress;
use illumnet::scene::{BuildHints, Scene};

/// A quick, coarse Cornell box build.
fn small_contents() -> archive::ArchiveContents {
    let scene = Scene::cornell_box();
    let hints = BuildHints { patch_size: Some(0.08), frequency: Some(4), ray_spacing: Some(0.02), buckets: None };
    bake::build(&scene, &BuildSettings::resolve(&scene, hints), &NoProgress).unwrap().0
}

#[test]
fn round_trip_through_a_file_and_memory() {
    let contents = small_contents();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("box.inet");
    let size = archive::write(&path, &contents).unwrap();
    assert_eq!(size, std::fs::metadata(&path).unwrap().len());
    // No temporary files are left behind.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    let mapped = Archive::open(&path).unwrap();
    let owned = Archive::from_bytes(&std::fs::read(&path).unwrap()).unwrap();
    for a in [&mapped, &owned] {
        let v = a.view();
        assert_eq!(*v.build, contents.build);
        let l = v.links.resident().expect("open and from_bytes hold the link ends");
        assert_eq!(l.window().other_ids(), contents.link_other);
        assert_eq!(l.window().buckets(), contents.link_bucket);
        assert_eq!(l.weight.to_vec(), contents.link_weight);
        assert_eq!(v.link_offsets, &contents.link_offsets[..]);
        assert_eq!(v.patch_hits, &contents.patch_hits[..]);
        assert_eq!(v.primitives, &contents.primitives[..]);
        assert_eq!(a.meta(), &contents.meta);
    }
    assert_eq!(mapped.sections(), owned.sections());
    let s1 = solve(&mapped);
    let s2 = solve(&owned);
    assert_eq!(s1.radiance, s2.radiance, "mmap and in-memory readers give identical light");
}

#[test]
fn every_flipped_byte_in_header_table_and_sections_is_an_error() {
    let bytes = archive::write_to_vec(&small_contents()).unwrap();
    let good = Archive::from_bytes(&bytes).unwrap();
    let mut probes: Vec<usize> = (0..layout::HEADER_SIZE).collect();
    let table = good.header().table_offset as usize;
    probes.extend(table..bytes.len());
    // Empty sections (LCNX when every weight fits LCNT) have no bytes.
    for e in good.sections().iter().filter(|e| e.stored_length > 0) {
        let (o, n) = (e.offset as usize, e.stored_length as usize);
        probes.extend([o, o + n / 2, o + n - 1]);
    }
    for &i in &probes {
        let mut bad = bytes.clone();
        bad[i] ^= 0x40;
        match Archive::from_bytes(&bad) {
            Err(ArchiveError::Corrupt(msg)) => assert!(!msg.is_empty()),
            Err(ArchiveError::UnsupportedVersion { .. }) => {
                panic!("byte {i}: version error for a flipped byte")
            }
            Err(e) => panic!("byte {i}: unexpected error {e}"),
            Ok(_) => panic!("byte {i} flipped, archive still opened"),
        }
    }
}

#[test]
fn truncated_and_garbage_files_are_errors() {
    let bytes = archive::write_to_vec(&small_contents()).unwrap();
    for len in [0, 1, 7, 64, 127, 128, 4096, bytes.len() / 2, bytes.len() - 64, bytes.len() - 1] {
        let err = Archive::from_bytes(&bytes[..len]).err().unwrap_or_else(|| panic!("{len} bytes opened"));
        assert!(err.to_string().contains("corrupt archive"), "{len}: {err}");
    }
    let err = Archive::from_bytes(b"PK\x03\x04 this is a zip file, not an archive......................................................................................................").err().unwrap();
    assert!(err.to_string().contains("not an illumnet archive"), "{err}");
    let dir = tempfile::tempdir().unwrap();
    let err = Archive::open(&dir.path().join("missing.inet")).err().unwrap();
    assert!(matches!(err, ArchiveError::Io { .. }), "{err}");
}

#[test]
fn newer_reader_version_is_refused_with_a_clear_message() {
    let mut bytes = archive::write_to_vec(&small_contents()).unwrap();
    bytes[8..12].copy_from_slice(&12u32.to_le_bytes()); // version_write
    bytes[12..16].copy_from_slice(&12u32.to_le_bytes()); // version_read
    let sum = xxhash_rust::xxh3::xxh3_64(&bytes[..120]);
    bytes[120..128].copy_from_slice(&sum.to_le_bytes());
    let err = Archive::from_bytes(&bytes).err().unwrap();
    assert!(matches!(err, ArchiveError::UnsupportedVersion { needs: 12, supports: 11 }), "{err}");
}

#[test]
fn archive_bytes_do_not_depend_on_thread_count() {
    let build_with = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| archive::write_to_vec(&small_contents()).unwrap())
    };
    let one = build_with(1);
    let two = build_with(2);
    let four = build_with(4);
    assert!(one == two && two == four, "archives differ across thread counts");
}

#[test]
fn versions_follow_the_compatibility_rule() {
    // Version 10 changed the link ends' ids to 16 bits in runs: every
    // archive needs a reader of version 10 (7 before, for the one-byte
    // weights; geodesic stills were readable by version 1 before that).
    // Version 11 lets patch blocks come in a spatial order: only files
    // that use it need a reader of version 11.
    let bytes = archive::write_to_vec(&small_contents()).unwrap();
    let a = Archive::from_bytes(&bytes).unwrap();
    assert_eq!((a.header().version_write, a.header().version_read), (11, 11));
    assert!(
        a.view().build.max_bucket > 0 && a.view().links.resident().unwrap().runs.records().iter().any(|r| r.bucket > 0)
    );
    {
        let scene = Scene::cornell_box();
        let hints = BuildHints { patch_size: Some(0.08), frequency: Some(4), ray_spacing: Some(0.02), buckets: None };
        let mut settings = BuildSettings::resolve(&scene, hints);
        settings.patch_order = illumnet::patch::order::PatchOrder::Primitives;
        let contents = bake::build(&scene, &settings, &NoProgress).unwrap().0;
        let a = Archive::from_bytes(&archive::write_to_vec(&contents).unwrap()).unwrap();
        assert_eq!((a.header().version_write, a.header().version_read), (11, 10), "primitive order");
    }
    // Ray-space baseline archives (version_read 2 before version 7).
    let scene = Scene::cornell_box();
    let hints = BuildHints { patch_size: Some(0.08), frequency: Some(4), ray_spacing: Some(0.02), buckets: None };
    let mut settings = BuildSettings::resolve(&scene, hints);
    settings.direction_set = illumnet::geodesic::DirectionSetKind::RaySpace;
    let contents = bake::build(&scene, &settings, &NoProgress).unwrap().0;
    let a = Archive::from_bytes(&archive::write_to_vec(&contents).unwrap()).unwrap();
    assert_eq!((a.header().version_write, a.header().version_read), (11, 11));
    // f = 4 gives 162 geodesic directions; m = round(√(162/6)) = 5 gives 150.
    assert_eq!(a.view().directions.len(), 6 * 5 * 5);
}

#[test]
fn absurd_resolutions_are_errors_not_overflows() {
    // See: review of issue #2 (bad input never panics).
    let scene = Scene::cornell_box();
    let build_with = |hints: BuildHints| bake::build(&scene, &BuildSettings::resolve(&scene, hints), &NoProgress);
    let err = build_with(BuildHints { patch_size: Some(1e-6), ..Default::default() }).unwrap_err();
    assert!(err.contains("cells"), "{err}");
    let err = build_with(BuildHints { ray_spacing: Some(2e-6), ..Default::default() }).unwrap_err();
    assert!(err.contains("rays"), "{err}");
    // Below the least ray spacing an archive may hold (§7, issue 42).
    let err = build_with(BuildHints { ray_spacing: Some(1e-9), ..Default::default() }).unwrap_err();
    assert!(err.contains("ray spacing must be a length of at least 1e-6 m"), "{err}");
}

#[test]
fn link_ends_to_missing_patches_cannot_reach_the_distributor() {
    // The gather reads per-patch state without a bounds check per end, over
    // ids checked against their runs once: the only ways to hand it link
    // ends (an opened archive's, or `LinkWindow::checked`) check them, so
    // ends that did not come through validation cannot carry an
    // out-of-range patch.
    use illumnet::archive::LinkWindow;
    let bytes = archive::write_to_vec(&small_contents()).unwrap();
    let a = Archive::from_bytes(&bytes).unwrap();
    let v = a.view();
    let l = *v.links.resident().unwrap();
    let runs = l.runs;
    let window = |ids: &[u16]| {
        let ids = ids.to_vec();
        LinkWindow::checked(0..v.patch_count(), &ids, l.weight, l.direction, runs).is_some()
    };
    let mut other = l.local_ids().to_vec();
    assert!(window(&other));
    let middle = other.len() / 2;
    other[middle] = v.patch_count() as u16;
    assert!(!window(&other), "an id past the last patch");
    other[middle] = v.patch_count() as u16 - 1;
    assert!(window(&other));
    assert!(!window(&other[1..]), "fewer ids than the runs hold");
}

#[test]
fn every_weight_escape_record_is_checked_mapped_or_streamed() {
    // See: format-spec/archive.md §5.10. LCNX holds one record per zero of
    // LCNT and no other: a record more (here the zeros after the section,
    // taken in by a longer table entry) is refused, whichever way the
    // archive is opened.
    let mut c = small_contents();
    for w in c.link_weight.iter_mut().step_by(50) {
        *w -= 0.5;
    }
    let good = archive::write_to_vec(&c).unwrap();
    let a = Archive::from_bytes(&good).unwrap();
    let escapes = a.view().links.resident().unwrap().weight.escapes().len();
    assert_eq!(escapes, c.link_weight.len().div_ceil(50));
    let i = a.sections().iter().position(|e| e.tag == layout::tag::LINK_ESCAPES).unwrap();
    let mut bad = good.clone();
    let t = a.header().table_offset as usize + i * layout::ENTRY_SIZE;
    let mut entry: layout::SectionEntry = bytemuck::pod_read_unaligned(&bad[t..t + layout::ENTRY_SIZE]);
    entry.count += 1;
    entry.length += 16;
    entry.stored_length += 16;
    bad[t..t + layout::ENTRY_SIZE].copy_from_slice(bytemuck::bytes_of(&entry));
    archive::reseal(&mut bad);
    let err = Archive::from_bytes(&bad).err().expect("an extra LCNX record must be refused").to_string();
    assert!(err.contains("LCNX"), "{err}");
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("a.inet");
    std::fs::write(&path, &bad).unwrap();
    let err = Archive::open_streamed(&path, 1000).err().expect("streamed too").to_string();
    assert!(err.contains("LCNX"), "{err}");
    std::fs::write(&path, &good).unwrap();
    assert!(Archive::open_streamed(&path, 1000).is_ok());
}

#[test]
fn patch_blocks_out_of_primitive_order_need_version_11_and_a_still() {
    use illumnet::archive::layout::{PrimitiveRecord, tag};
    // First patch of primitive i, at byte 16 of its PRIM record.
    let at = |bytes: &[u8], i: usize| {
        let a = Archive::from_bytes(bytes).unwrap();
        let prim = *a.sections().iter().find(|e| e.tag == tag::PRIMITIVES).unwrap();
        prim.offset as usize + i * std::mem::size_of::<PrimitiveRecord>() + 16
    };
    let forge = |bytes: &mut Vec<u8>, f: &dyn Fn(&mut Vec<u8>)| {
        f(bytes);
        archive::reseal(bytes);
    };
    let refused = |bytes: &[u8], says: &str| match Archive::from_bytes(bytes) {
        Err(e @ ArchiveError::Corrupt(_)) => assert!(e.to_string().contains(says), "{e}"),
        Err(e) => panic!("{says}: {e}"),
        Ok(_) => panic!("{says}: accepted"),
    };
    // A still in a spatial order, labelled as readable by version 10.
    let good = archive::write_to_vec(&small_contents()).unwrap();
    let mut bad = good.clone();
    forge(&mut bad, &|b| b[12..16].copy_from_slice(&10u32.to_le_bytes()));
    refused(&bad, "out of primitive order in a file whose version_read is 10");
    // A sequence whose blocks are swapped (two primitives of the same
    // grid), labelled version 11: tiling, but not in primitive order.
    let scene =
        Scene::from_file(&std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/fan_room.toml")).unwrap();
    let hints = BuildHints { frequency: Some(4), patch_size: Some(0.4), ray_spacing: Some(0.1), buckets: None };
    let mut settings = BuildSettings::resolve(&scene, hints);
    settings.prototype_library = None;
    let seq_bytes =
        archive::write_to_vec(&bake::build_sequence(&scene, &settings, &NoProgress).unwrap().contents).unwrap();
    let seq = Archive::from_bytes(&seq_bytes).unwrap();
    assert_eq!(seq.header().version_read, 10, "sequences keep primitive order");
    let v = seq.view();
    let grid = |r: &PrimitiveRecord| (r.kind, r.grid_u, r.grid_v);
    let (i, j) = (0..v.primitives.len())
        .flat_map(|i| (i + 1..v.primitives.len()).map(move |j| (i, j)))
        .find(|&(i, j)| v.primitives[i].kind == 0 && grid(&v.primitives[i]) == grid(&v.primitives[j]))
        .expect("two primitives of one grid");
    let (pi, pj) = (v.primitives[i].first_patch, v.primitives[j].first_patch);
    let mut bytes = seq_bytes.clone();
    let (oi, oj) = (at(&bytes, i), at(&bytes, j));
    forge(&mut bytes, &|b| {
        b[oi..oi + 4].copy_from_slice(&pj.to_le_bytes());
        b[oj..oj + 4].copy_from_slice(&pi.to_le_bytes());
        b[12..16].copy_from_slice(&11u32.to_le_bytes());
    });
    refused(&bytes, "out of primitive order in a sequence archive");
    // Blocks that overlap, and blocks that leave a patch uncovered.
    let mut bytes = good.clone();
    let (o0, o1) = (at(&good, 0), at(&good, 1));
    let first1 = u32::from_le_bytes(good[o1..o1 + 4].try_into().unwrap());
    forge(&mut bytes, &|b| b[o0..o0 + 4].copy_from_slice(&first1.to_le_bytes()));
    refused(&bytes, "overlap another primitive's");
}
