//! Frame 0's link-end columns (`LOTH`, `LCNT` with `LCNX`, `LDIR`) and
//! their runs (`LROF`, `LRUN`, §5.10), resident (slices of a mapped
//! archive) or streamed (read window by window into reused buffers,
//! [`super::LinkStream`]), behind one interface ([`super::Links`], in
//! `ends`): the distribution walks them in windows of consecutive patches
//! and never needs to know which. This file holds what both are made of
//! and checked by: windows, runs, patch ids proved in range; the stream
//! builds on it, and `ends` on both.
//!
//! A link end's other patch is stored in 16 bits, local to the sender
//! chunk of its run (`chunk · 2¹⁶ + LOTH`). The ids of a run are proved in
//! range (below the patch count, chunk base added) when the run's window
//! enters memory, so per-patch state is indexed with them unchecked; the
//! proof travels with the run ([`EndRun::ids`]), never apart from it.

use std::ops::Range;

use super::layout::{CHUNK_PATCHES, LinkRunRecord};
use super::weights::Weights;

/// Patch indices proved below `bound` when made, so that per-patch state
/// of at least `bound` entries can be indexed with them without a bounds
/// check per link end (9% of the distribution's time, measured): 32-bit
/// ids (overlays) or an archive run's 16-bit ones, whose state starts at
/// the run's chunk base.
#[derive(Clone, Copy)]
pub struct PatchIds<'a, I = u32> {
    ids: &'a [I],
    bound: usize,
}

impl<'a, I: Copy + Into<u32>> PatchIds<'a, I> {
    /// `None` unless every index is below `bound`.
    pub fn check(ids: &'a [I], bound: usize) -> Option<Self> {
        // The largest id, without an early exit: this vectorises (4× the
        // speed of `all`, which stops at the first failure).
        let max = ids.iter().map(|&x| x.into()).fold(0u32, u32::max);
        (ids.is_empty() || (max as usize) < bound).then_some(Self { ids, bound })
    }

    /// The indices in `range` (which must lie within them).
    pub fn slice(self, range: Range<usize>) -> Self {
        Self { ids: &self.ids[range], bound: self.bound }
    }

    /// The indices.
    pub fn ids(&self) -> &'a [I] {
        self.ids
    }

    /// What every index is below.
    pub fn bound(&self) -> usize {
        self.bound
    }
}

/// Each patch's link ends as runs of one bucket and one sender chunk
/// (`LROF`, `LRUN`, with `LOFF`), checked when the archive was opened
/// (§7): a patch's runs cover its row exactly, in ascending (bucket,
/// chunk), each chunk below the patch count's.
#[derive(Clone, Copy)]
pub struct LinkRuns<'a> {
    link_offsets: &'a [u64],
    run_offsets: &'a [u64],
    /// Runs `first .. first + runs.len()` of `LRUN`: all of them
    /// (resident), a window's (streamed), or none (a streamed archive's
    /// runs outside a window).
    runs: &'a [LinkRunRecord],
    first: usize,
}

impl<'a> LinkRuns<'a> {
    /// Runs validated by [`check_run_offsets`] and [`check_rows`], by the
    /// code of this module's parent only: all of them (`first` 0), or the
    /// runs of a window's patches (`first` the first's `LROF`).
    pub(super) fn validated(
        link_offsets: &'a [u64],
        run_offsets: &'a [u64],
        runs: &'a [LinkRunRecord],
        first: usize,
    ) -> Self {
        Self { link_offsets, run_offsets, runs, first }
    }

    /// Runs given by the caller (tests, tools), checked against
    /// `link_offsets` (`LOFF`, itself checked: from 0, never decreasing)
    /// and `max_bucket` by the rules of §7; `None` when one is broken.
    pub fn checked(
        link_offsets: &'a [u64],
        run_offsets: &'a [u64],
        runs: &'a [LinkRunRecord],
        max_bucket: u8,
    ) -> Option<Self> {
        let ascending = link_offsets.first() == Some(&0) && link_offsets.windows(2).all(|w| w[0] <= w[1]);
        let patches = link_offsets.len().saturating_sub(1);
        let ok = ascending
            && check_run_offsets(run_offsets, patches, runs.len() as u64).is_ok()
            && check_rows(link_offsets, run_offsets, 0..patches, runs, max_bucket).is_ok();
        ok.then_some(Self { link_offsets, run_offsets, runs, first: 0 })
    }

    /// The runs of patch `q` (one whose runs are held), in row order.
    pub fn of(&self, q: usize) -> &'a [LinkRunRecord] {
        &self.runs[self.run_offsets[q] as usize - self.first..self.run_offsets[q + 1] as usize - self.first]
    }

    /// The runs held, in file order.
    pub fn records(&self) -> &'a [LinkRunRecord] {
        self.runs
    }

    /// `LOFF`: per patch, its first link end (patches + 1 entries).
    pub fn link_offsets(&self) -> &'a [u64] {
        self.link_offsets
    }

    /// `LROF`: per patch, its first run (patches + 1 entries).
    pub fn offsets(&self) -> &'a [u64] {
        self.run_offsets
    }
}

/// The rules of §7 for `LROF` alone: P + 1 entries from 0, never
/// decreasing, to the `runs` of `LRUN`.
pub(super) fn check_run_offsets(run_offsets: &[u64], patches: usize, runs: u64) -> Result<(), String> {
    if run_offsets.len() != patches + 1 {
        return Err(format!("LROF: {} entries, expected {} (one per patch, and one)", run_offsets.len(), patches + 1));
    }
    if run_offsets[0] != 0 || run_offsets[patches] != runs || run_offsets.windows(2).any(|w| w[1] < w[0]) {
        return Err(format!("LROF: must run from 0 to the {runs} runs of LRUN, never decreasing"));
    }
    Ok(())
}

/// The content rules of §7 for the runs of `patches` (`runs`, from the
/// first of them on), against `LOFF` (`link_offsets`, checked), `LROF`
/// (`run_offsets`, checked by [`check_run_offsets`]), `max_bucket` and the
/// patch count: the first rule broken, if any.
pub(super) fn check_rows(
    link_offsets: &[u64],
    run_offsets: &[u64],
    patches: Range<usize>,
    runs: &[LinkRunRecord],
    max_bucket: u8,
) -> Result<(), String> {
    let chunks = (link_offsets.len() - 1).div_ceil(CHUNK_PATCHES);
    let first = run_offsets[patches.start];
    if run_offsets[patches.end] - first != runs.len() as u64 {
        return Err(format!(
            "LRUN: {} runs read for patches {patches:?}, LROF says {}",
            runs.len(),
            run_offsets[patches.end] - first
        ));
    }
    for q in patches {
        let (a, b) = ((run_offsets[q] - first) as usize, (run_offsets[q + 1] - first) as usize);
        let mut ends = 0u64;
        let mut last: Option<(u8, u16)> = None;
        for r in &runs[a..b] {
            if r.length == 0 || r.reserved != 0 {
                return Err(format!("LRUN: patch {q} has a run of no ends, or a reserved byte set"));
            }
            if r.bucket > max_bucket {
                return Err(format!(
                    "LRUN: patch {q} has a run of bucket {} above BILD.max_bucket {max_bucket}",
                    r.bucket
                ));
            }
            if r.chunk as usize >= chunks {
                return Err(format!(
                    "LRUN: patch {q} has a run of sender chunk {}, beyond the {chunks} chunks",
                    r.chunk
                ));
            }
            if last.is_some_and(|l| l >= (r.bucket, r.chunk)) {
                return Err(format!("LRUN: patch {q}'s runs are not in ascending (bucket, chunk)"));
            }
            last = Some((r.bucket, r.chunk));
            ends += r.length as u64;
        }
        let row = link_offsets[q + 1] - link_offsets[q];
        if ends != row {
            return Err(format!("LRUN: patch {q}'s runs hold {ends} link ends, its row (LOFF) {row}"));
        }
    }
    Ok(())
}

/// Checks link-end ids read in file order against the runs they fall in:
/// every id plus its run's chunk base below the patch count. Only runs of
/// the last chunk need looking at (any 16-bit id of an earlier chunk is
/// below it). Fed piece by piece, from the start of a run, with the runs
/// in file order (a slice's, or read from disk as they are needed).
pub(super) struct IdCheck<R> {
    runs: R,
    left: u32,
    /// Ids of the current run must be below this.
    bound: usize,
    patches: usize,
    /// Every run was taken.
    exhausted: bool,
}

impl<R: Iterator<Item = LinkRunRecord>> IdCheck<R> {
    /// A check of the ids of `runs` (consecutive, in file order) among
    /// `patches` patches.
    pub(super) fn new(runs: R, patches: usize) -> Self {
        Self { runs, left: 0, bound: 0, patches, exhausted: false }
    }

    /// Whether the next `ids.len()` ids are in range (false, too, when
    /// they run past the runs).
    pub(super) fn add(&mut self, mut ids: &[u16]) -> bool {
        while !ids.is_empty() {
            while self.left == 0 {
                let Some(r) = self.runs.next() else {
                    self.exhausted = true;
                    return false;
                };
                self.left = r.length;
                self.bound = self.patches.saturating_sub(r.chunk as usize * CHUNK_PATCHES);
            }
            let n = (self.left as usize).min(ids.len());
            let (head, tail) = ids.split_at(n);
            if self.bound < CHUNK_PATCHES && PatchIds::check(head, self.bound).is_none() {
                return false;
            }
            self.left -= n as u32;
            ids = tail;
        }
        true
    }

    /// Whether every id of the runs was given.
    pub(super) fn done(&mut self) -> bool {
        self.left == 0 && !self.exhausted && self.runs.next().is_none()
    }
}

/// The link-end columns of a resident archive, whole.
#[derive(Clone, Copy)]
pub struct LinkSlices<'a> {
    /// `LOTH`, checked against the runs when the archive was opened.
    other: &'a [u16],
    /// `LCNT` with `LCNX`.
    pub weight: Weights<'a>,
    /// `LDIR`.
    pub direction: &'a [u32],
    /// `LROF` and `LRUN`.
    pub runs: LinkRuns<'a>,
    /// Patches in all (rows of `LOFF`).
    pub(super) patches: usize,
}

impl<'a> LinkSlices<'a> {
    /// Columns validated when their archive was opened (§7, step 6), by
    /// the code of this module's parent only.
    pub(super) fn validated(
        other: &'a [u16],
        weight: Weights<'a>,
        direction: &'a [u32],
        runs: LinkRuns<'a>,
        patches: usize,
    ) -> Self {
        Self { other, weight, direction, runs, patches }
    }

    /// `LOTH` as stored: ids local to their runs' chunks.
    pub fn local_ids(&self) -> &'a [u16] {
        self.other
    }

    /// Every link end at once, as one window.
    pub fn window(&self) -> LinkWindow<'a> {
        LinkWindow {
            patches: 0..self.patches,
            first_end: 0,
            other: self.other,
            weight: self.weight,
            direction: self.direction,
            runs: self.runs,
            patch_count: self.patches,
        }
    }
}

/// A run of one patch's link ends in a window: one bucket, one sender
/// chunk, ids proved in range.
#[derive(Clone)]
pub struct EndRun<'w> {
    bucket: u8,
    base: usize,
    ends: Range<usize>,
    ids: &'w [u16],
    bound: usize,
}

impl<'w> EndRun<'w> {
    /// The bucket of the light received over the run's ends.
    pub fn bucket(&self) -> u8 {
        self.bucket
    }

    /// The first patch of the sender chunk: an end's other patch is this
    /// plus its id.
    pub fn base(&self) -> usize {
        self.base
    }

    /// The run's ends, as entries of the window's columns.
    pub fn ends(&self) -> Range<usize> {
        self.ends.clone()
    }

    /// The run's ids (when the window holds `LOTH`), below the patch count
    /// less [`Self::base`]: per-patch state sliced from the base can be
    /// indexed with them.
    pub fn ids(&self) -> PatchIds<'w, u16> {
        PatchIds { ids: &self.ids[self.ends.clone()], bound: self.bound }
    }

    /// The other patch of the run's `i`-th end.
    pub fn other(&self, i: usize) -> u32 {
        (self.base + self.ids[self.ends.start + i] as usize) as u32
    }
}

/// The columns a pass over the link ends reads (a streamed pass reads
/// only these; the others are empty in its windows). The runs (`LROF`,
/// `LRUN`) are always held.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Columns {
    /// `LOTH`.
    pub other: bool,
    /// `LCNT` (and the escapes of `LCNX`, always held).
    pub weight: bool,
    /// `LDIR`.
    pub direction: bool,
}

impl Columns {
    /// `LOTH` and `LCNT`: what the diffuse gather reads.
    pub const GATHER: Self = Self { other: true, weight: true, direction: false };
    /// Every column.
    pub const ALL: Self = Self { other: true, weight: true, direction: true };
}

/// The link ends of a run of consecutive patches: entry `i` of a column is
/// link end `first_end + i`. Columns not asked for are empty.
pub struct LinkWindow<'w> {
    /// The patches whose link ends these are, all of them.
    pub patches: Range<usize>,
    /// The index of the first end (`LOFF[patches.start]`).
    pub first_end: usize,
    /// `LOTH`, checked against the runs as the window entered memory.
    other: &'w [u16],
    /// `LCNT` with `LCNX`.
    pub weight: Weights<'w>,
    /// `LDIR`.
    pub direction: &'w [u32],
    /// The runs of every patch (not only the window's).
    pub runs: LinkRuns<'w>,
    patch_count: usize,
}

impl<'w> LinkWindow<'w> {
    /// A window over columns whose ids were checked against `runs` (by the
    /// code of this module's parent only).
    pub(super) fn validated(
        patches: Range<usize>,
        other: &'w [u16],
        weight: Weights<'w>,
        direction: &'w [u32],
        runs: LinkRuns<'w>,
    ) -> Self {
        let patch_count = runs.link_offsets.len() - 1;
        let first_end = runs.link_offsets[patches.start] as usize;
        Self { patches, first_end, other, weight, direction, runs, patch_count }
    }

    /// A window over columns given by the caller (tests, tools), its ids
    /// checked against `runs`; `None` when one is out of range, or there
    /// are not as many as the window's patches' runs hold.
    pub fn checked(
        patches: Range<usize>,
        other: &'w [u16],
        weight: Weights<'w>,
        direction: &'w [u32],
        runs: LinkRuns<'w>,
    ) -> Option<Self> {
        let link_offsets = runs.link_offsets;
        if patches.end >= link_offsets.len() || patches.start > patches.end {
            return None;
        }
        let n = (link_offsets[patches.end] - link_offsets[patches.start]) as usize;
        let (a, b) = (runs.run_offsets[patches.start] as usize, runs.run_offsets[patches.end] as usize);
        let window_runs = runs.runs.get(a.checked_sub(runs.first)?..b.checked_sub(runs.first)?)?;
        let mut ids = IdCheck::new(window_runs.iter().copied(), link_offsets.len() - 1);
        if other.len() != n || !ids.add(other) || !ids.done() {
            return None;
        }
        Some(Self::validated(patches, other, weight, direction, runs))
    }

    /// The window cut to the patches it shares with `range` (which must
    /// overlap it): its columns stay whole, its patches (and so the rows a
    /// pass walks) are those of `range`. For a process that gathers over
    /// its own receivers only (`distribute::Team`).
    pub fn narrowed(mut self, range: &Range<usize>) -> Self {
        let (start, end) = (self.patches.start.max(range.start), self.patches.end.min(range.end));
        self.patches = start..end.max(start);
        self
    }

    /// The window's entries of the ends `ends` (absolute indices).
    pub fn local(&self, ends: Range<usize>) -> Range<usize> {
        ends.start - self.first_end..ends.end - self.first_end
    }

    /// The entries of patch `q`'s row (a patch of the window).
    pub fn row(&self, q: usize) -> Range<usize> {
        self.local(self.runs.link_offsets[q] as usize..self.runs.link_offsets[q + 1] as usize)
    }

    /// The runs of patch `q` (a patch of the window), in row order.
    pub fn runs_of(&self, q: usize) -> impl Iterator<Item = EndRun<'w>> + use<'w> {
        let mut e = self.row(q).start;
        let (other, patch_count) = (self.other, self.patch_count);
        self.runs.of(q).iter().map(move |r| {
            let base = r.chunk as usize * CHUNK_PATCHES;
            let ends = e..e + r.length as usize;
            e = ends.end;
            EndRun { bucket: r.bucket, base, ends, ids: other, bound: patch_count - base }
        })
    }

    /// Patch `q`'s runs as [`Self::runs_of`] gives them, but with
    /// neighbouring runs of one sender chunk joined (their buckets
    /// differ; the bucket given is the first's): for passes that do not
    /// sort light into buckets, which then sum a row of an archive of one
    /// chunk at once.
    pub fn chunk_runs_of(&self, q: usize) -> impl Iterator<Item = EndRun<'w>> + use<'w> {
        let mut runs = self.runs_of(q).peekable();
        std::iter::from_fn(move || {
            let mut run = runs.next()?;
            while let Some(next) = runs.next_if(|n| n.base == run.base) {
                run.ends.end = next.ends.end;
            }
            Some(run)
        })
    }

    /// Patch `q`'s ends (a patch of the window) in row order: the entry,
    /// the other patch (when the window holds `LOTH`) and the bucket.
    pub fn ends_of(&self, q: usize) -> impl Iterator<Item = (usize, u32, u8)> + use<'w> {
        let read = !self.other.is_empty();
        self.runs_of(q).flat_map(move |r| {
            let k = r.bucket();
            let first = r.ends().start;
            r.ends().map(move |e| (e, if read { r.other(e - first) } else { 0 }, k))
        })
    }

    /// The other patch of every end of the window, decoded (for tools and
    /// tests; the gather reads runs).
    pub fn other_ids(&self) -> Vec<u32> {
        self.patches.clone().flat_map(|q| self.ends_of(q).map(|e| e.1)).collect()
    }

    /// The bucket of every end of the window, decoded.
    pub fn buckets(&self) -> Vec<u8> {
        self.patches.clone().flat_map(|q| self.ends_of(q).map(|e| e.2)).collect()
    }

    /// `LOTH` as read: ids local to their runs' chunks.
    pub fn local_ids(&self) -> &'w [u16] {
        self.other
    }
}
