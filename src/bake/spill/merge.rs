//! The merge of a bounded build's runs ([`super::SpilledLinks`] as the
//! archive writer's link-end source): a loser tree over the runs' next
//! slots, on a thread of its own a batch ahead of the writer, and the
//! merge passes that join groups of runs into one when there are more
//! than one merge may open.

use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::path::Path;

use super::{BuildError, MERGE_BUFFER, MERGE_BUFFERS, RUN_WRITE_BUFFER, Run, SpilledLinks, records};
use crate::archive::{LinkEndSink, LinkEndSource};
use crate::progress::Progress;

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

impl LinkEndSource for SpilledLinks {
    fn end_count(&self) -> u64 {
        self.ends
    }

    /// The merge runs on a thread of its own, filling batches of ends
    /// while the caller encodes and writes the one before (the two took
    /// turns on one core: the merge's reads and the archive's writes are
    /// each about half of the write stage). Three batches of 2¹⁶ ends
    /// (2.5 MiB) go round, in the room the tracers' links left.
    fn write_ends(&mut self, out: &mut LinkEndSink<'_>) -> std::io::Result<()> {
        use std::sync::mpsc::sync_channel;
        let runs = &self.runs;
        let (full_tx, full_rx) = sync_channel::<Batch>(BATCHES);
        let (empty_tx, empty_rx) = sync_channel::<Batch>(BATCHES);
        for _ in 0..BATCHES {
            empty_tx.send(Batch::default()).expect("the receiver is held here");
        }
        std::thread::scope(|scope| {
            let merger = std::thread::Builder::new()
                .name("merge".into())
                .spawn_scoped(scope, move || merge_batches(runs, &full_tx, &empty_rx))?;
            let mut written = Ok(());
            while let Ok(mut batch) = full_rx.recv() {
                written = out(&batch.other, &batch.weight, &batch.direction, &batch.bucket);
                if written.is_err() {
                    break;
                }
                batch.clear();
                // (The merge may have ended: the batch is not needed.)
                let _ = empty_tx.send(batch);
            }
            // Closed, so that a merge still under way stops.
            drop((full_rx, empty_tx));
            let merged = merger.join().unwrap_or_else(|_| Err(std::io::Error::other("the merge of the runs panicked")));
            written.and(merged)
        })
    }
}

/// Batches of ends the merge and the archive writer pass between them.
const BATCHES: usize = 3;

/// Ends a batch holds.
const BATCH_ENDS: usize = 1 << 16;

/// Link ends in the columns the archive writer takes.
#[derive(Default)]
struct Batch {
    other: Vec<u32>,
    weight: Vec<f32>,
    direction: Vec<u32>,
    bucket: Vec<u8>,
}

impl Batch {
    fn len(&self) -> usize {
        self.other.len()
    }

    fn clear(&mut self) {
        self.other.clear();
        self.weight.clear();
        self.direction.clear();
        self.bucket.clear();
    }
}

/// The merge of `runs` in batches: each filled from one of `empty` and
/// sent to `full`; stops with an error when the writer stopped taking
/// them.
fn merge_batches(
    runs: &[Run],
    full: &std::sync::mpsc::SyncSender<Batch>,
    empty: &std::sync::mpsc::Receiver<Batch>,
) -> std::io::Result<()> {
    let stopped = || std::io::Error::other("the archive writer stopped");
    let mut batch = empty.recv().map_err(|_| stopped())?;
    // A slot's records are read in pieces of up to 4 096 (48 KiB), not
    // one by one.
    const PIECE: usize = 1 << 12;
    let mut piece = vec![0u8; PIECE * records::WIDE as usize];
    merge_slots(runs, MERGE_BUFFERS, |_, k, count, ends, end_bytes| {
        let mut left = count as usize;
        while left > 0 {
            let n = left.min(BATCH_ENDS - batch.len()).min(PIECE);
            let bytes = &mut piece[..n * end_bytes as usize];
            ends.read_exact(bytes)?;
            for r in bytes.chunks_exact(end_bytes as usize) {
                let (other, weight, direction) = records::end(r, end_bytes);
                batch.other.push(other);
                batch.weight.push(weight);
                batch.direction.push(direction);
            }
            batch.bucket.resize(batch.len(), (k >> 16) as u8);
            left -= n;
            if batch.len() == BATCH_ENDS {
                crate::scratch::stop_point("merge");
                full.send(std::mem::take(&mut batch)).map_err(|_| stopped())?;
                batch = empty.recv().map_err(|_| stopped())?;
            }
        }
        Ok(())
    })?;
    if batch.len() > 0 {
        full.send(batch).map_err(|_| stopped())?;
    }
    Ok(())
}

/// Walks the slots of `runs` (in the order of their first link) in merged
/// order: smallest (owner, slot key) first, and within a slot the runs in
/// order. `slot(owner, key, count, ends, end_bytes)` must read the slot's
/// `count` end records (of `end_bytes` each) from `ends`. The read
/// buffers take at most `buffers` bytes (at least 4 KiB a file).
fn merge_slots(
    runs: &[Run],
    buffers: usize,
    mut slot: impl FnMut(u32, u32, u32, &mut BufReader<File>, u64) -> std::io::Result<()>,
) -> std::io::Result<()> {
    if runs.len() > 1 << RUN_BITS {
        return Err(std::io::Error::other(format!(
            "{} runs to merge at once, more than {}",
            runs.len(),
            1 << RUN_BITS
        )));
    }
    let mut readers = Vec::with_capacity(runs.len());
    let mut next = Vec::with_capacity(runs.len());
    let mut counts = vec![0u32; runs.len()];
    let buffer = (buffers / (2 * runs.len().max(1))).clamp(4 << 10, MERGE_BUFFER);
    for (i, run) in runs.iter().enumerate() {
        let open =
            || File::open(&run.path).map_err(|e| std::io::Error::new(e.kind(), format!("{}: {e}", run.path.display())));
        let ends = BufReader::with_capacity(buffer, open()?);
        let mut file = open()?;
        file.seek(SeekFrom::Start(run.ends * run.end_bytes))?;
        let mut r = RunReader { ends, slots: BufReader::with_capacity(buffer, file), slots_left: run.slots };
        next.push(merge_key(r.next_slot()?, i, &mut counts)?);
        readers.push(r);
    }
    let mut tournament = Tournament::new(next);
    loop {
        let (i, k) = tournament.winner();
        if k == NO_SLOT {
            return Ok(());
        }
        let (owner, key) = ((k >> (24 + RUN_BITS)) as u32, ((k >> RUN_BITS) & 0xff_ffff) as u32);
        let r = &mut readers[i];
        slot(owner, key, counts[i], &mut r.ends, runs[i].end_bytes)?;
        tournament.replace(merge_key(r.next_slot()?, i, &mut counts)?);
    }
}

/// Bits of a merge key that hold the run (the ties' order).
pub(super) const RUN_BITS: u32 = 10;

/// The merge key of a run with no slot left: after every other.
pub(super) const NO_SLOT: u64 = u64::MAX;

/// The merge key of run `i`'s next slot `(owner, key, count)`, its count
/// noted in `counts`: owner, slot key, then the run, in one word (owners
/// are below 2³⁰, [`crate::patch::MAX_PATCHES`]; slot keys below 2²⁴).
fn merge_key(next: Option<(u32, u32, u32)>, i: usize, counts: &mut [u32]) -> std::io::Result<u64> {
    let Some((owner, key, count)) = next else { return Ok(NO_SLOT) };
    if owner as u64 >= crate::patch::MAX_PATCHES || key >= 1 << 24 {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("a spilled run is corrupt: slot (patch {owner}, key {key:#x}) out of range"),
        ));
    }
    counts[i] = count;
    Ok(((owner as u64) << (24 + RUN_BITS)) | ((key as u64) << RUN_BITS) | i as u64)
}

/// A loser tree over the runs' next merge keys ([`merge_key`]): the
/// smallest found in log₂(runs) comparisons after each replacement, half
/// of what a binary heap's pop and push take (the heap was 8% of a
/// spilling build's samples).
pub(super) struct Tournament {
    /// Per run, its next key.
    keys: Vec<u64>,
    /// `nodes[p]` for `p` in `1..runs`: the run that lost the match at
    /// node `p` (whose children are `2p` and `2p + 1`, run `i` being node
    /// `runs + i`); `nodes[0]`: the run that won.
    nodes: Vec<usize>,
}

impl Tournament {
    pub(super) fn new(keys: Vec<u64>) -> Self {
        let n = keys.len();
        let mut nodes = vec![0; n.max(1)];
        let mut winners = vec![0; n.max(1)];
        let at = |p: usize, winners: &[usize]| if p >= n { p - n } else { winners[p] };
        for p in (1..n).rev() {
            let (a, b) = (at(2 * p, &winners), at(2 * p + 1, &winners));
            let (w, l) = if keys[a] <= keys[b] { (a, b) } else { (b, a) };
            (winners[p], nodes[p]) = (w, l);
        }
        if n > 1 {
            nodes[0] = winners[1];
        }
        Self { keys, nodes }
    }

    /// The run with the smallest key, and the key.
    pub(super) fn winner(&self) -> (usize, u64) {
        let i = self.nodes[0];
        (i, self.keys.get(i).copied().unwrap_or(NO_SLOT))
    }

    /// Gives the winner its next key, and plays its matches again.
    pub(super) fn replace(&mut self, key: u64) {
        let n = self.keys.len();
        let mut w = self.nodes[0];
        self.keys[w] = key;
        let mut p = (w + n) / 2;
        while p >= 1 {
            let l = self.nodes[p];
            if self.keys[l] < self.keys[w] {
                self.nodes[p] = w;
                w = l;
            }
            p /= 2;
        }
        self.nodes[0] = w;
    }
}

/// Merges `runs` (in the order of their first link) in passes of groups
/// of at most `fan_in` consecutive runs until at most `fan_in` are left,
/// each group into one run in `dir`, removing a group's runs once it is
/// merged (so a pass needs one group's bytes of disk more, not all).
pub(in crate::bake) fn merge_passes(
    mut runs: Vec<Run>,
    fan_in: usize,
    dir: &Path,
    progress: &dyn Progress,
) -> Result<Vec<Run>, BuildError> {
    let mut pass = 0;
    while runs.len() > fan_in {
        let groups = runs.len().div_ceil(fan_in);
        let size = runs.len().div_ceil(groups);
        let total: u64 = runs.iter().map(|r| r.ends).sum();
        progress.start(&format!("merging {} runs into {groups}", runs.len()), total);
        let mut merged = Vec::with_capacity(groups);
        let mut left = runs.into_iter();
        for g in 0..groups {
            let group: Vec<Run> = left.by_ref().take(size).collect();
            if group.is_empty() {
                break;
            }
            if let [run] = &group[..] {
                // A group of one is a run already.
                progress.advance(run.ends);
                merged.extend(group);
                continue;
            }
            let path = dir.join(format!("merge-{pass:02}-{g:06}.bin"));
            let run = merge_group(&group, &path).map_err(|e| {
                BuildError::Scratch(format!("cannot merge spilled link ends into {}: {e}", path.display()))
            })?;
            crate::scratch::stop_point("merge pass");
            for r in &group {
                let _ = std::fs::remove_file(&r.path);
            }
            progress.advance(run.ends);
            merged.push(run);
        }
        progress.finish();
        runs = merged;
        pass += 1;
    }
    Ok(runs)
}

/// `group`'s runs merged into one run at `path` (its slot records are
/// written beside it first, then appended).
fn merge_group(group: &[Run], path: &Path) -> std::io::Result<Run> {
    let slots_path = path.with_extension("slots");
    let mut ends_out = BufWriter::with_capacity(RUN_WRITE_BUFFER, File::create(path)?);
    let mut slots_out = BufWriter::with_capacity(RUN_WRITE_BUFFER, File::create(&slots_path)?);
    let (mut ends, mut slots) = (0u64, 0u64);
    let mut last: Option<(u32, u32, u32)> = None;
    let mut put = |out: &mut BufWriter<File>, slot: (u32, u32, u32)| -> std::io::Result<()> {
        slots += 1;
        records::put_slots(out, std::iter::once([slot.0, slot.1, slot.2]))
    };
    // Narrow if every run of the group is.
    let end_bytes = group.iter().map(|r| r.end_bytes).max().unwrap_or(records::NARROW);
    const PIECE: usize = 4 << 10;
    let (mut piece, mut converted) = (vec![0u8; PIECE * records::WIDE as usize], Vec::new());
    let buffers = MERGE_BUFFERS - 2 * RUN_WRITE_BUFFER - 3 * piece.len();
    merge_slots(group, buffers, |owner, key, count, from, from_bytes| {
        let mut left = count as usize;
        while left > 0 {
            let n = left.min(PIECE);
            let bytes = &mut piece[..n * from_bytes as usize];
            from.read_exact(bytes)?;
            converted.clear();
            records::convert(bytes, from_bytes, end_bytes, &mut converted);
            ends_out.write_all(&converted)?;
            left -= n;
        }
        ends += count as u64;
        // Runs of one slot in a row become one record while its count fits.
        match &mut last {
            Some((o, k, c)) if (*o, *k) == (owner, key) && c.checked_add(count).is_some() => *c += count,
            _ => {
                if let Some(previous) = last.replace((owner, key, count)) {
                    put(&mut slots_out, previous)?;
                }
            }
        }
        Ok(())
    })?;
    if let Some(previous) = last {
        put(&mut slots_out, previous)?;
    }
    slots_out.flush()?;
    drop(slots_out);
    let mut file = ends_out.into_inner().map_err(|e| e.into_error())?;
    std::io::copy(&mut File::open(&slots_path)?, &mut file)?;
    // (If it stays, the scratch directory goes with it.)
    let _ = std::fs::remove_file(&slots_path);
    Ok(Run { first: group[0].first, path: path.to_path_buf(), ends, slots, end_bytes })
}
