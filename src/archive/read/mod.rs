//! Opening archives: map, validate everything, then hand out zero-copy views.
//!
//! This file holds the opened [`Archive`] (where its bytes are, the typed
//! access to its sections) and the small checks every rule below is made
//! of. The rest, by what it does or checks:
//!
//! - `open`: the ways in ([`Archive::open`], [`Archive::open_streamed`],
//!   [`Archive::from_bytes`]) and [`Archive::summary`], which plans them;
//! - `structure`: the file's structure, before any section is trusted:
//!   header, section table, section bounds and checksums (§7, steps 1–4);
//! - `views`: the zero-copy views handed out once the contents are valid
//!   ([`InetView`], [`SequenceView`], [`ReflectanceView`], [`ShadingView`]);
//! - the contents' rules (§7, steps 5 and 6), one file per part, run in
//!   this order by `contents`: the build record, section counts, camera,
//!   materials and surfaces (`contents`); primitives, directions, patches
//!   and adjacency (`geometry`); frame 0's link ends and their runs
//!   (`link_ends`); the reflectance tables (`reflectance`); the shading
//!   sections (`shading`); a sequence's animation sections (`sequence`).

mod contents;
mod fingerprint;
mod geometry;
mod link_ends;
mod open;
mod reflectance;
mod sequence;
mod shading;
mod structure;
mod views;

use std::path::PathBuf;

use bytemuck::Pod;

use super::layout::{CameraRecord, HeaderRecord, SectionEntry, Tag, tag};
use super::stream::LinkStream;
use super::{ArchiveError, ArchiveMeta, tag_name};
use crate::limits::MAX_COORDINATE;

pub use open::ArchiveSummary;
pub(super) use structure::{check_digest, read_structure_of, required_common};
pub use views::{DeltaBytes, InetView, ReflectanceView, SequenceView, ShadingView};

/// Where an opened archive's bytes are.
enum Storage {
    /// The file, mapped read-only, its range recorded for the CLI's
    /// SIGBUS handler (`archive::mapped`).
    Mapped(memmap2::Mmap, #[allow(dead_code, reason = "held for its Drop")] super::mapped::Recorded),
    /// `u64` words keep owned bytes 8-byte aligned, as mapped pages are.
    Owned(Vec<u64>, usize),
    /// Every section but the link-end columns, copied out of the file
    /// (streamed archives): per section, its file offset and where its
    /// bytes start in `words`.
    Sparse { words: Vec<u64>, spans: Vec<(u64, usize)> },
}

impl Storage {
    /// The bytes of the section stored at `offset`, `len` long (already
    /// checked to lie in the file).
    fn section(&self, offset: u64, len: u64) -> &[u8] {
        match self {
            Storage::Mapped(m, _) => &m[offset as usize..(offset + len) as usize],
            Storage::Owned(words, _) => &bytemuck::cast_slice(words)[offset as usize..(offset + len) as usize],
            Storage::Sparse { words, spans } => {
                let at = spans.iter().find(|s| s.0 == offset).map_or(usize::MAX, |s| s.1);
                // A section not copied (a link column) has no bytes here.
                bytemuck::cast_slice(words).get(at..at + len as usize).unwrap_or(&[])
            }
        }
    }
}

/// An opened, fully validated archive.
pub struct Archive {
    storage: Storage,
    header: HeaderRecord,
    entries: Vec<SectionEntry>,
    meta: ArchiveMeta,
    /// The link ends, when they are streamed rather than held.
    stream: Option<LinkStream>,
    /// A streamed sequence's `DELT`, left on disk and read a frame at a time.
    deltas_on_disk: Option<OnDisk>,
    /// The file opened and its fingerprint then (none for bytes in memory).
    source: Option<fingerprint::Source>,
}

/// A section left on disk: read in pieces with `pread` (never mapped, so a
/// file cut short under a render is an error, not a SIGBUS).
pub struct OnDisk {
    file: std::fs::File,
    path: PathBuf,
    offset: u64,
    len: u64,
}

impl Archive {
    /// `Ok` when the archive's file is as it was when opened (its length,
    /// times, inode and device: `fstat`, no read); else the error a render
    /// stops with: "ended early" (exit 5) for a shorter file, "changed on
    /// disk" (exit 4) for one rewritten in place. A render calls it after
    /// each frame's distribution and before writing each output, mapped or
    /// streamed alike: a mapped file's bytes can change under it unseen.
    pub fn check_unchanged(&self) -> Result<(), ArchiveError> {
        self.source.as_ref().map_or(Ok(()), fingerprint::Source::check)
    }

    /// The link-end stream, when the archive was opened with
    /// [`Self::open_streamed`].
    pub fn link_stream(&self) -> Option<&LinkStream> {
        self.stream.as_ref()
    }

    /// Heap bytes the archive holds: the copied sections of a streamed
    /// archive (a mapped one holds none; its pages are the kernel's).
    pub fn held_bytes(&self) -> usize {
        match &self.storage {
            Storage::Mapped(..) => 0,
            Storage::Owned(words, _) | Storage::Sparse { words, .. } => {
                words.len() * 8 + self.stream.as_ref().map_or(0, LinkStream::held_bytes)
            }
        }
    }

    /// The header.
    pub fn header(&self) -> &HeaderRecord {
        &self.header
    }

    /// The section table, in file order.
    pub fn sections(&self) -> &[SectionEntry] {
        &self.entries
    }

    /// Names and provenance.
    pub fn meta(&self) -> &ArchiveMeta {
        &self.meta
    }

    /// Total file size in bytes.
    pub fn file_length(&self) -> u64 {
        self.header.file_length
    }

    fn entry(&self, t: Tag) -> Result<&SectionEntry, ArchiveError> {
        self.entries.iter().find(|e| e.tag == t).ok_or_else(|| bad(format!("section {} is missing", tag_name(t))))
    }

    fn stored(&self, e: &SectionEntry) -> &[u8] {
        self.storage.section(e.offset, e.stored_length)
    }

    fn column<T: Pod>(&self, t: Tag) -> Result<&[T], ArchiveError> {
        let e = self.entry(t)?;
        bytemuck::try_cast_slice(self.stored(e)).map_err(|err| bad(format!("section {}: {err:?}", tag_name(t))))
    }

    /// An optional section's records, `None` when the file lacks it.
    fn optional_column<T: Pod>(&self, t: Tag) -> Result<Option<&[T]>, ArchiveError> {
        match self.entries.iter().any(|e| e.tag == t) {
            true => self.column(t).map(Some),
            false => Ok(None),
        }
    }

    fn one<T: Pod>(&self, t: Tag) -> Result<&T, ArchiveError> {
        self.column::<T>(t)?.first().ok_or_else(|| bad(format!("section {} is empty", tag_name(t))))
    }

    fn read_meta(&self) -> Result<ArchiveMeta, ArchiveError> {
        let e = self.entry(tag::META)?;
        if e.length > 64 << 20 {
            return Err(bad(format!("META claims {} bytes uncompressed, more than 64 MiB", e.length)));
        }
        let raw = zstd::bulk::decompress(self.stored(e), e.length as usize)
            .map_err(|err| bad(format!("META does not decompress: {err}")))?;
        if raw.len() as u64 != e.length {
            return Err(bad(format!("META decompresses to {} bytes, the table says {}", raw.len(), e.length)));
        }
        let mut aligned = rkyv::util::AlignedVec::<16>::with_capacity(raw.len());
        aligned.extend_from_slice(&raw);
        let archived = rkyv::access::<super::ArchivedArchiveMeta, rkyv::rancor::Error>(&aligned)
            .map_err(|err| bad(format!("META fails validation: {err}")))?;
        rkyv::deserialize::<ArchiveMeta, rkyv::rancor::Error>(archived).map_err(|err| bad(format!("META: {err}")))
    }
}

/// A corrupt-archive error saying `msg`.
fn bad(msg: impl Into<String>) -> ArchiveError {
    ArchiveError::corrupt(msg)
}

/// `Ok` when `ok`, else a corrupt-archive error saying `msg()` (made only
/// then).
fn check(ok: bool, msg: impl FnOnce() -> String) -> Result<(), ArchiveError> {
    if ok { Ok(()) } else { Err(bad(msg())) }
}

/// Every value finite.
fn finite(v: &[f32]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// Finite and within ±[`MAX_COORDINATE`].
fn within(v: &[f32]) -> bool {
    v.iter().all(|x| x.abs() <= MAX_COORDINATE)
}

/// A camera rays can be made from ([`crate::limits::camera_is_usable`]).
fn camera_geometry(c: &CameraRecord) -> bool {
    crate::limits::camera_is_usable(c.position, c.look_at, c.up)
}

/// A section's record count against the count it must have.
fn count(name: &str, got: usize, want: usize) -> Result<(), ArchiveError> {
    check(got == want, || format!("section {name}: {got} records, expected {want}"))
}

/// The rules of an offsets column (CSR, `name`): from 0, never
/// decreasing, to `len` entries.
fn csr(name: &str, offsets: impl Iterator<Item = u64>, len: usize) -> Result<(), ArchiveError> {
    let mut prev = 0u64;
    let mut first = true;
    for o in offsets {
        check(if first { o == 0 } else { o >= prev }, || {
            format!("{name}: offsets must start at 0 and never decrease")
        })?;
        prev = o;
        first = false;
    }
    check(prev == len as u64, || format!("{name}: last offset {prev} ≠ {len} entries"))
}
