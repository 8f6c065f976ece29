//! Streamed link ends (`Archive::open_streamed`): the same light as a
//! mapped archive bit for bit, whatever the window size, and a file cut or
//! rewritten under a running distribution is an error, not a crash.

mod common;
use std::path::{Path, PathBuf};

use illumnet::archive::{self, Archive, layout::tag};
use illumnet::distribute::{DistributeOptions, Distributor, Lighting};
use illumnet::progress::NoProgress;
use illumnet::scene::{BuildHints, Scene};

/// The Cornell box at coarse settings (more than one 2¹⁶-end chunk of
/// link ends, so windows of a few hundred ends are hundreds), written
/// into `dir`.
fn coarse_cornell_box(dir: &Path) -> PathBuf {
    let hints = BuildHints { patch_size: Some(0.1), frequency: Some(6), ray_spacing: Some(0.02), buckets: None };
    common::write_scene(&Scene::cornell_box(), hints, dir)
}

#[test]
fn streamed_link_ends_give_the_mapped_light_bit_for_bit() {
    // Windows of a few hundred ends cut patches' rows at every kind of
    // boundary (chunks of 65 536 ends, bucket runs, patches with no ends).
    let cases = common::coarse_scenes();
    for (name, h) in cases {
        let dir = tempfile::tempdir().unwrap();
        let path = common::write_scene(&common::scene_file(name), h, dir.path());
        let mapped = Archive::open(&path).unwrap();
        let want = common::solve_all_frames(&mapped, None);
        let ends = mapped.view().link_end_count();
        for window in [300, 70_000, usize::MAX] {
            let streamed = Archive::open_streamed(&path, window).unwrap();
            let s = streamed.link_stream().expect("streamed");
            assert!(window > ends || s.window_count() > 1, "{name}: {} windows", s.window_count());
            assert_eq!(s.ends(), ends);
            common::assert_same_light(
                &want,
                &common::solve_all_frames(&streamed, None),
                &format!("{name} in windows of {window}"),
            );
            // The gather's workers each hold one window's buffers, the
            // other passes two: no more were ever made.
            let most = rayon::current_num_threads().max(2) * s.window_capacity() * 10;
            assert!(s.pooled_bytes() <= most, "{name}: {} bytes of windows kept, at most {most}", s.pooled_bytes());
        }
        eprintln!("{name}: {ends} link ends, {} frames", want.len());
    }
}

/// The file offset of section `t` of the archive at `path`.
fn section_offset(path: &Path, t: archive::layout::Tag) -> u64 {
    Archive::summary(path).unwrap().sections.iter().find(|e| e.tag == t).unwrap().offset
}

#[test]
fn a_link_column_cut_or_rewritten_under_a_distribution_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let path = coarse_cornell_box(dir.path());
    let opts = DistributeOptions::default();
    let run = |a: &Archive| {
        let v = a.view();
        Distributor::new(&v, &opts, &Lighting::from_view(&v)).and_then(|d| d.frame(0, None, &NoProgress)).map(|_| ())
    };

    // Rewritten in place after opening: the window's checksum catches it.
    let a = Archive::open_streamed(&path, 1000).unwrap();
    assert!(a.view().link_end_count() > 70_000, "the change lands in LCNT's second chunk");
    let at = section_offset(&path, tag::LINK_COUNT);
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[at as usize + 70_000] ^= 0x40;
    std::fs::write(&path, &bytes).unwrap();
    let err = run(&a).unwrap_err().to_string();
    assert!(err.contains("changed on disk") && err.contains("LCNT"), "{err}");
    // Opening it now fails on the section checksum, before any use.
    let err = Archive::open_streamed(&path, 1000).err().unwrap().to_string();
    assert!(err.contains("LCNT") && err.contains("checksum"), "{err}");
    bytes[at as usize + 70_000] ^= 0x40;

    // A run (LRUN, read with each window) rewritten: the same.
    std::fs::write(&path, &bytes).unwrap();
    let a = Archive::open_streamed(&path, 1000).unwrap();
    let runs = section_offset(&path, tag::LINK_RUNS);
    bytes[runs as usize + 8 * 40 + 2] ^= 0x01; // a bucket
    std::fs::write(&path, &bytes).unwrap();
    let err = run(&a).unwrap_err().to_string();
    assert!(err.contains("changed on disk") && err.contains("LRUN"), "{err}");
    bytes[runs as usize + 8 * 40 + 2] ^= 0x01;

    // Cut short after opening: a short read, never SIGBUS.
    std::fs::write(&path, &bytes).unwrap();
    let a = Archive::open_streamed(&path, 1000).unwrap();
    assert!(run(&a).is_ok());
    let file = std::fs::OpenOptions::new().write(true).open(&path).unwrap();
    file.set_len(section_offset(&path, tag::LINK_OTHER) + 4096).unwrap();
    let err = run(&a).unwrap_err().to_string();
    assert!(err.contains("ended early"), "{err}");
    let err = Archive::open_streamed(&path, 1000).err().unwrap().to_string();
    assert!(err.contains("truncated"), "{err}");
}

#[test]
fn a_streamed_sequence_reads_its_frames_from_disk_and_notices_changes() {
    // A streamed archive leaves DELT on disk too (its memory then holds one
    // frame's changes at a time): each frame is read when it is applied
    // and checked against its own checksum (DIDX), so a frame rewritten
    // or cut off under a render is an error.
    let dir = tempfile::tempdir().unwrap();
    let hints = BuildHints { patch_size: Some(0.4), frequency: Some(4), ray_spacing: Some(0.06), buckets: None };
    let path = common::write_scene(&common::scene_file("fan_room.toml"), hints, dir.path());
    let mapped = Archive::open(&path).unwrap();
    let a = Archive::open_streamed(&path, 1000).unwrap();
    let delt = Archive::summary(&path).unwrap().sections.iter().find(|e| e.tag == tag::DELTAS).unwrap().stored_length;
    assert!(delt > 100_000, "DELT {delt} bytes");
    assert!((a.held_bytes() as u64) < Archive::summary(&path).unwrap().held_bytes() + 1_000_000);
    let (m, s) = (mapped.view().sequence.unwrap(), a.view().sequence.unwrap());
    assert!(matches!(s.payload, archive::DeltaBytes::OnDisk(_)));
    for f in 0..s.frames() {
        assert_eq!(m.frame_delta(f).unwrap(), s.frame_delta(f).unwrap(), "frame {f}");
    }
    // A frame's bytes rewritten after opening: that frame's checksum.
    let ix = s.index.iter().enumerate().rfind(|(_, ix)| ix.stored_length > 0).unwrap();
    let at = section_offset(&path, tag::DELTAS) + ix.1.offset + ix.1.stored_length / 2;
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[at as usize] ^= 0x20;
    std::fs::write(&path, &bytes).unwrap();
    let frame = ix.0 as u32;
    let err = a.view().frame_links(frame).unwrap_err().to_string();
    assert!(err.contains(&format!("DELT frame {frame}")) && err.contains("checksum"), "{err}");
    assert!(a.view().frame_links(0).is_ok(), "other frames still read");
    // Cut off: a short read, never SIGBUS.
    let file = std::fs::OpenOptions::new().write(true).open(&path).unwrap();
    file.set_len(at).unwrap();
    let err = a.view().frame_links(frame).unwrap_err().to_string();
    assert!(err.contains("ended early"), "{err}");
}

#[test]
fn a_pass_holds_no_more_windows_than_its_limit_whatever_the_workers() {
    // Four workers, one to three windows at a time: the same light bit for
    // bit, and no more windows' buffers ever made than that (at least two:
    // the sequential passes read one while using another), as under a
    // budget with room for a few windows on a machine of many cores.
    let dir = tempfile::tempdir().unwrap();
    let path = coarse_cornell_box(dir.path());
    let want = common::solve_all_frames(&Archive::open(&path).unwrap(), None);
    let pool = rayon::ThreadPoolBuilder::new().num_threads(4).build().unwrap();
    pool.install(|| {
        for limit in [1, 2, 3] {
            let streamed = Archive::open_streamed(&path, 300).unwrap();
            let s = streamed.link_stream().expect("streamed");
            s.limit_windows_in_flight(limit);
            assert!(s.window_count() > 4 * limit, "{} windows", s.window_count());
            assert_eq!(s.windows_in_flight(), limit);
            common::assert_same_light(
                &want,
                &common::solve_all_frames(&streamed, None),
                &format!("{limit} windows at a time on 4 workers"),
            );
            assert!(s.pooled_buffers() <= limit.max(2), "{} windows' buffers made", s.pooled_buffers());
        }
    });
}

#[test]
fn the_least_a_streamed_render_needs_does_not_grow_with_the_cores() {
    use illumnet::memory::{BudgetSource, MemoryBudget};
    use illumnet::render::plan::{LinkAccess, RenderJob, plan_with};
    let dir = tempfile::tempdir().unwrap();
    let path = coarse_cornell_box(dir.path());
    let mut summary = Archive::summary(&path).unwrap();
    // As if the file were 1 TB: it is never mapped whole (the plan reads
    // the sizes of the sections held, not of the link ends).
    summary.file_length = 1 << 40;
    let job = |threads| RenderJob {
        width: 64,
        height: 64,
        samples_per_axis: 2,
        frames: 1,
        keep_images: false,
        anderson_depth: 5,
        buckets: true,
        threads,
        keeps_solving: false,
    };
    let budget = |bytes| MemoryBudget { bytes, source: BudgetSource::Given };
    // The least, from the refusal of a budget far too small: the same on
    // 2 and on 64 workers, spilling or not (the windows below are planned
    // without spilling).
    let (runs, ends) = (summary.section_count(tag::LINK_RUNS), summary.build.link_end_count);
    let plan = |s: &_, j: &_, b| plan_with(s, j, b, false);
    let least = |threads| plan(&summary, &job(threads), budget(1 << 20)).unwrap_err().needed();
    assert_eq!(least(2), least(64));
    let spilled = |threads| plan_with(&summary, &job(threads), budget(1 << 20), true).unwrap_err().needed();
    assert_eq!(spilled(2), spilled(64));
    assert!(spilled(2) < least(2), "spilling needs less: {} against {}", spilled(2), least(2));
    for (threads, extra_windows, want) in [(64, 0, 2), (64, 3, 5), (2, 3, 2), (4, 100, 4)] {
        // A smallest window: (2¹⁶ + 2 × 2¹⁶ ends) × 7 bytes, and its runs
        // (planned at twice the archive's mean per end).
        let per_end = 7 + (16 * runs).div_ceil(ends).min(8);
        let bytes = least(threads) + extra_windows * 3 * 65_536 * per_end;
        let p = plan(&summary, &job(threads), budget(bytes)).unwrap();
        match p.access {
            LinkAccess::Streamed { in_flight, .. } => {
                assert_eq!(in_flight as u64, want, "{threads} threads, {bytes} bytes")
            }
            other => panic!("{threads} threads, {bytes} bytes: {other:?}"),
        }
        assert!(p.total() <= bytes, "{threads} threads: planned {} of {bytes}", p.total());
    }
}
