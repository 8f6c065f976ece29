//! Sorting a pair's link keys: a byte-wise LSD radix sort. The keys of a
//! pair (one a facing hit pair, about one a ray) are sorted before they
//! are merged into its bundle; comparison sorting them was the largest
//! single cost of a scan-converted build (`docs/notebook/
//! 2026-12-07-scan-conversion.md`). The second buffer is the tracer's own,
//! kept from pair to pair and counted in a bounded build's scratch.

use super::LinkKey;

/// Bytes of a key the sort looks at: the bucket at b, the bucket at a,
/// then the eight bytes of `a << 32 | b`, least significant first.
const DIGITS: usize = 10;

/// Keys fewer than this are sorted by comparison.
const SMALL: usize = 256;

#[inline]
fn digit(k: &LinkKey, d: usize) -> usize {
    match d {
        0 => k.2 as usize,
        1 => k.1 as usize,
        _ => ((k.0 >> (8 * (d - 2))) & 0xff) as usize,
    }
}

/// Sorts `keys` ascending, as `sort_unstable` would, with `buf` as the
/// second buffer (grown to the keys' length); the two may trade places.
/// Bytes that every key shares (most of a patch id's high bytes) cost no
/// pass.
pub(super) fn sort_keys(keys: &mut Vec<LinkKey>, buf: &mut Vec<LinkKey>) {
    let n = keys.len();
    if n < SMALL {
        keys.sort_unstable();
        return;
    }
    let mut counts = [[0usize; 256]; DIGITS];
    for k in keys.iter() {
        for (d, c) in counts.iter_mut().enumerate() {
            c[digit(k, d)] += 1;
        }
    }
    buf.clear();
    buf.reserve_exact(n);
    buf.resize(n, (0, 0, 0));
    for (d, c) in counts.iter().enumerate() {
        if c.contains(&n) {
            continue;
        }
        let mut at = [0usize; 256];
        let mut sum = 0;
        for (a, &x) in at.iter_mut().zip(c) {
            *a = sum;
            sum += x;
        }
        for k in keys.iter() {
            let i = &mut at[digit(k, d)];
            buf[*i] = *k;
            *i += 1;
        }
        std::mem::swap(keys, buf);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    proptest::proptest! {
        /// The same order as a comparison sort, for keys whose patch ids
        /// and buckets span few or many bytes, with many repeats.
        #[test]
        fn radix_sorted_keys_are_comparison_sorted(
            seed in proptest::collection::vec((0u64..u64::MAX, 0u8..4, 0u8..4), 0..2000),
            spread in 0u32..64,
        ) {
            let mask = if spread == 0 { 0 } else { u64::MAX >> (64 - spread) };
            let mut keys: Vec<LinkKey> = seed.iter().map(|&(k, a, b)| (k & mask, a, b)).collect();
            // Repeats, as parallel rays give.
            keys.extend_from_slice(&keys.clone()[..keys.len() / 3]);
            let mut want = keys.clone();
            want.sort_unstable();
            let mut buf = Vec::new();
            sort_keys(&mut keys, &mut buf);
            proptest::prop_assert_eq!(keys, want);
        }
    }
}
