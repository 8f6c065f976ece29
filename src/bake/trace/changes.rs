//! Per-frame link changes of temporal instances (§5.13): a pair's per-ray
//! changes summed into its changes relative to frame 0 at every frame
//! ([`accumulate_changes`]), held per chunk of pairs and compressed as
//! parts of fixed size ([`part_records`], [`compress_part`]), so that the
//! blocks depend on neither the threads nor the budget.

use super::scratch::Scratch;
use crate::archive::deltas::{Block, BlockCompressor};
use crate::archive::layout::DeltaRecord;
use crate::archive::presence::FrameSpan;
use crate::bake::BuildError;
use crate::bake::spill::Spill;

/// Per-frame link changes a chunk holds (over all frames) before it
/// compresses them as a part of its blocks: at least 128 Ki records
/// (2.5 MiB) and 512 per frame, so that a sequence's changes take little
/// memory while they are traced (the fan room's chunks held up to 14 MiB
/// each) and a long sequence's blocks do not shrink to a few records.
/// Fixed by the frame count alone, like [`CHUNKS`](super::CHUNKS), so that the archive's
/// bytes depend on neither the threads nor the budget. (A part is cut
/// after a whole pair: it may exceed this by one pair's records.)
pub(in crate::bake) fn part_records(frames: usize) -> usize {
    (1usize << 17).max(frames.saturating_mul(512))
}

/// Bytes a tracer holds per record of a part: the record (20), its
/// encoded columns (18) and compressed copy, and the slack of the
/// per-frame lists.
pub(in crate::bake) const PART_BYTES_PER_RECORD: u64 = 56;

/// Turns the current pair's per-ray changes (`s.changes`, per frame) into
/// its changes relative to frame 0 at every frame, appended to `s.chunk`:
/// frame `f`'s list is frame `f − 1`'s merged with the changes at `f`, less
/// the records with an end at a patch that has left before `f`. The format
/// removes links with an end at an absent patch from every frame (§5.13),
/// so neither their removal when a patch leaves (`Walk::ray` writes none)
/// nor frame 0's links of instances that have left need records (they were
/// 35–40% of the fan room's); every record kept has both ends present.
/// Pairs whose links never change append nothing.
pub(super) fn accumulate_changes(s: &mut Scratch, patch_active: &[FrameSpan]) {
    s.cumulative.clear();
    for f in 1..s.changes.len() {
        let changes = &mut s.changes[f];
        if changes.is_empty() && s.cumulative.is_empty() {
            continue;
        }
        let frame = f as u32;
        // Patches never return once they leave (instances span one run of
        // frames): what the sum holds for them is dropped for good.
        let gone = |d: &DeltaRecord| patch_active[d.a as usize].last < frame || patch_active[d.b as usize].last < frame;
        // Sum the rays' changes of one link.
        changes.sort_unstable_by_key(record_key);
        let mut n = 0;
        for i in 0..changes.len() {
            if n > 0 && record_key(&changes[n - 1]) == record_key(&changes[i]) {
                changes[n - 1].count += changes[i].count;
            } else {
                changes[n] = changes[i];
                n += 1;
            }
        }
        changes.truncate(n);
        s.next.clear();
        let (prev, add) = (&s.cumulative, &*changes);
        let (mut i, mut j) = (0, 0);
        while i < prev.len() || j < add.len() {
            let d = match (prev.get(i), add.get(j)) {
                (Some(p), Some(c)) => match record_key(p).cmp(&record_key(c)) {
                    std::cmp::Ordering::Less => {
                        i += 1;
                        *p
                    }
                    std::cmp::Ordering::Greater => {
                        j += 1;
                        *c
                    }
                    std::cmp::Ordering::Equal => {
                        i += 1;
                        j += 1;
                        DeltaRecord { count: p.count + c.count, ..*p }
                    }
                },
                (Some(p), None) => {
                    i += 1;
                    *p
                }
                (None, Some(c)) => {
                    j += 1;
                    *c
                }
                (None, None) => unreachable!(),
            };
            if d.count != 0 && !gone(&d) {
                s.next.push(d);
            }
        }
        changes.clear();
        std::mem::swap(&mut s.cumulative, &mut s.next);
        debug_assert!(
            s.cumulative.iter().all(|d| [d.a, d.b].iter().all(|&p| patch_active[p as usize].contains(frame)))
        );
        s.chunk[f].extend_from_slice(&s.cumulative);
    }
}

/// The order of one pair's records: `(a, b, bucket_a, bucket_b)`.
#[inline]
fn record_key(d: &DeltaRecord) -> u128 {
    ((d.a as u128) << 48) | ((d.b as u128) << 16) | ((d.bucket_a as u128) << 8) | d.bucket_b as u128
}

/// Compresses the chunk's per-frame changes held in `s.chunk` as one part:
/// a block per frame (the lists are emptied for the next part). Under a
/// budget, `spill` holds the blocks or writes them to its spill file.
pub(super) fn compress_part(s: &mut Scratch, spill: Option<&Spill>) -> Result<Vec<Block>, BuildError> {
    let error = |e: std::io::Error| BuildError::Failed(format!("cannot compress the per-frame link changes: {e}"));
    if s.compressor.is_none() {
        s.compressor = Some(BlockCompressor::new().map_err(error)?);
    }
    let z = s.compressor.as_mut().expect("just made");
    let mut blocks = s
        .chunk
        .iter_mut()
        .map(|records| {
            let b = z.compress(records);
            records.clear();
            b
        })
        .collect::<std::io::Result<Vec<Block>>>()
        .map_err(error)?;
    if let Some(spill) = spill {
        spill.spill_deltas(&mut blocks)?;
    }
    Ok(blocks)
}
