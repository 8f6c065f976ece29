//! Link tables: merged bundle links → per-patch link-end lists (CSR).
//!
//! Each merged link `(a, b, w)` of pair `k` is stored twice, once at each
//! end: at `a` as `(other = b, weight = w, direction = 2k)` and at `b` as
//! `(a, w, 2k+1)`, the direction being the one light leaves the owner along.
//! Storing both ends makes distribution a pure gather, parallel over patches
//! with no atomics and a deterministic summation order. The rejected
//! alternative, one record per link scattered to both ends, needs atomics or
//! per-thread copies of the patch state.
//!
//! A patch's ends are grouped by bucket (ascending), then by sender chunk
//! (the other patch's id divided by 2¹⁶, §5.10), then by pair and the
//! bundle's `(a, b)` order: the archive stores each (bucket, chunk) run's
//! ids in 16 bits, and the distribution accumulates a run in registers
//! (accumulating into a bucket slot chosen per end measured 2.5× slower: a
//! store-to-load dependency per end).

use rayon::prelude::*;

use super::bundle::Bundle;
use crate::archive::layout::CHUNK_PATCHES;

/// The CSR link-end table.
pub struct LinkTable {
    /// `offsets[p]..offsets[p+1]` are patch `p`'s link ends.
    pub offsets: Vec<u64>,
    /// Patch at the other end.
    pub other: Vec<u32>,
    /// Rays merged into the link.
    pub weight: Vec<f32>,
    /// Direction light leaves the owner along.
    pub direction: Vec<u32>,
    /// Bucket (§3.4) of the light the owner receives over the link.
    pub bucket: Vec<u8>,
}

/// Builds the table (see the module docs for the order).
pub fn assemble(bundles: &[Bundle], patch_count: usize, max_bucket: u32) -> LinkTable {
    let nb = max_bucket as usize + 1;
    // Ends per (patch, bucket).
    let mut count = vec![0u64; patch_count * nb];
    for b in bundles {
        for i in 0..b.a.len() {
            count[b.a[i] as usize * nb + b.bucket_a[i] as usize] += 1;
            count[b.b[i] as usize * nb + b.bucket_b[i] as usize] += 1;
        }
    }
    let mut offsets = Vec::with_capacity(patch_count + 1);
    let mut cursor = vec![0u64; patch_count * nb];
    let mut sum = 0u64;
    for p in 0..patch_count {
        offsets.push(sum);
        for k in 0..nb {
            cursor[p * nb + k] = sum;
            sum += count[p * nb + k];
        }
    }
    offsets.push(sum);
    let n = sum as usize;
    let mut other = vec![0u32; n];
    let mut weight = vec![0f32; n];
    let mut direction = vec![0u32; n];
    let mut bucket = vec![0u8; n];
    // Scatter in parallel over ranges of owner patches with about equal
    // numbers of ends: each task scans every bundle and writes only its own
    // owners' ends, so every end lands where the sequential order puts it.
    // (One sequential scatter into 160 MB of columns ran at TLB-miss speed.)
    let tasks = (rayon::current_num_threads() * 2).clamp(1, 16);
    let mut cuts = vec![0usize];
    for t in 1..tasks {
        let target = (n as u64 * t as u64 / tasks as u64) as u64;
        let p = offsets.partition_point(|&o| o < target).min(patch_count);
        cuts.push(p.max(*cuts.last().expect("non-empty")));
    }
    cuts.push(patch_count);
    let mut parts = Vec::with_capacity(tasks);
    let (mut o, mut w, mut d, mut k) = (&mut other[..], &mut weight[..], &mut direction[..], &mut bucket[..]);
    for t in 0..tasks {
        let (lo, hi) = (cuts[t], cuts[t + 1]);
        let len = (offsets[hi] - offsets[lo]) as usize;
        let (o1, o2) = std::mem::take(&mut o).split_at_mut(len);
        let (w1, w2) = std::mem::take(&mut w).split_at_mut(len);
        let (d1, d2) = std::mem::take(&mut d).split_at_mut(len);
        let (k1, k2) = std::mem::take(&mut k).split_at_mut(len);
        parts.push((lo, hi, o1, w1, d1, k1));
        (o, w, d, k) = (o2, w2, d2, k2);
    }
    parts.into_par_iter().for_each(|(lo, hi, other, weight, direction, bucket)| {
        let base = offsets[lo];
        // Each row's ends lie by bucket, in spans the counts give: the
        // buckets are written span by span, in order, and the scatter
        // below writes three columns, not four.
        for (q, row) in count[lo * nb..hi * nb].chunks_exact(nb).enumerate() {
            let mut at = (offsets[lo + q] - base) as usize;
            for (k, &c) in row.iter().enumerate() {
                bucket[at..at + c as usize].fill(k as u8);
                at += c as usize;
            }
        }
        let mut cursor: Vec<u64> = cursor[lo * nb..hi * nb].to_vec();
        for bundle in bundles {
            for i in 0..bundle.a.len() {
                for (me, them, k, dir) in [
                    (bundle.a[i], bundle.b[i], bundle.bucket_a[i], 2 * bundle.pair),
                    (bundle.b[i], bundle.a[i], bundle.bucket_b[i], 2 * bundle.pair + 1),
                ] {
                    let me = me as usize;
                    if me < lo || me >= hi {
                        continue;
                    }
                    let slot = &mut cursor[(me - lo) * nb + k as usize];
                    let e = (*slot - base) as usize;
                    other[e] = them;
                    weight[e] = bundle.w[i] as f32;
                    direction[e] = dir;
                    *slot += 1;
                }
            }
        }
        // Within a bucket, by sender chunk, keeping the order above (only
        // archives of more than one chunk have anything to move).
        if patch_count > CHUNK_PATCHES {
            let mut order = Vec::new();
            let (mut o2, mut w2, mut d2) = (Vec::new(), Vec::new(), Vec::new());
            for q in lo..hi {
                let row = (offsets[q] - base) as usize..(offsets[q + 1] - base) as usize;
                let key = |e: usize| (bucket[e], other[e] as usize / CHUNK_PATCHES);
                if row.clone().zip(row.clone().skip(1)).all(|(a, b)| key(a) <= key(b)) {
                    continue;
                }
                order.clear();
                order.extend(row.clone());
                order.sort_by_key(|&e| key(e));
                o2.clear();
                o2.extend(order.iter().map(|&e| other[e]));
                w2.clear();
                w2.extend(order.iter().map(|&e| weight[e]));
                d2.clear();
                d2.extend(order.iter().map(|&e| direction[e]));
                other[row.clone()].copy_from_slice(&o2);
                weight[row.clone()].copy_from_slice(&w2);
                direction[row].copy_from_slice(&d2);
                // Buckets were ascending already: they stay where they are.
            }
        }
    });
    LinkTable { offsets, other, weight, direction, bucket }
}
