//! `illumnet upgrade`: rewrites an archive of format version 6 to 9 in
//! the current format (§8), without building it again.
//!
//! What changed since version 6, and what the upgrade does about it:
//!
//! * Version 7 stores link-end weights as one byte (`LCNT`, with `LCNX`
//!   for weights that are not a count in 1..=255) instead of an f32
//!   (`LWGT`), and says in `PRIM.cell_order` how a quad's patches are
//!   numbered — 0, rows, is what version 6 files (whose field was reserved
//!   and zero) already mean.
//! * Version 10 stores a link end's other patch in 16 bits, local to its
//!   run's sender chunk (`LOTH`), and the runs of one bucket and chunk per
//!   patch (`LROF`, `LRUN`) instead of a bucket per end (`LBKT`); a row's
//!   ends are ordered by bucket, then chunk, then as before.
//!
//! So an upgrade copies every other section as it is and rewrites the
//! link ends: each row re-ordered by a stable sort on (bucket, chunk) —
//! the order a version 10 build gives — through the archive writer, the
//! same weights exactly. Its bytes are those a build of the same links
//! in primitive order (`--patch-order primitives`; the upgrade keeps the
//! file's patch numbers) would write, and it renders the same light up
//! to the order of sums. It streams: memory holds `LOFF`, the escapes and a batch of
//! rows, whatever the file's size. The old columns are checked against
//! their checksums as they are read, and the result is validated in full
//! before it replaces anything; the write goes to a temporary file renamed
//! into place.

use std::fs::File;
use std::io::{BufWriter, Read, Seek, Write};
use std::path::Path;

use xxhash_rust::xxh3::Xxh3;

use super::layout::{self, SectionEntry, WeightEscape, compression, tag};
use super::read::{check_digest, read_structure_of, required_common};
use super::stream::for_each_piece;
use super::weights::Weights;
use super::write::LinkEndSource;
use super::write::SectionWriter;
use super::{Archive, ArchiveError};
use crate::scratch;

/// What an upgrade did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Upgraded {
    /// Size of the file read.
    pub bytes_before: u64,
    /// Size of the file written.
    pub bytes_after: u64,
    /// Link ends whose weight went to `LCNX`.
    pub escapes: u64,
    /// The file was in the current format already: nothing was written.
    pub already_current: bool,
    /// The format version of the file read.
    pub version_before: u32,
}

/// Link ends read from the old file per batch of rows (at least a row).
const BATCH_ENDS: usize = 1 << 20;

/// Whether `a` and `b` name one file, however spelt (`x.inet`,
/// `./x.inet`, a link to it): an upgrade in place.
pub fn same_file(a: &Path, b: &Path) -> bool {
    a == b || matches!((std::fs::canonicalize(a), std::fs::canonicalize(b)), (Ok(x), Ok(y)) if x == y)
}

/// Rewrites the archive `input` (format version 6 to 9) in the current
/// format at `output` (which may be `input`: it is replaced atomically);
/// a file in the current format is copied (nothing done if `output` is
/// `input`). Fails, leaving `output` as it was, on a file of another
/// version, a damaged one, or one whose result does not validate.
pub fn upgrade(input: &Path, output: &Path) -> Result<Upgraded, ArchiveError> {
    let io_in = |e: std::io::Error| ArchiveError::Io { path: input.into(), source: e };
    let (file, _) = crate::limits::open_regular(input, u64::MAX).map_err(io_in)?;
    let (header, _) = read_structure_of(&file, input, Some(&[]))?;
    let version = header.version_write;
    let io_out = |e: std::io::Error| ArchiveError::Io { path: output.into(), source: e };
    // The temporary file `output` is written to (its folder made, a
    // crashed writer's leftovers removed), renamed over it once checked;
    // with the folder, kept only then.
    let temporary = || {
        let dir = scratch::dir_of(output);
        let folder = scratch::OutputDir::make(output).map_err(|e| ArchiveError::Io { path: dir.into(), source: e })?;
        let _ = scratch::remove_stale(output);
        let (file, path) = scratch::temp_file(output).map_err(io_out)?.into_parts();
        // The folder first, so that it drops last (after the file in it).
        Ok::<_, ArchiveError>((folder, file, path))
    };
    if version >= layout::OLDEST_READABLE {
        // Nothing to rewrite: the result is the file itself, or a copy of
        // it, checked as a render would check it before it replaces
        // `output`.
        if !same_file(input, output) {
            let (folder, mut tmp_file, tmp_path) = temporary()?;
            let (mut from, mut buf) = (&file, vec![0u8; 1 << 20]);
            // From the start, whatever reading the header did to the cursor.
            from.seek(std::io::SeekFrom::Start(0)).map_err(io_in)?;
            loop {
                let n = from.read(&mut buf).map_err(io_in)?;
                if n == 0 {
                    break;
                }
                tmp_file.write_all(&buf[..n]).map_err(io_out)?;
            }
            tmp_file.sync_all().map_err(io_out)?;
            validates(tmp_path.as_ref(), input, output)?;
            tmp_path.persist(output).map_err(|e| io_out(e.error))?;
            folder.keep();
        } else {
            // In place, "nothing to do" only for a file that opens: a
            // header's version says nothing of the layout after it (a
            // version-9 layout under version 12 was "current", issue 42).
            validates(input, input, output)?;
        }
        let len = header.file_length;
        return Ok(Upgraded {
            bytes_before: len,
            bytes_after: len,
            escapes: 0,
            already_current: true,
            version_before: version,
        });
    }
    if version < layout::UPGRADABLE {
        return Err(ArchiveError::Outdated { written: version });
    }
    let (_, mut entries) = read_structure_of(&file, input, Some(&required_before(version)))?;
    entries.sort_by_key(|e| e.offset);
    let old = OldLinks::open(&file, input, &entries, version)?;
    let (folder, tmp_file, tmp_path) = temporary()?;
    let mut w = SectionWriter::new(BufWriter::with_capacity(1 << 20, tmp_file)).map_err(io_out)?;
    // The new link columns go where the first old one was (by index: with
    // no link ends, several sections share an offset).
    let first_link_column = entries.iter().position(|e| OLD_LINK_COLUMNS.contains(&e.tag));
    let mut buf = Vec::new();
    let mut source = OldLinkSource { old, error: None };
    let mut escapes = 0;
    for (i, e) in entries.iter().enumerate() {
        if Some(i) == first_link_column {
            let offsets = source.old.offsets.clone();
            let written = w.link_columns(&mut source, &offsets);
            if let Some(e) = source.error.take() {
                return Err(e);
            }
            escapes = written.map_err(io_out)?;
        }
        if OLD_LINK_COLUMNS.contains(&e.tag) {
            continue;
        }
        let mut hasher = Xxh3::new();
        w.streamed(e.tag, e.compression, e.stored_length, e.length, e.count, e.record_size, |sink| {
            for_each_piece(&file, e.offset, e.stored_length, &mut buf, |piece| {
                hasher.update(piece);
                sink(piece)
            })
        })
        .map_err(|x| either(x, input, output))?;
        check_digest(e, hasher.digest())?;
    }
    source.old.finish()?;
    let out = w.finish().map_err(io_out)?;
    let tmp_file = out.into_inner().map_err(|e| io_out(e.into_error()))?;
    tmp_file.sync_all().map_err(io_out)?;
    let bytes_after = tmp_file.metadata().map_err(io_out)?.len();
    // Everything a render would check, with the link columns streamed so
    // that memory stays small for any size.
    Archive::open_streamed(tmp_path.as_ref(), 1 << 18).map_err(|e| {
        ArchiveError::corrupt(format!("the upgraded archive does not validate (nothing was replaced): {e}"))
    })?;
    tmp_path.persist(output).map_err(|e| io_out(e.error))?;
    folder.keep();
    drop(tmp_file);
    Ok(Upgraded {
        bytes_before: header.file_length,
        bytes_after,
        escapes,
        already_current: false,
        version_before: version,
    })
}

/// Checks that `path` (`input` or a copy of it) opens as a render would
/// open it, its error saying that nothing was written to `output`.
fn validates(path: &Path, input: &Path, output: &Path) -> Result<(), ArchiveError> {
    Archive::open_streamed(path, 1 << 18).map(drop).map_err(|e| match e {
        ArchiveError::Corrupt(m) => ArchiveError::corrupt(format!(
            "{} does not validate, so nothing was written to {}: {m}",
            input.display(),
            output.display()
        )),
        other => other,
    })
}

/// The link-end sections of files before version 10, which an upgrade
/// rewrites (every other section is copied byte for byte).
pub const OLD_LINK_COLUMNS: [layout::Tag; 6] = [
    tag::LINK_OTHER,
    tag::LINK_WEIGHT_V6,
    tag::LINK_COUNT,
    tag::LINK_ESCAPES,
    tag::LINK_DIRECTION,
    tag::LINK_BUCKET_V9,
];

/// The link-end columns of a file before version 10, read a batch of rows
/// at a time, each column checked against its checksum once read whole.
struct OldLinks<'f> {
    file: &'f File,
    path: &'f Path,
    offsets: Vec<u64>,
    /// `LOTH` (u32), the weights (`LWGT` f32, or `LCNT` bytes), `LDIR`,
    /// `LBKT` (absent in files without buckets).
    columns: [Option<SectionEntry>; 4],
    hashers: [Xxh3; 4],
    /// `LCNX` of a version 7 to 9 file, whole (escapes are rare).
    escapes_in: Vec<WeightEscape>,
    patch_count: usize,
}

impl<'f> OldLinks<'f> {
    fn open(file: &'f File, path: &'f Path, entries: &[SectionEntry], version: u32) -> Result<Self, ArchiveError> {
        let find = |t: layout::Tag| entries.iter().find(|e| e.tag == t).copied();
        let read = |e: &SectionEntry| -> Result<Vec<u8>, ArchiveError> {
            let mut bytes = Vec::new();
            for_each_piece(file, e.offset, e.stored_length, &mut Vec::new(), |piece| {
                bytes.extend_from_slice(piece);
                Ok(())
            })
            .map_err(|x| ArchiveError::Io { path: path.into(), source: x })?;
            check_digest(e, xxhash_rust::xxh3::xxh3_64(&bytes))?;
            Ok(bytes)
        };
        let stored = |t: layout::Tag, width: u32| -> Result<Option<SectionEntry>, ArchiveError> {
            match find(t) {
                Some(e) if e.compression != compression::NONE || e.record_size != width => Err(ArchiveError::corrupt(
                    format!("{}: not a stored column of {width}-byte records", super::tag_name(t)),
                )),
                e => Ok(e),
            }
        };
        let offsets: Vec<u64> = bytemuck::pod_collect_to_vec(&read(&find(tag::LINK_OFFSETS).expect("required"))?);
        let ends = offsets.last().copied().unwrap_or(0);
        if offsets.is_empty() || offsets[0] != 0 || offsets.windows(2).any(|w| w[1] < w[0]) {
            return Err(ArchiveError::corrupt("LOFF: not ascending from 0"));
        }
        let weights = if version < layout::VERSION_COUNTS { (tag::LINK_WEIGHT_V6, 4) } else { (tag::LINK_COUNT, 1) };
        let columns = [
            stored(tag::LINK_OTHER, 4)?,
            stored(weights.0, weights.1)?,
            stored(tag::LINK_DIRECTION, 4)?,
            stored(tag::LINK_BUCKET_V9, 1)?,
        ];
        for (c, width) in columns.iter().zip([4u64, weights.1 as u64, 4, 1]) {
            if let Some(c) = c
                && c.stored_length != ends * width
            {
                return Err(ArchiveError::corrupt(format!(
                    "section {}: {} bytes, expected {} for {ends} link ends",
                    super::tag_name(c.tag),
                    c.stored_length,
                    ends * width
                )));
            }
        }
        let escapes_in = match version >= layout::VERSION_COUNTS {
            true => bytemuck::pod_collect_to_vec(&read(&find(tag::LINK_ESCAPES).expect("required"))?),
            false => Vec::new(),
        };
        Ok(Self {
            file,
            path,
            patch_count: offsets.len() - 1,
            offsets,
            columns,
            hashers: std::array::from_fn(|_| Xxh3::new()),
            escapes_in,
        })
    }

    /// Reads column `c`'s ends `a..b` (`width` bytes each), hashing them.
    fn read(&mut self, c: usize, width: u64, a: u64, b: u64, buf: &mut Vec<u8>) -> Result<bool, ArchiveError> {
        let Some(e) = &self.columns[c] else { return Ok(false) };
        buf.resize(((b - a) * width) as usize, 0);
        super::stream::read_at(self.file, buf, e.offset + a * width)
            .map_err(|x| super::stream::short(self.path, &super::tag_name(e.tag), x))?;
        self.hashers[c].update(buf);
        Ok(true)
    }

    /// After every end was read: the columns' checksums.
    fn finish(&self) -> Result<(), ArchiveError> {
        for (c, h) in self.columns.iter().zip(&self.hashers) {
            if let Some(c) = c {
                check_digest(c, h.digest())?;
            }
        }
        Ok(())
    }
}

/// The old link ends, rows re-ordered, as the writer's source.
struct OldLinkSource<'f> {
    old: OldLinks<'f>,
    /// What went wrong reading the old file (the writer sees an I/O error).
    error: Option<ArchiveError>,
}

impl LinkEndSource for OldLinkSource<'_> {
    fn end_count(&self) -> u64 {
        self.old.offsets.last().copied().unwrap_or(0)
    }

    fn write_ends(&mut self, out: &mut super::LinkEndSink<'_>) -> std::io::Result<()> {
        match self.rows(out) {
            Ok(r) => r,
            Err(e) => {
                let message = e.to_string();
                self.error = Some(e);
                Err(std::io::Error::other(message))
            }
        }
    }
}

impl OldLinkSource<'_> {
    /// Gives `out` the rows in batches; the outer error is the old file's.
    fn rows(&mut self, out: &mut super::LinkEndSink<'_>) -> Result<std::io::Result<()>, ArchiveError> {
        let old = &mut self.old;
        let n = old.patch_count;
        let counts = old.columns[1].is_some_and(|c| c.record_size == 1);
        let (mut raw, mut other, mut weight, mut direction, mut bucket) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let (mut o2, mut w2, mut d2, mut k2, mut order) = (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let mut p = 0;
        while p < n {
            // Whole rows, about a batch of ends.
            let a = old.offsets[p];
            let mut q = p + 1;
            while q < n && old.offsets[q + 1] - a <= BATCH_ENDS as u64 {
                q += 1;
            }
            let b = old.offsets[q];
            old.read(0, 4, a, b, &mut raw)?;
            other.clear();
            other.extend(raw.chunks_exact(4).map(|x| u32::from_le_bytes([x[0], x[1], x[2], x[3]])));
            old.read(1, if counts { 1 } else { 4 }, a, b, &mut raw)?;
            weight.clear();
            if counts {
                weight.extend(Weights::new(&raw, &old.escapes_in, a).iter());
            } else {
                weight.extend(raw.chunks_exact(4).map(|x| f32::from_le_bytes([x[0], x[1], x[2], x[3]])));
                if let Some(i) = weight.iter().position(|w| !w.is_finite() || *w < 0.0) {
                    return Err(ArchiveError::corrupt(format!(
                        "LWGT[{}]: weight negative or non-finite",
                        a + i as u64
                    )));
                }
            }
            old.read(2, 4, a, b, &mut raw)?;
            direction.clear();
            direction.extend(raw.chunks_exact(4).map(|x| u32::from_le_bytes([x[0], x[1], x[2], x[3]])));
            bucket.clear();
            match old.read(3, 1, a, b, &mut raw)? {
                true => bucket.extend_from_slice(&raw),
                false => bucket.resize(other.len(), 0),
            }
            if let Some(i) = other.iter().position(|&o| o as usize >= n) {
                return Err(ArchiveError::corrupt(format!("LOTH[{}]: patch id out of range", a + i as u64)));
            }
            // Each row by (bucket, sender chunk), stably.
            o2.clear();
            w2.clear();
            d2.clear();
            k2.clear();
            for r in p..q {
                let row = (old.offsets[r] - a) as usize..(old.offsets[r + 1] - a) as usize;
                order.clear();
                order.extend(row);
                order.sort_by_key(|&e| (bucket[e], other[e] as usize / layout::CHUNK_PATCHES));
                for &e in &order {
                    o2.push(other[e]);
                    w2.push(weight[e]);
                    d2.push(direction[e]);
                    k2.push(bucket[e]);
                }
            }
            if let Err(e) = out(&o2, &w2, &d2, &k2) {
                return Ok(Err(e));
            }
            p = q;
        }
        Ok(Ok(()))
    }
}

/// The sections a file of format `version` (6 to 9) requires, as
/// [`read_structure_of`] checks them: the current ones but for the link
/// ends, whose columns [`OldLinks`] checks itself.
fn required_before(version: u32) -> Vec<(layout::Tag, u32, u32)> {
    let mut r = required_common();
    if version >= layout::VERSION_COUNTS {
        r.push((tag::LINK_ESCAPES, size_of::<WeightEscape>() as u32, compression::NONE));
    }
    r
}

/// An I/O error of the copy: reading `input` or writing `output` (the
/// message of a short read names the input).
fn either(e: std::io::Error, input: &Path, output: &Path) -> ArchiveError {
    let path = if e.kind() == std::io::ErrorKind::UnexpectedEof { input } else { output };
    ArchiveError::Io { path: path.into(), source: e }
}
