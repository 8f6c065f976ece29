//! Per-patch vectors a distribution can keep in a scratch file instead of
//! memory: the ones an iteration touches once, block by block (the
//! received totals) or reads a few times (Anderson's secant pairs), so
//! that on disk they cost a few sequential passes over the page cache per
//! iteration, beside the link ends it streams anyway. A render under a
//! tight memory budget spills them (`render::plan`); the values, and so
//! the solution, are the same bit for bit.
//!
//! The file is unnamed (`O_TMPFILE` where the system has it, else
//! created and unlinked at once): nothing is left behind however the
//! process ends.

use std::fs::File;
use std::io;
use std::marker::PhantomData;
use std::ops::Range;
use std::os::unix::fs::FileExt;
use std::path::Path;

use bytemuck::Pod;

/// A vector of `len` plain records in an unnamed scratch file.
pub(super) struct DiskVec<T> {
    file: File,
    len: usize,
    _records: PhantomData<T>,
}

impl<T: Pod> DiskVec<T> {
    /// `len` zeroed records in a new scratch file in `dir` (a sparse file:
    /// nothing is written until the records are).
    fn zeroed(dir: &Path, len: usize) -> io::Result<Self> {
        let file = tempfile::tempfile_in(dir)?;
        file.set_len((len * size_of::<T>()) as u64)?;
        Ok(Self { file, len, _records: PhantomData })
    }

    /// Reads the records from `first` on into `out`.
    fn read(&self, first: usize, out: &mut [T]) -> io::Result<()> {
        debug_assert!(first + out.len() <= self.len);
        self.file.read_exact_at(bytemuck::cast_slice_mut(out), (first * size_of::<T>()) as u64)
    }

    /// Writes `records` from record `first` on.
    fn write(&self, first: usize, records: &[T]) -> io::Result<()> {
        debug_assert!(first + records.len() <= self.len);
        self.file.write_all_at(bytemuck::cast_slice(records), (first * size_of::<T>()) as u64)
    }

    /// A copy in a new scratch file in `dir`.
    fn try_clone(&self, dir: &Path) -> io::Result<Self> {
        let copy = Self::zeroed(dir, self.len)?;
        let mut buf = vec![T::zeroed(); COPY_RECORDS.min(self.len)];
        for first in (0..self.len).step_by(COPY_RECORDS) {
            let n = COPY_RECORDS.min(self.len - first);
            self.read(first, &mut buf[..n])?;
            copy.write(first, &buf[..n])?;
        }
        Ok(copy)
    }
}

/// Records a copy moves at a time.
const COPY_RECORDS: usize = 1 << 16;

/// A per-patch vector held in memory or spilled to a scratch file.
pub(super) enum PatchVec<T> {
    /// In memory.
    Memory(Vec<T>),
    /// In a scratch file, with the directory further copies go to.
    Disk(DiskVec<T>, std::path::PathBuf),
}

impl<T: Pod + Send + Sync> PatchVec<T> {
    /// `len` zeroed records: in memory, or in a scratch file in `spill`.
    pub(super) fn zeroed(len: usize, spill: Option<&Path>) -> io::Result<Self> {
        Ok(match spill {
            None => Self::Memory(vec![T::zeroed(); len]),
            Some(dir) => Self::Disk(DiskVec::zeroed(dir, len)?, dir.into()),
        })
    }

    /// Records held.
    pub(super) fn len(&self) -> usize {
        match self {
            Self::Memory(v) => v.len(),
            Self::Disk(d, _) => d.len,
        }
    }

    /// Heap bytes held (a spilled vector holds none).
    #[cfg(test)]
    pub(super) fn heap_bytes(&self) -> usize {
        match self {
            Self::Memory(v) => v.len() * size_of::<T>(),
            Self::Disk(..) => 0,
        }
    }

    /// The records of `range`: borrowed when in memory, else read into
    /// `buf`.
    pub(super) fn range<'s>(&'s self, range: Range<usize>, buf: &'s mut Vec<T>) -> io::Result<&'s [T]> {
        match self {
            Self::Memory(v) => Ok(&v[range]),
            Self::Disk(d, _) => {
                buf.resize(range.len(), T::zeroed());
                d.read(range.start, buf)?;
                Ok(buf)
            }
        }
    }

    /// The vector cut into blocks of `block` records, each to read and
    /// write on its own (in parallel).
    pub(super) fn blocks_mut(&mut self, block: usize) -> Vec<BlockMut<'_, T>> {
        match self {
            Self::Memory(v) => v.chunks_mut(block).map(BlockMut::Memory).collect(),
            Self::Disk(d, _) => {
                let d = &*d;
                (0..d.len.div_ceil(block)).map(|b| BlockMut::Disk(d, b * block..((b + 1) * block).min(d.len))).collect()
            }
        }
    }

    /// The whole vector in memory (a spilled one read back).
    #[cfg(test)]
    pub(super) fn into_vec(self) -> io::Result<Vec<T>> {
        match self {
            Self::Memory(v) => Ok(v),
            Self::Disk(d, _) => {
                let mut v = vec![T::zeroed(); d.len];
                d.read(0, &mut v)?;
                Ok(v)
            }
        }
    }

    /// A copy, in memory or in a new scratch file beside this one.
    pub(super) fn try_clone(&self) -> io::Result<Self> {
        Ok(match self {
            Self::Memory(v) => Self::Memory(v.clone()),
            Self::Disk(d, dir) => Self::Disk(d.try_clone(dir)?, dir.clone()),
        })
    }

    /// Whether both hold the same records (for tests and history checks).
    pub(super) fn same_as(&self, other: &Self) -> io::Result<bool> {
        if self.len() != other.len() {
            return Ok(false);
        }
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for first in (0..self.len()).step_by(COPY_RECORDS) {
            let r = first..(first + COPY_RECORDS).min(self.len());
            if bytemuck::cast_slice::<T, u8>(self.range(r.clone(), &mut a)?)
                != bytemuck::cast_slice::<T, u8>(other.range(r, &mut b)?)
            {
                return Ok(false);
            }
        }
        Ok(true)
    }
}

/// One block of a [`PatchVec`], to work on from one thread.
pub(super) enum BlockMut<'a, T> {
    /// Borrowed from memory.
    Memory(&'a mut [T]),
    /// These records of a scratch file.
    Disk(&'a DiskVec<T>, Range<usize>),
}

impl<T: Pod> BlockMut<'_, T> {
    /// Records in the block.
    #[cfg(test)]
    pub(super) fn len(&self) -> usize {
        match self {
            Self::Memory(s) => s.len(),
            Self::Disk(_, r) => r.len(),
        }
    }

    /// The block's records to work on: borrowed when in memory, else
    /// read into `buf` (or, unless `read`, zeroed there: the caller writes
    /// them all). A spilled block is written back by [`Self::close`].
    pub(super) fn open<'b>(&'b mut self, read: bool, buf: &'b mut Vec<T>) -> io::Result<&'b mut [T]> {
        match self {
            Self::Memory(s) => Ok(s),
            Self::Disk(d, r) => {
                buf.clear();
                buf.resize(r.len(), T::zeroed());
                if read {
                    d.read(r.start, buf)?;
                }
                Ok(buf)
            }
        }
    }

    /// Writes a spilled block's records, `buf` as [`Self::open`] left it
    /// and the caller changed it, back to its file (in memory: nothing to
    /// do).
    pub(super) fn close(&self, buf: &[T]) -> io::Result<()> {
        match self {
            Self::Memory(_) => Ok(()),
            Self::Disk(d, r) => d.write(r.start, &buf[..r.len()]),
        }
    }

    /// [`Self::open`], `f`, [`Self::close`].
    #[cfg(test)]
    pub(super) fn with<R>(mut self, read: bool, buf: &mut Vec<T>, f: impl FnOnce(&mut [T]) -> R) -> io::Result<R> {
        let out = f(self.open(read, buf)?);
        self.close(buf)?;
        Ok(out)
    }
}

/// Why a spilled vector could not be used: the scratch directory and the
/// system's error.
pub(super) fn scratch_error(dir: Option<&Path>, e: io::Error) -> super::DistributeError {
    super::DistributeError::Scratch { dir: dir.map(Path::to_path_buf).unwrap_or_default(), source: e }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_spilled_vector_keeps_what_is_written_block_by_block() {
        let dir = tempfile::tempdir().unwrap();
        for spill in [None, Some(dir.path())] {
            let mut v = PatchVec::<[f32; 3]>::zeroed(1000, spill).unwrap();
            let mut buf = Vec::new();
            for (b, block) in v.blocks_mut(300).into_iter().enumerate() {
                let len = block.len();
                block
                    .with(true, &mut buf, |x| {
                        assert!(x.iter().all(|r| *r == [0.0; 3]), "zeroed");
                        for (i, r) in x.iter_mut().enumerate() {
                            *r = [(b * 300 + i) as f32, 1.0, 2.0];
                        }
                    })
                    .unwrap();
                assert!(len == 300 || (b == 3 && len == 100));
            }
            let copy = v.try_clone().unwrap();
            assert!(copy.same_as(&v).unwrap());
            assert_eq!(v.range(998..1000, &mut buf).unwrap(), &[[998.0, 1.0, 2.0], [999.0, 1.0, 2.0]]);
            assert_eq!(v.heap_bytes(), if spill.is_some() { 0 } else { 12_000 });
            let all = copy.into_vec().unwrap();
            assert!(all.iter().enumerate().all(|(i, r)| *r == [i as f32, 1.0, 2.0]));
        }
        // Nothing is left in the directory: the files are unnamed.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }
}
