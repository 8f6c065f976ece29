//! A shard's counts file (format-spec/shard.md, "Counts file"): what its
//! tracing counted beside the link ends, which the merge sums.

use std::io::{Read, Write};

use crate::archive::deltas::{Block, Stored};

/// The counts file's first 8 bytes.
const MAGIC: &[u8; 8] = b"INSHCNT1";

/// What a shard counted: per patch its hits, back-face hits and link ends;
/// per non-diffuse patch and pair its rays and back-face rays; totals; and
/// its chunks' parts of per-frame link changes, compressed as traced.
#[derive(Debug, Default, Clone, PartialEq)]
pub struct ShardCounts {
    /// `H_p` of this shard's rays.
    pub hits: Vec<u32>,
    /// Back-face hits per patch.
    pub backs: Vec<u32>,
    /// Link ends per patch in this shard's runs.
    pub ends: Vec<u64>,
    /// Rays per non-diffuse patch and pair.
    pub nd_hits: Vec<u32>,
    /// Back-face rays per non-diffuse patch and pair.
    pub nd_backs: Vec<u32>,
    /// Rays, hits and links traced.
    pub totals: [u64; 3],
    /// Per part (in chunk order), per frame: records and zstd bytes.
    pub parts: Vec<Vec<(u64, Vec<u8>)>>,
}

impl ShardCounts {
    /// Writes the counts, little-endian.
    pub fn write(&self, out: &mut impl Write) -> std::io::Result<()> {
        out.write_all(MAGIC)?;
        let lens = [self.hits.len(), self.nd_hits.len(), self.parts.len()];
        for n in lens {
            out.write_all(&(n as u64).to_le_bytes())?;
        }
        for column in [&self.hits, &self.backs] {
            column.iter().try_for_each(|v| out.write_all(&v.to_le_bytes()))?;
        }
        self.ends.iter().try_for_each(|v| out.write_all(&v.to_le_bytes()))?;
        for column in [&self.nd_hits, &self.nd_backs] {
            column.iter().try_for_each(|v| out.write_all(&v.to_le_bytes()))?;
        }
        self.totals.iter().try_for_each(|v| out.write_all(&v.to_le_bytes()))?;
        for part in &self.parts {
            out.write_all(&(part.len() as u64).to_le_bytes())?;
            for (records, bytes) in part {
                out.write_all(&records.to_le_bytes())?;
                out.write_all(&(bytes.len() as u64).to_le_bytes())?;
                out.write_all(bytes)?;
            }
        }
        Ok(())
    }

    /// Reads counts of `patches` patches, `nd` non-diffuse rows and
    /// `frames` frames (what the merge's own setup says), from a file of
    /// `len` bytes whose checksum was checked: a file that does not hold
    /// them is an error, never a large allocation.
    pub fn read(input: &mut impl Read, len: u64, patches: usize, nd: usize, frames: u64) -> Result<Self, String> {
        let mut r = Reader { input, left: len };
        let mut magic = [0u8; 8];
        r.bytes(&mut magic)?;
        if &magic != MAGIC {
            return Err("not a shard counts file".into());
        }
        let (p, n, parts) = (r.u64()?, r.u64()?, r.u64()?);
        if p != patches as u64 || n != nd as u64 {
            return Err(format!(
                "counts for {p} patches and {n} non-diffuse rows, where the build has {patches} and {nd}"
            ));
        }
        let mut c = ShardCounts {
            hits: r.u32s(patches)?,
            backs: r.u32s(patches)?,
            ends: (0..patches).map(|_| r.u64()).collect::<Result<_, _>>()?,
            nd_hits: r.u32s(nd)?,
            nd_backs: r.u32s(nd)?,
            totals: [r.u64()?, r.u64()?, r.u64()?],
            parts: Vec::new(),
        };
        for _ in 0..parts {
            let blocks = r.u64()?;
            if blocks != frames {
                return Err(format!("a part of {blocks} frames, where the build has {frames}"));
            }
            let mut part = Vec::new();
            for _ in 0..blocks {
                let records = r.u64()?;
                let len = r.u64()?;
                if len > r.left {
                    return Err("a part's block runs past the end of the file".into());
                }
                let mut bytes = vec![0u8; len as usize];
                r.bytes(&mut bytes)?;
                part.push((records, bytes));
            }
            c.parts.push(part);
        }
        if r.left != 0 {
            return Err(format!("{} bytes after the counts", r.left));
        }
        Ok(c)
    }

    /// The parts as the archive's blocks, in memory.
    pub fn blocks(parts: Vec<Vec<(u64, Vec<u8>)>>) -> Vec<Vec<Block>> {
        let block = |(count, bytes): (u64, Vec<u8>)| Block { stored: Stored::Held(bytes), count };
        parts.into_iter().map(|p| p.into_iter().map(block).collect()).collect()
    }
}

/// Reads from a file of known length, refusing to read past it.
struct Reader<'a, R: Read> {
    input: &'a mut R,
    left: u64,
}

impl<R: Read> Reader<'_, R> {
    fn bytes(&mut self, buf: &mut [u8]) -> Result<(), String> {
        if buf.len() as u64 > self.left {
            return Err("the file ends early".into());
        }
        self.input.read_exact(buf).map_err(|e| e.to_string())?;
        self.left -= buf.len() as u64;
        Ok(())
    }

    fn u64(&mut self) -> Result<u64, String> {
        let mut b = [0u8; 8];
        self.bytes(&mut b)?;
        Ok(u64::from_le_bytes(b))
    }

    fn u32s(&mut self, n: usize) -> Result<Vec<u32>, String> {
        if n as u64 * 4 > self.left {
            return Err("the file ends early".into());
        }
        let mut b = vec![0u8; n * 4];
        self.bytes(&mut b)?;
        Ok(b.chunks_exact(4).map(|c| u32::from_le_bytes(c.try_into().expect("4 bytes"))).collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_read_back_and_a_cut_file_is_refused() {
        let c = ShardCounts {
            hits: vec![1, 2],
            backs: vec![0, 1],
            ends: vec![3, 4],
            nd_hits: vec![5],
            nd_backs: vec![0],
            totals: [10, 9, 8],
            parts: vec![vec![(0, vec![]), (2, vec![1, 2, 3])]],
        };
        let mut bytes = Vec::new();
        c.write(&mut bytes).unwrap();
        let n = bytes.len() as u64;
        assert_eq!(ShardCounts::read(&mut &bytes[..], n, 2, 1, 2).unwrap(), c);
        assert!(ShardCounts::read(&mut &bytes[..], n, 3, 1, 2).is_err(), "another build's patch count");
        assert!(ShardCounts::read(&mut &bytes[..], n, 2, 1, 1).is_err(), "another frame count");
        for cut in [0, 8, 20, n as usize - 1] {
            assert!(ShardCounts::read(&mut &bytes[..cut], cut as u64, 2, 1, 2).is_err(), "cut at {cut}");
        }
    }
}
