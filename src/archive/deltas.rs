//! The per-frame link changes of a sequence archive (`DIDX` + `DELT`,
//! `format-spec/archive.md` §5.13): how blocks of delta records become zstd
//! frames, and how a frame's blocks are decoded and checked.
//!
//! A frame's changes are stored as one or more zstd frames, each holding a
//! block of records, so that a build can compress blocks while it traces
//! (no frame ever has to exist uncompressed in one piece) and a reader can
//! decompress a frame's blocks in parallel.

use bytemuck::cast_slice_mut;
use rayon::prelude::*;
use xxhash_rust::xxh3::xxh3_64;

use super::ArchiveError;
use super::layout::{DeltaIndexRecord, DeltaRecord};

/// zstd level of delta blocks: level 1 compresses sorted delta records
/// about as well as level 3, in less time.
pub const LEVEL: i32 = 1;

/// One compressed block of a frame: a zstd frame (declaring its content
/// size) and the number of records it holds.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Block {
    /// The zstd frame.
    pub stored: Vec<u8>,
    /// Records it decompresses to.
    pub count: u64,
}

impl Block {
    /// Compresses `records` (sorted, as §5.13 requires of the whole frame).
    pub fn compress(records: &[DeltaRecord]) -> std::io::Result<Self> {
        if records.is_empty() {
            return Ok(Self::default());
        }
        let stored = zstd::bulk::compress(bytemuck::cast_slice(records), LEVEL)?;
        Ok(Self { stored, count: records.len() as u64 })
    }
}

/// The `DIDX` and `DELT` sections of a sequence, ready to write: per frame,
/// the concatenation of its blocks.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct EncodedDeltas {
    /// `DIDX`: one record per frame.
    pub index: Vec<DeltaIndexRecord>,
    /// `DELT`: every frame's blocks, frame after frame.
    pub payload: Vec<u8>,
}

impl EncodedDeltas {
    /// Assembles `frames` frames from blocks: `blocks[c][f]` is block `c` of
    /// frame `f` (a missing entry is an empty block); each frame's blocks
    /// are concatenated in `c` order, so the blocks of one frame must hold
    /// consecutive ranges of its sorted records.
    pub fn from_blocks(frames: usize, blocks: &[Vec<Block>]) -> Self {
        let mut index = Vec::with_capacity(frames);
        let total: usize = blocks.iter().flatten().map(|b| b.stored.len()).sum();
        let mut payload = Vec::with_capacity(total);
        for f in 0..frames {
            let offset = payload.len();
            let mut count = 0;
            for b in blocks.iter().filter_map(|c| c.get(f)) {
                payload.extend_from_slice(&b.stored);
                count += b.count;
            }
            index.push(DeltaIndexRecord {
                offset: offset as u64,
                stored_length: (payload.len() - offset) as u64,
                count,
                checksum: xxh3_64(&payload[offset..]),
            });
        }
        Self { index, payload }
    }

    /// Encodes whole frames of sorted records, one block per frame.
    pub fn from_frames(frames: &[Vec<DeltaRecord>]) -> std::io::Result<Self> {
        let blocks = frames.iter().map(|r| Block::compress(r)).collect::<std::io::Result<Vec<_>>>()?;
        Ok(Self::from_blocks(frames.len(), &[blocks]))
    }

    /// Decodes frame `frame` (no range or order checks: see
    /// [`super::SequenceView::frame_delta`] for the reader's).
    pub fn frame(&self, frame: usize) -> Result<Vec<DeltaRecord>, ArchiveError> {
        let ix = self.index.get(frame).ok_or_else(|| ArchiveError::corrupt(format!("no delta for frame {frame}")))?;
        let stored = &self.payload[ix.offset as usize..][..ix.stored_length as usize];
        decode(stored, ix.count, frame as u32)
    }
}

fn bad(frame: u32, what: String) -> ArchiveError {
    ArchiveError::corrupt(format!("DELT frame {frame}: {what}"))
}

/// Decompresses a frame's stored bytes, a sequence of zstd frames, into
/// `count` records. The frames' declared content sizes are checked against
/// `count` before anything is allocated; blocks decompress in parallel.
pub(crate) fn decode(stored: &[u8], count: u64, frame: u32) -> Result<Vec<DeltaRecord>, ArchiveError> {
    const SIZE: u64 = size_of::<DeltaRecord>() as u64;
    // Split into zstd frames, each with its declared output range.
    let mut parts: Vec<(&[u8], usize, usize)> = Vec::new();
    let (mut rest, mut records) = (stored, 0u64);
    while !rest.is_empty() {
        let len = zstd::zstd_safe::find_frame_compressed_size(rest)
            .map_err(|_| bad(frame, "not a sequence of whole zstd frames".into()))?;
        let size = match zstd::zstd_safe::get_frame_content_size(rest) {
            Ok(Some(n)) if n % SIZE == 0 && n > 0 => n / SIZE,
            _ => return Err(bad(frame, "a zstd frame does not declare a whole number of records".into())),
        };
        records = records
            .checked_add(size)
            .filter(|&r| r <= count)
            .ok_or_else(|| bad(frame, format!("zstd frames declare more than the {count} records DIDX states")))?;
        parts.push((&rest[..len], (records - size) as usize, records as usize));
        rest = &rest[len..];
    }
    if records != count {
        return Err(bad(frame, format!("zstd frames declare {records} records, DIDX states {count}")));
    }
    let mut out = vec![DeltaRecord::default(); count as usize];
    // Hand each part its own slice of the output.
    let mut slices = Vec::with_capacity(parts.len());
    let mut tail = &mut out[..];
    for &(_, start, end) in &parts {
        let (head, t) = std::mem::take(&mut tail).split_at_mut(end - start);
        slices.push(head);
        tail = t;
    }
    parts.par_iter().zip(slices).try_for_each(|(&(src, _, _), dst)| {
        let bytes: &mut [u8] = cast_slice_mut(dst);
        match zstd::bulk::decompress_to_buffer(src, bytes) {
            Ok(n) if n == bytes.len() => Ok(()),
            Ok(_) => Err(bad(frame, "a zstd frame decompresses to fewer bytes than it declares".into())),
            Err(e) => Err(bad(frame, format!("does not decompress: {e}"))),
        }
    })?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(pair: u32, a: u32, count: i32) -> DeltaRecord {
        DeltaRecord { pair, a, b: a + 1, count, bucket_a: 0, bucket_b: 1, reserved: 0 }
    }

    #[test]
    fn blocks_of_a_frame_decode_in_order() {
        let f1: Vec<DeltaRecord> = (0..1000).map(|i| record(i / 100, i, 1 + (i % 3) as i32)).collect();
        let blocks = vec![
            vec![Block::default(), Block::compress(&f1[..300]).unwrap()],
            vec![Block::default(), Block::compress(&f1[300..]).unwrap()],
        ];
        let e = EncodedDeltas::from_blocks(2, &blocks);
        assert_eq!(e.index[0].count, 0);
        assert_eq!(e.index[0].stored_length, 0);
        assert_eq!(e.index[1].count, 1000);
        assert_eq!(e.frame(1).unwrap(), f1);
        assert!(e.frame(0).unwrap().is_empty());
        // One block per frame gives the same records.
        assert_eq!(EncodedDeltas::from_frames(&[Vec::new(), f1.clone()]).unwrap().frame(1).unwrap(), f1);
    }

    #[test]
    fn wrong_counts_and_damaged_frames_are_errors() {
        let f1: Vec<DeltaRecord> = (0..500).map(|i| record(0, i, 1)).collect();
        let e = EncodedDeltas::from_frames(&[Vec::new(), f1]).unwrap();
        let stored = &e.payload[..];
        for count in [0, 499, 501, u64::MAX] {
            let err = decode(stored, count, 1).unwrap_err().to_string();
            assert!(err.contains("DELT frame 1"), "{err}");
        }
        // Truncated: not whole zstd frames.
        assert!(decode(&stored[..stored.len() - 3], 500, 1).is_err());
        // Garbage.
        assert!(decode(&[0x55; 64], 4, 1).is_err());
    }
}
