//! Link tables: merged bundle links → per-patch link-end lists (CSR).
//!
//! Each merged link `(a, b, w)` of pair `k` is stored twice, once at each
//! end: at `a` as `(other = b, weight = w, direction = 2k)` and at `b` as
//! `(a, w, 2k+1)`, the direction being the one light leaves the owner along.
//! Storing both ends makes distribution a pure gather, parallel over patches
//! with no atomics and a deterministic summation order. The rejected
//! alternative, one record per link scattered to both ends, needs atomics or
//! per-thread copies of the patch state.

use super::trace::Bundle;

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
}

/// Builds the table; entries of a patch are ordered by pair, then by the
/// bundle's `(a, b)` order.
pub fn assemble(bundles: &[Bundle], patch_count: usize) -> LinkTable {
    let mut count = vec![0u64; patch_count + 1];
    for b in bundles {
        for (&x, &y) in b.a.iter().zip(&b.b) {
            count[x as usize] += 1;
            count[y as usize] += 1;
        }
    }
    let mut offsets = Vec::with_capacity(patch_count + 1);
    let mut sum = 0u64;
    for c in &count[..patch_count] {
        offsets.push(sum);
        sum += c;
    }
    offsets.push(sum);
    let n = sum as usize;
    let mut other = vec![0u32; n];
    let mut weight = vec![0f32; n];
    let mut direction = vec![0u32; n];
    let mut cursor: Vec<u64> = offsets[..patch_count].to_vec();
    for bundle in bundles {
        for i in 0..bundle.a.len() {
            let (a, b, w) = (
                bundle.a[i] as usize,
                bundle.b[i] as usize,
                bundle.w[i] as f32,
            );
            let ca = cursor[a] as usize;
            other[ca] = b as u32;
            weight[ca] = w;
            direction[ca] = 2 * bundle.pair;
            cursor[a] += 1;
            let cb = cursor[b] as usize;
            other[cb] = a as u32;
            weight[cb] = w;
            direction[cb] = 2 * bundle.pair + 1;
            cursor[b] += 1;
        }
    }
    LinkTable {
        offsets,
        other,
        weight,
        direction,
    }
}
