//! The bounded build's external sort: link bundles spilled to disk as
//! sorted runs while tracing goes on, and merged into the archive's link
//! columns as it is written (an [`LinkEndSource`]), so that a build holds
//! its scene, its BVH and a budgeted amount of links, not all of them.
//!
//! A run is the link ends of a contiguous range of direction pairs, sorted
//! by (owner patch, bucket, sender chunk), in the order the in-memory
//! table has them within one such slot: pair, then the bundle's order, the
//! `a` end before the `b` end. Runs cover disjoint pair ranges, so taking each
//! slot's ends from the runs in pair order gives the in-memory table end
//! for end: the archive is byte-identical to an unbounded build's (tested).
//! A sharded build on several machines is the same merge over runs written
//! by each.
//!
//! Scratch files live in one directory next to the output, named
//! `.illumnet-*.spill` (the writer's temporary archive is `.illumnet-*.tmp`),
//! removed when the build ends, succeeds or fails.
//!
//! Run file: `E` records of 12 bytes (other patch u32, weight f32,
//! direction u32, little-endian), then `S` records of 12 bytes (owner u32,
//! bucket · 2¹⁶ + sender chunk u32, count u32), one per non-empty slot,
//! ascending.

use std::collections::BinaryHeap;
use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};

use super::BuildError;
use super::trace::Bundle;
use crate::archive::deltas::{Block, SpillFile};
use crate::archive::layout::CHUNK_PATCHES;
use crate::archive::{LinkEndSink, LinkEndSource};

/// Bytes a bundle holds per link (a, b, w: u32; two u8 buckets).
pub(super) const BUNDLE_BYTES_PER_LINK: u64 = 14;
/// Bytes spilling holds per link while it sorts: the bundle's 14 and two
/// ends of 24-byte records (sorted in place).
const SORT_BYTES_PER_LINK: u64 = 62;
/// Read buffer per run and stream while merging: 64 KiB, less when there
/// are many runs (the merge then holds at most 16 MiB of buffers), never
/// less than 4 KiB.
const MERGE_BUFFER: usize = 64 << 10;
/// What the merge's read buffers take at most, unless runs are so many
/// that 4 KiB each is more.
const MERGE_BUFFERS: usize = 16 << 20;

/// One spilled run.
struct Run {
    first_pair: u32,
    path: PathBuf,
    ends: u64,
    slots: u64,
}

/// Where a build spills, and what it has spilled.
pub(super) struct Spill {
    /// The archive: the scratch directory goes next to it.
    output: std::path::PathBuf,
    /// The scratch directory and its lock (held while it lives), made
    /// at the first spill.
    dir: Mutex<Option<Scratch>>,
    /// Bytes held (bundles, and the per-frame link changes kept in
    /// memory) above which a worker spills its bundles.
    threshold: u64,
    in_memory: AtomicU64,
    runs: Mutex<Vec<Run>>,
    /// Sort buffers kept between spills (fresh ones each time would leave
    /// the allocator holding freed pages).
    buffers: Mutex<Vec<Vec<SortEnd>>>,
    /// Link ends per patch, over every run.
    ends_per_patch: Mutex<Vec<u64>>,
    sequence: AtomicU64,
    /// Where a sequence's per-frame link changes go once they no longer
    /// fit in memory (made when the first part does not).
    deltas: std::sync::OnceLock<SpillFile>,
    /// Bytes of per-frame link changes held in memory (also counted in
    /// `in_memory`): at most half the threshold.
    deltas_held: AtomicU64,
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
type Scratch = (tempfile::TempDir, std::fs::File);

fn io_error(path: &Path, e: std::io::Error) -> BuildError {
    BuildError::Scratch(format!("cannot spill link ends to {}: {e}", path.display()))
}

impl Spill {
    /// A scratch directory next to `output`, spilling when the
    /// bundles held exceed `threshold` bytes.
    pub(super) fn new(output: &Path, threshold: u64, patches: usize) -> Result<Self, String> {
        Ok(Self {
            output: output.to_path_buf(),
            dir: Mutex::new(None),
            threshold,
            in_memory: AtomicU64::new(0),
            runs: Mutex::new(Vec::new()),
            buffers: Mutex::new(Vec::new()),
            ends_per_patch: Mutex::new(vec![0; patches]),
            sequence: AtomicU64::new(0),
            deltas: std::sync::OnceLock::new(),
            deltas_held: AtomicU64::new(0),
        })
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
        let share = self.threshold / (2 * rayon::current_num_threads() as u64).max(1);
        if total > self.threshold && own >= share {
            self.spill(held)?;
        }
        Ok(())
    }

    /// Writes `bundles` (consecutive pairs) as one sorted run and lets them go.
    pub(super) fn spill(&self, bundles: &mut Vec<Bundle>) -> Result<(), BuildError> {
        let links: u64 = bundles.iter().map(|b| b.a.len() as u64).sum();
        if bundles.is_empty() {
            return Ok(());
        }
        let first_pair = bundles[0].pair;
        let mut ends = self.buffers.lock().ok().and_then(|mut b| b.pop()).unwrap_or_default();
        ends.clear();
        ends.reserve(2 * links as usize);
        for b in bundles.iter() {
            for i in 0..b.a.len() {
                let w = b.w[i] as f32;
                let seq = ends.len() as u32;
                ends.push(SortEnd {
                    owner: b.a[i],
                    bucket: b.bucket_a[i],
                    seq,
                    other: b.b[i],
                    weight: w,
                    direction: 2 * b.pair,
                });
                ends.push(SortEnd {
                    owner: b.b[i],
                    bucket: b.bucket_b[i],
                    seq: seq + 1,
                    other: b.a[i],
                    weight: w,
                    direction: 2 * b.pair + 1,
                });
            }
        }
        self.in_memory.fetch_sub(links * BUNDLE_BYTES_PER_LINK, Ordering::Relaxed);
        bundles.clear();
        bundles.shrink_to_fit();
        // Within a slot, ends keep the bundle order (`seq` is unique).
        ends.sort_unstable_by_key(|e| (e.owner, e.slot(), e.seq));
        let n = self.sequence.fetch_add(1, Ordering::Relaxed);
        let path = self.run_path(&format!("run-{first_pair:06}-{n:04}.bin"))?;
        let file = File::create(&path).map_err(|e| io_error(&path, e))?;
        let mut out = BufWriter::with_capacity(1 << 20, file);
        let write = |out: &mut BufWriter<File>, ends: &[SortEnd]| -> std::io::Result<u64> {
            for e in ends {
                out.write_all(&e.other.to_le_bytes())?;
                out.write_all(&e.weight.to_le_bytes())?;
                out.write_all(&e.direction.to_le_bytes())?;
            }
            let mut slots = 0u64;
            for run in ends.chunk_by(|x, y| (x.owner, x.slot()) == (y.owner, y.slot())) {
                out.write_all(&run[0].owner.to_le_bytes())?;
                out.write_all(&run[0].slot().to_le_bytes())?;
                out.write_all(&(run.len() as u32).to_le_bytes())?;
                slots += 1;
            }
            out.flush()?;
            Ok(slots)
        };
        let slots = write(&mut out, &ends).map_err(|e| io_error(&path, e))?;
        drop(out);
        crate::scratch::stop_point("spill");
        {
            let mut per = self.ends_per_patch.lock().expect("no panics while held");
            for e in &ends {
                per[e.owner as usize] += 1;
            }
        }
        self.runs.lock().expect("no panics while held").push(Run { first_pair, path, ends: ends.len() as u64, slots });
        if let Ok(mut b) = self.buffers.lock() {
            b.push(ends);
        }
        Ok(())
    }

    /// At the end of a worker's chunk: spills what it still holds when the
    /// build holds more than the threshold (else the tails of many chunks
    /// would add up in memory).
    pub(super) fn end_chunk(&self, held: &mut Vec<Bundle>) -> Result<(), BuildError> {
        if self.in_memory.load(Ordering::Relaxed) > self.threshold {
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
            *dir = Some(crate::scratch::scratch_dir(&self.output).map_err(|e| {
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
        let room = self.threshold / 2;
        if self
            .deltas_held
            .fetch_update(Ordering::Relaxed, Ordering::Relaxed, |h| (h + bytes <= room).then_some(h + bytes))
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

    /// The merge of every run, and `LOFF` from the runs' counts.
    pub(super) fn finish(self) -> Result<(SpilledLinks, Vec<u64>), String> {
        let mut runs = self.runs.into_inner().expect("no panics while held");
        runs.sort_by_key(|r| r.first_pair);
        let per = self.ends_per_patch.into_inner().expect("no panics while held");
        let mut offsets = Vec::with_capacity(per.len() + 1);
        let mut sum = 0u64;
        offsets.push(0);
        for e in per {
            sum += e;
            offsets.push(sum);
        }
        Ok((SpilledLinks { _dir: self.dir.into_inner().expect("no panics while held"), runs, ends: sum }, offsets))
    }

    /// Bytes held per link of a run being sorted.
    pub(super) fn sort_bytes_per_link() -> u64 {
        SORT_BYTES_PER_LINK
    }
}

/// The runs of a spilled build, merged while the archive is written
/// (give it to [`crate::archive::write_with_links`]); its scratch
/// directory goes when it is dropped.
pub struct SpilledLinks {
    /// Removed (with the runs) when the build ends.
    _dir: Option<Scratch>,
    runs: Vec<Run>,
    ends: u64,
}

/// A run being read: its ends and its slot list.
struct RunReader {
    ends: BufReader<File>,
    slots: BufReader<File>,
    slots_left: u64,
}

impl RunReader {
    /// The next slot: owner, bucket · 2¹⁶ + sender chunk, ends.
    fn next_slot(&mut self) -> std::io::Result<Option<(u32, u32, u32)>> {
        if self.slots_left == 0 {
            return Ok(None);
        }
        self.slots_left -= 1;
        let mut r = [0u8; 12];
        self.slots.read_exact(&mut r)?;
        let word = |i: usize| u32::from_le_bytes(r[4 * i..4 * i + 4].try_into().expect("4 bytes"));
        Ok(Some((word(0), word(1), word(2))))
    }
}

impl SpilledLinks {
    /// Runs spilled.
    pub fn run_count(&self) -> usize {
        self.runs.len()
    }

    /// Bytes the runs take on disk.
    pub fn spilled_bytes(&self) -> u64 {
        self.runs.iter().map(|r| (r.ends + r.slots) * 12).sum()
    }
}

impl LinkEndSource for SpilledLinks {
    fn end_count(&self) -> u64 {
        self.ends
    }

    fn write_ends(&mut self, out: &mut LinkEndSink<'_>) -> std::io::Result<()> {
        let mut readers = Vec::with_capacity(self.runs.len());
        let mut heap = BinaryHeap::new();
        let buffer = (MERGE_BUFFERS / (2 * self.runs.len().max(1))).clamp(4 << 10, MERGE_BUFFER);
        for (i, run) in self.runs.iter().enumerate() {
            let ends = BufReader::with_capacity(buffer, File::open(&run.path)?);
            let mut file = File::open(&run.path)?;
            file.seek(SeekFrom::Start(run.ends * 12))?;
            let mut r = RunReader { ends, slots: BufReader::with_capacity(buffer, file), slots_left: run.slots };
            if let Some((owner, bucket, count)) = r.next_slot()? {
                heap.push(std::cmp::Reverse((owner, bucket, i, count)));
            }
            readers.push(r);
        }
        const BATCH: usize = 1 << 16;
        let (mut other, mut weight, mut direction, mut bucket) = (
            Vec::with_capacity(BATCH),
            Vec::with_capacity(BATCH),
            Vec::with_capacity(BATCH),
            Vec::with_capacity(BATCH),
        );
        let mut record = [0u8; 12];
        // Smallest slot first; within a slot, runs in pair order.
        while let Some(std::cmp::Reverse((_, k, i, count))) = heap.pop() {
            let r = &mut readers[i];
            for _ in 0..count {
                r.ends.read_exact(&mut record)?;
                let word = |j: usize| u32::from_le_bytes(record[4 * j..4 * j + 4].try_into().expect("4 bytes"));
                other.push(word(0));
                weight.push(f32::from_bits(word(1)));
                direction.push(word(2));
                bucket.push((k >> 16) as u8);
                if other.len() == BATCH {
                    crate::scratch::stop_point("merge");
                    out(&other, &weight, &direction, &bucket)?;
                    other.clear();
                    weight.clear();
                    direction.clear();
                    bucket.clear();
                }
            }
            if let Some((owner, bucket, count)) = r.next_slot()? {
                heap.push(std::cmp::Reverse((owner, bucket, i, count)));
            }
        }
        if !other.is_empty() {
            out(&other, &weight, &direction, &bucket)?;
        }
        Ok(())
    }
}
