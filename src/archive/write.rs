//! Single-pass archive writer: header placeholder, sections, table, header.

use std::io::{Seek, SeekFrom, Write};
use std::path::Path;

use bytemuck::{Pod, bytes_of, cast_slice};
use xxhash_rust::xxh3::{Xxh3, xxh3_64};

use super::layout::{self, HeaderRecord, LinkRunRecord, SectionEntry, Tag, compression, tag};
use super::{ArchiveContents, ArchiveError, weights};
use crate::scratch;

/// Receives batches of link ends: other patch, weight, direction, bucket.
pub type LinkEndSink<'a> = dyn FnMut(&[u32], &[f32], &[u32], &[u8]) -> std::io::Result<()> + 'a;

/// The link ends (other patch, weight, direction, bucket; stored as
/// `LOTH`, `LCNT` with `LCNX`, `LDIR`, `LROF` and `LRUN`, §5.10) of
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

    /// Stores the link ends `source` gives (rows per `link_offsets`,
    /// `LOFF`) as `LOTH`, `LCNT`, `LDIR`, `LROF` and `LRUN`, then `LCNX`
    /// (§5.10): the places of the first four follow from E and the patch
    /// count alone, so they are written side by side while the source
    /// produces them; `LRUN`, whose length is known at the end, goes after
    /// them at a page boundary, and the weights' escapes (rare) are held
    /// and stored last. Fails when a row's ends are not in ascending
    /// (bucket, sender chunk), the order the format requires. Returns the
    /// number of weights kept apart in `LCNX`.
    pub(super) fn link_columns(
        &mut self,
        source: &mut dyn LinkEndSource,
        link_offsets: &[u64],
    ) -> std::io::Result<u64> {
        let e = source.end_count();
        let patches = link_offsets.len().saturating_sub(1);
        if link_offsets.last().copied().unwrap_or(0) != e {
            return Err(std::io::Error::other(format!(
                "LOFF ends at {:?}, the link-end source gives {e}",
                link_offsets.last()
            )));
        }
        let tags = [tag::LINK_OTHER, tag::LINK_COUNT, tag::LINK_DIRECTION, tag::LINK_RUN_OFFSETS, tag::LINK_RUNS];
        let lengths = [e * 2, e, e * 4, (patches as u64 + 1) * 8];
        let widths = [2u32, 1, 4, 8, 8];
        let mut columns = Vec::with_capacity(5);
        let mut position = self.position;
        for len in lengths.into_iter().map(Some).chain([None]) {
            // `LRUN`, of a length not known yet, at a page boundary.
            let align = match len {
                Some(len) if len < layout::LARGE_SECTION => layout::SECTION_ALIGN,
                _ => layout::PAGE_ALIGN,
            };
            let offset = position.next_multiple_of(align);
            // The padding before the column, written as zeros.
            self.out.seek(SeekFrom::Start(position))?;
            self.out.write_all(&vec![0u8; (offset - position) as usize])?;
            columns.push(PlacedColumn { offset, written: 0, buf: Vec::new(), hasher: Xxh3::new() });
            position = offset + len.unwrap_or(0);
        }
        let out = &mut self.out;
        let mut rows = RunWriter::new(link_offsets);
        let (mut counts, mut escapes, mut ids, mut runs) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let mut run_offsets: Vec<u64> = Vec::new();
        source.write_ends(&mut |other, weight, direction, bucket| {
            let n = other.len();
            if weight.len() != n || direction.len() != n || bucket.len() != n || rows.given + n as u64 > e {
                return Err(std::io::Error::other("link-end source gave columns of unequal length or too many ends"));
            }
            counts.clear();
            weights::encode(weight, rows.given, &mut counts, &mut escapes);
            ids.clear();
            runs.clear();
            run_offsets.clear();
            rows.add(other, bucket, &mut ids, &mut runs, &mut run_offsets)?;
            columns[0].add(out, cast_slice(&ids))?;
            columns[1].add(out, &counts)?;
            columns[2].add(out, cast_slice(direction))?;
            columns[3].add(out, cast_slice(&run_offsets))?;
            columns[4].add(out, cast_slice(&runs))
        })?;
        if rows.given != e {
            return Err(std::io::Error::other(format!("link-end source gave {} of its {e} ends", rows.given)));
        }
        runs.clear();
        run_offsets.clear();
        rows.finish(&mut runs, &mut run_offsets);
        columns[3].add(out, cast_slice(&run_offsets))?;
        columns[4].add(out, cast_slice(&runs))?;
        let run_count = rows.runs;
        for (i, (mut c, t)) in columns.into_iter().zip(tags).enumerate() {
            c.flush(&mut self.out)?;
            let count = match i {
                0..=2 => e,
                3 => patches as u64 + 1,
                _ => run_count,
            };
            let len = count * widths[i] as u64;
            if c.written != len {
                return Err(std::io::Error::other(format!(
                    "section {}: {} bytes written, {len} expected",
                    super::tag_name(t),
                    c.written
                )));
            }
            self.entries.push(SectionEntry {
                tag: t,
                compression: compression::NONE,
                offset: c.offset,
                stored_length: len,
                length: len,
                count,
                record_size: widths[i],
                flags: 0,
                checksum: c.hasher.digest(),
                reserved: 0,
            });
            position = c.offset + len;
        }
        self.out.seek(SeekFrom::Start(position))?;
        self.position = position;
        self.column(tag::LINK_ESCAPES, &escapes)?;
        Ok(escapes.len() as u64)
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

/// The link ends held in [`ArchiveContents`], as a source.
struct HeldLinks<'c>(&'c ArchiveContents);

impl LinkEndSource for HeldLinks<'_> {
    fn end_count(&self) -> u64 {
        self.0.link_other.len() as u64
    }

    fn write_ends(&mut self, out: &mut LinkEndSink<'_>) -> std::io::Result<()> {
        let c = self.0;
        const BATCH: usize = 1 << 20;
        let n = c.link_other.len();
        if c.link_weight.len() != n || c.link_direction.len() != n || c.link_bucket.len() != n {
            return Err(std::io::Error::other("link-end columns of unequal length"));
        }
        for a in (0..n).step_by(BATCH) {
            let r = a..(a + BATCH).min(n);
            out(&c.link_other[r.clone()], &c.link_weight[r.clone()], &c.link_direction[r.clone()], &c.link_bucket[r])?;
        }
        Ok(())
    }
}

/// Cuts link ends given in file order into rows (`LOFF`) and runs of one
/// (bucket, sender chunk): what `LOTH`, `LROF` and `LRUN` store (§5.10).
struct RunWriter<'o> {
    link_offsets: &'o [u64],
    /// Ends given so far.
    given: u64,
    /// The patch whose row the next end is in; its row's end.
    patch: usize,
    row_end: u64,
    /// The run being made: its (bucket, chunk) and length.
    open: Option<((u8, u16), u32)>,
    /// Runs closed so far.
    runs: u64,
}

impl<'o> RunWriter<'o> {
    fn new(link_offsets: &'o [u64]) -> Self {
        Self { link_offsets, given: 0, patch: 0, row_end: 0, open: None, runs: 0 }
    }

    /// Closes the open run, if any, into `runs`.
    fn close(&mut self, runs: &mut Vec<LinkRunRecord>) {
        if let Some(((bucket, chunk), length)) = self.open.take() {
            runs.push(LinkRunRecord { chunk, bucket, reserved: 0, length });
            self.runs += 1;
        }
    }

    /// Moves to the rows that hold the next end, closing runs and giving
    /// each row passed its first run (`LROF`).
    fn advance(&mut self, runs: &mut Vec<LinkRunRecord>, run_offsets: &mut Vec<u64>) {
        let patches = self.link_offsets.len().saturating_sub(1);
        while self.given == self.row_end && self.patch < patches {
            self.close(runs);
            run_offsets.push(self.runs);
            self.row_end = self.link_offsets[self.patch + 1];
            self.patch += 1;
        }
    }

    fn add(
        &mut self,
        other: &[u32],
        bucket: &[u8],
        ids: &mut Vec<u16>,
        runs: &mut Vec<LinkRunRecord>,
        run_offsets: &mut Vec<u64>,
    ) -> std::io::Result<()> {
        let patches = self.link_offsets.len().saturating_sub(1);
        for (&o, &k) in other.iter().zip(bucket) {
            self.advance(runs, run_offsets);
            if o as usize >= patches {
                return Err(std::io::Error::other(format!("link end {}: patch {o} of {patches}", self.given)));
            }
            let key = (k, (o as usize / layout::CHUNK_PATCHES) as u16);
            match &mut self.open {
                Some((open, length)) if *open == key => {
                    *length = length.checked_add(1).ok_or_else(|| {
                        std::io::Error::other(format!("link end {}: a run of more than 2³² − 1 ends", self.given))
                    })?;
                }
                Some((open, _)) if *open > key => {
                    return Err(std::io::Error::other(format!(
                        "link end {}: patch {}'s ends are not in ascending (bucket, sender chunk)",
                        self.given,
                        self.patch - 1
                    )));
                }
                _ => {
                    self.close(runs);
                    self.open = Some((key, 1));
                }
            }
            ids.push((o as usize % layout::CHUNK_PATCHES) as u16);
            self.given += 1;
        }
        Ok(())
    }

    /// After the last end: the last run and the rows left (empty ones at
    /// the end), and `LROF`'s last entry.
    fn finish(&mut self, runs: &mut Vec<LinkRunRecord>, run_offsets: &mut Vec<u64>) {
        self.advance(runs, run_offsets);
        self.close(runs);
        run_offsets.push(self.runs);
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
    // Patch blocks in a spatial order, not primitive order: older readers
    // would take them for a corrupt file (§5.5).
    if !c.primitives.windows(2).all(|p| p[0].first_patch <= p[1].first_patch) {
        w.version_read = layout::VERSION_READ_SPATIAL;
    }
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
            w.column(tag::GROUPED_TRIANGLE_VERTICES, &c.grouped_triangles)?;
        }
        w.column(tag::ADJACENCY_OFFSETS, &c.adjacency_offsets)?;
        w.column(tag::ADJACENCY, &c.adjacency)?;
        w.column(tag::LINK_OFFSETS, &c.link_offsets)?;
        match links.as_deref_mut() {
            Some(source) => w.link_columns(source, &c.link_offsets)?,
            None => w.link_columns(&mut HeldLinks(c), &c.link_offsets)?,
        };
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
    let folder = scratch::OutputDir::make(path).map_err(|e| ArchiveError::Io { path: dir.into(), source: e })?;
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
    folder.keep();
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
