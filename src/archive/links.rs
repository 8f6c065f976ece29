//! Frame 0's link-end columns (`LOTH`, `LCNT` with `LCNX`, `LDIR`,
//! `LBKT`, §5.10),
//! resident (slices of a mapped archive) or streamed (read window by
//! window into reused buffers, [`LinkStream`]), behind one interface: the
//! distribution walks them in windows of consecutive patches and never
//! needs to know which.

use std::ops::Range;

use super::ArchiveError;
use super::stream::LinkStream;
use super::weights::Weights;

/// Patch indices proved below `bound` when made, so that per-patch state
/// of at least `bound` entries can be indexed with them without a bounds
/// check per link end (9% of the distribution's time, measured).
#[derive(Clone, Copy)]
pub struct PatchIds<'a> {
    ids: &'a [u32],
    bound: usize,
}

impl<'a> PatchIds<'a> {
    /// `None` unless every index is below `bound`.
    pub fn check(ids: &'a [u32], bound: usize) -> Option<Self> {
        // The largest id, without an early exit: this vectorises (4× the
        // speed of `all`, which stops at the first failure).
        let max = ids.iter().copied().fold(0u32, u32::max);
        (ids.is_empty() || (max as usize) < bound).then_some(Self { ids, bound })
    }

    /// Indices validated when their archive was opened (§7, step 6), by
    /// the code of this module only.
    pub(super) fn validated(ids: &'a [u32], bound: usize) -> Self {
        Self { ids, bound }
    }

    /// The indices in `range` (which must lie within them).
    pub fn slice(self, range: Range<usize>) -> Self {
        Self { ids: &self.ids[range], bound: self.bound }
    }

    /// The indices.
    pub fn ids(&self) -> &'a [u32] {
        self.ids
    }

    /// What every index is below.
    pub fn bound(&self) -> usize {
        self.bound
    }
}

/// The four link-end columns of a resident archive, whole.
#[derive(Clone, Copy)]
pub struct LinkSlices<'a> {
    /// `LOTH`, each below the patch count (validated when the archive was
    /// opened, §7).
    pub other: PatchIds<'a>,
    /// `LCNT` with `LCNX`.
    pub weight: Weights<'a>,
    /// `LDIR`.
    pub direction: &'a [u32],
    /// `LBKT`, when present.
    pub bucket: Option<&'a [u8]>,
}

/// Frame 0's link ends, wherever they are.
#[derive(Clone, Copy)]
pub enum Links<'a> {
    /// In memory (a mapped or owned archive): one window holds them all.
    Resident(LinkSlices<'a>),
    /// On disk, read a window at a time (an archive opened with
    /// [`super::Archive::open_streamed`]).
    Streamed(&'a LinkStream),
}

/// The columns a pass over the link ends reads (a streamed pass reads
/// only these; the others are empty in its windows).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Columns {
    /// `LOTH`.
    pub other: bool,
    /// `LCNT` (and the escapes of `LCNX`, always held).
    pub weight: bool,
    /// `LDIR`.
    pub direction: bool,
    /// `LBKT` (empty in archives without it).
    pub bucket: bool,
}

impl Columns {
    /// `LOTH` and `LCNT`: what the diffuse gather reads.
    pub const GATHER: Self = Self { other: true, weight: true, direction: false, bucket: false };
    /// Every column.
    pub const ALL: Self = Self { other: true, weight: true, direction: true, bucket: true };
}

/// The link ends of a run of consecutive patches: entry `i` of a column is
/// link end `first_end + i`. Columns not asked for are empty.
pub struct LinkWindow<'w> {
    /// The patches whose link ends these are, all of them.
    pub patches: Range<usize>,
    /// The index of the first end (`LOFF[patches.start]`).
    pub first_end: usize,
    /// `LOTH`.
    pub other: PatchIds<'w>,
    /// `LCNT` with `LCNX`.
    pub weight: Weights<'w>,
    /// `LDIR`.
    pub direction: &'w [u32],
    /// `LBKT`.
    pub bucket: &'w [u8],
}

impl<'w> LinkWindow<'w> {
    /// The window's entries of the ends `ends` (absolute indices).
    pub fn local(&self, ends: Range<usize>) -> Range<usize> {
        ends.start - self.first_end..ends.end - self.first_end
    }
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
        match self {
            Links::Resident(s) => {
                let mut f = f;
                f(LinkWindow {
                    patches: 0..patches,
                    first_end: 0,
                    other: s.other,
                    weight: s.weight,
                    direction: s.direction,
                    bucket: s.bucket.unwrap_or(&[]),
                })
            }
            Links::Streamed(stream) => stream.for_each_window(columns, None, f),
        }
    }

    /// Like [`Self::for_each_window`], but windows are taken several at
    /// once (streamed: [`LinkStream::windows_in_flight`] at a time, each
    /// read by the worker that uses it), calling `f` with each and its
    /// patches' part of `out` (`per_patch` entries a patch): for the
    /// gather, whose windows are independent. Resident ends are one
    /// window, given all of `out`; `f` should then split its work over the
    /// workers itself, and so when streamed with fewer windows in flight
    /// than workers.
    pub fn for_each_window_par<T: Send, E: From<ArchiveError> + Send>(
        &self,
        columns: Columns,
        patches: usize,
        out: &mut [T],
        per_patch: usize,
        f: impl Fn(LinkWindow<'_>, &mut [T]) -> Result<(), E> + Sync,
    ) -> Result<(), E> {
        match self {
            Links::Resident(_) => self.for_each_window(columns, patches, |w| f(w, &mut *out)),
            Links::Streamed(stream) => stream.for_each_window_par(columns, out, per_patch, f),
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
            Links::Streamed(stream) => stream.for_each_window(columns, Some(wanted), f),
        }
    }

    /// The link ends of `patches` (in any order), every column, for passes
    /// that revisit a few patches' ends many times: borrowed from resident
    /// columns, copied out of a streamed archive in one pass.
    pub fn rows(&self, offsets: &'a [u64], patches: &[u32]) -> Result<LinkRows<'a>, ArchiveError> {
        match self {
            Links::Resident(s) => {
                // Weights decoded to f32: these rows are read many times.
                let mut starts = vec![0usize];
                let mut weight = Vec::new();
                for &q in patches {
                    let (a, b) = (offsets[q as usize] as usize, offsets[q as usize + 1] as usize);
                    weight.extend(s.weight.slice(a..b).iter());
                    starts.push(weight.len());
                }
                Ok(LinkRows {
                    patches: patches.to_vec(),
                    store: RowStore::Borrowed { offsets, slices: *s, weight, starts },
                })
            }
            Links::Streamed(stream) => {
                let mut order: Vec<usize> = (0..patches.len()).collect();
                order.sort_by_key(|&k| patches[k]);
                let mut row_of = vec![0u32; patches.len()];
                let mut compact_offsets = vec![0u64];
                let (mut other, mut weight, mut direction) = (Vec::new(), Vec::new(), Vec::new());
                let wanted: Vec<u32> = order.iter().map(|&k| patches[k]).collect();
                let mut next = 0;
                stream.for_each_window(Columns::ALL, Some(&wanted), |w: LinkWindow<'_>| {
                    while next < order.len() && (wanted[next] as usize) < w.patches.end {
                        let q = wanted[next] as usize;
                        let r = w.local(offsets[q] as usize..offsets[q + 1] as usize);
                        other.extend_from_slice(&w.other.ids()[r.clone()]);
                        weight.extend(w.weight.slice(r.clone()).iter());
                        direction.extend_from_slice(&w.direction[r]);
                        row_of[order[next]] = (compact_offsets.len() - 1) as u32;
                        compact_offsets.push(other.len() as u64);
                        next += 1;
                    }
                    Ok::<(), ArchiveError>(())
                })?;
                Ok(LinkRows {
                    patches: patches.to_vec(),
                    store: RowStore::Owned { row_of, offsets: compact_offsets, other, weight, direction },
                })
            }
        }
    }

    /// Whether the archive has `LBKT`.
    pub fn has_bucket(&self) -> bool {
        match self {
            Links::Resident(s) => s.bucket.is_some(),
            Links::Streamed(stream) => stream.has_bucket(),
        }
    }

    /// Whether the ends are streamed from disk.
    pub fn is_streamed(&self) -> bool {
        matches!(self, Links::Streamed(_))
    }

    /// The resident columns, if they are.
    pub fn resident(&self) -> Option<&LinkSlices<'a>> {
        match self {
            Links::Resident(s) => Some(s),
            Links::Streamed(_) => None,
        }
    }
}

/// The link ends of chosen patches (see [`Links::rows`]).
pub struct LinkRows<'a> {
    patches: Vec<u32>,
    store: RowStore<'a>,
}

enum RowStore<'a> {
    Borrowed { offsets: &'a [u64], slices: LinkSlices<'a>, weight: Vec<f32>, starts: Vec<usize> },
    Owned { row_of: Vec<u32>, offsets: Vec<u64>, other: Vec<u32>, weight: Vec<f32>, direction: Vec<u32> },
}

impl LinkRows<'_> {
    /// The ends of the `k`-th patch asked for: `(other, weight, direction)`.
    pub fn ends(&self, k: usize) -> (&[u32], &[f32], &[u32]) {
        match &self.store {
            RowStore::Borrowed { offsets, slices, weight, starts } => {
                let q = self.patches[k] as usize;
                let (a, b) = (offsets[q] as usize, offsets[q + 1] as usize);
                (&slices.other.ids()[a..b], &weight[starts[k]..starts[k + 1]], &slices.direction[a..b])
            }
            RowStore::Owned { row_of, offsets, other, weight, direction } => {
                let r = row_of[k] as usize;
                let (a, b) = (offsets[r] as usize, offsets[r + 1] as usize);
                (&other[a..b], &weight[a..b], &direction[a..b])
            }
        }
    }

    /// Heap bytes held (zero when borrowed).
    pub fn heap_bytes(&self) -> usize {
        match &self.store {
            RowStore::Borrowed { weight, starts, .. } => self.patches.len() * 4 + weight.len() * 4 + starts.len() * 8,
            RowStore::Owned { other, .. } => self.patches.len() * 8 + other.len() * 12,
        }
    }
}
