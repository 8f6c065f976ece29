//! The external sort's tests: runs, merge passes and the plan.

use super::*;
use crate::archive::LinkEndSource;
use crate::bake::links::{LinkTable, assemble};

#[test]
fn a_plan_fills_its_room_and_no_more() {
    for room in [16u64 << 20, 1 << 30, 1900 << 20, 3 << 40] {
        for workers in [1, 2, 3, 8, 64] {
            let plan = SpillPlan::new(room, workers);
            let peak = plan.peak_bytes(workers);
            assert!(peak <= room, "{plan:?} with {workers} workers holds {peak} of {room} bytes");
            if plan.run_links == u32::MAX as u64 / 2 {
                continue; // a run's ends are numbered in u32: rooms of terabytes are not filled
            }
            // Rounding aside, it uses the room: within 1%.
            assert!(peak as f64 >= 0.99 * room as f64, "{plan:?}: {peak} of {room}");
            // A worker's run is twice what it holds before it spills.
            let share = plan.threshold / (2 * workers as u64);
            assert!((plan.run_links * BUNDLE_BYTES_PER_LINK).abs_diff(2 * share) <= BUNDLE_BYTES_PER_LINK + 2);
        }
    }
}

/// Patches of the bundles below: 40 in two sender chunks.
const PATCHES: usize = CHUNK_PATCHES + 20;

/// Patch `i` of 40: the first 20 in chunk 0, the rest in chunk 1.
fn patch(i: u32) -> u32 {
    if i < 20 { i } else { CHUNK_PATCHES as u32 + i - 20 }
}

/// Bundles of pairs 0..6, of 0 to 9 links, over 40 patches in two
/// sender chunks; one link of pair 2 has a weight past 16 bits, so that
/// runs holding it have wide records and the others narrow ones (merge
/// passes then join both).
fn bundles() -> Vec<Bundle> {
    (0..6u32)
        .map(|pair| {
            let n = [7, 0, 9, 1, 4, 0][pair as usize];
            let mut b = Bundle { pair, ..Default::default() };
            for i in 0..n {
                b.a.push(patch((pair * 7 + i * 3) % 40));
                b.b.push(patch((pair * 11 + i * 5 + 1) % 40));
                b.w.push(if (pair, i) == (2, 4) { 70_000 } else { 1 + (i + pair) % 4 });
                b.bucket_a.push((i % 2) as u8);
                b.bucket_b.push(((i + pair) % 3 == 0) as u8);
            }
            b
        })
        .collect()
}

#[test]
fn runs_of_a_few_links_cut_bundles_and_merge_to_the_in_memory_table() {
    let expected = assemble(&bundles(), PATCHES, 1);
    // Fan-ins of 2 and 3 merge the runs of one link in passes first.
    for (run_links, fan_in) in [(1, 2), (1, 3), (1, 256), (2, 2), (3, 4), (5, 256), (8, 2), (100, 256)] {
        let dir = tempfile::tempdir().expect("a temporary directory");
        let plan = SpillPlan { threshold: 1 << 20, run_links };
        let spill = Spill::new(&dir.path().join("a.inet"), plan, PATCHES, 0, 1).expect("a spill");
        // Two spills of consecutive pairs, as two workers would.
        let mut all = bundles();
        let mut second = all.split_off(2);
        spill.spill(&mut all).expect("spilled");
        spill.spill(&mut second).expect("spilled");
        assert!(all.is_empty() && second.is_empty(), "spilled bundles are let go");
        assert_eq!(spill.buffers_made(), 1, "one sort buffer, reused");
        let mut runs = spill.runs.lock().expect("runs");
        assert!(runs.iter().all(|r| r.ends <= 2 * run_links), "a run holds at most {run_links} links");
        assert!(runs.iter().all(|r| r.ends > 0), "no empty runs");
        assert!(runs.iter().any(|r| r.end_bytes == records::WIDE), "a wide run");
        assert!(runs.iter().any(|r| r.end_bytes == records::NARROW), "narrow runs");
        let links: u64 = 7 + 9 + 1 + 4;
        assert!(runs.len() as u64 >= links.div_ceil(run_links), "{} runs of {run_links}", runs.len());
        // Runs finish in any order on several workers: the merge orders them.
        runs.reverse();
        let spilled = runs.len();
        drop(runs);
        let (mut merged, offsets) = spill.finish_with(fan_in, &crate::progress::NoProgress).expect("finished");
        assert_eq!(offsets, expected.offsets);
        assert_eq!(merged.run_count(), spilled, "runs spilled, whatever the passes");
        assert!(merged.runs.len() <= fan_in, "{} runs left to merge with fan-in {fan_in}", merged.runs.len());
        // A pass removes the runs it merged: only those left remain.
        let files = std::fs::read_dir(dir.path()).expect("the output's directory");
        let scratch = files.flatten().find(|f| f.path().is_dir()).expect("a scratch directory").path();
        let left = std::fs::read_dir(scratch).expect("the scratch directory").count();
        assert_eq!(left, merged.runs.len() + 1, "the runs left and the lock file, nothing else");
        let (table, _) = merged_table(&mut merged);
        let LinkTable { other, weight, direction, bucket, .. } = table;
        assert_eq!(other, expected.other, "run_links {run_links}");
        assert_eq!(weight, expected.weight);
        assert_eq!(direction, expected.direction);
        assert_eq!(bucket, expected.bucket);
    }
}

proptest::proptest! {
    /// The loser tree hands out every run's keys in ascending order, for
    /// any number of runs (including none and one) and runs running dry.
    #[test]
    fn a_tournament_gives_keys_in_order(
        runs in proptest::collection::vec(proptest::collection::vec(0u64..1 << 40, 0..20), 0..40),
    ) {
        let runs: Vec<Vec<u64>> = runs.into_iter().map(|mut r| { r.sort_unstable(); r }).collect();
        let key = |k: u64, i: usize| (k << RUN_BITS) | i as u64;
        let mut want: Vec<u64> = runs.iter().enumerate().flat_map(|(i, r)| r.iter().map(move |&k| key(k, i))).collect();
        want.sort_unstable();
        let mut next = vec![0usize; runs.len()];
        let first = runs.iter().enumerate().map(|(i, r)| r.first().map_or(NO_SLOT, |&k| key(k, i))).collect();
        let mut t = Tournament::new(first);
        let mut got = Vec::new();
        loop {
            let (i, k) = t.winner();
            if k == NO_SLOT {
                break;
            }
            got.push(k);
            next[i] += 1;
            t.replace(runs[i].get(next[i]).map_or(NO_SLOT, |&k| key(k, i)));
        }
        proptest::prop_assert_eq!(got, want);
    }
}

/// The link-end columns `merged` writes (its offsets left empty), and the
/// batches it wrote them in.
fn merged_table(merged: &mut SpilledLinks) -> (LinkTable, usize) {
    let mut t = LinkTable { offsets: vec![], other: vec![], weight: vec![], direction: vec![], bucket: vec![] };
    let mut batches = 0;
    merged
        .write_ends(&mut |o, w, d, k| {
            t.other.extend_from_slice(o);
            t.weight.extend_from_slice(w);
            t.direction.extend_from_slice(d);
            t.bucket.extend_from_slice(k);
            batches += 1;
            Ok(())
        })
        .expect("merged");
    (t, batches)
}

/// Bundles of 40 pairs of 5 000 links each over [`PATCHES`] patches (4·10⁵
/// ends: several of the merge's batches).
fn many_bundles() -> Vec<Bundle> {
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = move |m: u32| {
        state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        ((state >> 33) % m as u64) as u32
    };
    (0..40u32)
        .map(|pair| {
            let mut links: Vec<(u32, u32)> = (0..5000).map(|_| (next(PATCHES as u32), next(PATCHES as u32))).collect();
            links.sort_unstable();
            let mut b = Bundle { pair, ..Default::default() };
            for (x, y) in links {
                b.a.push(x);
                b.b.push(y);
                b.w.push(1 + next(7));
                b.bucket_a.push(next(2) as u8);
                b.bucket_b.push(next(2) as u8);
            }
            b
        })
        .collect()
}

#[test]
fn the_merge_thread_hands_the_writer_every_batch_and_stops_when_it_fails() {
    let expected = assemble(&many_bundles(), PATCHES, 1);
    let dir = tempfile::tempdir().expect("a temporary directory");
    let spill =
        Spill::new(&dir.path().join("a.inet"), SpillPlan { threshold: 1 << 20, run_links: 30_000 }, PATCHES, 0, 1)
            .expect("a spill");
    spill.spill(&mut many_bundles()).expect("spilled");
    let (mut merged, _) = spill.finish_with(256, &crate::progress::NoProgress).expect("finished");
    assert!(merged.run_count() >= 6, "{} runs", merged.run_count());
    let (table, batches) = merged_table(&mut merged);
    assert!(batches >= 6, "{batches} batches");
    assert_eq!(table.other, expected.other);
    assert_eq!(table.weight, expected.weight);
    assert_eq!(table.direction, expected.direction);
    assert_eq!(table.bucket, expected.bucket);
    // A writer failing at its second batch: its error, and no hang.
    let mut taken = 0;
    let failed = merged.write_ends(&mut |_, _, _, _| {
        taken += 1;
        if taken == 2 { Err(std::io::Error::other("disk full")) } else { Ok(()) }
    });
    assert_eq!(failed.expect_err("the writer's error").to_string(), "disk full");
    assert_eq!(taken, 2, "no batch after the failure");
}
