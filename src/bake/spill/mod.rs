//! The bounded build's external sort: link bundles spilled to disk as
//! sorted runs while tracing goes on, and merged into the archive's link
//! columns as it is written (an [`LinkEndSource`]), so that a build holds
//! its scene, its BVH and a budgeted amount of links, not all of them.
//!
//! A run is the link ends of a contiguous range of links in pair order
//! (it may begin and end inside a pair's bundle: a run holds at most
//! [`SpillPlan::run_links`] links), sorted by (owner
//! patch, bucket, sender chunk), in the order the in-memory table has them
//! within one such slot: pair, then the bundle's order, the `a` end before
//! the `b` end. Runs cover disjoint ranges, so taking each slot's ends from
//! the runs in the order of their first link gives the in-memory table end
//! for end: the archive is byte-identical to an unbounded build's (tested).
//! A sharded build on several machines is the same merge over runs written
//! by each.
//!
//! Scratch files live in one directory next to the output, named
//! `.illumnet-*.spill` (the writer's temporary archive is `.illumnet-*.tmp`),
//! removed when the build ends, succeeds or fails.
//!
//! Run file: `E` end records of 8 bytes (other patch u32, weight u16,
//! direction u16, little-endian) when all of the run's fit, else of 12
//! (u32, f32, u32), then `S` records of 12 bytes (owner u32, the bucket
//! times 2¹⁶ plus the sender chunk as u32, count u32), one per non-empty
//! slot, ascending (a slot repeats only where its count would pass u32):
//! `records.rs`.
//!
//! More runs than one merge may open ([`MERGE_FAN_IN`], or fewer under a
//! low limit of open files) are merged in passes: groups of
//! consecutive runs (in the order of their first link) become one run
//! each, in the same format, until few enough remain. A group's slot keeps
//! its runs' ends in run order, as the final merge takes them, so the
//! archive's bytes do not depend on how many passes there were (tested).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};

use super::BuildError;
use super::bundle::Bundle;
use crate::archive::deltas::{Block, SpillFile};
use crate::archive::layout::CHUNK_PATCHES;
use crate::progress::Progress;

/// Bytes a bundle holds per link (a, b, w: u32; two u8 buckets).
pub(super) const BUNDLE_BYTES_PER_LINK: u64 = 14;
/// Bytes a sort buffer holds per link of a run: two ends of 24-byte
/// records.
const SORT_BYTES_PER_LINK: u64 = 2 * size_of::<SortEnd>() as u64;
/// Read buffer per run and stream while merging: 64 KiB, less when there
/// are many runs (the merge then holds at most [`MERGE_BUFFERS`]).
const MERGE_BUFFER: usize = 64 << 10;
/// What a merge's buffers take at most: 16 MiB, read buffers (two per
/// run: its ends and its slots) and, in a merge into a run, the writers'.
const MERGE_BUFFERS: usize = 16 << 20;
/// Runs merged at once, at most. More runs are first merged in groups of
/// consecutive runs into fewer, larger runs (a pass reads and writes the
/// spilled bytes once more), so that a merge opens at most 514 files
/// (under the usual limit of 1 024 a process; fewer where the process may
/// open fewer: [`merge_fan_in`]) and its read buffers hold about 28 KiB
/// each.
const MERGE_FAN_IN: usize = 256;
/// Files a merge leaves the rest of the process (standard streams, the
/// archive being written, locks, the spilled per-frame changes).
const OTHER_FILES: u64 = 32;

/// Runs one merge may open (two files each, and a merge pass writes two):
/// [`MERGE_FAN_IN`], or fewer when the process's soft limit of open files
/// (`ulimit -n`) would not leave [`OTHER_FILES`] beside them; at least 2.
pub(super) fn merge_fan_in() -> usize {
    let mut limit = libc::rlimit { rlim_cur: 0, rlim_max: 0 };
    // SAFETY: getrlimit only writes the struct it is given, which lives
    // for the call.
    #[allow(clippy::unnecessary_cast)] // rlim_t is not u64 everywhere
    let soft =
        if unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut limit) } == 0 { limit.rlim_cur as u64 } else { 1024 };
    (soft.saturating_sub(OTHER_FILES + 2) / 2).clamp(2, MERGE_FAN_IN as u64) as usize
}
/// Write buffer of each file a run is written to (one per spilling
/// worker while tracing: counted as fixed).
pub(super) const RUN_WRITE_BUFFER: usize = 1 << 20;

/// One spilled run.
pub(super) struct Run {
    /// Where the run starts: its first pair, and the index of its first
    /// link within that pair's bundle (a bundle larger than a run is cut
    /// into several); runs are merged in this order.
    pub(super) first: (u32, u64),
    pub(super) path: PathBuf,
    pub(super) ends: u64,
    pub(super) slots: u64,
    /// Bytes of its end records ([`records::NARROW`] or [`records::WIDE`]).
    pub(super) end_bytes: u64,
}

impl Run {
    /// Bytes of its file.
    pub(super) fn bytes(&self) -> u64 {
        self.ends * self.end_bytes + self.slots * records::SLOT
    }
}

/// How a bounded build spends `room`, the bytes its links may hold:
///
/// - bundles traced and not yet spilled, a sequence's per-frame link
///   changes held in memory, and the tracers' growing per-pair scratch,
///   all counted in `Spill::in_memory`: at most `1.5 · threshold` (a
///   worker spills once the count passes the threshold and it holds at
///   least `threshold / 2n` itself; those below hold less than
///   `threshold / 2` together);
/// - sort buffers, pooled: one per spill under way (at most one per
///   worker), made when none is free and never grown: a run holds at most
///   `run_links` links, so the n buffers take at most
///   `n · run_links · 48 = threshold · 48 / 14` bytes.
///
/// The first holds while what cannot be spilled (the scratch, the changes
/// held) stays below half the threshold, and bundles are small against
/// the threshold: a worker counts a bundle once it is traced, so each may
/// hold one more than its count says.
///
/// Both together fill `room`. The buffers are kept, not freed after each
/// run: the allocator would keep freed pages resident for a while, and
/// fresh ones are faulted in again.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct SpillPlan {
    /// Bytes counted in memory above which workers spill.
    pub(super) threshold: u64,
    /// Links a run holds at most.
    pub(super) run_links: u64,
}

impl SpillPlan {
    /// The plan for `room` bytes and `workers` tracing threads.
    pub(super) fn new(room: u64, workers: usize) -> Self {
        let n = workers.max(1) as u64;
        // 1.5·T + T·48/14 = room.
        let threshold = room * 2 * BUNDLE_BYTES_PER_LINK / (3 * BUNDLE_BYTES_PER_LINK + 2 * SORT_BYTES_PER_LINK);
        // A run's ends are numbered in u32 (`SortEnd::seq`).
        let run_links = (threshold / (BUNDLE_BYTES_PER_LINK * n)).clamp(1, u32::MAX as u64 / 2);
        Self { threshold, run_links }
    }

    /// Bytes the plan holds at most: the counted bytes and the sort
    /// buffers (what `room` must cover).
    #[cfg(test)]
    fn peak_bytes(&self, workers: usize) -> u64 {
        self.threshold * 3 / 2 + workers.max(1) as u64 * self.run_links * SORT_BYTES_PER_LINK
    }
}

/// Where a build spills, and what it has spilled.
pub(super) struct Spill {
    /// The archive: the scratch directory goes next to it.
    output: std::path::PathBuf,
    /// The scratch directory and its lock (held while it lives), made
    /// at the first spill.
    dir: Mutex<Option<Scratch>>,
    /// Bytes held (bundles, the per-frame link changes kept in memory,
    /// the tracers' scratch) above which a worker spills its bundles;
    /// links per run at most.
    plan: SpillPlan,
    in_memory: AtomicU64,
    runs: Mutex<Vec<Run>>,
    /// Sort buffers kept between spills, one per worker that has spilled
    /// ([`SpillPlan`]), each of `2 · run_links` ends.
    buffers: Mutex<Vec<Vec<SortEnd>>>,
    /// Sort buffers made so far.
    buffers_made: AtomicU64,
    /// Link ends per patch, over every run.
    ends_per_patch: Mutex<Vec<u64>>,
    /// Patches of the build (owners are below it).
    patches: usize,
    sequence: AtomicU64,
    /// Where a sequence's per-frame link changes go once they no longer
    /// fit in memory (made when the first part does not).
    deltas: std::sync::OnceLock<SpillFile>,
    /// Bytes of per-frame link changes held in memory (also counted in
    /// `in_memory`): at most half the threshold.
    deltas_held: AtomicU64,
    /// Bytes of a tracer's scratch the build counted as fixed (a pair's
    /// link keys at one link a ray), and how many tracers may still
    /// claim them ([`Spill::scratch_credit`]).
    pair_scratch: u64,
    credits: AtomicU64,
}

/// An end as it is sorted.
#[derive(Clone, Copy)]
struct SortEnd {
    owner: u32,
    bucket: u8,
    /// Position in the bundle order, so that an unstable (in-place) sort
    /// gives the stable order.
    seq: u32,
    other: u32,
    weight: f32,
    direction: u32,
}

impl SortEnd {
    /// The slot key after the owner: bucket, then sender chunk (§5.10).
    fn slot(&self) -> u32 {
        ((self.bucket as u32) << 16) | (self.other as usize / CHUNK_PATCHES) as u32
    }
}

/// A scratch directory and its lock file ([`crate::scratch::scratch_dir`]).
pub(super) type Scratch = (tempfile::TempDir, std::fs::File);

fn io_error(path: &Path, e: std::io::Error) -> BuildError {
    BuildError::Scratch(format!("cannot spill link ends to {}: {e}", path.display()))
}

impl Spill {
    /// A scratch directory next to `output`, spilling as `plan` says.
    /// `pair_scratch` bytes of each of `workers` tracers' scratch are
    /// counted outside the plan's room, as fixed.
    pub(super) fn new(
        output: &Path,
        plan: SpillPlan,
        patches: usize,
        pair_scratch: u64,
        workers: usize,
    ) -> Result<Self, String> {
        Ok(Self {
            output: output.to_path_buf(),
            dir: Mutex::new(None),
            plan,
            in_memory: AtomicU64::new(0),
            runs: Mutex::new(Vec::new()),
            buffers: Mutex::new(Vec::new()),
            buffers_made: AtomicU64::new(0),
            ends_per_patch: Mutex::new(vec![0; patches]),
            patches,
            sequence: AtomicU64::new(0),
            deltas: std::sync::OnceLock::new(),
            deltas_held: AtomicU64::new(0),
            pair_scratch,
            credits: AtomicU64::new(workers as u64),
        })
    }

    /// Bytes of a new tracer's scratch already counted (as fixed, before
    /// the plan's room): a pair's link keys for each of the first
    /// `workers` tracers that ask, nothing for any after them.
    pub(super) fn scratch_credit(&self) -> u64 {
        let claimed = self.credits.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |c| c.checked_sub(1));
        if claimed.is_ok() { self.pair_scratch } else { 0 }
    }

    /// Counts `bundle` as held, and spills `held` (the worker's bundles of
    /// consecutive pairs, `bundle` last) when the build holds more than
    /// the threshold.
    pub(super) fn hold(&self, held: &mut Vec<Bundle>) -> Result<(), BuildError> {
        let bytes = held.last().map_or(0, |b| b.a.len() as u64 * BUNDLE_BYTES_PER_LINK);
        let total = self.in_memory.fetch_add(bytes, Ordering::Relaxed) + bytes;
        // A worker holding little waits for the others to spill, so that
        // runs do not come out tiny: the build holds at most
        // `threshold · 1.5` (each of n workers below threshold / 2n).
        let own: u64 = held.iter().map(|b| b.a.len() as u64 * BUNDLE_BYTES_PER_LINK).sum();
        let share = self.plan.threshold / (2 * rayon::current_num_threads() as u64).max(1);
        if total > self.plan.threshold && own >= share {
            self.spill(held)?;
        }
        Ok(())
    }

    /// Counts `bytes` more of a tracer's scratch as held (it keeps them
    /// until the trace ends).
    pub(super) fn hold_scratch(&self, bytes: u64) {
        self.in_memory.fetch_add(bytes, Ordering::Relaxed);
    }

    /// Writes `bundles` (consecutive pairs) as sorted runs of at most
    /// `run_links` links each, and lets them go.
    pub(super) fn spill(&self, bundles: &mut Vec<Bundle>) -> Result<(), BuildError> {
        let links: u64 = bundles.iter().map(|b| b.a.len() as u64).sum();
        if bundles.is_empty() {
            return Ok(());
        }
        let cap = self.plan.run_links.max(1);
        let mut ends = self.buffers.lock().ok().and_then(|mut b| b.pop()).unwrap_or_else(|| {
            self.buffers_made.fetch_add(1, Ordering::Relaxed);
            Vec::with_capacity(2 * cap as usize)
        });
        // The next link to spill: its bundle, and its index in the bundle.
        let (mut bundle, mut at) = (0usize, 0usize);
        let mut segments = Vec::new();
        let result = loop {
            if bundle == bundles.len() {
                break Ok(());
            }
            let first = (bundles[bundle].pair, at as u64);
            // The run's links: up to `cap` from here, by bundle.
            segments.clear();
            let mut left = cap as usize;
            while bundle < bundles.len() && left > 0 {
                let take = (bundles[bundle].a.len() - at).min(left);
                segments.push((bundle, at..at + take));
                left -= take;
                at += take;
                if at == bundles[bundle].a.len() {
                    (bundle, at) = (bundle + 1, 0);
                }
            }
            sort::sorted_run(bundles, &segments, self.patches, &mut ends);
            debug_assert!(
                ends.len() as u64 <= 2 * cap && ends.capacity() as u64 == 2 * cap,
                "a run fills its buffer, never grows it"
            );
            // (Bundles of no links after the last run's end give none.)
            if !ends.is_empty()
                && let Err(e) = self.write_run(&ends, first)
            {
                break Err(e);
            }
        };
        if let Ok(mut b) = self.buffers.lock() {
            b.push(ends);
        }
        self.in_memory.fetch_sub(links * BUNDLE_BYTES_PER_LINK, Ordering::Relaxed);
        bundles.clear();
        bundles.shrink_to_fit();
        result
    }

    /// Writes `ends` (a run starting at `first`, sorted: within a slot in
    /// the bundle order, [`sort::sorted_run`]).
    fn write_run(&self, ends: &[SortEnd], first: (u32, u64)) -> Result<(), BuildError> {
        let n = self.sequence.fetch_add(1, Ordering::Relaxed);
        let path = self.run_path(&format!("run-{:06}-{n:04}.bin", first.0))?;
        let file = File::create(&path).map_err(|e| io_error(&path, e))?;
        let mut out = BufWriter::with_capacity(RUN_WRITE_BUFFER, file);
        let end_bytes = records::end_bytes(ends);
        let write = |out: &mut BufWriter<File>, ends: &[SortEnd]| -> std::io::Result<u64> {
            records::put_ends(out, ends, end_bytes)?;
            let mut slots = 0u64;
            let runs = ends.chunk_by(|x, y| (x.owner, x.slot()) == (y.owner, y.slot()));
            records::put_slots(
                out,
                runs.map(|run| [run[0].owner, run[0].slot(), run.len() as u32]).inspect(|_| slots += 1),
            )?;
            out.flush()?;
            Ok(slots)
        };
        let slots = write(&mut out, ends).map_err(|e| io_error(&path, e))?;
        drop(out);
        crate::scratch::stop_point("spill");
        {
            let mut per = self.ends_per_patch.lock().expect("no panics while held");
            for e in ends.iter() {
                per[e.owner as usize] += 1;
            }
        }
        self.runs.lock().expect("no panics while held").push(Run {
            first,
            path,
            ends: ends.len() as u64,
            slots,
            end_bytes,
        });
        Ok(())
    }

    /// At the end of a worker's chunk: spills what it still holds when the
    /// build holds more than the threshold (else the tails of many chunks
    /// would add up in memory).
    pub(super) fn end_chunk(&self, held: &mut Vec<Bundle>) -> Result<(), BuildError> {
        if self.in_memory.load(Ordering::Relaxed) > self.plan.threshold {
            self.spill(held)?;
        }
        Ok(())
    }

    /// Where run `name` goes, in the scratch directory (made now if this
    /// is the first run, after removing what killed builds left).
    fn run_path(&self, name: &str) -> Result<std::path::PathBuf, BuildError> {
        let mut dir = self.dir.lock().expect("no panics while held");
        if dir.is_none() {
            let _ = crate::scratch::remove_stale(&self.output);
            // The folder, if a caller did not make it (or another process
            // made it and removed it again); the archive goes there too.
            let made = crate::scratch::OutputDir::make(&self.output).map(crate::scratch::OutputDir::keep);
            *dir = Some(made.and_then(|()| crate::scratch::scratch_dir(&self.output)).map_err(|e| {
                BuildError::Scratch(format!(
                    "cannot make a scratch directory in {}: {e}",
                    crate::scratch::dir_of(&self.output).display()
                ))
            })?);
        }
        Ok(dir.as_ref().expect("made above").0.path().join(name))
    }

    /// Holds a part's compressed per-frame link changes (counted in
    /// `in_memory` with the links) while they fit in half the threshold;
    /// beyond it, writes them to the spill file (an unnamed file next to
    /// the output, made at the first such part) and points the blocks
    /// into it, so that a sequence's changes are not all held until the
    /// archive is written.
    pub(super) fn spill_deltas(&self, blocks: &mut [Block]) -> Result<(), BuildError> {
        let dir = crate::scratch::dir_of(&self.output);
        let error = |e: std::io::Error| {
            BuildError::Scratch(format!("cannot spill per-frame link changes to {}: {e}", dir.display()))
        };
        let bytes: u64 = blocks.iter().map(|b| b.stored.len()).sum();
        if bytes == 0 {
            return Ok(());
        }
        // Held while they take at most half the threshold, and while the
        // count stays below it (bundles can be spilled, changes held cannot).
        let room = self.plan.threshold / 2;
        let below = |h: u64| h + bytes <= room && self.in_memory.load(Ordering::Relaxed) + bytes <= self.plan.threshold;
        if self
            .deltas_held
            .fetch_update(Ordering::Relaxed, Ordering::Relaxed, |h| below(h).then_some(h + bytes))
            .is_ok()
        {
            self.in_memory.fetch_add(bytes, Ordering::Relaxed);
            return Ok(());
        }
        let file = match self.deltas.get() {
            Some(f) => f,
            None => {
                let made = SpillFile::new_in(dir).map_err(error)?;
                self.deltas.get_or_init(|| made)
            }
        };
        blocks.iter_mut().try_for_each(|b| file.spill(b)).map_err(error)?;
        Ok(())
    }

    /// The file the per-frame link changes were spilled to, if any were.
    pub(super) fn delta_file(&self) -> Option<SpillFile> {
        self.deltas.get().cloned()
    }

    /// Runs spilled so far.
    pub(super) fn run_count(&self) -> usize {
        self.runs.lock().map_or(0, |r| r.len())
    }

    /// The merge of every run, and `LOFF` from the runs' counts. Runs
    /// beyond what one merge may open ([`merge_fan_in`]) are merged into
    /// fewer first (reported to `progress`).
    pub(super) fn finish(self, progress: &dyn Progress) -> Result<(SpilledLinks, Vec<u64>), BuildError> {
        self.finish_with(merge_fan_in(), progress)
    }

    /// [`Self::finish`] merging at most `fan_in` (≥ 2) runs at once.
    fn finish_with(self, fan_in: usize, progress: &dyn Progress) -> Result<(SpilledLinks, Vec<u64>), BuildError> {
        // The sort buffers (most of the links' room) go before any merge.
        drop(self.buffers);
        let mut runs = self.runs.into_inner().expect("no panics while held");
        runs.sort_by_key(|r| r.first);
        let spilled = (runs.len(), runs.iter().map(Run::bytes).sum());
        let dir = self.dir.into_inner().expect("no panics while held");
        if let Some((scratch, _)) = &dir {
            runs = merge_passes(runs, fan_in.max(2), scratch.path(), progress)?;
        }
        let per = self.ends_per_patch.into_inner().expect("no panics while held");
        let mut offsets = Vec::with_capacity(per.len() + 1);
        let mut sum = 0u64;
        offsets.push(0);
        for e in per {
            sum += e;
            offsets.push(sum);
        }
        Ok((SpilledLinks { _dir: dir, runs, spilled, ends: sum }, offsets))
    }

    /// Sort buffers made: at most one per thread that spilled.
    #[cfg(test)]
    fn buffers_made(&self) -> u64 {
        self.buffers_made.load(Ordering::Relaxed)
    }
}

/// The runs of a spilled build, merged while the archive is written
/// (give it to [`crate::archive::write_with_links`]); its scratch
/// directory goes when it is dropped.
pub struct SpilledLinks {
    /// Removed (with the runs) when the build ends.
    pub(super) _dir: Option<Scratch>,
    /// The runs left to merge, in the order of their first link.
    pub(super) runs: Vec<Run>,
    /// Runs the tracers spilled (before any merge pass), and their bytes.
    pub(super) spilled: (usize, u64),
    pub(super) ends: u64,
}

impl SpilledLinks {
    /// Runs spilled while tracing.
    pub fn run_count(&self) -> usize {
        self.spilled.0
    }

    /// Bytes the runs spilled while tracing took on disk.
    pub fn spilled_bytes(&self) -> u64 {
        self.spilled.1
    }
}

mod merge;
mod records;
pub(super) use merge::merge_passes;
#[cfg(test)]
use merge::{NO_SLOT, RUN_BITS, Tournament};
mod sort;
#[cfg(test)]
mod tests;
