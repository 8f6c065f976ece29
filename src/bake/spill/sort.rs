//! A run's link ends in their sorted order ([`sorted_run`]): placed by
//! owner into pieces of a few dozen ends as they are made (a counting
//! sort's scatter: a count pass, then each end written where its piece
//! goes), then each piece sorted by comparison where it lies, in cache.
//! Sorting the whole run by comparison took a sixth of a spilling build's
//! samples; an in-place radix sort (American flag) was slower still, its
//! swaps a chain of dependent cache misses. The pieces need no second
//! buffer, which the budget would count ([`super::SpillPlan`]).

use std::ops::Range;

use super::SortEnd;
use crate::bake::bundle::Bundle;

/// Ends a piece holds on average, at least: the pieces' counts (8 bytes
/// a piece, start and end) take at most 1/96 of the run's 24-byte ends,
/// beside the budgeted sort buffer.
const PIECE_ENDS: usize = 32;

/// Pieces a run is placed in, at most (2 MiB of counts; 2¹⁴ pieces of
/// ~670 ends sorted ~2% slower on the top rung's shard 3 of 16).
const MAX_PIECES: usize = 1 << 18;

/// The key an end is sorted by before its sequence number: owner, then
/// its slot (bucket, sender chunk: 24 bits).
#[inline]
fn key(e: &SortEnd) -> u64 {
    ((e.owner as u64) << 24) | e.slot() as u64
}

/// Fills `ends` with the two ends of each link of `segments` (a bundle of
/// `bundles` and a range of its links, in the run's order), numbered in
/// that order (the `a` end before the `b` end) and sorted by (owner,
/// slot, number): the order `sort_unstable_by_key(|e| (e.owner,
/// e.slot(), e.seq))` gives. Owners are below `patches`. Holds no memory
/// past `ends` (which it does not grow beyond the ends) and the pieces'
/// counts.
pub(super) fn sorted_run(
    bundles: &[Bundle],
    segments: &[(usize, Range<usize>)],
    patches: usize,
    ends: &mut Vec<SortEnd>,
) {
    let n: usize = 2 * segments.iter().map(|(_, r)| r.len()).sum::<usize>();
    let pieces = (n / PIECE_ENDS).clamp(1, MAX_PIECES);
    // Monotonic in the owner, so pieces hold ascending ranges of owners
    // (a multiplication and a shift: owners below 2³⁰, pieces below 2³²).
    let scale = ((pieces as u64) << 32) / patches.max(1) as u64;
    let piece = |owner: u32| ((owner as u64 * scale) >> 32).min(pieces as u64 - 1) as usize;
    let mut at = vec![0u32; pieces + 1];
    for &(b, ref links) in segments {
        let bundle = &bundles[b];
        for i in links.clone() {
            at[piece(bundle.a[i]) + 1] += 1;
            at[piece(bundle.b[i]) + 1] += 1;
        }
    }
    for p in 0..pieces {
        at[p + 1] += at[p];
    }
    let starts = at.clone();
    ends.clear();
    ends.resize(n, SortEnd { owner: 0, bucket: 0, seq: 0, other: 0, weight: 0.0, direction: 0 });
    let mut seq = 0u32;
    for &(b, ref links) in segments {
        let bundle = &bundles[b];
        for i in links.clone() {
            let weight = bundle.w[i] as f32;
            let (a, bb) = (bundle.a[i], bundle.b[i]);
            let place = &mut at[piece(a)];
            ends[*place as usize] =
                SortEnd { owner: a, bucket: bundle.bucket_a[i], seq, other: bb, weight, direction: 2 * bundle.pair };
            *place += 1;
            let place = &mut at[piece(bb)];
            ends[*place as usize] = SortEnd {
                owner: bb,
                bucket: bundle.bucket_b[i],
                seq: seq + 1,
                other: a,
                weight,
                direction: 2 * bundle.pair + 1,
            };
            *place += 1;
            seq += 2;
        }
    }
    for p in 0..pieces {
        ends[starts[p] as usize..starts[p + 1] as usize].sort_unstable_by_key(|e| (key(e), e.seq));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    proptest::proptest! {
        /// The comparison sort's order, for links over few or many
        /// patches, bundles cut anywhere.
        #[test]
        fn a_run_is_comparison_sorted(
            links in proptest::collection::vec((0u32..u32::MAX, 0u32..u32::MAX, 1u32..9, 0u8..5, 0u8..5), 0..3000),
            patches in 1usize..200_000,
            cuts in proptest::collection::vec(0usize..3000, 0..6),
        ) {
            // Bundles of consecutive pairs, the links cut between them.
            let mut cuts: Vec<usize> = cuts.into_iter().map(|c| c.min(links.len())).collect();
            cuts.extend([0, links.len()]);
            cuts.sort_unstable();
            let bundles: Vec<Bundle> = cuts
                .windows(2)
                .enumerate()
                .map(|(pair, w)| {
                    let mut b = Bundle { pair: pair as u32, ..Default::default() };
                    for &(a, bb, weight, ba, bbk) in &links[w[0]..w[1]] {
                        b.a.push(a % patches as u32);
                        b.b.push(bb % patches as u32);
                        b.w.push(weight);
                        b.bucket_a.push(ba);
                        b.bucket_b.push(bbk);
                    }
                    b
                })
                .collect();
            // The run: all but the first link of the first bundle.
            let segments: Vec<(usize, Range<usize>)> =
                bundles.iter().enumerate().map(|(i, b)| (i, usize::from(i == 0).min(b.a.len())..b.a.len())).collect();
            let mut want = Vec::new();
            for (b, r) in &segments {
                let bundle = &bundles[*b];
                for i in r.clone() {
                    let (a, bb, w) = (bundle.a[i], bundle.b[i], bundle.w[i] as f32);
                    let seq = want.len() as u32;
                    let d = 2 * bundle.pair;
                    let (ka, kb) = (bundle.bucket_a[i], bundle.bucket_b[i]);
                    want.push(SortEnd { owner: a, bucket: ka, seq, other: bb, weight: w, direction: d });
                    want.push(SortEnd { owner: bb, bucket: kb, seq: seq + 1, other: a, weight: w, direction: d + 1 });
                }
            }
            want.sort_unstable_by_key(|e| (e.owner, e.slot(), e.seq));
            let mut ends = Vec::new();
            sorted_run(&bundles, &segments, patches, &mut ends);
            let fields = |v: &[SortEnd]| {
                let f = |e: &SortEnd| (e.owner, e.bucket, e.seq, e.other, e.weight.to_bits(), e.direction);
                v.iter().map(f).collect::<Vec<_>>()
            };
            proptest::prop_assert_eq!(fields(&ends), fields(&want));
        }
    }
}
