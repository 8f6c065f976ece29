//! The rules that keep a distribution's results finite, checked against
//! the data they bound (§5.10, §5.13): a patch's link ends carry no more
//! rays than cross it, and a frame's delta removes no more rays from a
//! link than frame 0 gave it.
//!
//! Checksums prove a file is what its writer wrote; these prove that what
//! it holds is something a build can produce. A forged or buggy file that
//! breaks them would divide by a share of zero, give links negative
//! weights, or send more power than a patch holds, and render NaN.
//!
//! The first rule is checked as the weights are read, by
//! [`super::weights::WeightSums`] (beside the weights it sums, so that the
//! link stream, which this module's frame check walks, can use it); the
//! second, a frame at a time, here.

use rayon::prelude::*;

use super::ArchiveError;
use super::ends::Links;
use super::layout::DeltaRecord;
use super::links::{Columns, EndRun, LinkWindow};

/// A run of a row: (bucket, sender chunk).
type RunKey = (u8, u16);
/// An end's place in its run: (direction pair, the link's patch pair, direction).
type InRun = (u32, (u32, u32), u32);

/// One end of a removal record: the owner patch `q`'s end of the link
/// with `other`, leaving along `direction`, in `bucket`.
#[derive(Clone, Copy, Default)]
struct RemovedEnd {
    owner: u32,
    other: u32,
    direction: u32,
    bucket: u8,
    /// The record, and its count (held here: reading it from the record
    /// was a cache miss a fifth of the check's time).
    record: u32,
    count: i32,
}

impl RemovedEnd {
    /// The end's place in its owner's row (§5.10): its run (bucket, sender
    /// chunk), then direction pair, the link's patch pair and direction.
    #[inline]
    fn key(&self) -> (RunKey, InRun) {
        let (q, d) = (self.owner, self.direction);
        let link = if d.is_multiple_of(2) { (q, self.other) } else { (self.other, q) };
        ((self.bucket, chunk_of(self.other)), (d / 2, link, d))
    }
}

/// Checks frame `frame`'s decoded `records` (indices already checked)
/// against the hit counts and frame 0's `links` (rows `offsets`): no
/// record moves more rays than cross either of its patches, and no link
/// loses more rays than frame 0 gave it (§5.13: "the result has no
/// negative weights"), at either end. Reads only the rows of patches some
/// record removes rays at, window by window.
pub(super) fn check_frame(
    frame: u32,
    records: &[DeltaRecord],
    hits: &[u32],
    offsets: &[u64],
    links: &Links<'_>,
) -> Result<(), ArchiveError> {
    let bad = |i: usize, what: String| ArchiveError::corrupt(format!("DELT frame {frame}, record {i}: {what}"));
    // The first record (in file order, whatever the threads) that moves too many rays.
    let too_many = |d: &DeltaRecord| d.count.unsigned_abs() > hits[d.a as usize].min(hits[d.b as usize]);
    if let Some(i) = records.par_iter().position_first(too_many) {
        let d = &records[i];
        let (ha, hb) = (hits[d.a as usize], hits[d.b as usize]);
        return Err(bad(
            i,
            format!(
                "count {} is more rays than the {} that cross patch {} (PHIT)",
                d.count,
                ha.min(hb),
                if ha <= hb { d.a } else { d.b }
            ),
        ));
    }
    // The two ends of each removal: at `a` (direction 2k, other `b`,
    // bucket `bucket_a`) and at `b` (2k + 1, `a`, `bucket_b`), grouped by
    // owner (a counting sort, so no global sort), each owner's in row
    // order. An end's key recurs for links that differ only in the other
    // end's bucket: their removals are summed, against frame 0's ends of
    // that key summed too. (Additions are left out: a valid frame's
    // removals of a key never exceed what frame 0 gave it, whatever it
    // adds.)
    let patches = offsets.len() - 1;
    let removals = || records.iter().enumerate().filter(|(_, d)| d.count < 0);
    // (usize: a frame may hold up to 2³² records, so twice as many ends.)
    let mut start = vec![0usize; patches + 1];
    for (_, d) in removals() {
        start[d.a as usize + 1] += 1;
        start[d.b as usize + 1] += 1;
    }
    for q in 0..patches {
        start[q + 1] += start[q];
    }
    if start[patches] == 0 {
        return Ok(());
    }
    let total = start[patches];
    let mut ends = Vec::new();
    ends.try_reserve_exact(total).map_err(|_| {
        ArchiveError::corrupt(format!("DELT frame {frame}: its {total} removed link ends do not fit in memory"))
    })?;
    ends.resize(total, RemovedEnd::default());
    let mut cursor = start.clone();
    for (i, d) in removals() {
        for (owner, other, bucket, direction) in
            [(d.a, d.b, d.bucket_a, 2 * d.pair), (d.b, d.a, d.bucket_b, 2 * d.pair + 1)]
        {
            let at = &mut cursor[owner as usize];
            ends[*at] = RemovedEnd { owner, other, direction, bucket, record: i as u32, count: d.count };
            *at += 1;
        }
    }
    // (Record indices make keys unique: the order does not depend on the threads.)
    ends.par_chunk_by_mut(|x, y| x.owner == y.owner)
        .for_each(|mine| mine.sort_unstable_by_key(|e| (e.key(), e.record)));
    let wanted: Vec<u32> = (0..patches as u32).filter(|&q| start[q as usize] < start[q as usize + 1]).collect();
    links.for_each_window_of(Columns::ALL, patches, &wanted, |w: LinkWindow<'_>| {
        let range = start[w.patches.start]..start[w.patches.end];
        // Per patch, in patch order, the first record that removes too much.
        let found = ends[range].par_chunk_by(|x, y| x.owner == y.owner).map(|mine| removal_error(&w, mine));
        match found.find_first(Option::is_some).flatten() {
            Some((first, what)) => Err(bad(first, what)),
            None => Ok(()),
        }
    })
}

/// Of the removed ends `mine` (one patch's, in row order), the first
/// record that takes more rays from an end than frame 0 gave it, and what
/// is wrong.
fn removal_error(w: &LinkWindow<'_>, mine: &[RemovedEnd]) -> Option<(usize, String)> {
    let q = mine[0].owner;
    // A row is ordered by bucket, sender chunk, direction pair and the
    // link's patch pair (§5.10): its runs by (bucket, chunk), the ends of
    // a run by the rest, so frame 0's weight of each removed end is found
    // by a search within its run that starts where the last one ended
    // (galloping), without decoding the row.
    let within = |r: &EndRun<'_>, e: usize| {
        let (d, other) = (w.direction[e], r.other(e - r.ends().start));
        (d / 2, if d.is_multiple_of(2) { (q, other) } else { (other, q) }, d)
    };
    let mut worst: Option<(u32, u32, u32, i64, f64)> = None;
    let mut runs = w.runs_of(q as usize).peekable();
    let mut from = runs.peek().map_or(0, |r| r.ends().start);
    for same in mine.chunk_by(|x, y| x.key() == y.key()) {
        let (run_key, key) = same[0].key();
        let net: i64 = same.iter().map(|e| e.count as i64).sum();
        while runs.next_if(|r| (r.bucket(), chunk_of(r.base() as u32)) < run_key).is_some() {
            from = runs.peek().map_or(0, |r| r.ends().start);
        }
        let base = match runs.peek() {
            Some(r) if (r.bucket(), chunk_of(r.base() as u32)) == run_key => {
                let end = r.ends().end;
                from += gallop(end - from, |i| within(r, from + i) < key);
                (from..end).take_while(|&e| within(r, e) == key).map(|e| w.weight.get(e) as f64).sum::<f64>() + 0.0
            }
            _ => 0.0,
        };
        // `same` is sorted by record last: its first is its earliest.
        if base + (net as f64) < 0.0 && worst.is_none_or(|w| same[0].record < w.0) {
            worst = Some((same[0].record, key.2, same[0].other, net, base));
        }
    }
    worst.map(|(record, direction, other, net, base)| {
        (
            record as usize,
            format!(
                "removes {} rays from patch {q}'s end of its link with patch {other} along direction \
                 {direction}, which frame 0 gave {base}: a negative weight",
                -net
            ),
        )
    })
}

/// The sender chunk of patch `p` (§5.10).
fn chunk_of(p: u32) -> u16 {
    (p as usize / super::layout::CHUNK_PATCHES) as u16
}

/// The first of `0..n` for which `before` is false, `before` being true
/// and then false along `0..n`, found near the start when it is there:
/// steps doubling from 0, then a binary search in the last step.
fn gallop(n: usize, before: impl Fn(usize) -> bool) -> usize {
    let mut step = 1;
    let mut lo = 0;
    while lo + step <= n && before(lo + step - 1) {
        lo += step;
        step *= 2;
    }
    let hi = (lo + step).min(n);
    lo + first_false(hi - lo, |i| before(lo + i))
}

/// The first of `0..n` for which `before` is false, `before` being true
/// and then false along `0..n` (a binary search).
fn first_false(n: usize, before: impl Fn(usize) -> bool) -> usize {
    let (mut lo, mut hi) = (0, n);
    while lo < hi {
        let mid = lo + (hi - lo) / 2;
        if before(mid) {
            lo = mid + 1;
        } else {
            hi = mid;
        }
    }
    lo
}

#[cfg(test)]
mod tests {
    use super::super::layout::{CHUNK_PATCHES, LinkRunRecord};
    use super::super::links::{LinkRuns, LinkSlices};
    use super::super::weights::Weights;
    use super::*;

    /// The run walk finds frame 0's weight of every removed end, in rows
    /// of several buckets and sender chunks: a removal of exactly that
    /// weight passes, one ray more is named, ends a row lacks have none,
    /// and removals of one end by several records are summed.
    #[test]
    fn removals_are_weighed_against_their_runs_across_buckets_and_chunks() {
        let (q, far) = (3u32, CHUNK_PATCHES as u32);
        let n = CHUNK_PATCHES + 100;
        // Patch q's row: (bucket 0, chunk 0), (bucket 0, chunk 1), (bucket 1, chunk 0).
        let ends: [(u32, u32, u8); 6] =
            [(10, 0, 5), (10, 2, 3), (20, 2, 4), (far + 5, 0, 7), (far + 9, 1, 2), (10, 0, 6)];
        let bucket_of = |i: usize| if i == 5 { 1u8 } else { 0 };
        let local: Vec<u16> = ends.iter().map(|e| (e.0 as usize % CHUNK_PATCHES) as u16).collect();
        let direction: Vec<u32> = ends.iter().map(|e| e.1).collect();
        let counts: Vec<u8> = ends.iter().map(|e| e.2).collect();
        let link_offsets: Vec<u64> = (0..=n).map(|p| if p <= q as usize { 0 } else { 6 }).collect();
        let run_offsets: Vec<u64> = (0..=n).map(|p| if p <= q as usize { 0 } else { 3 }).collect();
        let run = |chunk, bucket, length| LinkRunRecord { chunk, bucket, reserved: 0, length };
        let runs = [run(0, 0, 3), run(1, 0, 2), run(0, 1, 1)];
        let runs = LinkRuns::checked(&link_offsets, &run_offsets, &runs, 1).expect("valid runs");
        let slices = LinkSlices::validated(&local, Weights::whole(&counts, &[]), &direction, runs, n);
        let w = slices.window();
        // Removes `count` rays from each end `(other, direction, bucket)`, one record each.
        let check = |removed: &[(u32, u32, u8, i32)]| {
            let mut mine: Vec<RemovedEnd> = removed
                .iter()
                .enumerate()
                .map(|(i, &(other, direction, bucket, count))| RemovedEnd {
                    owner: q,
                    other,
                    direction,
                    bucket,
                    record: i as u32,
                    count,
                })
                .collect();
            mine.sort_unstable_by_key(|e| (e.key(), e.record));
            removal_error(&w, &mine).map(|(record, _)| record)
        };
        for (i, &(other, d, weight)) in ends.iter().enumerate() {
            let (k, weight) = (bucket_of(i), weight as i32);
            assert_eq!(check(&[(other, d, k, -weight)]), None, "end {i}");
            assert_eq!(check(&[(other, d, k, -weight - 1)]), Some(0), "end {i}");
            // The same end in the other bucket, or along the other direction of its pair.
            for (d, k) in [(d, 1 - k), (d ^ 1, k)] {
                let base: i32 = (0..6)
                    .filter(|&j| (ends[j].0, ends[j].1, bucket_of(j)) == (other, d, k))
                    .map(|j| ends[j].2 as i32)
                    .sum();
                assert_eq!(check(&[(other, d, k, -base - 1)]), Some(0), "end {i}, {d}, {k}");
                assert_eq!(check(&[(other, d, k, -base)]), None, "end {i}, {d}, {k}");
            }
            // Every end at once, and this one twice (two records that sum).
            let mut all: Vec<_> =
                ends.iter().enumerate().map(|(j, e)| (e.0, e.1, bucket_of(j), -(e.2 as i32))).collect();
            all.push((other, d, k, -1));
            let last = all.len() - 1;
            all[i].3 += 1;
            assert_eq!(check(&all), None, "end {i} in all");
            all[last].3 -= 1;
            assert_eq!(check(&all), Some(i.min(last)), "end {i} in all, one ray too many");
        }
        // An end of chunk 1 whose id lies in chunk 0's run is not that run's.
        assert_eq!(check(&[(far + 10, 0, 0, -1)]), Some(0));
    }
}
