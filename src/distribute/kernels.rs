//! The distribution's inner loops: the gathers over link ends and the
//! prototype-table scatter of non-diffuse patches. They hold the
//! distribution's only `unsafe`: per-patch state read without a bounds
//! check over link-end indices a [`Bounded`] proved in range once, and the
//! AVX2 table kernel called after a run-time CPU check.

use rayon::prelude::*;

use super::overlay::Ends;
use crate::archive::{EndRun, LinkWindow, PatchIds};

/// Patches per parallel task: large enough to amortise scheduling, small
/// enough to balance two to dozens of cores.
pub(super) const BLOCK: usize = 512;

/// Link-end patch indices known to be below `bound` (checked once, when
/// made), so that the gather indexes per-patch state with them without a
/// bounds check per end (9% of the distribution's time, measured): 32-bit
/// ids (overlays) or a run's 16-bit ones (the archive's, the state then
/// sliced from the run's chunk base).
#[derive(Clone, Copy)]
pub(super) struct Bounded<'a, I = u32> {
    other: &'a [I],
    bound: usize,
}

impl<'a, I> Bounded<'a, I> {
    /// The indices in `range` (which must lie within them).
    pub(super) fn slice(self, range: std::ops::Range<usize>) -> Self {
        Self { other: &self.other[range], bound: self.bound }
    }
}

impl<'a, I: Copy + Into<u32>> From<PatchIds<'a, I>> for Bounded<'a, I> {
    fn from(ids: PatchIds<'a, I>) -> Self {
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

/// Per-patch state as the gathers read it: four lanes a patch, the first
/// three RGB (the fourth is never a result).
pub(super) trait StateRows: Copy {
    /// Patches that can be read.
    fn patches(self) -> usize;
    /// The rows from patch `base` on (`base ≤ patches`).
    fn from(self, base: usize) -> Self;
    /// Patch `i`'s lanes.
    ///
    /// # Safety
    /// `i < self.patches()`.
    unsafe fn lanes(self, i: usize) -> [f32; 4];

    /// Patch `i`'s lanes, bounds checked (away from the inner loops).
    #[inline]
    fn row(self, i: usize) -> [f32; 4] {
        assert!(i < self.patches(), "patch {i} of {}", self.patches());
        // SAFETY: `i < self.patches()`, just checked.
        unsafe { self.lanes(i) }
    }
}

impl StateRows for &[[f32; 4]] {
    fn patches(self) -> usize {
        self.len()
    }

    fn from(self, base: usize) -> Self {
        &self[base..]
    }

    #[inline(always)]
    unsafe fn lanes(self, i: usize) -> [f32; 4] {
        // SAFETY: `i < self.len()`, the caller's promise.
        unsafe { *self.get_unchecked(i) }
    }
}

/// The per-patch state the gather of frame 0's links reads, packed: each
/// patch's RGB in 12 bytes instead of the iteration's 16, and one float of
/// padding at the end. A patch is still one 16-byte load (its RGB and the
/// next patch's red, which is summed into a lane no one reads), so the
/// gather runs the same instructions over three quarters of the memory:
/// 1.14× faster on a 10⁶-patch building in primitive order (which
/// sequences keep), 1.0–1.05× in spatial order, as fast on the default
/// Cornell box, whose state fits in L2 anyway (docs/notebook/
/// 2026-12-05-packed-state.md). RGB sums are bit for bit those of the unpacked state.
#[derive(Debug, Default)]
pub(super) struct PackedRgb {
    rgb: Vec<f32>,
}

impl PackedRgb {
    /// Room for `patches` patches.
    pub(super) fn new(patches: usize) -> Self {
        Self { rgb: vec![0.0; 3 * patches + 1] }
    }

    /// Copies the RGB of `state` (one entry per patch) in.
    #[cfg(test)]
    pub(super) fn fill(&mut self, state: &[[f32; 4]]) {
        assert_eq!(self.rgb.len(), 3 * state.len() + 1, "one packed patch per state entry");
        self.rgb[..3 * state.len()].par_chunks_mut(3 * BLOCK).zip(state.par_chunks(BLOCK)).for_each(|(to, from)| {
            for (t, f) in to.chunks_exact_mut(3).zip(from) {
                t.copy_from_slice(&f[..3]);
            }
        });
    }

    /// The packed rows, for the gather.
    pub(super) fn rows(&self) -> Packed<'_> {
        Packed(&self.rgb)
    }

    /// The RGB of each block of [`BLOCK`] patches (three floats a patch,
    /// the padding apart), to write in parallel.
    pub(super) fn blocks_mut(&mut self) -> rayon::slice::ChunksMut<'_, f32> {
        let n = self.rgb.len() - 1;
        self.rgb[..n].par_chunks_mut(3 * BLOCK)
    }
}

/// [`PackedRgb`]'s rows (from some patch on), with the padding float.
#[derive(Clone, Copy)]
pub(super) struct Packed<'a>(&'a [f32]);

impl StateRows for Packed<'_> {
    fn patches(self) -> usize {
        self.0.len().saturating_sub(1) / 3
    }

    fn from(self, base: usize) -> Self {
        Packed(&self.0[3 * base..])
    }

    #[inline(always)]
    unsafe fn lanes(self, i: usize) -> [f32; 4] {
        // SAFETY: `i < self.patches()` (the caller's promise), so
        // `3i + 4 ≤ self.0.len()`: the four floats lie within the slice.
        unsafe { self.0.as_ptr().add(3 * i).cast::<[f32; 4]>().read_unaligned() }
    }
}

/// `Σ w·shoot[other]` over a run of link ends, in four partial sums (ends
/// `4i + j` go to sum `j`): one sum would chain every addition on the one
/// before it, and the latency of that chain (4 cycles per end) was the
/// gather's limit. Generic over the id's width (an archive run's 16 bits,
/// an overlay's 32) and the weight's storage: f32 (overlays) or the
/// archive's one-byte counts (`LCNT`), which convert to the same f32.
#[inline(always)]
pub(super) fn weighted_sum<I: Copy + Into<u32>, W: Copy + Into<f32>, S: StateRows>(
    other: Bounded<'_, I>,
    weight: &[W],
    shoot: S,
) -> [f32; 4] {
    let mut acc = [[0.0f32; 4]; 4];
    accumulate(&mut acc, other, weight, shoot);
    reduce(&acc)
}

/// Adds `w·shoot[other]` over a run of link ends to the four partial sums
/// `acc` (ends `4i + j` of the run to sum `j`), without adding them up:
/// consecutive runs of one receiver's slot (its sender chunks) share one
/// reduction ([`reduce`]).
#[inline(always)]
fn accumulate<I: Copy + Into<u32>, W: Copy + Into<f32>, S: StateRows>(
    acc: &mut [[f32; 4]; 4],
    other: Bounded<'_, I>,
    weight: &[W],
    shoot: S,
) {
    assert!(shoot.patches() >= other.bound, "per-patch state shorter than the patch indices allow");
    let n = other.other.len().min(weight.len());
    let (other, weight) = (&other.other[..n], &weight[..n]);
    // SAFETY: every index of a `Bounded` is below its `bound` (checked when
    // it was made), and `bound ≤ shoot.patches()` (the assertion above).
    let at = |o: I| unsafe { shoot.lanes(o.into() as usize) };
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
}

/// The sum of four partial sums, in a fixed order.
#[inline(always)]
fn reduce(acc: &[[f32; 4]; 4]) -> [f32; 4] {
    [0, 1, 2, 3].map(|c| (acc[0][c] + acc[1][c]) + (acc[2][c] + acc[3][c]))
}

/// Adds what the window's weights kept apart (`LCNX`: weights that are
/// not a count in 1..=255, whose `LCNT` byte 0 gave nothing in the gather)
/// to their owners' slots of `out` (`buckets` slots for each of the
/// window's patches). Serial: escapes are rare (none in the scenes we
/// ship).
fn add_escapes(w: &LinkWindow<'_>, buckets: usize, present: Option<&[bool]>, shoot: Packed<'_>, out: &mut [[f32; 3]]) {
    let offsets = w.runs.link_offsets();
    // The escapes of the window's rows (a narrowed window's columns hold
    // other patches' ends too).
    let (first, last) = (offsets[w.patches.start], offsets[w.patches.end]);
    let escapes = w.weight.escapes();
    let escapes = &escapes[escapes.partition_point(|x| x.end < first)..escapes.partition_point(|x| x.end < last)];
    for x in escapes {
        let end = x.end as usize;
        // The owner: the last patch whose row starts at or before the end.
        let q = w.patches.start + offsets[w.patches.clone()].partition_point(|&o| o as usize <= end) - 1;
        if present.is_some_and(|p| !p[q]) {
            continue;
        }
        let Some((_, other, bucket)) = w.ends_of(q).find(|e| e.0 + w.first_end == end) else { continue };
        let s = shoot.row(other as usize);
        let k = if buckets > 1 { bucket as usize } else { 0 };
        let r = &mut out[(q - w.patches.start) * buckets + k];
        for c in 0..3 {
            r[c] += x.weight * s[c];
        }
    }
}

/// Runs `f` over `out` in blocks of `BLOCK` patches (`per_patch` slots
/// each), `f` given the block's first patch index within `out`: on rayon's
/// workers when `parallel`, else on this thread (a window of a streamed
/// pass, whose workers each take whole windows).
fn for_blocks(
    out: &mut [[f32; 3]],
    per_patch: usize,
    parallel: bool,
    f: impl Fn(usize, &mut [[f32; 3]]) + Sync + Send,
) {
    let size = BLOCK * per_patch;
    if parallel {
        out.par_chunks_mut(size).enumerate().for_each(|(i, o)| f(i * BLOCK, o));
    } else {
        out.chunks_mut(size).enumerate().for_each(|(i, o)| f(i * BLOCK, o));
    }
}

/// Gathers `Σ w·shoot[other]` over the link ends of the window's patches
/// into `out`, sorted into buckets: slot `(q − first)·B + k` holds the
/// light patch `q` received over ends of bucket `k` (B = `buckets`; with
/// one, every end's light goes to the patch's one slot). Patches not
/// `present` (temporal instances absent from the frame) receive nothing.
/// A run of ends (one bucket, one sender chunk) is summed at a time, its
/// 16-bit ids against the state from its chunk's base; a slot's runs share
/// one reduction. On rayon's workers when `parallel`.
pub(super) fn gather(
    w: &LinkWindow<'_>,
    buckets: usize,
    present: Option<&[bool]>,
    packed: Packed<'_>,
    out: &mut [[f32; 3]],
    parallel: bool,
) {
    assert_eq!(out.len(), w.patches.len() * buckets, "one slot per patch of the window and bucket");
    let base = w.patches.start;
    let counts = w.weight.counts();
    for_blocks(out, buckets, parallel, |first, out| {
        for (i, r) in out.chunks_exact_mut(buckets).enumerate() {
            let q = base + first + i;
            r.fill([0.0; 3]);
            if present.is_some_and(|p| !p[q]) {
                continue;
            }
            // A slot's runs (its sender chunks) add into one set of
            // partial sums, reduced once: a receiver of a 10⁶-patch
            // archive has ~7 runs of ~65 ends.
            let mut acc = [[0.0f32; 4]; 4];
            let mut slot: Option<usize> = None;
            let mut add = |run: EndRun<'_>, k: usize| {
                if slot.is_some_and(|s| s != k) {
                    let sum = reduce(&acc);
                    let to = &mut r[slot.expect("checked")];
                    // RGB: the packed state's fourth lane is another
                    // patch's red.
                    for c in 0..3 {
                        to[c] += sum[c];
                    }
                    acc = [[0.0f32; 4]; 4];
                }
                slot = Some(k);
                accumulate(&mut acc, Bounded::from(run.ids()), &counts[run.ends()], packed.from(run.base()));
            };
            if buckets > 1 {
                // Buckets are validated to be at most the archive's widest.
                w.runs_of(q).for_each(|run| {
                    let k = run.bucket() as usize;
                    add(run, k)
                });
            } else {
                w.chunk_runs_of(q).for_each(|run| add(run, 0));
            }
            if let Some(k) = slot {
                let sum = reduce(&acc);
                for c in 0..3 {
                    r[k][c] += sum[c];
                }
            }
        }
    });
    add_escapes(w, buckets, present, packed, out);
}

/// What non-diffuse senders send along link ends ([`add_ends`]): a plain
/// view of the non-diffuse patches' per-ray power, so that the kernels
/// need not know the non-diffuse state that makes it
/// (`NonDiffuse::senders`).
#[derive(Clone, Copy)]
pub(super) struct DirectionalSenders<'a> {
    /// Per patch, its non-diffuse index (`u32::MAX`: diffuse).
    pub nd_of: &'a [u32],
    /// Directions in the set.
    pub directions: usize,
    /// Per-ray power of non-diffuse patch `k` along direction `d` at
    /// `k · directions + d` (`NonDiffuse::slot`).
    pub phi: &'a [[f32; 4]],
}

/// Adds `sign · Σ w·shoot[other]` over the ends of `ends` to each owner's
/// bucket slot of `recv` (a sparse gather: owners without ends cost one
/// offset comparison per bucket), and, given the non-diffuse senders,
/// what they send along the ends.
pub(super) fn add_ends<S: StateRows + Sync>(
    ends: &Ends,
    buckets: usize,
    shoot: S,
    sign: f32,
    nd: Option<DirectionalSenders<'_>>,
    recv: &mut [[f32; 3]],
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
                // RGB: a packed state's fourth lane is another patch's red.
                for c in 0..3 {
                    slot[c] += sign * acc[c];
                }
                if let Some(nd) = nd {
                    for e in run {
                        let j = nd.nd_of[ends.other[e] as usize];
                        if j != u32::MAX {
                            let p = nd.phi[j as usize * nd.directions + (ends.direction[e] ^ 1) as usize];
                            for c in 0..3 {
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
pub(super) fn silence_absent(present: Option<&[bool]>, buckets: usize, recv: &mut [[f32; 3]]) {
    if let Some(present) = present {
        for (p, r) in recv.chunks_exact_mut(buckets).enumerate() {
            if !present[p] {
                r.fill([0.0; 3]);
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
    use crate::archive::LinkRuns;

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
    fn the_run_gather_equals_a_per_end_sum_across_chunks_buckets_and_windows() {
        // 70 000 patches: two sender chunks (the second partly filled), a
        // few patches with rows of every length around the four partial
        // sums, ends in both chunks and two buckets, weights that are
        // counts and weights kept apart (escapes).
        use crate::archive::layout::{CHUNK_PATCHES, LinkRunRecord};
        let n = 70_000;
        let owners = [0usize, 1, 3, 4, 65_540, 69_999];
        let lengths = [0usize, 1, 5, 9, 13, 30];
        let mut rows: Vec<Vec<(u8, u32, f32)>> = vec![Vec::new(); n];
        for (i, (&q, &len)) in owners.iter().zip(&lengths).enumerate() {
            for e in 0..len {
                let other = ((q * 7 + e * 9_973 + i) % n) as u32;
                let bucket = ((e + i) % 3 == 0) as u8;
                rows[q].push((bucket, other, 1.0 + e as f32 * 0.25));
            }
            // The format's order: by bucket, then sender chunk, stably.
            rows[q].sort_by_key(|&(k, o, _)| (k, o as usize / CHUNK_PATCHES));
        }
        let (mut offsets, mut run_offsets) = (vec![0u64], vec![0u64]);
        let (mut ids, mut weight, mut runs, mut other) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for row in &rows {
            for run in row.chunk_by(|x, y| (x.0, x.1 as usize / CHUNK_PATCHES) == (y.0, y.1 as usize / CHUNK_PATCHES)) {
                let chunk = (run[0].1 as usize / CHUNK_PATCHES) as u16;
                runs.push(LinkRunRecord { chunk, bucket: run[0].0, reserved: 0, length: run.len() as u32 });
                for &(_, o, w) in run {
                    ids.push((o as usize % CHUNK_PATCHES) as u16);
                    weight.push(w);
                    other.push(o);
                }
            }
            offsets.push(ids.len() as u64);
            run_offsets.push(runs.len() as u64);
        }
        assert!(runs.iter().any(|r| r.chunk == 1) && runs.iter().any(|r| r.chunk == 0));
        let shoot: Vec<[f32; 4]> = (0..n).map(|p| [(p % 17) as f32 + 1.0, 0.5, 2.0 - (p % 5) as f32, 0.0]).collect();
        // Weights 1 + e/4: whole ones are one-byte counts, the rest escapes.
        let (mut counts, mut escapes) = (Vec::new(), Vec::new());
        crate::archive::weights::encode(&weight, 0, &mut counts, &mut escapes);
        assert!(!escapes.is_empty() && escapes.len() < weight.len());
        let window = |patches: std::ops::Range<usize>| {
            let ends = offsets[patches.start] as usize..offsets[patches.end] as usize;
            let weights = crate::archive::Weights::new(&counts[ends.clone()], &escapes, ends.start as u64);
            let all = LinkRuns::checked(&offsets, &run_offsets, &runs, 1).unwrap();
            LinkWindow::checked(patches, &ids[ends], weights, &[], all).unwrap()
        };
        let mut want = vec![[0.0f64; 3]; n * 2];
        for (q, row) in rows.iter().enumerate() {
            for &(k, o, w) in row {
                for c in 0..3 {
                    want[q * 2 + k as usize][c] += w as f64 * shoot[o as usize][c] as f64;
                }
            }
        }
        let close = |got: &[[f32; 3]], want: &[[f64; 3]]| {
            for (got, want) in got.iter().zip(want) {
                for c in 0..3 {
                    assert!((got[c] as f64 - want[c]).abs() <= 1e-5 * want[c].abs().max(1.0), "{got:?} vs {want:?}");
                }
            }
        };
        let mut packed = PackedRgb::new(n);
        packed.fill(&shoot);
        let state = packed.rows();
        let mut recv = vec![[9.0f32; 3]; n * 2]; // overwritten, not added to
        gather(&window(0..n), 2, None, state, &mut recv, true);
        close(&recv, &want);
        // The same in three windows.
        let mut split = vec![[0.0f32; 3]; n * 2];
        for w in [0..2, 2..65_000, 65_000..n] {
            let out = &mut split[w.start * 2..w.end * 2];
            gather(&window(w), 2, None, state, out, false);
        }
        assert_eq!(split, recv, "windows give the same sums in any windows");
        // One bucket: each patch's light in its one slot.
        let mut one = vec![[0.0f32; 3]; n];
        gather(&window(0..n), 1, None, state, &mut one, true);
        let merged: Vec<[f64; 3]> = want.chunks(2).map(|b| std::array::from_fn(|c| b[0][c] + b[1][c])).collect();
        close(&one, &merged);
        // The decoded ids are the other patches.
        assert_eq!(window(0..n).other_ids(), other);
        // Ids past the patch count in the last chunk are refused.
        let mut bad = ids.clone();
        let last = runs.iter().position(|r| r.chunk == 1).unwrap();
        let at = (0..runs.len()).take(last).map(|r| runs[r].length as usize).sum::<usize>();
        bad[at] = (n - CHUNK_PATCHES) as u16;
        let weights = crate::archive::Weights::new(&counts, &escapes, 0);
        let all = LinkRuns::checked(&offsets, &run_offsets, &runs, 1).unwrap();
        assert!(LinkWindow::checked(0..n, &bad, weights, &[], all).is_none());
        // Runs that do not cover their rows are refused.
        let mut short = runs.clone();
        short[0].length += 1;
        assert!(LinkRuns::checked(&offsets, &run_offsets, &short, 1).is_none());
    }
}
