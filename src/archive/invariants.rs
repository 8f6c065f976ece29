//! The rules that keep a distribution's results finite, checked against
//! the data they bound (§5.10, §5.13): a patch's link ends carry no more
//! rays than cross it, and a frame's delta removes no more rays from a
//! link than frame 0 gave it.
//!
//! Checksums prove a file is what its writer wrote; these prove that what
//! it holds is something a build can produce. A forged or buggy file that
//! breaks them would divide by a share of zero, give links negative
//! weights, or send more power than a patch holds, and render NaN.

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
    for (i, d) in records.iter().enumerate() {
        let most = hits[d.a as usize].min(hits[d.b as usize]);
        if d.count.unsigned_abs() > most {
            return Err(bad(
                i,
                format!(
                    "count {} is more rays than the {most} that cross patch {} (PHIT)",
                    d.count,
                    if hits[d.a as usize] <= hits[d.b as usize] { d.a } else { d.b }
                ),
            ));
        }
    }
    // The two ends of each removal: at `a` (direction 2k, other `b`,
    // bucket `bucket_a`) and at `b` (2k + 1, `a`, `bucket_b`). An end's key
    // recurs for links that differ only in the other end's bucket: their
    // removals are summed, against frame 0's ends of that key summed too.
    // (Additions are left out: a valid frame's removals of a key never
    // exceed what frame 0 gave it, whatever it adds.)
    let mut keyed: Vec<(EndKey, u32)> = records
        .iter()
        .enumerate()
        .filter(|(_, d)| d.count < 0)
        .flat_map(|(i, d)| {
            [((d.a, d.bucket_a, 2 * d.pair, d.b), i as u32), ((d.b, d.bucket_b, 2 * d.pair + 1, d.a), i as u32)]
        })
        .collect();
    if keyed.is_empty() {
        return Ok(());
    }
    keyed.sort_unstable();
    // Per removed end: the key, the rays removed and the first record.
    let mut removals: Vec<(EndKey, i64, usize)> = Vec::new();
    for run in keyed.chunk_by(|x, y| x.0 == y.0) {
        let net: i64 = run.iter().map(|&(_, i)| records[i as usize].count as i64).sum();
        removals.push((run[0].0, net, run[0].1 as usize));
    }
    let mut wanted: Vec<u32> = removals.iter().map(|r| r.0.0).collect();
    wanted.dedup();
    let patches = offsets.len() - 1;
    let mut next = 0;
    let mut base: Vec<f64> = Vec::new();
    links.for_each_window_of(Columns::ALL, patches, &wanted, |w: LinkWindow<'_>| {
        while next < removals.len() && (removals[next].0.0 as usize) < w.patches.end {
            let q = removals[next].0.0;
            let count = removals[next..].iter().take_while(|r| r.0.0 == q).count();
            let mine = &removals[next..next + count];
            next += count;
            if (q as usize) < w.patches.start {
                continue;
            }
            // Frame 0's weight of each removed end, found by binary search:
            // a row is ordered by bucket, direction pair and the link's
            // patch pair (§5.10), that is by `order_key`.
            let r = w.local(offsets[q as usize] as usize..offsets[q as usize + 1] as usize);
            let order_key = |e: usize| {
                let (d, other) = (w.direction[e], w.other.ids()[e]);
                let link = if d.is_multiple_of(2) { (q, other) } else { (other, q) };
                (w.bucket.get(e).copied().unwrap_or(0), d / 2, link, d)
            };
            base.clear();
            for &((_, bucket, direction, other), _, _) in mine {
                let link = if direction.is_multiple_of(2) { (q, other) } else { (other, q) };
                let key = (bucket, direction / 2, link, direction);
                let from = r.start + first_false(r.len(), |i| order_key(r.start + i) < key);
                base.push(
                    (from..r.end).take_while(|&e| order_key(e) == key).map(|e| w.weight.get(e) as f64).sum::<f64>()
                        + 0.0,
                );
            }
            for (k, &((_, _, direction, other), net, first)) in mine.iter().enumerate() {
                if base[k] + (net as f64) < 0.0 {
                    return Err(bad(
                        first,
                        format!(
                            "removes {} rays from patch {q}'s end of its link with patch {other} along direction \
                             {direction}, which frame 0 gave {}: a negative weight",
                            -net, base[k]
                        ),
                    ));
                }
            }
        }
        Ok(())
    })
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
