//! The distribution's inner loops: the gathers over link ends and the
//! prototype-table scatter of non-diffuse patches. They hold the
//! distribution's only `unsafe`: per-patch state read without a bounds
//! check over link-end indices a [`Bounded`] proved in range once, and the
//! AVX2 table kernel called after a run-time CPU check.

use rayon::prelude::*;

use super::nondiffuse::NonDiffuse;
use super::overlay::Ends;
use crate::archive::{LinkWindow, PatchIds};

/// Patches per parallel task: large enough to amortise scheduling, small
/// enough to balance two to dozens of cores.
pub(super) const BLOCK: usize = 512;

/// Link-end patch indices known to be below `bound` (checked once, when
/// made), so that the gather indexes per-patch state with them without a
/// bounds check per end (9% of the distribution's time, measured).
#[derive(Clone, Copy)]
pub(super) struct Bounded<'a> {
    other: &'a [u32],
    bound: usize,
}

impl<'a> Bounded<'a> {
    /// The indices in `range` (which must lie within them).
    pub(super) fn slice(self, range: std::ops::Range<usize>) -> Self {
        Self { other: &self.other[range], bound: self.bound }
    }
}

impl<'a> From<PatchIds<'a>> for Bounded<'a> {
    fn from(ids: PatchIds<'a>) -> Self {
        Self { other: ids.ids(), bound: ids.bound() }
    }
}

impl Ends {
    /// The other patches, as indices below the patch count.
    pub(super) fn bounded(&self) -> Bounded<'_> {
        // Every `other` is a record's patch, asserted below `patches` in
        // `Ends::new`.
        Bounded { other: &self.other, bound: self.patches }
    }
}

/// `Σ w·shoot[other]` over a run of link ends, in four partial sums (ends
/// `4i + j` go to sum `j`): one sum would chain every addition on the one
/// before it, and the latency of that chain (4 cycles per end) was the
/// gather's limit. Generic over the weight's storage: f32 (overlays) or
/// the archive's one-byte counts (`LCNT`), which convert to the same f32.
#[inline(always)]
pub(super) fn weighted_sum<W: Copy + Into<f32>>(other: Bounded<'_>, weight: &[W], shoot: &[[f32; 4]]) -> [f32; 4] {
    assert!(shoot.len() >= other.bound, "per-patch state shorter than the patch indices allow");
    let n = other.other.len().min(weight.len());
    let (other, weight) = (&other.other[..n], &weight[..n]);
    // SAFETY (both `get_unchecked`): every index of a `Bounded` is below its
    // `bound` (checked when it was made), and `bound ≤ shoot.len()` (the
    // assertion above).
    let at = |o: u32| unsafe { *shoot.get_unchecked(o as usize) };
    let mut acc = [[0.0f32; 4]; 4];
    let (o4, w4) = (other.chunks_exact(4), weight.chunks_exact(4));
    let (o_rest, w_rest) = (o4.remainder(), w4.remainder());
    for (o, w) in o4.zip(w4) {
        for j in 0..4 {
            let s = at(o[j]);
            let wj: f32 = w[j].into();
            for c in 0..4 {
                acc[j][c] += wj * s[c];
            }
        }
    }
    for (j, (&o, &w)) in o_rest.iter().zip(w_rest).enumerate() {
        let s = at(o);
        let w: f32 = w.into();
        for c in 0..4 {
            acc[j][c] += w * s[c];
        }
    }
    [0, 1, 2, 3].map(|c| (acc[0][c] + acc[1][c]) + (acc[2][c] + acc[3][c]))
}

/// Adds what the window's weights kept apart (`LCNX`: weights that are
/// not a count in 1..=255, whose `LCNT` byte 0 gave nothing in the gather)
/// to their owners' slots of `out` (the window's patches' slots),
/// `slot(q, end)` choosing, within `out`, the slot of owner `q`'s end.
/// Serial: escapes are rare (none in the scenes we ship).
fn add_escapes(
    w: &LinkWindow<'_>,
    offsets: &[u64],
    present: Option<&[bool]>,
    shoot: &[[f32; 4]],
    out: &mut [[f32; 4]],
    slot: impl Fn(usize, usize) -> usize,
) {
    for x in w.weight.escapes() {
        let end = x.end as usize;
        // The owner: the last patch whose row starts at or before the end.
        let q = w.patches.start + offsets[w.patches.clone()].partition_point(|&o| o as usize <= end) - 1;
        if present.is_some_and(|p| !p[q]) {
            continue;
        }
        let s = shoot[w.other.ids()[end - w.first_end] as usize];
        let r = &mut out[slot(q, end)];
        for c in 0..4 {
            r[c] += x.weight * s[c];
        }
    }
}

/// Runs `f` over `out` in blocks of `BLOCK` patches (`per_patch` slots
/// each), `f` given the block's first patch index within `out`: on rayon's
/// workers when `parallel`, else on this thread (a window of a streamed
/// pass, whose workers each take whole windows).
fn for_blocks(
    out: &mut [[f32; 4]],
    per_patch: usize,
    parallel: bool,
    f: impl Fn(usize, &mut [[f32; 4]]) + Sync + Send,
) {
    let size = BLOCK * per_patch;
    if parallel {
        out.par_chunks_mut(size).enumerate().for_each(|(block, o)| f(block * BLOCK, o));
    } else {
        out.chunks_mut(size).enumerate().for_each(|(block, o)| f(block * BLOCK, o));
    }
}

/// Gathers `out[q − first] = Σ w·shoot[other]` over the link ends of the
/// window's patches (`first` its first patch; `offsets` is `LOFF`, `out`
/// has one entry per patch of the window); patches not `present`
/// (temporal instances absent from the frame) receive nothing. On rayon's
/// workers when `parallel`.
pub(super) fn gather(
    w: &LinkWindow<'_>,
    offsets: &[u64],
    present: Option<&[bool]>,
    shoot: &[[f32; 4]],
    out: &mut [[f32; 4]],
    parallel: bool,
) {
    assert_eq!(out.len(), w.patches.len(), "one entry per patch of the window");
    let other = Bounded::from(w.other);
    let base = w.patches.start;
    for_blocks(out, 1, parallel, |first, out| {
        for (i, r) in out.iter_mut().enumerate() {
            let q = base + first + i;
            if present.is_some_and(|p| !p[q]) {
                *r = [0.0; 4];
                continue;
            }
            let e = w.local(offsets[q] as usize..offsets[q + 1] as usize);
            *r = weighted_sum(other.slice(e.clone()), &w.weight.counts()[e], shoot);
        }
    });
    add_escapes(w, offsets, present, shoot, out, |q, _| q - base);
}

/// The runs of equal bucket in each patch's link ends (`LBKT`), found once
/// per archive: the gather then sums each run without looking at the
/// bucket of every end (that scan took a quarter of the gather's time).
pub(super) struct BucketRuns {
    /// Per patch, its runs `offsets[q]..offsets[q + 1]`.
    pub(super) offsets: Vec<u64>,
    /// Per run, the link end after its last one.
    end: Vec<u64>,
    /// Per run, its bucket.
    bucket: Vec<u8>,
}

impl BucketRuns {
    /// An empty set, to which [`Self::add`] appends patches in order.
    pub(super) fn with_patches(patches: usize) -> Self {
        let mut offsets = Vec::with_capacity(patches + 1);
        offsets.push(0);
        Self { offsets, end: Vec::new(), bucket: Vec::new() }
    }

    /// Appends the runs of the window's patches (`LOFF` is `link_offsets`;
    /// the window holds `LBKT`).
    pub(super) fn add(&mut self, link_offsets: &[u64], w: &LinkWindow<'_>) {
        for q in w.patches.clone() {
            let (a, b) = (link_offsets[q] as usize, link_offsets[q + 1] as usize);
            let bucket = &w.bucket[w.local(a..b)];
            for (i, k) in bucket.iter().enumerate() {
                if i + 1 == b - a || bucket[i + 1] != *k {
                    self.end.push((a + i + 1) as u64);
                    self.bucket.push(*k);
                }
            }
            self.offsets.push(self.end.len() as u64);
        }
    }
}

/// Like [`gather`], but sorts what arrives into buckets: slot
/// `(q − first)·B + k` of `out` holds the light patch `q` received over
/// ends of bucket `k` (B = buckets).
#[allow(clippy::too_many_arguments)]
pub(super) fn gather_buckets(
    w: &LinkWindow<'_>,
    offsets: &[u64],
    runs: &BucketRuns,
    buckets: usize,
    present: Option<&[bool]>,
    shoot: &[[f32; 4]],
    out: &mut [[f32; 4]],
    parallel: bool,
) {
    assert_eq!(out.len(), w.patches.len() * buckets, "one slot per patch of the window and bucket");
    let other = Bounded::from(w.other);
    let base = w.patches.start;
    for_blocks(out, buckets, parallel, |first, out| {
        for (i, r) in out.chunks_exact_mut(buckets).enumerate() {
            let q = base + first + i;
            r.fill([0.0; 4]);
            if present.is_some_and(|p| !p[q]) {
                continue;
            }
            // Buckets are validated to be < `buckets`.
            let mut e = offsets[q] as usize - w.first_end;
            for run in runs.offsets[q] as usize..runs.offsets[q + 1] as usize {
                let end = runs.end[run] as usize - w.first_end;
                let acc = weighted_sum(other.slice(e..end), &w.weight.counts()[e..end], shoot);
                let slot = &mut r[runs.bucket[run] as usize];
                for c in 0..4 {
                    slot[c] += acc[c];
                }
                e = end;
            }
        }
    });
    add_escapes(w, offsets, present, shoot, out, |q, end| {
        // The run of `q` that holds the end gives its bucket.
        let r = runs.offsets[q] as usize..runs.offsets[q + 1] as usize;
        let k = r.start + runs.end[r.clone()].partition_point(|&x| x as usize <= end);
        (q - base) * buckets + runs.bucket[k.min(r.end - 1)] as usize
    });
}

/// Adds `sign · Σ w·shoot[other]` over the ends of `ends` to each owner's
/// bucket slot of `recv` (a sparse gather: owners without ends cost one
/// offset comparison per bucket), and, given the non-diffuse patches and
/// their per-ray power `phi`, what non-diffuse senders send along the ends.
pub(super) fn add_ends(
    ends: &Ends,
    buckets: usize,
    shoot: &[[f32; 4]],
    sign: f32,
    nd: Option<(&NonDiffuse<'_>, &[[f32; 4]])>,
    recv: &mut [[f32; 4]],
) {
    recv.par_chunks_mut(BLOCK * buckets).enumerate().for_each(|(block, out)| {
        let first = block * BLOCK;
        for (i, r) in out.chunks_exact_mut(buckets).enumerate() {
            let q = first + i;
            for (k, slot) in r.iter_mut().enumerate() {
                let run = ends.run(q, buckets, k);
                if run.is_empty() {
                    continue;
                }
                let acc = weighted_sum(ends.bounded().slice(run.clone()), &ends.weight[run.clone()], shoot);
                for c in 0..4 {
                    slot[c] += sign * acc[c];
                }
                if let Some((nd, phi)) = nd {
                    for e in run {
                        let j = nd.nd_of[ends.other[e] as usize];
                        if j != u32::MAX {
                            let p = phi[nd.slot(j, ends.direction[e] ^ 1)];
                            for c in 0..4 {
                                slot[c] += sign * ends.weight[e] * p[c];
                            }
                        }
                    }
                }
            }
        }
    });
}

/// Zeroes the rows (`buckets` entries per patch) of patches absent from the
/// frame: what they received through the correction list of non-diffuse
/// senders, which holds frame 0's ends (the diffuse gathers skip absent
/// patches already), and what a mixed step would have them send.
pub(super) fn silence_absent(present: Option<&[bool]>, buckets: usize, recv: &mut [[f32; 4]]) {
    if let Some(present) = present {
        for (p, r) in recv.chunks_exact_mut(buckets).enumerate() {
            if !present[p] {
                r.fill([0.0; 4]);
            }
        }
    }
}

/// Patches that go through a prototype table together (see
/// `NonDiffuse::step`).
pub(super) const BATCH: usize = 8;
/// RGB of a batch, patch-major: lane `3b + c` is band `c` of patch `b`.
pub(super) const LANES: usize = 3 * BATCH;
/// One direction's light for a batch of patches.
pub(super) type Lanes = [f32; LANES];
/// A table row: outgoing directions and factors.
pub(super) type Row<'r> = (&'r [u32], &'r [f32]);

/// Adds, for each incoming direction `i` with light, row `rows(i)` of a
/// prototype table times that light to the scratch area (prototype
/// directions), `bands` factors per entry; with AVX2 and FMA when the CPU
/// has them (checked at run time).
pub(super) fn scatter_table_rows<'r>(
    bands: usize,
    inbuf: &[Lanes],
    scratch: &mut [Lanes],
    rows: &dyn Fn(usize) -> Row<'r>,
) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU was just checked to support AVX2 and FMA, the
        // only requirement of a `#[target_feature]` function.
        unsafe { scatter_rows_avx2(bands, inbuf, scratch, rows) };
        return;
    }
    scatter_rows(bands, inbuf, scratch, rows);
}

/// The scatter kernel, compiled twice: for the baseline target, and with
/// AVX2 + FMA (chosen at run time), where 24 lanes are three 8-wide FMAs
/// (1.2× faster than SSE2 on the glossy floor).
#[inline(always)]
fn scatter_rows<'r>(bands: usize, inbuf: &[Lanes], scratch: &mut [Lanes], rows: &dyn Fn(usize) -> Row<'r>) {
    for (i, light) in inbuf.iter().enumerate() {
        if light.iter().all(|&l| l == 0.0) {
            continue;
        }
        let (outs, f) = rows(i);
        if bands == 1 {
            for (&o, &f) in outs.iter().zip(f) {
                let s = &mut scratch[o as usize];
                for j in 0..LANES {
                    s[j] += f * light[j];
                }
            }
        } else {
            for (e, &o) in outs.iter().enumerate() {
                let s = &mut scratch[o as usize];
                let fe = [f[e * 3], f[e * 3 + 1], f[e * 3 + 2]];
                for j in 0..LANES {
                    s[j] += fe[j % 3] * light[j];
                }
            }
        }
    }
}

/// A prototype table by outgoing direction (its transpose), made when a
/// distributor is set up: for prototype direction `p`, the incoming rows
/// that reach it and their factors. Gathering by column keeps each output
/// in registers; scattering by row loads and stores it once per entry
/// (the row form skips unlit rows, which pays while few rows are lit).
pub(super) struct TableColumns {
    /// Factors per entry.
    pub bands: usize,
    /// Per prototype direction, its first entry (`n + 1` values).
    pub offsets: Vec<u32>,
    /// Per entry, the incoming prototype row.
    pub rows: Vec<u32>,
    /// Per entry, `bands` factors.
    pub factors: Vec<f32>,
}

impl TableColumns {
    /// The transpose of the `n` rows `rows(i)`.
    pub fn new<'r>(n: usize, bands: usize, rows: &dyn Fn(usize) -> Row<'r>) -> Self {
        let mut count = vec![0u32; n + 1];
        for i in 0..n {
            for &o in rows(i).0 {
                count[o as usize + 1] += 1;
            }
        }
        for p in 0..n {
            count[p + 1] += count[p];
        }
        let total = count[n] as usize;
        let (mut at, mut out_rows, mut factors) = (count.clone(), vec![0u32; total], vec![0.0f32; total * bands]);
        for i in 0..n {
            let (outs, f) = rows(i);
            for (e, &o) in outs.iter().enumerate() {
                let k = at[o as usize] as usize;
                at[o as usize] += 1;
                out_rows[k] = i as u32;
                factors[k * bands..(k + 1) * bands].copy_from_slice(&f[e * bands..(e + 1) * bands]);
            }
        }
        Self { bands, offsets: count, rows: out_rows, factors }
    }
}

/// `scratch[p] = Σ_r T(r→p)·light[r]` over the columns of a table, with
/// `light` in prototype order; with AVX2 and FMA when the CPU has them.
pub(super) fn gather_table_columns(cols: &TableColumns, light: &[Lanes], scratch: &mut [Lanes]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU was just checked to support AVX2 and FMA, the
        // only requirement of a `#[target_feature]` function.
        unsafe { gather_columns_avx2(cols, light, scratch) };
        return;
    }
    gather_columns(cols, light, scratch);
}

#[inline(always)]
fn gather_columns(cols: &TableColumns, light: &[Lanes], scratch: &mut [Lanes]) {
    for (p, out) in scratch.iter_mut().enumerate() {
        let (a, b) = (cols.offsets[p] as usize, cols.offsets[p + 1] as usize);
        let mut acc = [0.0f32; LANES];
        if cols.bands == 1 {
            for (&r, &f) in cols.rows[a..b].iter().zip(&cols.factors[a..b]) {
                let l = &light[r as usize];
                for j in 0..LANES {
                    acc[j] += f * l[j];
                }
            }
        } else {
            for (e, &r) in cols.rows[a..b].iter().enumerate() {
                let l = &light[r as usize];
                let k = (a + e) * 3;
                let fe = [cols.factors[k], cols.factors[k + 1], cols.factors[k + 2]];
                for j in 0..LANES {
                    acc[j] += fe[j % 3] * l[j];
                }
            }
        }
        *out = acc;
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn gather_columns_avx2(cols: &TableColumns, light: &[Lanes], scratch: &mut [Lanes]) {
    gather_columns(cols, light, scratch)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn scatter_rows_avx2<'r>(bands: usize, inbuf: &[Lanes], scratch: &mut [Lanes], rows: &dyn Fn(usize) -> Row<'r>) {
    scatter_rows(bands, inbuf, scratch, rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gathering_by_column_equals_scattering_by_row() {
        // A 1-band and a 3-band table of irregular sparse rows (some empty),
        // light in every lane: the transpose gathers what the rows scatter,
        // up to the order of the sums.
        let n = 37;
        for bands in [1, 3] {
            let mut outs: Vec<Vec<u32>> = Vec::new();
            let mut factors: Vec<Vec<f32>> = Vec::new();
            for i in 0..n {
                let len = (i * 7) % 11;
                outs.push(
                    (0..len)
                        .map(|e| ((i * 5 + e * 3) % n) as u32)
                        .collect::<std::collections::BTreeSet<_>>()
                        .into_iter()
                        .collect(),
                );
                factors
                    .push((0..outs[i].len() * bands).map(|k| 0.01 + ((i * 13 + k * 7) % 17) as f32 * 0.03).collect());
            }
            let rows = |i: usize| -> Row<'_> { (&outs[i], &factors[i]) };
            let light: Vec<Lanes> = (0..n).map(|i| std::array::from_fn(|j| ((i * 3 + j) % 5) as f32 - 1.0)).collect();
            let mut by_row = vec![[0.0f32; LANES]; n];
            scatter_table_rows(bands, &light, &mut by_row, &rows);
            let cols = TableColumns::new(n, bands, &rows);
            assert_eq!(cols.rows.len(), outs.iter().map(Vec::len).sum::<usize>());
            let mut by_column = vec![[1e9f32; LANES]; n]; // overwritten, not added to
            gather_table_columns(&cols, &light, &mut by_column);
            for (a, b) in by_row.iter().flatten().zip(by_column.iter().flatten()) {
                assert!((a - b).abs() <= 1e-5 * a.abs().max(1.0), "bands {bands}: {a} vs {b}");
            }
            assert!(by_row.iter().flatten().any(|&x| x != 0.0));
        }
    }

    #[test]
    fn bucketed_gather_equals_a_per_end_sum_whatever_the_bucket_order() {
        // Runs of equal bucket, found once, must give what adding every end
        // into its own bucket gives, also for ends not grouped by bucket
        // (the format does not require grouping) and for runs of every
        // length around the four partial sums.
        let n = 5;
        let lengths = [0usize, 1, 3, 4, 9, 13];
        let mut offsets = vec![0u64];
        let (mut other, mut weight, mut bucket) = (Vec::new(), Vec::new(), Vec::new());
        for q in 0..n {
            for e in 0..lengths[q % lengths.len()] + q {
                other.push(((q * 7 + e * 3) % n) as u32);
                weight.push(1.0 + e as f32 * 0.25);
                bucket.push(if q == 3 { (e % 2) as u8 } else { (e / 5).min(1) as u8 });
            }
            offsets.push(other.len() as u64);
        }
        let shoot: Vec<[f32; 4]> = (0..n).map(|p| [p as f32 + 1.0, 0.5, 2.0 - p as f32, 0.0]).collect();
        // Weights 1 + e/4: whole ones are one-byte counts, the rest escapes.
        let (mut counts, mut escapes) = (Vec::new(), Vec::new());
        crate::archive::weights::encode(&weight, 0, &mut counts, &mut escapes);
        assert!(!escapes.is_empty() && escapes.len() < weight.len());
        let window = |patches: std::ops::Range<usize>| {
            let ends = offsets[patches.start] as usize..offsets[patches.end] as usize;
            LinkWindow {
                first_end: ends.start,
                other: PatchIds::check(&other[ends.clone()], n).unwrap(),
                weight: crate::archive::Weights::new(&counts[ends.clone()], &escapes, ends.start as u64),
                direction: &[],
                bucket: &bucket[ends],
                patches,
            }
        };
        let mut runs = BucketRuns::with_patches(n);
        runs.add(&offsets, &window(0..n));
        assert_eq!(runs.offsets.len(), n + 1);
        assert!(PatchIds::check(&other, n - 1).is_none(), "the test reaches the last patch");
        let mut recv = vec![[0.0f32; 4]; n * 2];
        gather_buckets(&window(0..n), &offsets, &runs, 2, None, &shoot, &mut recv, true);
        // The same in three windows, runs found window by window too.
        let mut split = vec![[0.0f32; 4]; n * 2];
        let mut split_runs = BucketRuns::with_patches(n);
        for w in [0..2, 2..3, 3..n] {
            split_runs.add(&offsets, &window(w.clone()));
        }
        for w in [0..2, 2..3, 3..n] {
            let out = &mut split[w.start * 2..w.end * 2];
            gather_buckets(&window(w), &offsets, &split_runs, 2, None, &shoot, out, false);
        }
        assert_eq!(split, recv, "windows give the same sums in any windows");
        let mut want = vec![[0.0f64; 4]; n * 2];
        for q in 0..n {
            for e in offsets[q] as usize..offsets[q + 1] as usize {
                for c in 0..4 {
                    want[q * 2 + bucket[e] as usize][c] += weight[e] as f64 * shoot[other[e] as usize][c] as f64;
                }
            }
        }
        for (got, want) in recv.iter().zip(&want) {
            for c in 0..4 {
                assert!((got[c] as f64 - want[c]).abs() <= 1e-5 * want[c].abs().max(1.0), "{got:?} vs {want:?}");
            }
        }
        // Patch 3 alternates buckets: one run per end.
        assert_eq!(runs.offsets[4] - runs.offsets[3], offsets[4] - offsets[3]);
    }
}
