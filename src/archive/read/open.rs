//! The ways in: an archive mapped ([`Archive::open`]), held in memory
//! ([`Archive::from_bytes`]) or with its link ends streamed from disk
//! ([`Archive::open_streamed`]), each validated whole before it is
//! returned; and [`Archive::summary`], what the header, table and a few
//! small sections say, to plan which way to take.

use std::path::Path;

use bytemuck::pod_read_unaligned;

use super::contents::validate_contents;
use super::sequence::check_delta_count;
use super::structure::{check_digest, check_sum, read_structure, stream_read, validate_structure};
use super::{Archive, OnDisk, Storage, bad, check, csr};
use crate::archive::layout::{self, BuildRecord, CameraRecord, DeltaIndexRecord, SectionEntry, Tag, WeightEscape, tag};
use crate::archive::links::{LinkRuns, check_run_offsets};
use crate::archive::stream::{self, LinkStream};
use crate::archive::{ArchiveError, ArchiveMeta, tag_name};

/// Tags of the link-end columns a streamed archive reads from disk with
/// each window (it holds `LOFF` and `LROF`).
const LINK_COLUMNS: [Tag; 4] = [tag::LINK_OTHER, tag::LINK_COUNT, tag::LINK_DIRECTION, tag::LINK_RUNS];

/// What an archive's header, section table and build record say, read
/// without reading the sections (to plan how to open it).
#[derive(Clone, Debug)]
pub struct ArchiveSummary {
    /// Total file size in bytes.
    pub file_length: u64,
    /// The header's `table_checksum`: XXH3-64 of the section table, whose
    /// entries hold every section's checksum, so a cheap identity of the
    /// whole contents (frames a render writes record it, and a farm's
    /// `--skip-done` and `frames check` compare it).
    pub table_checksum: u64,
    /// The section table.
    pub sections: Vec<SectionEntry>,
    /// `BILD`, checked against its section checksum.
    pub build: BuildRecord,
    /// `CAMR`, checked against its section checksum (not validated).
    pub camera: CameraRecord,
    /// The most delta records a frame of a sequence has (`DIDX`, checked
    /// against its checksum; 0 for a still).
    pub max_delta_records: u64,
    /// The most stored bytes a frame's delta has (what a streamed
    /// sequence reads at once).
    pub max_delta_stored: u64,
}

impl ArchiveSummary {
    /// The archive's identity as frames record it: `xxh3:` and the
    /// section table's checksum in 16 hex digits.
    pub fn identity(&self) -> String {
        format!("xxh3:{:016x}", self.table_checksum)
    }

    /// Stored bytes of the sections with tag `t` (0 when absent).
    pub fn section_bytes(&self, t: Tag) -> u64 {
        self.sections.iter().filter(|e| e.tag == t).map(|e| e.stored_length).sum()
    }

    /// Records in the section `t` (0 when absent).
    pub fn section_count(&self, t: Tag) -> u64 {
        self.sections.iter().filter(|e| e.tag == t).map(|e| e.count).sum()
    }

    /// Stored bytes of the link-end columns, the part a streamed archive
    /// leaves on disk.
    pub fn link_bytes(&self) -> u64 {
        LINK_COLUMNS.iter().map(|&t| self.section_bytes(t)).sum()
    }

    /// Stored bytes of every other section but `DELT` (read a frame at a
    /// time): what a streamed archive holds.
    pub fn held_bytes(&self) -> u64 {
        self.sections.iter().map(|e| e.stored_length).sum::<u64>() - self.link_bytes() - self.section_bytes(tag::DELTAS)
    }
}

impl Archive {
    /// Maps and validates the archive at `path`.
    pub fn open(path: &Path) -> Result<Self, ArchiveError> {
        let io = |e: std::io::Error| ArchiveError::Io { path: path.into(), source: e };
        let (file, _) = crate::limits::open_regular(path, u64::MAX).map_err(io)?;
        let len = file.metadata().map_err(io)?.len();
        if len < layout::HEADER_SIZE as u64 {
            return Err(bad(format!(
                "file is {len} bytes, shorter than the {}-byte header (truncated?)",
                layout::HEADER_SIZE
            )));
        }
        // SAFETY: the map is read-only and private to this process. Another
        // process truncating or rewriting the file while it is mapped would
        // break the validation below (SIGBUS or changed bytes); archives are
        // written once to a temporary file and renamed, never modified in
        // place, so this does not happen with files illumnet writes.
        #[allow(unsafe_code)]
        let map = unsafe { memmap2::Mmap::map(&file) }.map_err(io)?;
        // Taken before validation reads a byte: a change from here on is seen.
        let source = super::fingerprint::Source::new(file, path)?;
        let recorded = super::super::mapped::record(map.as_ptr(), map.len(), path);
        let mut archive = Self::from_storage(Storage::Mapped(map, recorded))?;
        archive.source = Some(source);
        Ok(archive)
    }

    /// Opens the archive at `path` with its link ends streamed from disk
    /// in windows of about `window_ends` ends (see [`LinkStream`]): memory
    /// holds every other section, a window per worker (at least two), and
    /// one checksum per column per 65 536 ends. Validation is that of [`Self::open`], the link
    /// columns read once, in chunks, without mapping the file.
    pub fn open_streamed(path: &Path, window_ends: usize) -> Result<Self, ArchiveError> {
        let io = |e: std::io::Error| ArchiveError::Io { path: path.into(), source: e };
        let (file, _) = crate::limits::open_regular(path, u64::MAX).map_err(io)?;
        let source = super::fingerprint::Source::new(file.try_clone().map_err(io)?, path)?;
        let (header, entries) = read_structure(&file, path)?;
        // The link columns and `DELT` stay on disk; the stream holds `LCNX`
        // itself.
        let on_disk = |t: Tag| LINK_COLUMNS.contains(&t) || t == tag::LINK_ESCAPES || t == tag::DELTAS;
        let held = || entries.iter().filter(|e| !on_disk(e.tag));
        // Allocated once at its size: a vector grown section by section
        // would hold its old and new buffers at once at each doubling.
        let total: usize = held().map(|e| (e.stored_length as usize).div_ceil(8)).sum();
        let mut words = vec![0u64; total];
        let mut spans = Vec::new();
        let mut next = 0;
        for e in held() {
            let at = next * 8;
            next += (e.stored_length as usize).div_ceil(8);
            let buf = &mut bytemuck::cast_slice_mut::<u64, u8>(&mut words)[at..at + e.stored_length as usize];
            stream_read(&file, buf, e.offset).map_err(io)?;
            check_sum(e, buf)?;
            spans.push((e.offset, at));
        }
        // `DELT`: its section checksum taken by one pass over it now; each
        // frame is checked against its own when read.
        let deltas_on_disk = match entries.iter().find(|e| e.tag == tag::DELTAS) {
            Some(e) => {
                let mut hasher = xxhash_rust::xxh3::Xxh3::new();
                stream::for_each_piece(&file, e.offset, e.stored_length, &mut Vec::new(), |piece| {
                    hasher.update(piece);
                    Ok(())
                })
                .map_err(|x| stream::short(path, "DELT", x))?;
                check_digest(e, hasher.digest())?;
                let file = file.try_clone().map_err(io)?;
                Some(OnDisk { file, path: path.into(), offset: e.offset, len: e.stored_length })
            }
            None => None,
        };
        let mut archive = Self {
            storage: Storage::Sparse { words, spans },
            header,
            entries,
            meta: ArchiveMeta::default(),
            stream: None,
            deltas_on_disk,
            source: Some(source),
        };
        archive.meta = archive.read_meta()?;
        let b: BuildRecord = *archive.one(tag::BUILD)?;
        let offsets: &[u64] = archive.column(tag::LINK_OFFSETS)?;
        check(offsets.len() == b.patch_count as usize + 1, || {
            format!("section LOFF: {} records, expected {}", offsets.len(), b.patch_count as u64 + 1)
        })?;
        csr("LOFF", offsets.iter().copied(), b.link_end_count as usize)?;
        let hits: &[u32] = archive.column(tag::PATCH_HITS)?;
        check(hits.len() == b.patch_count as usize, || {
            format!("section PHIT: {} records, expected {}", hits.len(), b.patch_count)
        })?;
        let limits = stream::Limits {
            hits,
            patches: b.patch_count as usize,
            directions: b.direction_count as usize,
            max_bucket: b.max_bucket.min(255) as u8,
        };
        let run_offsets: &[u64] = archive.column(tag::LINK_RUN_OFFSETS)?;
        check_run_offsets(run_offsets, b.patch_count as usize, archive.entry(tag::LINK_RUNS)?.count).map_err(bad)?;
        // The runs themselves are read, and checked, with the columns.
        let runs = LinkRuns::validated(offsets, run_offsets, &[], 0);
        let columns = [
            archive.entry(tag::LINK_OTHER)?,
            archive.entry(tag::LINK_COUNT)?,
            archive.entry(tag::LINK_DIRECTION)?,
            archive.entry(tag::LINK_RUNS)?,
        ];
        let escapes: Vec<WeightEscape> = {
            let e = archive.entry(tag::LINK_ESCAPES)?;
            let mut records = vec![WeightEscape::default(); (e.stored_length as usize) / size_of::<WeightEscape>()];
            let buf: &mut [u8] = bytemuck::cast_slice_mut(&mut records);
            check(buf.len() as u64 == e.stored_length, || "section LCNX: not whole records".into())?;
            stream_read(&file, buf, e.offset).map_err(io)?;
            check_sum(e, buf)?;
            records
        };
        let links = LinkStream::open(file, path, columns, escapes, offsets, runs, &limits, window_ends)?;
        archive.stream = Some(links);
        validate_contents(&archive.view_unchecked()?, &archive.meta, archive.header.version_read)?;
        Ok(archive)
    }

    /// Reads what the header, the section table and `BILD` of the archive
    /// at `path` say, checking their checksums and bounds, without reading
    /// the other sections: enough to plan how to open it.
    pub fn summary(path: &Path) -> Result<ArchiveSummary, ArchiveError> {
        let io = |e: std::io::Error| ArchiveError::Io { path: path.into(), source: e };
        let (file, _) = crate::limits::open_regular(path, u64::MAX).map_err(io)?;
        let (header, entries) = read_structure(&file, path)?;
        let record = |t: Tag, size: usize| -> Result<Vec<u8>, ArchiveError> {
            let e = entries
                .iter()
                .find(|e| e.tag == t)
                .ok_or_else(|| bad(format!("section {} is missing", tag_name(t))))?;
            let mut buf = vec![0u8; e.stored_length as usize];
            stream_read(&file, &mut buf, e.offset).map_err(io)?;
            check_sum(e, &buf)?;
            check(buf.len() >= size, || format!("section {} is shorter than its record", tag_name(t)))?;
            Ok(buf)
        };
        let build: BuildRecord =
            pod_read_unaligned(&record(tag::BUILD, size_of::<BuildRecord>())?[..size_of::<BuildRecord>()]);
        check_build_counts(&build, &entries)?;
        let camera: CameraRecord =
            pod_read_unaligned(&record(tag::CAMERA, size_of::<CameraRecord>())?[..size_of::<CameraRecord>()]);
        let (mut max_delta_records, mut max_delta_stored) = (0, 0);
        if let Some(e) = entries.iter().find(|e| e.tag == tag::DELTA_INDEX) {
            let mut buf = vec![0u8; e.stored_length as usize];
            stream_read(&file, &mut buf, e.offset).map_err(io)?;
            check_sum(e, &buf)?;
            let records =
                || buf.chunks_exact(size_of::<DeltaIndexRecord>()).map(pod_read_unaligned::<DeltaIndexRecord>);
            for (f, r) in records().enumerate() {
                check_delta_count(f, r.count, r.stored_length)?;
            }
            max_delta_records = records().map(|r| r.count).max().unwrap_or(0);
            // Capped by the payload: DIDX ranges are checked only at open.
            let payload = entries.iter().find(|e| e.tag == tag::DELTAS).map_or(0, |e| e.stored_length);
            max_delta_stored = records().map(|r| r.stored_length).max().unwrap_or(0).min(payload);
        }
        Ok(ArchiveSummary {
            file_length: header.file_length,
            table_checksum: header.table_checksum,
            sections: entries,
            build,
            camera,
            max_delta_records,
            max_delta_stored,
        })
    }

    /// Validates an archive held in memory (the bytes are copied once into
    /// an aligned buffer).
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, ArchiveError> {
        let mut words = vec![0u64; bytes.len().div_ceil(8)];
        bytemuck::cast_slice_mut::<u64, u8>(&mut words)[..bytes.len()].copy_from_slice(bytes);
        Self::from_storage(Storage::Owned(words, bytes.len()))
    }

    fn from_storage(storage: Storage) -> Result<Self, ArchiveError> {
        let bytes = match &storage {
            Storage::Mapped(m, _) => &m[..],
            Storage::Owned(words, len) => &bytemuck::cast_slice(words)[..*len],
            Storage::Sparse { .. } => unreachable!("sparse storage is made by open_streamed"),
        };
        let (header, entries) = validate_structure(bytes)?;
        let mut archive = Self {
            storage,
            header,
            entries,
            meta: ArchiveMeta::default(),
            stream: None,
            deltas_on_disk: None,
            source: None,
        };
        archive.meta = archive.read_meta()?;
        validate_contents(&archive.view_unchecked()?, &archive.meta, archive.header.version_read)?;
        Ok(archive)
    }
}

/// `BILD`'s counts against the sections' record counts in the table,
/// which the table's rules hold to the file's length: what
/// [`Archive::summary`] checks before a render plans memory from them (a
/// claim of 2³¹ patches was planned as 1.4 TiB, exit 6, where open says
/// corrupt, exit 4: issue 42, §5). Open checks the same, record by record.
fn check_build_counts(b: &BuildRecord, entries: &[SectionEntry]) -> Result<(), ArchiveError> {
    for (t, want) in [
        (tag::SURFACES, b.surface_count as u64),
        (tag::MATERIALS, b.material_count as u64),
        (tag::PRIMITIVES, b.primitive_count as u64),
        (tag::DIRECTIONS, b.direction_count as u64),
        (tag::PATCH_CENTRE, b.patch_count as u64),
        (tag::PATCH_AREA, b.patch_count as u64),
        (tag::LINK_OFFSETS, b.patch_count as u64 + 1),
        (tag::VERTEX_POSITION, b.vertex_count as u64),
        (tag::LINK_DIRECTION, b.link_end_count),
    ] {
        if let Some(e) = entries.iter().find(|e| e.tag == t) {
            check(e.count == want, || format!("section {}: {} records, BILD implies {want}", tag_name(t), e.count))?;
        }
    }
    Ok(())
}
