//! Single-pass archive writer: header placeholder, sections, table, header.

use std::io::{Seek, SeekFrom, Write};
use std::path::Path;

use bytemuck::{Pod, bytes_of, cast_slice};
use xxhash_rust::xxh3::{Xxh3, xxh3_64};

use super::layout::{self, HeaderRecord, SectionEntry, Tag, WeightEscape, compression, tag};
use super::{ArchiveContents, ArchiveError, weights};
use crate::scratch;

/// Receives batches of link ends: other patch, weight, direction, bucket.
pub type LinkEndSink<'a> = dyn FnMut(&[u32], &[f32], &[u32], &[u8]) -> std::io::Result<()> + 'a;

/// The link-end columns (`LOTH`, the weights stored as `LCNT` and `LCNX`,
/// `LDIR`, `LBKT`, §5.10) of
/// an archive too large to hold them in memory, produced in file order
/// (for example by merging sorted runs spilled to disk) while they are
/// written: the archive's bytes are those of the same columns held in
/// [`ArchiveContents`].
pub trait LinkEndSource {
    /// Link ends it gives in all (E).
    fn end_count(&self) -> u64;
    /// Calls `out` with consecutive batches of link ends, in file order,
    /// as four columns of equal length (other patch, weight, direction,
    /// bucket), until all [`Self::end_count`] are given.
    fn write_ends(&mut self, out: &mut LinkEndSink<'_>) -> std::io::Result<()>;
}

/// One column being written at its own place in the file.
struct PlacedColumn {
    offset: u64,
    written: u64,
    buf: Vec<u8>,
    hasher: Xxh3,
}

impl PlacedColumn {
    const BUFFER: usize = 256 << 10;

    fn add<W: Write + Seek>(&mut self, out: &mut W, bytes: &[u8]) -> std::io::Result<()> {
        self.hasher.update(bytes);
        self.buf.extend_from_slice(bytes);
        if self.buf.len() >= Self::BUFFER { self.flush(out) } else { Ok(()) }
    }

    fn flush<W: Write + Seek>(&mut self, out: &mut W) -> std::io::Result<()> {
        if !self.buf.is_empty() {
            out.seek(SeekFrom::Start(self.offset + self.written))?;
            out.write_all(&self.buf)?;
            self.written += self.buf.len() as u64;
            self.buf.clear();
        }
        Ok(())
    }
}

/// Writes sections one after another, then the table and the header.
pub(super) struct SectionWriter<W: Write + Seek> {
    out: W,
    position: u64,
    entries: Vec<SectionEntry>,
    version_read: u32,
}

impl<W: Write + Seek> SectionWriter<W> {
    pub(super) fn new(mut out: W) -> std::io::Result<Self> {
        out.write_all(&[0u8; layout::HEADER_SIZE])?;
        Ok(Self { out, position: layout::HEADER_SIZE as u64, entries: Vec::new(), version_read: layout::VERSION_READ })
    }

    fn pad_to(&mut self, align: u64) -> std::io::Result<()> {
        let pad = self.position.next_multiple_of(align) - self.position;
        const ZEROS: [u8; 4096] = [0; 4096];
        self.out.write_all(&ZEROS[..pad as usize])?;
        self.position += pad;
        Ok(())
    }

    /// Stores one section whose `stored_length` bytes `fill` hands to the
    /// sink it is given, piece by piece (sections larger than memory).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn streamed(
        &mut self,
        tag: Tag,
        comp: u32,
        stored_length: u64,
        length: u64,
        count: u64,
        record_size: u32,
        fill: impl FnOnce(&mut dyn FnMut(&[u8]) -> std::io::Result<()>) -> std::io::Result<()>,
    ) -> std::io::Result<()> {
        let align = if stored_length >= layout::LARGE_SECTION { layout::PAGE_ALIGN } else { layout::SECTION_ALIGN };
        self.pad_to(align)?;
        let mut hasher = Xxh3::new();
        let mut written = 0u64;
        let out = &mut self.out;
        fill(&mut |piece: &[u8]| {
            hasher.update(piece);
            written += piece.len() as u64;
            out.write_all(piece)
        })?;
        if written != stored_length {
            return Err(std::io::Error::other(format!(
                "section {}: {written} bytes given, {stored_length} announced",
                super::tag_name(tag)
            )));
        }
        self.entries.push(SectionEntry {
            tag,
            compression: comp,
            offset: self.position,
            stored_length,
            length,
            count,
            record_size,
            flags: 0,
            checksum: hasher.digest(),
            reserved: 0,
        });
        self.position += stored_length;
        Ok(())
    }

    /// Stores one section as is: `records` zero-copy readable.
    pub(super) fn column<T: Pod>(&mut self, tag: Tag, records: &[T]) -> std::io::Result<()> {
        let bytes: &[u8] = cast_slice(records);
        self.raw(tag, compression::NONE, bytes, bytes.len() as u64, records.len() as u64, size_of::<T>() as u32)
    }

    fn raw(
        &mut self,
        tag: Tag,
        comp: u32,
        stored: &[u8],
        length: u64,
        count: u64,
        record_size: u32,
    ) -> std::io::Result<()> {
        self.pieces(tag, comp, &[stored], length, count, record_size)
    }

    /// Stores one section whose bytes are the concatenation of `pieces`.
    fn pieces(
        &mut self,
        tag: Tag,
        comp: u32,
        pieces: &[&[u8]],
        length: u64,
        count: u64,
        record_size: u32,
    ) -> std::io::Result<()> {
        let stored_length: u64 = pieces.iter().map(|p| p.len() as u64).sum();
        self.streamed(tag, comp, stored_length, length, count, record_size, |sink| {
            // Large columns are written in chunks so the hash streams with the write.
            pieces.iter().flat_map(|p| p.chunks(1 << 20)).try_for_each(sink)
        })
    }

    /// Stores the link-end columns `source` gives, as [`Self::column`] of
    /// each would: their places follow from E alone, so the four are
    /// written side by side while the source produces them; the weights'
    /// escapes (`LCNX`, rare) are held and stored after them.
    fn link_columns(&mut self, source: &mut dyn LinkEndSource) -> std::io::Result<()> {
        let e = source.end_count();
        let tags = [tag::LINK_OTHER, tag::LINK_COUNT, tag::LINK_DIRECTION, tag::LINK_BUCKET];
        let widths = [4u64, 1, 4, 1];
        let mut columns = Vec::with_capacity(4);
        let mut position = self.position;
        for w in widths {
            let len = e * w;
            let align = if len >= layout::LARGE_SECTION { layout::PAGE_ALIGN } else { layout::SECTION_ALIGN };
            let offset = position.next_multiple_of(align);
            // The padding before the column, written as zeros.
            self.out.seek(SeekFrom::Start(position))?;
            self.out.write_all(&vec![0u8; (offset - position) as usize])?;
            columns.push(PlacedColumn { offset, written: 0, buf: Vec::new(), hasher: Xxh3::new() });
            position = offset + len;
        }
        let out = &mut self.out;
        let mut given = 0u64;
        let (mut counts, mut escapes) = (Vec::new(), Vec::new());
        source.write_ends(&mut |other, weight, direction, bucket| {
            let n = other.len();
            if weight.len() != n || direction.len() != n || bucket.len() != n || given + n as u64 > e {
                return Err(std::io::Error::other("link-end source gave columns of unequal length or too many ends"));
            }
            counts.clear();
            weights::encode(weight, given, &mut counts, &mut escapes);
            given += n as u64;
            columns[0].add(out, cast_slice(other))?;
            columns[1].add(out, &counts)?;
            columns[2].add(out, cast_slice(direction))?;
            columns[3].add(out, bucket)
        })?;
        if given != e {
            return Err(std::io::Error::other(format!("link-end source gave {given} of its {e} ends")));
        }
        for ((mut c, t), w) in columns.into_iter().zip(tags).zip(widths) {
            c.flush(&mut self.out)?;
            self.entries.push(SectionEntry {
                tag: t,
                compression: compression::NONE,
                offset: c.offset,
                stored_length: e * w,
                length: e * w,
                count: e,
                record_size: w as u32,
                flags: 0,
                checksum: c.hasher.digest(),
                reserved: 0,
            });
        }
        self.out.seek(SeekFrom::Start(position))?;
        self.position = position;
        self.column(tag::LINK_ESCAPES, &escapes)
    }

    pub(super) fn finish(mut self) -> std::io::Result<W> {
        self.pad_to(layout::SECTION_ALIGN)?;
        let table_offset = self.position;
        let table: &[u8] = cast_slice(&self.entries);
        self.out.write_all(table)?;
        self.position += table.len() as u64;
        let mut header = HeaderRecord {
            magic: layout::MAGIC,
            version_write: layout::VERSION_WRITE,
            version_read: self.version_read,
            header_size: layout::HEADER_SIZE as u32,
            flags: 0,
            file_length: self.position,
            table_offset,
            section_count: self.entries.len() as u32,
            entry_size: layout::ENTRY_SIZE as u32,
            table_checksum: xxh3_64(table),
            reserved: [0; 8],
            header_checksum: 0,
        };
        header.header_checksum = xxh3_64(&bytes_of(&header)[..120]);
        self.out.seek(SeekFrom::Start(0))?;
        self.out.write_all(bytes_of(&header))?;
        self.out.flush()?;
        Ok(self.out)
    }
}

fn write_all<W: Write + Seek>(
    out: W,
    c: &ArchiveContents,
    mut links: Option<&mut dyn LinkEndSource>,
) -> Result<W, ArchiveError> {
    let io = |e: std::io::Error| ArchiveError::Io { path: "<archive>".into(), source: e };
    let meta = rkyv::to_bytes::<rkyv::rancor::Error>(&c.meta)
        .map_err(|e| ArchiveError::corrupt(format!("cannot serialise META: {e}")))?;
    let meta_z = zstd::bulk::compress(&meta, 3).map_err(io)?;
    let mut w = SectionWriter::new(out).map_err(io)?;
    let mut sections = || -> std::io::Result<()> {
        w.column(tag::BUILD, std::slice::from_ref(&c.build))?;
        w.column(tag::CAMERA, std::slice::from_ref(&c.camera))?;
        w.column(tag::MATERIALS, &c.materials)?;
        w.column(tag::SURFACES, &c.surfaces)?;
        w.column(tag::PRIMITIVES, &c.primitives)?;
        w.column(tag::DIRECTIONS, &c.directions)?;
        w.column(tag::PATCH_CENTRE, &c.patch_centre)?;
        w.column(tag::PATCH_NORMAL, &c.patch_normal)?;
        w.column(tag::PATCH_AREA, &c.patch_area)?;
        w.column(tag::PATCH_PRIMITIVE, &c.patch_primitive)?;
        w.column(tag::PATCH_CORNERS, &c.patch_corners)?;
        w.column(tag::PATCH_HITS, &c.patch_hits)?;
        w.column(tag::PATCH_EXPECTED_HITS, &c.patch_expected_hits)?;
        w.column(tag::VERTEX_POSITION, &c.vertex_position)?;
        if !c.patch_back_hits.is_empty() {
            w.column(tag::PATCH_BACK_HITS, &c.patch_back_hits)?;
        }
        if !c.grouped_triangles.is_empty() {
            // Version 7 readers would take kind 2 for a grid of their own.
            w.version_read = w.version_read.max(layout::VERSION_READ_GROUPED);
            w.column(tag::GROUPED_TRIANGLE_VERTICES, &c.grouped_triangles)?;
        }
        w.column(tag::ADJACENCY_OFFSETS, &c.adjacency_offsets)?;
        w.column(tag::ADJACENCY, &c.adjacency)?;
        w.column(tag::LINK_OFFSETS, &c.link_offsets)?;
        match links.as_deref_mut() {
            Some(source) => w.link_columns(source)?,
            None => {
                let (mut counts, mut escapes) = (Vec::new(), Vec::<WeightEscape>::new());
                weights::encode(&c.link_weight, 0, &mut counts, &mut escapes);
                w.column(tag::LINK_OTHER, &c.link_other)?;
                w.column(tag::LINK_COUNT, &counts)?;
                w.column(tag::LINK_DIRECTION, &c.link_direction)?;
                w.column(tag::LINK_BUCKET, &c.link_bucket)?;
                w.column(tag::LINK_ESCAPES, &escapes)?;
            }
        }
        w.raw(tag::META, compression::ZSTD, &meta_z, meta.len() as u64, 1, 0)?;
        if let Some(r) = &c.reflectance {
            w.column(tag::PROTOTYPES, &r.prototypes)?;
            w.column(tag::PROTOTYPE_ROWS, &r.rows)?;
            w.column(tag::PROTOTYPE_DIRECTIONS, &r.outgoing)?;
            w.column(tag::PROTOTYPE_FACTORS, &r.factors)?;
            w.column(tag::ORIENTATIONS, &r.orientations)?;
            w.column(tag::ORIENTATION_MAPS, &r.maps)?;
            w.column(tag::NONDIFFUSE_PATCHES, &r.patches)?;
            w.column(tag::NONDIFFUSE_HITS, &r.hits)?;
            if !r.back_hits.is_empty() {
                w.column(tag::NONDIFFUSE_BACK_HITS, &r.back_hits)?;
            }
        }
        if let Some(sh) = &c.shading {
            w.column(tag::SHADING, &sh.primitives)?;
            w.column(tag::TEXTURES, &sh.textures)?;
            w.column(tag::TEXELS, &sh.texels)?;
        }
        if let Some(seq) = &c.sequence {
            w.column(tag::ANIMATION, std::slice::from_ref(&seq.record))?;
            w.column(tag::INSTANCES, &seq.instances)?;
            if !seq.cameras.is_empty() {
                w.column(tag::FRAME_CAMERAS, &seq.cameras)?;
            }
            if !seq.emissions.is_empty() {
                w.column(tag::FRAME_EMISSION, &seq.emissions)?;
            }
            let d = &seq.deltas;
            w.column(tag::DELTA_INDEX, &d.index)?;
            let length = d.stored_length();
            w.streamed(tag::DELTAS, compression::NONE, length, length, d.index.len() as u64, 0, |sink| {
                d.write_to(sink)
            })?;
        }
        Ok(())
    };
    sections().map_err(io)?;
    w.finish().map_err(io)
}

/// Writes `contents` to `path` atomically: into a temporary file in the same
/// directory, flushed and synced, then renamed over `path`. Returns the file
/// size in bytes.
pub fn write(path: &Path, contents: &ArchiveContents) -> Result<u64, ArchiveError> {
    write_with_links(path, contents, None)
}

/// [`write()`], the link-end columns given by `links` when they are not in
/// `contents` (whose link-end vectors are then ignored).
pub fn write_with_links(
    path: &Path,
    contents: &ArchiveContents,
    links: Option<&mut dyn LinkEndSource>,
) -> Result<u64, ArchiveError> {
    let dir = scratch::dir_of(path);
    let io = |e: std::io::Error| ArchiveError::Io { path: path.into(), source: e };
    std::fs::create_dir_all(dir).map_err(|e| ArchiveError::Io { path: dir.into(), source: e })?;
    // What a killed write of this archive left (never a live one's).
    let _ = scratch::remove_stale(path);
    let tmp = scratch::temp_file(path).map_err(io)?;
    let (file, tmp_path) = tmp.into_parts();
    let buffered = std::io::BufWriter::with_capacity(1 << 20, file);
    let buffered = write_all(buffered, contents, links).map_err(|e| match e {
        ArchiveError::Io { source, .. } => io(source),
        other => other,
    })?;
    let file = buffered.into_inner().map_err(|e| io(e.into_error()))?;
    scratch::stop_point("write");
    file.sync_all().map_err(io)?;
    let len = file.metadata().map_err(io)?.len();
    // Renamed while still open and locked, so that no other process's
    // stale-file sweep ever sees it unlocked (`scratch::remove_stale`).
    tmp_path.persist(path).map_err(|e| io(e.error))?;
    drop(file);
    Ok(len)
}

/// Serialises `contents` to bytes (the same bytes [`write()`] stores).
pub fn write_to_vec(contents: &ArchiveContents) -> Result<Vec<u8>, ArchiveError> {
    Ok(write_all(std::io::Cursor::new(Vec::new()), contents, None)?.into_inner())
}

/// [`write_to_vec`] with the link-end columns given by `links`.
pub fn write_to_vec_with_links(
    contents: &ArchiveContents,
    links: &mut dyn LinkEndSource,
) -> Result<Vec<u8>, ArchiveError> {
    Ok(write_all(std::io::Cursor::new(Vec::new()), contents, Some(links))?.into_inner())
}

/// Recomputes every checksum of the archive held in `bytes` — each frame's
/// in `DIDX` (of its `DELT` bytes), each section's, the table's and the
/// header's — after its bytes were changed in place: how tests and fuzzers
/// forge archives that get past the checksums to the rules behind them.
/// Entries or ranges that lie outside `bytes` are left as they are.
pub fn reseal(bytes: &mut [u8]) {
    if bytes.len() < layout::HEADER_SIZE {
        return;
    }
    let header: HeaderRecord = bytemuck::pod_read_unaligned(&bytes[..layout::HEADER_SIZE]);
    let t = header.table_offset as usize;
    let table_end = (header.section_count as usize).checked_mul(layout::ENTRY_SIZE).and_then(|n| n.checked_add(t));
    let Some(table_end) = table_end.filter(|&e| e <= bytes.len()) else { return };
    let entry_at = |i: usize| t + i * layout::ENTRY_SIZE;
    let entries: Vec<SectionEntry> = (0..header.section_count as usize)
        .map(|i| bytemuck::pod_read_unaligned(&bytes[entry_at(i)..entry_at(i) + layout::ENTRY_SIZE]))
        .collect();
    let len = bytes.len();
    let range = |e: &SectionEntry| {
        let a = e.offset as usize;
        a.checked_add(e.stored_length as usize).filter(|&b| b <= len).map(|b| a..b)
    };
    let find = |t: Tag| entries.iter().find(|e| e.tag == t).and_then(range);
    if let (Some(index), Some(payload)) = (find(tag::DELTA_INDEX), find(tag::DELTAS)) {
        let size = size_of::<layout::DeltaIndexRecord>();
        for at in index.step_by(size) {
            if at + size > bytes.len() {
                break;
            }
            let mut r: layout::DeltaIndexRecord = bytemuck::pod_read_unaligned(&bytes[at..at + size]);
            let a = payload.start.saturating_add(r.offset as usize);
            if let Some(b) = a.checked_add(r.stored_length as usize).filter(|&b| b <= payload.end) {
                r.checksum = xxh3_64(&bytes[a..b]);
                bytes[at..at + size].copy_from_slice(bytes_of(&r));
            }
        }
    }
    for (i, mut e) in entries.into_iter().enumerate() {
        if let Some(r) = range(&e) {
            e.checksum = xxh3_64(&bytes[r]);
        }
        bytes[entry_at(i)..entry_at(i) + layout::ENTRY_SIZE].copy_from_slice(bytes_of(&e));
    }
    let mut header = header;
    header.table_checksum = xxh3_64(&bytes[t..table_end]);
    bytes[..layout::HEADER_SIZE].copy_from_slice(bytes_of(&header));
    let sum = xxh3_64(&bytes[..120]);
    bytes[120..128].copy_from_slice(&sum.to_le_bytes());
}
