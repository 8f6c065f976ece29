//! Frame 0's link ends wherever they are, behind one interface,
//! [`Links`]: resident (slices of a mapped archive, [`LinkSlices`]) or
//! streamed (read window by window into reused buffers, [`LinkStream`]).
//! The distribution walks them in windows of consecutive patches
//! ([`LinkWindow`]) and never needs to know which. [`LinkRows`] copies a
//! few patches' ends out, for passes that revisit them.
//!
//! The windows, runs and checks both kinds are made of are in
//! [`super::links`], which the stream builds on; this file stands on
//! both, so that neither needs the other's types.

use super::ArchiveError;
use super::links::{Columns, LinkRuns, LinkSlices, LinkWindow};
use super::stream::LinkStream;

/// Frame 0's link ends, wherever they are.
#[derive(Clone, Copy)]
pub enum Links<'a> {
    /// In memory (a mapped or owned archive): one window holds them all.
    Resident(LinkSlices<'a>),
    /// On disk, read a window at a time (an archive opened with
    /// [`super::Archive::open_streamed`]), with `LOFF` and `LROF` (its
    /// runs, `LRUN`, are read with each window).
    Streamed(&'a LinkStream, LinkRuns<'a>),
}

impl<'a> Links<'a> {
    /// Calls `f` on every window of link ends in patch order, reading
    /// `columns`. Resident ends are one window; streamed ones are read
    /// ahead on a second thread while `f` works, and each is checked
    /// (checksums and patch ids) as it enters memory.
    pub fn for_each_window<E: From<ArchiveError>>(
        &self,
        columns: Columns,
        patches: usize,
        f: impl FnMut(LinkWindow<'_>) -> Result<(), E>,
    ) -> Result<(), E> {
        self.for_each_window_in(columns, patches, 0..patches, f)
    }

    /// Like [`Self::for_each_window`], but over the rows of the patches of
    /// `range` only: windows cut to it ([`LinkWindow::narrowed`]), those
    /// without one of its patches not read. For a process that owns a
    /// range of receivers (`distribute::Team`).
    pub fn for_each_window_in<E: From<ArchiveError>>(
        &self,
        columns: Columns,
        patches: usize,
        range: std::ops::Range<usize>,
        f: impl FnMut(LinkWindow<'_>) -> Result<(), E>,
    ) -> Result<(), E> {
        debug_assert!(range.end <= patches);
        match self {
            Links::Resident(s) => {
                debug_assert_eq!(s.patches, patches);
                let mut f = f;
                if range.is_empty() { Ok(()) } else { f(s.window().narrowed(&range)) }
            }
            Links::Streamed(stream, runs) => stream.for_each_window(columns, *runs, range, None, f),
        }
    }

    /// Like [`Self::for_each_window`], but windows are taken several at
    /// once (streamed: [`LinkStream::windows_in_flight`] at a time, each
    /// read by the worker that uses it), calling `f` with each and its
    /// patches' part of `out` (`per_patch` entries a patch): for the
    /// gather, whose windows are independent. Resident ends are one
    /// window, given all of `out`; `f` should then split its work over the
    /// workers itself, and so when streamed with fewer windows in flight
    /// than workers. Only the rows of the patches of `range` are walked,
    /// and `out` has entries for those patches only.
    pub fn for_each_window_par<T: Send, E: From<ArchiveError> + Send>(
        &self,
        columns: Columns,
        patches: usize,
        range: std::ops::Range<usize>,
        out: &mut [T],
        per_patch: usize,
        f: impl Fn(LinkWindow<'_>, &mut [T]) -> Result<(), E> + Sync,
    ) -> Result<(), E> {
        match self {
            Links::Resident(_) => self.for_each_window_in(columns, patches, range, |w| f(w, &mut *out)),
            Links::Streamed(stream, runs) => stream.for_each_window_par(columns, *runs, range, out, per_patch, f),
        }
    }

    /// Like [`Self::for_each_window`], but only over the windows that hold
    /// a patch of the ascending list `wanted` (a resident archive is one
    /// window): for checks that look at a few patches' rows.
    pub fn for_each_window_of<E: From<ArchiveError>>(
        &self,
        columns: Columns,
        patches: usize,
        wanted: &[u32],
        f: impl FnMut(LinkWindow<'_>) -> Result<(), E>,
    ) -> Result<(), E> {
        match self {
            Links::Resident(_) => self.for_each_window(columns, patches, f),
            Links::Streamed(stream, runs) => stream.for_each_window(columns, *runs, 0..patches, Some(wanted), f),
        }
    }

    /// The link ends of `patches` (in any order), every column decoded
    /// (other patches as 32-bit ids, weights as f32), for passes that
    /// revisit a few patches' ends many times: copied out of resident
    /// columns, or out of a streamed archive in one pass.
    pub fn rows(&self, offsets: &'a [u64], patches: &[u32]) -> Result<LinkRows, ArchiveError> {
        let mut order: Vec<usize> = (0..patches.len()).collect();
        order.sort_by_key(|&k| patches[k]);
        let mut row_of = vec![0u32; patches.len()];
        let mut compact_offsets = vec![0u64];
        let (mut other, mut weight, mut direction) = (Vec::new(), Vec::new(), Vec::new());
        let wanted: Vec<u32> = order.iter().map(|&k| patches[k]).collect();
        let mut next = 0;
        let n = offsets.len() - 1;
        self.for_each_window_of(Columns::ALL, n, &wanted, |w: LinkWindow<'_>| {
            while next < order.len() && (wanted[next] as usize) < w.patches.end {
                let q = wanted[next] as usize;
                let r = w.row(q);
                other.extend(w.ends_of(q).map(|e| e.1));
                weight.extend(w.weight.slice(r.clone()).iter());
                direction.extend_from_slice(&w.direction[r]);
                row_of[order[next]] = (compact_offsets.len() - 1) as u32;
                compact_offsets.push(other.len() as u64);
                next += 1;
            }
            Ok::<(), ArchiveError>(())
        })?;
        Ok(LinkRows { row_of, offsets: compact_offsets, other, weight, direction })
    }

    /// Whether the ends are streamed from disk.
    pub fn is_streamed(&self) -> bool {
        matches!(self, Links::Streamed(..))
    }

    /// The resident columns, if they are.
    pub fn resident(&self) -> Option<&LinkSlices<'a>> {
        match self {
            Links::Resident(s) => Some(s),
            Links::Streamed(..) => None,
        }
    }
}

/// The link ends of chosen patches (see [`Links::rows`]).
pub struct LinkRows {
    row_of: Vec<u32>,
    offsets: Vec<u64>,
    other: Vec<u32>,
    weight: Vec<f32>,
    direction: Vec<u32>,
}

impl LinkRows {
    /// The ends of the `k`-th patch asked for: `(other, weight, direction)`.
    pub fn ends(&self, k: usize) -> (&[u32], &[f32], &[u32]) {
        let r = self.row_of[k] as usize;
        let (a, b) = (self.offsets[r] as usize, self.offsets[r + 1] as usize);
        (&self.other[a..b], &self.weight[a..b], &self.direction[a..b])
    }

    /// Heap bytes held.
    pub fn heap_bytes(&self) -> usize {
        self.row_of.len() * 4 + self.offsets.len() * 8 + self.other.len() * 12
    }
}
