//! Sorting a pair's link keys and merging them into its bundle
//! ([`merged_bundle`]): LSD radix sorts. The keys of a pair (one
//! a facing hit pair, about one a ray) are sorted before they are merged;
//! comparison sorting them was the largest single cost of a
//! scan-converted build (`docs/notebook/2026-12-07-scan-conversion.md`).
//! Where a build's keys fit 64 bits they are packed into words first
//! ([`Packing`]): 1.11–1.19× the top rung's shard trace, the same bytes
//! (`docs/notebook/2026-12-08-spill-and-merge.md`), and sorted in digits
//! of up to 11 bits rather than bytes (fewer passes over the keys; its
//! gain, 1–10% of a shard's trace, is within this machine's noise:
//! `docs/notebook/2026-12-08-render-rays.md`). The second buffer is the
//! tracer's own, kept from pair to pair and counted in a bounded build's
//! scratch (16 bytes a key either way).

use super::LinkKey;
use crate::bake::bundle::Bundle;

/// Bytes of a key the sort looks at: the bucket at b, the bucket at a,
/// then the eight bytes of `a << 32 | b`, least significant first.
const DIGITS: usize = 10;

/// Keys fewer than this are sorted by comparison.
const SMALL: usize = 256;

/// Widest digit of a radix pass: its counts (4 bytes each, 8 KiB) stay in
/// the first-level cache beside the pass's two streams.
const DIGIT_BITS: u32 = 11;

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
    if n < SMALL || n > u32::MAX as usize {
        keys.sort_unstable();
        return;
    }
    buf.clear();
    buf.reserve_exact(n);
    buf.resize(n, (0, 0, 0));
    let second = buf.as_ptr();
    if lsd::<_, DIGITS, 256>(keys, buf, (DIGITS, 8), digit).as_ptr() == second {
        std::mem::swap(keys, buf);
    }
}

/// Sorts `a` by `passes` LSD passes over digits of `width` bits
/// (`R` = 2^width at most, at most `D` passes), `digit(x, d)` being digit
/// `d` (least significant first), with `b` (as long, at most 2³² − 1) as
/// the second buffer; a digit every element shares costs no pass. The
/// sorted elements: `a` or `b`.
fn lsd<'w, T: Copy, const D: usize, const R: usize>(
    a: &'w mut [T],
    b: &'w mut [T],
    (passes, width): (usize, u32),
    digit: impl Fn(&T, usize) -> usize,
) -> &'w mut [T] {
    let n = a.len();
    let mut counts = [[0u32; R]; D];
    let counts = &mut counts[..passes.min(D)];
    for x in a.iter() {
        for (d, c) in counts.iter_mut().enumerate() {
            c[digit(x, d)] += 1;
        }
    }
    let (mut from, mut to) = (a, b);
    for (d, c) in counts.iter_mut().enumerate() {
        let c = &mut c[..(1usize << width).min(R)];
        if c.contains(&(n as u32)) {
            continue;
        }
        // The counts become each digit's first place.
        let mut sum = 0;
        for k in c.iter_mut() {
            (*k, sum) = (sum, sum + *k);
        }
        for x in from.iter() {
            let i = &mut c[digit(x, d)];
            to[*i as usize] = *x;
            *i += 1;
        }
        std::mem::swap(&mut from, &mut to);
    }
    from
}

/// A pair's link keys packed into one word each, in the same order: `a`,
/// `b`, then the two buckets, each in as many bits as the build's patch
/// count and largest bucket need. Sorting words of 8 bytes in as many
/// byte passes as the packed keys have significant bytes moves a third
/// of the bytes the tuples' sort moves (Cornell box: 4 passes of 8 bytes
/// against 6 of 16).
#[derive(Debug, Clone, Copy)]
pub(super) struct Packing {
    patch_bits: u32,
    bucket_bits: u32,
}

impl Packing {
    /// The packing for `patches` patches and buckets up to `max_bucket`,
    /// or `None` when a key would not fit 64 bits.
    pub(super) fn new(patches: usize, max_bucket: u32) -> Option<Self> {
        let bits = |n: u64| 64 - n.leading_zeros();
        let (patch_bits, bucket_bits) = (bits(patches.saturating_sub(1) as u64), bits(max_bucket as u64));
        (2 * patch_bits + 2 * bucket_bits <= 64).then_some(Self { patch_bits, bucket_bits })
    }

    /// Bits a packed key spans.
    fn bits(&self) -> u32 {
        2 * (self.patch_bits + self.bucket_bits)
    }

    #[inline]
    fn pack(&self, &(key, ba, bb): &LinkKey) -> u64 {
        let (a, b) = (key >> 32, key & 0xffff_ffff);
        let ab = (a << self.patch_bits) | b;
        (((ab << self.bucket_bits) | ba as u64) << self.bucket_bits) | bb as u64
    }

    #[inline]
    fn unpack(&self, x: u64) -> LinkKey {
        let bucket = (1u64 << self.bucket_bits) - 1;
        let (bb, ba) = ((x & bucket) as u8, ((x >> self.bucket_bits) & bucket) as u8);
        let ab = x >> (2 * self.bucket_bits);
        let (a, b) = (ab >> self.patch_bits, ab & ((1u64 << self.patch_bits) - 1));
        ((a << 32) | b, ba, bb)
    }
}

/// A pair's link keys (`keys`, one per facing hit pair on a ray) sorted
/// and merged into pair `pair`'s bundle: one link per distinct key,
/// weighed by the rays that gave it. Packed by `packing` ([`Packing`])
/// into `words` (grown to twice the keys: 16 bytes a key, as the tuples'
/// second buffer took), else sorted in place by [`sort_keys`] with `buf`.
pub(super) fn merged_bundle(
    pair: u32,
    keys: &mut Vec<LinkKey>,
    packing: Option<Packing>,
    words: &mut Vec<u64>,
    buf: &mut Vec<LinkKey>,
) -> Bundle {
    let Some(p) = packing else {
        sort_keys(keys, buf);
        let n = keys.chunk_by(|x, y| x == y).count();
        return bundle_of(pair, n, keys.chunk_by(|x, y| x == y).map(|r| (r[0], r.len() as u32)));
    };
    let n = keys.len();
    // Grown (and zeroed) only when a pair has more keys than any before.
    if words.len() < 2 * n {
        words.reserve_exact(2 * n - words.len());
        words.resize(2 * n, 0);
    }
    let (sorted, other) = words[..2 * n].split_at_mut(n);
    for (w, k) in sorted.iter_mut().zip(keys.iter()) {
        *w = p.pack(k);
    }
    let sorted = sort_words(sorted, other, p.bits());
    let distinct = sorted.chunk_by(|x, y| x == y).count();
    bundle_of(pair, distinct, sorted.chunk_by(|x, y| x == y).map(|r| (p.unpack(r[0]), r.len() as u32)))
}

/// The bundle of pair `pair` of the `n` links `runs` (key, rays), in order.
fn bundle_of(pair: u32, n: usize, runs: impl Iterator<Item = (LinkKey, u32)>) -> Bundle {
    let mut bundle = Bundle {
        pair,
        a: Vec::with_capacity(n),
        b: Vec::with_capacity(n),
        w: Vec::with_capacity(n),
        bucket_a: Vec::with_capacity(n),
        bucket_b: Vec::with_capacity(n),
    };
    for ((key, ba, bb), w) in runs {
        bundle.a.push((key >> 32) as u32);
        bundle.b.push(key as u32);
        bundle.w.push(w);
        bundle.bucket_a.push(ba);
        bundle.bucket_b.push(bb);
    }
    bundle
}

/// Sorts `a`, whose words span their low `bits` bits, ascending with `b`
/// (as long) as the second buffer; the sorted words (in `a` or `b`). The
/// bits are cut into as few equal digits of at most [`DIGIT_BITS`] as
/// cover them, one pass each (the Cornell box's 32 bits: three passes of
/// 11, where bytes took four).
fn sort_words<'w>(a: &'w mut [u64], b: &'w mut [u64], bits: u32) -> &'w [u64] {
    if a.len() < SMALL || a.len() > u32::MAX as usize {
        a.sort_unstable();
        return a;
    }
    let bits = bits.clamp(1, 64);
    let passes = bits.div_ceil(DIGIT_BITS);
    let width = bits.div_ceil(passes);
    let mask = (1u64 << width) - 1;
    const PASSES: usize = 64usize.div_ceil(DIGIT_BITS as usize);
    lsd::<_, PASSES, { 1 << DIGIT_BITS }>(a, b, (passes as usize, width), |w, d| {
        ((w >> (d as u32 * width)) & mask) as usize
    })
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

        /// Packed, the same runs as the tuples sorted and merged, for
        /// patch counts and buckets of any width that fits.
        #[test]
        fn packed_keys_merge_as_tuples(
            seed in proptest::collection::vec((0u32..u32::MAX, 0u32..u32::MAX, 0u8..8, 0u8..8), 0..2000),
            patches in 1usize..1 << 30,
            max_bucket in 0u32..8,
        ) {
            let (p, m) = (patches as u32, max_bucket as u8 + 1);
            let mut keys: Vec<LinkKey> =
                seed.iter().map(|&(a, b, x, y)| ((((a % p) as u64) << 32) | (b % p) as u64, x % m, y % m)).collect();
            keys.extend_from_slice(&keys.clone()[..keys.len() / 3]);
            let mut want = keys.clone();
            want.sort_unstable();
            let want: Vec<(LinkKey, u32)> = want.chunk_by(|x, y| x == y).map(|r| (r[0], r.len() as u32)).collect();
            for packing in [Packing::new(patches, max_bucket), None] {
                // A second buffer longer than needed, holding what an earlier pair left.
                let (mut words, mut buf, mut k) = (vec![u64::MAX; 3 * keys.len() + 7], Vec::new(), keys.clone());
                let b = merged_bundle(7, &mut k, packing, &mut words, &mut buf);
                let got: Vec<(LinkKey, u32)> = (0..b.a.len())
                    .map(|i| ((((b.a[i] as u64) << 32) | b.b[i] as u64, b.bucket_a[i], b.bucket_b[i]), b.w[i]))
                    .collect();
                proptest::prop_assert_eq!(&got, &want);
                proptest::prop_assert_eq!(b.a.capacity(), want.len());
            }
        }
    }

    #[test]
    fn keys_pack_while_they_fit_64_bits() {
        assert!(Packing::new(1 << 30, 15).is_none(), "30 + 30 + 4 + 4 bits");
        assert!(Packing::new(1 << 30, 3).is_some(), "30 + 30 + 2 + 2 bits");
        assert!(Packing::new(1, 0).is_some());
    }
}
