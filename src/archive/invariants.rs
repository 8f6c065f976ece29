//! The rules that keep a distribution's results finite, checked against
//! the data they bound (§5.10, §5.13): a patch's link ends carry no more
//! rays than cross it, and a frame's delta removes no more rays from a
//! link than frame 0 gave it.
//!
//! Checksums prove a file is what its writer wrote; these prove that what
//! it holds is something a build can produce. A forged or buggy file that
//! breaks them would divide by a share of zero, give links negative
//! weights, or send more power than a patch holds, and render NaN.

use rayon::prelude::*;

use super::ArchiveError;
use super::layout::DeltaRecord;
use super::links::{Columns, LinkWindow, Links};
use super::weights::Weights;

/// Relative slack on sums of f32 ray counts (exact integers below 2²⁴;
/// larger sums round).
const SUM_SLACK: f64 = 1e-6;

/// Folds link-end weights into per-patch sums and checks each finished
/// patch's sum against its hit count `PHIT[p]` (each ray line crossing a
/// patch makes at most one link end there). Fed weights in end order, in
/// any slicing.
pub(super) struct WeightSums<'a> {
    offsets: &'a [u64],
    hits: &'a [u32],
    /// The patch whose ends come next.
    patch: usize,
    /// The end that comes next.
    end: usize,
    sum: f64,
}

impl<'a> WeightSums<'a> {
    /// Sums over the rows `offsets` (validated CSR) of patches with `hits`.
    pub(super) fn new(offsets: &'a [u64], hits: &'a [u32]) -> Self {
        Self { offsets, hits, patch: 0, end: 0, sum: 0.0 }
    }

    /// Adds the next `weights` (ends `self.end ..`).
    pub(super) fn add(&mut self, weights: Weights<'_>) -> Result<(), ArchiveError> {
        let mut i = 0;
        while i < weights.len() {
            self.finish_empty()?;
            let row_end = self.offsets[self.patch + 1] as usize;
            let take = (row_end - self.end).min(weights.len() - i);
            self.sum += weights.slice(i..i + take).iter().map(|w| w as f64).sum::<f64>();
            self.end += take;
            i += take;
        }
        self.finish_empty()
    }

    /// Closes every patch whose row is complete.
    fn finish_empty(&mut self) -> Result<(), ArchiveError> {
        while self.patch + 1 < self.offsets.len() && self.offsets[self.patch + 1] as usize == self.end {
            let h = self.hits[self.patch] as f64;
            if self.sum > h * (1.0 + SUM_SLACK) {
                return Err(ArchiveError::corrupt(format!(
                    "LCNT: patch {}'s link ends carry {} rays, more than the {h} that cross it (PHIT)",
                    self.patch, self.sum
                )));
            }
            self.sum = 0.0;
            self.patch += 1;
        }
        Ok(())
    }
}

/// A link end: (owner patch, bucket, direction it leaves along, other patch).
type EndKey = (u32, u8, u32, u32);

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
    // bucket `bucket_a`) and at `b` (2k + 1, `a`, `bucket_b`). An end's key
    // recurs for links that differ only in the other end's bucket: their
    // removals are summed, against frame 0's ends of that key summed too.
    // (Additions are left out: a valid frame's removals of a key never
    // exceed what frame 0 gave it, whatever it adds.)
    let mut keyed: Vec<(EndKey, u32)> = records
        .par_iter()
        .enumerate()
        .filter(|(_, d)| d.count < 0)
        .flat_map_iter(|(i, d)| {
            [((d.a, d.bucket_a, 2 * d.pair, d.b), i as u32), ((d.b, d.bucket_b, 2 * d.pair + 1, d.a), i as u32)]
        })
        .collect();
    if keyed.is_empty() {
        return Ok(());
    }
    // Keys with their record indices are unique: the order is the same
    // whatever the threads.
    keyed.par_sort_unstable();
    let mut wanted: Vec<u32> = keyed.iter().map(|k| k.0.0).collect();
    wanted.dedup();
    let patches = offsets.len() - 1;
    links.for_each_window_of(Columns::ALL, patches, &wanted, |w: LinkWindow<'_>| {
        let lo = keyed.partition_point(|k| (k.0.0 as usize) < w.patches.start);
        let hi = keyed.partition_point(|k| (k.0.0 as usize) < w.patches.end);
        // Per patch, in patch order, the first end it removes too much from.
        let found =
            keyed[lo..hi].par_chunk_by(|x, y| x.0.0 == y.0.0).map(|mine| removal_error(&w, offsets, records, mine));
        match found.find_first(Option::is_some).flatten() {
            Some((first, what)) => Err(bad(first, what)),
            None => Ok(()),
        }
    })
}

/// Of the removals `mine` (keyed ends of one patch, sorted), the first
/// that takes more rays from an end than frame 0 gave it: its first
/// record and what is wrong.
fn removal_error(
    w: &LinkWindow<'_>,
    offsets: &[u64],
    records: &[DeltaRecord],
    mine: &[(EndKey, u32)],
) -> Option<(usize, String)> {
    let q = mine[0].0.0;
    // Frame 0's weight of each removed end, found by binary search: a row
    // is ordered by bucket, sender chunk, direction pair and the link's
    // patch pair (§5.10), that is by `order_key`.
    let r = w.local(offsets[q as usize] as usize..offsets[q as usize + 1] as usize);
    debug_assert_eq!(r, w.row(q as usize));
    let row: Vec<(u32, u8)> = w.ends_of(q as usize).map(|(_, other, bucket)| (other, bucket)).collect();
    let order_key = |e: usize| {
        let (d, (other, bucket)) = (w.direction[e], row[e - r.start]);
        let link = if d.is_multiple_of(2) { (q, other) } else { (other, q) };
        (bucket, chunk_of(other), d / 2, link, d)
    };
    // The removed keys in row order, each with its net count and its
    // place in `mine`, so that each search starts where the last ended
    // (galloping), in rows read once instead of once per key.
    let mut wanted: Vec<(_, i64, usize)> = mine
        .chunk_by(|x, y| x.0 == y.0)
        .scan(0, |at, run| {
            let (_, bucket, direction, other) = run[0].0;
            let net: i64 = run.iter().map(|&(_, i)| records[i as usize].count as i64).sum();
            let link = if direction.is_multiple_of(2) { (q, other) } else { (other, q) };
            let place = *at;
            *at += run.len();
            Some(((bucket, chunk_of(other), direction / 2, link, direction), net, place))
        })
        .collect();
    wanted.sort_unstable_by_key(|w| w.0);
    let mut worst: Option<(usize, u32, u32, i64, f64)> = None;
    let mut from = r.start;
    for &(key, net, place) in &wanted {
        from += gallop(r.end - from, |i| order_key(from + i) < key);
        let base =
            (from..r.end).take_while(|&e| order_key(e) == key).map(|e| w.weight.get(e) as f64).sum::<f64>() + 0.0;
        if base + (net as f64) < 0.0 && worst.is_none_or(|w| place < w.0) {
            worst = Some((place, key.4, if key.4.is_multiple_of(2) { key.3.1 } else { key.3.0 }, net, base));
        }
    }
    worst.map(|(place, direction, other, net, base)| {
        (
            mine[place].1 as usize,
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
