//! The records of a run file (`format-spec/shard.md`, "Runs"): link ends
//! of 8 bytes where every weight and direction of the run fits 16 bits
//! (other patch u32, weight u16, direction u16: the usual case, up to
//! 65 536 directions), else of 12 (other u32, weight f32, direction u32);
//! then slot records of 12 (owner u32, bucket·2¹⁶ + sender chunk u32,
//! count u32). A bounded build writes its runs once and reads them once
//! or more; at the top ladder rung that is 26 GB of 12-byte ends, which
//! the page cache cannot hold, so the bytes are time.

use std::io::Write;

use super::SortEnd;

/// Bytes of an end record with 16-bit weight and direction.
pub(super) const NARROW: u64 = 8;

/// Bytes of an end record with 32-bit fields.
pub(super) const WIDE: u64 = 12;

/// Bytes of a slot record.
pub(super) const SLOT: u64 = 12;

/// Bytes of the end records of `ends`: [`NARROW`] when every weight and
/// direction fits 16 bits, else [`WIDE`].
pub(super) fn end_bytes(ends: &[SortEnd]) -> u64 {
    let narrow = ends.iter().all(|e| e.weight < 65_536.0 && e.direction < 65_536);
    if narrow { NARROW } else { WIDE }
}

/// Writes `ends` as records of `bytes` ([`end_bytes`]).
pub(super) fn put_ends(out: &mut impl Write, ends: &[SortEnd], bytes: u64) -> std::io::Result<()> {
    if bytes == NARROW {
        put(
            out,
            ends.iter().map(|e| {
                let mut r = [0u8; 8];
                r[..4].copy_from_slice(&e.other.to_le_bytes());
                r[4..6].copy_from_slice(&(e.weight as u16).to_le_bytes());
                r[6..].copy_from_slice(&(e.direction as u16).to_le_bytes());
                r
            }),
        )
    } else {
        put(out, ends.iter().map(|e| words([e.other, e.weight.to_bits(), e.direction])))
    }
}

/// Writes slot records `(owner, key, count)`.
pub(super) fn put_slots(out: &mut impl Write, slots: impl Iterator<Item = [u32; 3]>) -> std::io::Result<()> {
    put(out, slots.map(words))
}

/// Three little-endian u32.
fn words(w: [u32; 3]) -> [u8; 12] {
    let mut r = [0u8; 12];
    for (j, x) in w.iter().enumerate() {
        r[4 * j..4 * j + 4].copy_from_slice(&x.to_le_bytes());
    }
    r
}

/// Writes `records` a piece of 1 024 at a time (a write call per field
/// cost more than the bytes).
fn put<const N: usize>(out: &mut impl Write, records: impl Iterator<Item = [u8; N]>) -> std::io::Result<()> {
    let mut piece = vec![0u8; N * 1024];
    let mut n = 0;
    for r in records {
        piece[n..n + N].copy_from_slice(&r);
        n += N;
        if n == piece.len() {
            out.write_all(&piece)?;
            n = 0;
        }
    }
    out.write_all(&piece[..n])
}

/// One end record of `bytes` ([`NARROW`] or [`WIDE`]) as (other,
/// weight, direction).
#[inline]
pub(super) fn end(r: &[u8], bytes: u64) -> (u32, f32, u32) {
    let u32_at = |i: usize| u32::from_le_bytes(r[i..i + 4].try_into().expect("4 bytes"));
    let u16_at = |i: usize| u16::from_le_bytes(r[i..i + 2].try_into().expect("2 bytes"));
    if bytes == NARROW {
        (u32_at(0), u16_at(4) as f32, u16_at(6) as u32)
    } else {
        (u32_at(0), f32::from_bits(u32_at(4)), u32_at(8))
    }
}

/// `from` (end records of `from_bytes`) as records of `to_bytes`,
/// appended to `out` (a merge of narrow and wide runs writes wide ones).
pub(super) fn convert(from: &[u8], from_bytes: u64, to_bytes: u64, out: &mut Vec<u8>) {
    if from_bytes == to_bytes {
        out.extend_from_slice(from);
        return;
    }
    debug_assert_eq!((from_bytes, to_bytes), (NARROW, WIDE), "runs are only widened");
    for r in from.chunks_exact(from_bytes as usize) {
        let (other, weight, direction) = end(r, from_bytes);
        out.extend_from_slice(&words([other, weight.to_bits(), direction]));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ends_read_back_as_written_narrow_or_wide() {
        let end =
            |weight: f32, direction: u32| SortEnd { owner: 3, bucket: 1, seq: 0, other: 70_000, weight, direction };
        let narrow = [end(1.0, 0), end(65_535.0, 65_535)];
        let wide = [end(1.0, 0), end(65_536.0, 7)];
        let wider = [end(2.0, 65_536)];
        assert_eq!(end_bytes(&narrow), NARROW);
        assert_eq!(end_bytes(&wide), WIDE);
        assert_eq!(end_bytes(&wider), WIDE);
        for ends in [&narrow[..], &wide[..], &wider[..]] {
            let bytes = end_bytes(ends);
            let mut out = Vec::new();
            put_ends(&mut out, ends, bytes).expect("written");
            assert_eq!(out.len() as u64, bytes * ends.len() as u64);
            let back: Vec<_> = out.chunks_exact(bytes as usize).map(|r| super::end(r, bytes)).collect();
            let want: Vec<_> = ends.iter().map(|e| (e.other, e.weight, e.direction)).collect();
            assert_eq!(back, want);
            // Widened, the same ends.
            let mut widened = Vec::new();
            convert(&out, bytes, WIDE, &mut widened);
            let back: Vec<_> = widened.chunks_exact(12).map(|r| super::end(r, WIDE)).collect();
            assert_eq!(back, want);
        }
    }
}
