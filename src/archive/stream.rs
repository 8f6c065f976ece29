//! Streaming frame 0's link ends from disk: the columns of §5.10 read in
//! windows of consecutive patches into reused buffers, so that memory
//! holds a few windows (one per worker, or as many as the memory plan
//! allows, at least two), not the archive, whatever its size.
//!
//! Reads are `pread`s into owned buffers, not a mapping: a file truncated
//! or rewritten under a running render is an error (a short read, a
//! checksum that no longer matches), never a SIGBUS or undefined
//! behaviour. Opening reads every column once, checks it against its
//! section checksum and its content rules (§7), and keeps one XXH3-64 per
//! column per chunk of [`CHUNK_ENDS`] ends; every window read later is
//! checked against those before use, and its patch ids checked in range.

use std::fs::File;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc::sync_channel;

use xxhash_rust::xxh3::{Xxh3, xxh3_64};

use super::ArchiveError;
use super::layout::LinkRunRecord;
use super::layout::{SectionEntry, WeightEscape};
use super::links::{Columns, IdCheck, LinkRuns, LinkWindow, check_rows};
use super::weights::{self, WeightSums, Weights};

/// Link ends per checked chunk: windows are read in whole chunks.
pub const CHUNK_ENDS: usize = 1 << 16;

/// Bytes per link end of each column: `LOTH`, `LCNT`, `LDIR`.
const WIDTH: [usize; 3] = [2, 1, 4];

/// The columns' names, in that order.
const NAMES: [&str; 3] = ["LOTH", "LCNT", "LDIR"];

/// Chunks read per `pread` when opening (4 MiB of `LOTH`).
const OPEN_READ_CHUNKS: usize = 16;

/// What the content rules of §7 bound the columns by.
pub(super) struct Limits<'h> {
    /// `PHIT`: what each patch's link-end weights sum to at most.
    pub hits: &'h [u32],
    pub patches: usize,
    pub directions: usize,
    pub max_bucket: u8,
}

/// The link-end columns of an archive on disk, read window by window.
pub struct LinkStream {
    file: File,
    path: PathBuf,
    patches: usize,
    ends: usize,
    /// File offset of each column (`LOTH`, `LCNT`, `LDIR`).
    at: [u64; 3],
    /// `LCNX`, held whole (weights that are not a count in 1..=255: rare).
    escapes: Vec<WeightEscape>,
    /// Per chunk, each column's XXH3-64.
    sums: Vec<[u64; 3]>,
    /// File offset of `LRUN`.
    runs_at: u64,
    /// Per window, the XXH3-64 of its runs' bytes.
    run_sums: Vec<u64>,
    /// The most runs a window holds.
    run_capacity: usize,
    windows: Vec<Window>,
    /// The most ends a window's buffers hold (whole chunks).
    capacity: usize,
    /// Buffers kept between passes.
    pool: Mutex<Vec<Buffers>>,
    /// Drop the file's cached pages before every full pass (measurement).
    evict: AtomicBool,
    /// The most windows a parallel pass holds at once.
    in_flight: AtomicUsize,
    /// `BILD.max_bucket`, which runs are checked against.
    max_bucket: u8,
}

struct Window {
    patches: Range<usize>,
    ends: Range<usize>,
}

#[derive(Default)]
struct Buffers {
    other: Vec<u16>,
    weight: Vec<u8>,
    direction: Vec<u32>,
    runs: Vec<LinkRunRecord>,
}

impl Buffers {
    fn bytes(&self) -> usize {
        self.other.capacity() * 2 + self.weight.capacity() + self.direction.capacity() * 4 + self.runs.capacity() * 8
    }
}

/// `LRUN` read from the file in order, a piece at a time, hashed as read:
/// the runs an open's check of `LOTH` walks beside it.
struct RunReader<'f> {
    file: &'f File,
    at: u64,
    left: u64,
    buf: Vec<LinkRunRecord>,
    next: usize,
    hash: Xxh3,
    error: Option<std::io::Error>,
}

impl Iterator for RunReader<'_> {
    type Item = LinkRunRecord;

    fn next(&mut self) -> Option<LinkRunRecord> {
        if self.next == self.buf.len() {
            if self.left == 0 || self.error.is_some() {
                return None;
            }
            let n = self.left.min(1 << 16) as usize;
            self.buf.resize(n, LinkRunRecord::default());
            if let Err(e) = read_at(self.file, bytemuck::cast_slice_mut(&mut self.buf), self.at) {
                self.error = Some(e);
                return None;
            }
            self.hash.update(bytemuck::cast_slice(&self.buf));
            self.at += n as u64 * 8;
            self.left -= n as u64;
            self.next = 0;
        }
        self.next += 1;
        Some(self.buf[self.next - 1])
    }
}

pub(super) fn short(path: &Path, what: &str, e: std::io::Error) -> ArchiveError {
    let source = if e.kind() == std::io::ErrorKind::UnexpectedEof {
        std::io::Error::new(e.kind(), format!("{what}: the file ended early (truncated while in use?)"))
    } else {
        std::io::Error::new(e.kind(), format!("{what}: {e}"))
    };
    ArchiveError::Io { path: path.into(), source }
}

#[cfg(unix)]
pub(super) fn read_at(file: &File, buf: &mut [u8], offset: u64) -> std::io::Result<()> {
    std::os::unix::fs::FileExt::read_exact_at(file, buf, offset)
}

#[cfg(not(unix))]
pub(super) fn read_at(file: &File, mut buf: &mut [u8], mut offset: u64) -> std::io::Result<()> {
    while !buf.is_empty() {
        match std::os::windows::fs::FileExt::seek_read(file, buf, offset)? {
            0 => return Err(std::io::ErrorKind::UnexpectedEof.into()),
            n => {
                buf = &mut buf[n..];
                offset += n as u64;
            }
        }
    }
    Ok(())
}

impl LinkStream {
    /// Reads and checks the columns `entries` (`LOTH`, `LCNT`, `LDIR`,
    /// `LRUN`, already checked to lie in the file) of the archive open as
    /// `file`, with `escapes` (`LCNX`, checked against its checksum), against
    /// their checksums, `runs` (`LOFF` and `LROF`, checked) and `limits`,
    /// and plans windows of at most `window_ends` ends (more for a patch
    /// with more).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn open(
        file: File,
        path: &Path,
        entries: [&SectionEntry; 4],
        escapes: Vec<WeightEscape>,
        offsets: &[u64],
        runs: LinkRuns<'_>,
        limits: &Limits<'_>,
        window_ends: usize,
    ) -> Result<Self, ArchiveError> {
        let ends = offsets.last().copied().unwrap_or(0) as usize;
        let (windows, capacity) = plan(offsets, window_ends.max(1));
        let run_entry = entries[3];
        let run_offsets = runs.offsets();
        let run_count = run_offsets.last().copied().unwrap_or(0);
        let (run_sums, run_capacity) =
            check_window_runs(&file, path, run_entry, offsets, run_offsets, &windows, limits.max_bucket)?;
        let mut run_reader = RunReader {
            file: &file,
            at: run_entry.offset,
            left: run_count,
            buf: Vec::new(),
            next: 0,
            hash: Xxh3::new(),
            error: None,
        };
        let mut ids = IdCheck::new(&mut run_reader, limits.patches);
        let columns = [entries[0], entries[1], entries[2]];
        let sums = check_columns(&file, path, columns, &escapes, offsets, limits, &mut ids)?;
        if !ids.done() {
            return Err(ArchiveError::corrupt("LOTH: fewer ids than the runs hold"));
        }
        if let Some(e) = run_reader.error.take() {
            return Err(short(path, "LRUN", e));
        }
        // Read twice: the second time, the bytes the first checked.
        check_sum_of(run_entry, run_reader.hash.digest(), "LRUN")?;
        let at = [entries[0].offset, entries[1].offset, entries[2].offset];
        Ok(Self {
            file,
            path: path.into(),
            patches: limits.patches,
            ends,
            at,
            escapes,
            sums,
            runs_at: run_entry.offset,
            run_sums,
            run_capacity,
            windows,
            capacity,
            pool: Mutex::new(Vec::new()),
            evict: AtomicBool::new(false),
            in_flight: AtomicUsize::new(usize::MAX),
            max_bucket: limits.max_bucket,
        })
    }

    /// For measurement: before every pass over all windows, ask the kernel
    /// to drop the file's pages from its cache (`posix_fadvise`
    /// `DONTNEED`), so that each pass reads the disk, as passes over an
    /// archive larger than memory do. Linux only; elsewhere a no-op.
    pub fn evict_each_pass(&self, on: bool) {
        self.evict.store(on, Ordering::Relaxed);
    }

    /// Lets a parallel pass hold at most `n` windows at once (at least
    /// one), so that the memory it takes does not grow with the cores: a
    /// budget that has room for a few windows holds them, and the workers
    /// beyond share each window's patches. Unlimited by default (one
    /// window per worker).
    pub fn limit_windows_in_flight(&self, n: usize) {
        self.in_flight.store(n.max(1), Ordering::Relaxed);
    }

    /// The windows a parallel pass holds at once: one per worker, at most
    /// the limit ([`Self::limit_windows_in_flight`]) and the window count.
    pub fn windows_in_flight(&self) -> usize {
        let limit = self.in_flight.load(Ordering::Relaxed);
        rayon::current_num_threads().min(limit).min(self.windows.len()).max(1)
    }

    /// Heap bytes held for the whole pass: `LCNX` and the chunk checksums
    /// (windows' buffers are [`Self::pass_bytes`]).
    pub fn held_bytes(&self) -> usize {
        self.escapes.len() * size_of::<WeightEscape>()
            + self.sums.len() * size_of::<[u64; 3]>()
            + self.run_sums.len() * 8
    }

    /// Link ends in all.
    pub fn ends(&self) -> usize {
        self.ends
    }

    /// Windows a full pass reads.
    pub fn window_count(&self) -> usize {
        self.windows.len()
    }

    /// The most ends one window's buffers hold.
    pub fn window_capacity(&self) -> usize {
        self.capacity
    }

    /// The most heap a sequential pass reading `columns`
    /// holds (two windows' buffers: one in use, one being read; the
    /// gather's parallel passes hold [`Self::windows_in_flight`]).
    pub fn pass_bytes(&self, columns: Columns) -> usize {
        2 * (self.capacity * bytes_per_end(columns) + self.run_capacity * 8)
    }

    /// Buffers kept between passes (each holds one window).
    pub fn pooled_buffers(&self) -> usize {
        self.pool.lock().map_or(0, |p| p.len())
    }

    /// Frees the buffers kept between passes (the next pass makes its own):
    /// for the memory a render shades in once a frame's light is solved.
    pub fn release_buffers(&self) {
        if let Ok(mut pool) = self.pool.lock() {
            *pool = Vec::new();
        }
    }

    /// Heap held now by buffers kept between passes.
    pub fn pooled_bytes(&self) -> usize {
        self.pool.lock().map_or(0, |p| p.iter().map(Buffers::bytes).sum())
    }

    /// How many windows hold a patch of `range` (what a pass over those
    /// patches reads).
    pub fn windows_meeting(&self, range: &Range<usize>) -> usize {
        (0..self.windows.len()).filter(|&i| self.meets(i, range)).count()
    }

    /// Whether window `i` holds a patch of `range`.
    fn meets(&self, i: usize, range: &Range<usize>) -> bool {
        let r = &self.windows[i].patches;
        r.start < range.end && range.start < r.end && !range.is_empty()
    }

    /// Calls `f` on every window in patch order that holds a patch of
    /// `range` (cut to it, [`LinkWindow::narrowed`]), and of the ascending
    /// list `wanted` when given, reading the next on a second thread while
    /// `f` works on one.
    pub(super) fn for_each_window<E: From<ArchiveError>>(
        &self,
        columns: Columns,
        runs: LinkRuns<'_>,
        range: Range<usize>,
        wanted: Option<&[u32]>,
        mut f: impl FnMut(LinkWindow<'_>) -> Result<(), E>,
    ) -> Result<(), E> {
        let selected: Vec<usize> = (0..self.windows.len())
            .filter(|&i| self.meets(i, &range))
            .filter(|&i| {
                let Some(w) = wanted else { return true };
                let r = &self.windows[i].patches;
                let k = w.partition_point(|&q| (q as usize) < r.start);
                k < w.len() && (w[k] as usize) < r.end
            })
            .collect();
        if selected.is_empty() {
            return Ok(());
        }
        if wanted.is_none() && self.evict.load(Ordering::Relaxed) {
            drop_cached(&self.file);
        }
        std::thread::scope(|scope| -> Result<(), E> {
            let (full_tx, full_rx) = sync_channel::<Result<Buffers, ArchiveError>>(1);
            let (free_tx, free_rx) = sync_channel::<Buffers>(2);
            for _ in 0..2 {
                let b = self.pool.lock().ok().and_then(|mut p| p.pop()).unwrap_or_default();
                free_tx.send(b).expect("the channel holds two buffers");
            }
            let order = &selected;
            // The reader hands its receiver back, so that the buffers
            // returned to it are kept for the next pass.
            let reader = scope.spawn(move || {
                for &i in order {
                    let Ok(mut b) = free_rx.recv() else { break };
                    let read = self.read_window(i, columns, runs, &mut b).map(|()| b);
                    let failed = read.is_err();
                    if full_tx.send(read).is_err() || failed {
                        break;
                    }
                }
                free_rx
            });
            for &i in &selected {
                let b = full_rx.recv().map_err(|_| ArchiveError::Io {
                    path: self.path.clone(),
                    source: std::io::Error::other("the link reader stopped"),
                })??;
                f(self.window(i, &b, runs).narrowed(&range))?;
                // Two buffers and room for two: this never blocks.
                let _ = free_tx.send(b);
            }
            if let (Ok(free_rx), Ok(mut pool)) = (reader.join(), self.pool.lock()) {
                pool.extend(free_rx.try_iter());
            }
            Ok(())
        })
    }

    /// Calls `f` on every window, several at once: each of
    /// [`Self::windows_in_flight`] lanes (rayon tasks) takes the next
    /// window not yet taken, reads it into a buffer of its own, checks it
    /// as [`Self::for_each_window`] does, and calls `f` with it and the
    /// window's part of `out` (`per_patch` entries a patch, `out` having
    /// them for every patch). Each core then copies, checks and uses its
    /// own windows, where a reader thread beside the workers handed every
    /// window over: a stage that one core ran for all, and three threads
    /// contending for two cores. Holds one window's buffers per lane (the
    /// memory plan counts them); with fewer lanes than workers, `f` is
    /// expected to split its window's work among them. Only the windows
    /// holding a patch of `range` are read, cut to it, and `out` has
    /// entries for the patches of `range` only.
    pub(super) fn for_each_window_par<T: Send, E: From<ArchiveError> + Send>(
        &self,
        columns: Columns,
        runs: LinkRuns<'_>,
        range: Range<usize>,
        out: &mut [T],
        per_patch: usize,
        f: impl Fn(LinkWindow<'_>, &mut [T]) -> Result<(), E> + Sync,
    ) -> Result<(), E> {
        use rayon::prelude::*;
        assert!(range.end <= self.patches, "patches of the archive");
        assert_eq!(out.len(), range.len() * per_patch, "one entry set per patch");
        if self.evict.load(Ordering::Relaxed) {
            drop_cached(&self.file);
        }
        // Each window's part of `out`, taken by the lane that takes the window.
        let selected: Vec<usize> = (0..self.windows.len()).filter(|&i| self.meets(i, &range)).collect();
        let mut parts = Vec::with_capacity(selected.len());
        let mut rest = out;
        for &i in &selected {
            let w = &self.windows[i].patches;
            let len = w.end.min(range.end) - w.start.max(range.start);
            let (part, tail) = std::mem::take(&mut rest).split_at_mut(len * per_patch);
            parts.push(Mutex::new(Some(part)));
            rest = tail;
        }
        let next = AtomicUsize::new(0);
        (0..self.windows_in_flight()).into_par_iter().with_max_len(1).try_for_each(|_| {
            let mut b = self.pool.lock().ok().and_then(|mut p| p.pop()).unwrap_or_default();
            let mut done = Ok(());
            loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some(slot) = parts.get(i) else { break };
                let part = slot.lock().unwrap_or_else(std::sync::PoisonError::into_inner).take();
                let part = part.expect("each window is taken once");
                let i = selected[i];
                done = self
                    .read_window(i, columns, runs, &mut b)
                    .map_err(E::from)
                    .and_then(|()| f(self.window(i, &b, runs).narrowed(&range), part));
                if done.is_err() {
                    // The other lanes stop at their next window.
                    next.store(parts.len(), Ordering::Relaxed);
                    break;
                }
            }
            if let Ok(mut pool) = self.pool.lock() {
                pool.push(b);
            }
            done
        })
    }

    /// Window `i` over the buffers `read_window` filled (and checked
    /// against `runs`).
    fn window<'b>(&'b self, i: usize, b: &'b Buffers, runs: LinkRuns<'b>) -> LinkWindow<'b> {
        let w = &self.windows[i];
        let local = self.local(i);
        let pick = |len: usize| if len == 0 { 0..0 } else { local.clone() };
        let first = runs.offsets()[w.patches.start] as usize;
        LinkWindow::validated(
            w.patches.clone(),
            &b.other[pick(b.other.len())],
            Weights::new(&b.weight[pick(b.weight.len())], &self.escapes, w.ends.start as u64),
            &b.direction[pick(b.direction.len())],
            LinkRuns::validated(runs.link_offsets(), runs.offsets(), &b.runs, first),
        )
    }

    /// Window `i`'s ends within its buffers (which start at a chunk).
    fn local(&self, i: usize) -> Range<usize> {
        let w = &self.windows[i];
        let first_chunk_end = (w.ends.start / CHUNK_ENDS) * CHUNK_ENDS;
        w.ends.start - first_chunk_end..w.ends.end - first_chunk_end
    }

    /// Reads window `i`'s `columns` into `b` in whole chunks, each checked
    /// against the checksum taken when the archive was opened, and checks
    /// its patch ids against its patches' `runs`.
    fn read_window(&self, i: usize, columns: Columns, runs: LinkRuns<'_>, b: &mut Buffers) -> Result<(), ArchiveError> {
        let w = &self.windows[i];
        let c0 = w.ends.start / CHUNK_ENDS;
        let c1 = w.ends.end.div_ceil(CHUNK_ENDS).max(c0);
        let (a, e) = (c0 * CHUNK_ENDS, (c1 * CHUNK_ENDS).min(self.ends));
        let want = [columns.other, columns.weight, columns.direction];
        let n = |c: usize| if want[c] { e - a } else { 0 };
        // Grown once, to the largest window exactly (growing by doubling
        // could hold twice what the memory plan counts).
        fn fit<T: Copy + Default>(v: &mut Vec<T>, n: usize, most: usize) {
            if v.capacity() < n {
                v.reserve_exact(most.max(n) - v.len());
            }
            v.resize(n, T::default());
        }
        fit(&mut b.other, n(0), self.capacity);
        fit(&mut b.weight, n(1), self.capacity);
        fit(&mut b.direction, n(2), self.capacity);
        // The window's runs, always: checked against their checksum and,
        // since the proof below rests on them, their rules again.
        let (r0, r1) = (runs.offsets()[w.patches.start], runs.offsets()[w.patches.end]);
        fit(&mut b.runs, (r1 - r0) as usize, self.run_capacity);
        let run_bytes: &mut [u8] = bytemuck::cast_slice_mut(&mut b.runs);
        read_at(&self.file, run_bytes, self.runs_at + r0 * 8).map_err(|x| short(&self.path, "LRUN", x))?;
        if xxh3_64(run_bytes) != self.run_sums[i] {
            return Err(ArchiveError::corrupt(format!(
                "{}: the runs of window {i} (LRUN) changed on disk while in use (was the archive rewritten?)",
                self.path.display()
            )));
        }
        check_rows(runs.link_offsets(), runs.offsets(), w.patches.clone(), &b.runs, self.max_bucket)
            .map_err(ArchiveError::Corrupt)?;
        let bytes: [&mut [u8]; 3] =
            [bytemuck::cast_slice_mut(&mut b.other), &mut b.weight, bytemuck::cast_slice_mut(&mut b.direction)];
        let names = NAMES;
        for (c, buf) in bytes.into_iter().enumerate() {
            if !want[c] {
                continue;
            }
            let at = self.at[c];
            // A chunk at a time, checked while it is in the cache.
            for (k, chunk) in buf.chunks_mut(CHUNK_ENDS * WIDTH[c]).enumerate() {
                let offset = at + ((a + k * CHUNK_ENDS) * WIDTH[c]) as u64;
                read_at(&self.file, chunk, offset).map_err(|x| short(&self.path, names[c], x))?;
                if xxh3_64(chunk) != self.sums[c0 + k][c] {
                    return Err(ArchiveError::corrupt(format!(
                        "{}: chunk {} of {} changed on disk while in use (was the archive rewritten?)",
                        self.path.display(),
                        c0 + k,
                        names[c]
                    )));
                }
            }
        }
        if want[0] {
            // The ids the window uses, against its patches' runs: the proof
            // the gather's unchecked reads rest on, made again for every
            // window read.
            let mut ids = IdCheck::new(b.runs.iter().copied(), self.patches);
            if !ids.add(&b.other[self.local(i)]) || !ids.done() {
                return Err(ArchiveError::corrupt("LOTH: a link end's patch is out of range"));
            }
        }
        Ok(())
    }
}

/// The runs of an archive being opened (`LRUN`, `run_entry`, with `LOFF`
/// and `LROF`, checked), read window by window: their rules (§7) against
/// `max_bucket`, and the section's checksum. Returns per window the XXH3-64
/// of its runs' bytes (what later reads are checked against) and the most
/// runs a window holds.
fn check_window_runs(
    file: &File,
    path: &Path,
    run_entry: &SectionEntry,
    offsets: &[u64],
    run_offsets: &[u64],
    windows: &[Window],
    max_bucket: u8,
) -> Result<(Vec<u64>, usize), ArchiveError> {
    let run_count = run_offsets.last().copied().unwrap_or(0);
    if run_entry.length != run_count * 8 {
        return Err(ArchiveError::corrupt(format!(
            "section LRUN: {} bytes, expected {} for LROF's {run_count} runs",
            run_entry.length,
            run_count * 8
        )));
    }
    let (mut run_sums, mut run_capacity, mut section) = (Vec::with_capacity(windows.len()), 0, Xxh3::new());
    let mut run_buf: Vec<LinkRunRecord> = Vec::new();
    for w in windows {
        let (a, b) = (run_offsets[w.patches.start], run_offsets[w.patches.end]);
        run_buf.resize((b - a) as usize, LinkRunRecord::default());
        read_at(file, bytemuck::cast_slice_mut(&mut run_buf), run_entry.offset + a * 8)
            .map_err(|x| short(path, "LRUN", x))?;
        let bytes: &[u8] = bytemuck::cast_slice(&run_buf);
        section.update(bytes);
        run_sums.push(xxh3_64(bytes));
        run_capacity = run_capacity.max(run_buf.len());
        check_rows(offsets, run_offsets, w.patches.clone(), &run_buf, max_bucket).map_err(ArchiveError::Corrupt)?;
    }
    check_sum_of(run_entry, section.digest(), "LRUN")?;
    Ok((run_sums, run_capacity))
}

/// The columns `LOTH`, `LCNT` and `LDIR` (`entries`) of an archive being
/// opened, read once, a few chunks at a time: each checked against its
/// section checksum and its content rules (§7), `LOTH`'s ids against the
/// runs (`ids`, fed in file order), `LCNT` against `escapes` (`LCNX`) and
/// its rows' sums against `limits.hits`. Returns per chunk of
/// [`CHUNK_ENDS`] ends each column's XXH3-64.
fn check_columns<R: Iterator<Item = LinkRunRecord>>(
    file: &File,
    path: &Path,
    entries: [&SectionEntry; 3],
    escapes: &[WeightEscape],
    offsets: &[u64],
    limits: &Limits<'_>,
    ids: &mut IdCheck<R>,
) -> Result<Vec<[u64; 3]>, ArchiveError> {
    let ends = offsets.last().copied().unwrap_or(0) as usize;
    let chunks = ends.div_ceil(CHUNK_ENDS);
    let mut sums = vec![[0u64; 3]; chunks];
    let names = NAMES;
    let mut buf = Vec::new();
    let mut next_escape = 0;
    for (c, e) in entries.iter().enumerate() {
        let mut sums_of_rows = WeightSums::new(offsets, limits.hits);
        if e.length != (ends * WIDTH[c]) as u64 {
            return Err(ArchiveError::corrupt(format!(
                "section {}: {} bytes, expected {} for {ends} link ends",
                names[c],
                e.length,
                ends * WIDTH[c]
            )));
        }
        let mut section = Xxh3::new();
        for first in (0..chunks).step_by(OPEN_READ_CHUNKS) {
            let a = first * CHUNK_ENDS;
            let b = ((first + OPEN_READ_CHUNKS) * CHUNK_ENDS).min(ends);
            buf.resize((b - a) * WIDTH[c], 0u8);
            read_at(file, &mut buf, e.offset + (a * WIDTH[c]) as u64).map_err(|x| short(path, names[c], x))?;
            section.update(&buf);
            for (i, chunk) in buf.chunks(CHUNK_ENDS * WIDTH[c]).enumerate() {
                sums[first + i][c] = xxh3_64(chunk);
            }
            check_column(c, &buf, limits)?;
            if c == 0 && !ids.add(bytemuck::cast_slice(&buf)) {
                return Err(ArchiveError::corrupt("LOTH: patch id out of range"));
            }
            if c == 1 {
                weights::check(&buf, a as u64, escapes, &mut next_escape).map_err(ArchiveError::Corrupt)?;
                sums_of_rows.add(Weights::new(&buf, escapes, a as u64))?;
            }
        }
        let sum = section.digest();
        if sum != e.checksum {
            return Err(ArchiveError::corrupt(format!(
                "section {}: checksum mismatch (stored {:#018x}, computed {sum:#018x})",
                names[c], e.checksum
            )));
        }
    }
    if next_escape != escapes.len() {
        return Err(ArchiveError::corrupt(format!(
            "LCNX: {} entries, but LCNT has {next_escape} zero counts",
            escapes.len()
        )));
    }
    Ok(sums)
}

/// A section's checksum against `sum`, its bytes' XXH3-64.
fn check_sum_of(e: &SectionEntry, sum: u64, name: &str) -> Result<(), ArchiveError> {
    if sum != e.checksum {
        return Err(ArchiveError::corrupt(format!(
            "section {name}: checksum mismatch (stored {:#018x}, computed {sum:#018x})",
            e.checksum
        )));
    }
    Ok(())
}

/// Calls `f` with the `len` bytes of `file` at `offset`, read in pieces
/// of up to 4 MiB into `buf` (whole sections larger than memory).
pub(super) fn for_each_piece(
    file: &File,
    offset: u64,
    len: u64,
    buf: &mut Vec<u8>,
    mut f: impl FnMut(&[u8]) -> std::io::Result<()>,
) -> std::io::Result<()> {
    const PIECE: u64 = 4 << 20;
    let mut at = 0u64;
    while at < len {
        buf.resize((len - at).min(PIECE) as usize, 0);
        read_at(file, buf, offset + at)?;
        f(buf)?;
        at += buf.len() as u64;
    }
    Ok(())
}

/// Asks the kernel to drop `file`'s clean cached pages (advice: errors
/// are ignored, and the pages of a file being written stay).
fn drop_cached(file: &File) {
    #[cfg(target_os = "linux")]
    {
        use std::os::fd::AsRawFd;
        // SAFETY: posix_fadvise reads no memory of ours; it takes an open
        // descriptor (borrowed from `file`, alive for the call) and
        // integers, and only advises the page cache.
        unsafe {
            libc::posix_fadvise(file.as_raw_fd(), 0, 0, libc::POSIX_FADV_DONTNEED);
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = file;
}

/// Heap bytes per link end of a window reading `columns`.
pub fn bytes_per_end(columns: Columns) -> usize {
    [columns.other, columns.weight, columns.direction].iter().zip(WIDTH).map(|(&on, w)| if on { w } else { 0 }).sum()
}

/// Windows of consecutive patches with at most `window_ends` ends each (a
/// patch with more has a window of its own), and the most ends a window's
/// buffers need in whole chunks.
fn plan(offsets: &[u64], window_ends: usize) -> (Vec<Window>, usize) {
    let patches = offsets.len().saturating_sub(1);
    let mut windows = Vec::new();
    let mut start = 0;
    for q in 0..patches {
        if offsets[q + 1] - offsets[start] > window_ends as u64 && q > start {
            windows.push(start..q);
            start = q;
        }
    }
    if patches > start || windows.is_empty() {
        windows.push(start..patches);
    }
    let windows: Vec<Window> = windows
        .into_iter()
        .map(|r| Window { ends: offsets[r.start] as usize..offsets[r.end] as usize, patches: r })
        .collect();
    let capacity = windows
        .iter()
        .map(|w| (w.ends.end.div_ceil(CHUNK_ENDS) - w.ends.start / CHUNK_ENDS) * CHUNK_ENDS)
        .max()
        .unwrap_or(0);
    (windows, capacity)
}

/// The content rules of §7 for column `c` of some link ends (`LOTH`'s ids
/// are checked against their runs, by the caller).
fn check_column(c: usize, bytes: &[u8], limits: &Limits<'_>) -> Result<(), ArchiveError> {
    let ok = match c {
        2 => bytes.chunks_exact(4).all(|x| (u32::from_le_bytes(x.try_into().unwrap()) as usize) < limits.directions),
        // Any count is a weight; zeros are checked against LCNX.
        _ => true,
    };
    if ok {
        return Ok(());
    }
    Err(ArchiveError::corrupt("LDIR: direction out of range"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn windows_cover_every_patch_once_within_the_limit() {
        let rows = [0u64, 3, 0, 70_000, 5, 5, 1, 200_000, 2];
        let mut offsets = vec![0u64];
        for r in rows {
            offsets.push(offsets.last().unwrap() + r);
        }
        let (w, cap) = plan(&offsets, 10);
        let mut next = 0;
        for x in &w {
            assert_eq!(x.patches.start, next);
            assert!(x.patches.end > x.patches.start);
            let n = x.ends.end - x.ends.start;
            assert!(n <= 10 || x.patches.len() == 1, "{n} ends in {:?}", x.patches);
            next = x.patches.end;
        }
        assert_eq!(next, rows.len());
        assert!(cap >= 200_000 && cap % CHUNK_ENDS == 0);
        // No ends at all: one empty window.
        let (w, cap) = plan(&[0, 0, 0], 10);
        assert_eq!((w.len(), cap), (1, 0));
    }
}
