//! `illumnet upgrade`: rewrites a version 6 archive in the current format
//! (§8), without building it again.
//!
//! Version 7 changed two things a version 6 file holds: link-end weights
//! are one byte (`LCNT`, with `LCNX` for weights that are not a count in
//! 1..=255) instead of an f32 (`LWGT`), and `PRIM.cell_order` says how a
//! quad's patches are numbered — 0, rows, is what version 6 files (whose
//! field was reserved and zero) already mean. So an upgrade copies every
//! section as it is, turns `LWGT` into `LCNT` and `LCNX` (the same weights,
//! exactly), and writes the new versions: the light it renders is the
//! same, bit for bit, and its bytes those a version 7 build with row order
//! would write. It streams: memory holds one piece of a section at a time
//! and the escapes, whatever the file's size. The result is validated in
//! full before it replaces anything; the write goes to a temporary file
//! renamed into place.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

use xxhash_rust::xxh3::Xxh3;

use super::layout::{self, SectionEntry, WeightEscape, compression, tag};
use super::read::{check_digest, read_structure_of, required_v6};
use super::stream::for_each_piece;
use super::write::SectionWriter;
use super::{Archive, ArchiveError, weights};
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
}

/// Rewrites the version 6 archive `input` in the current format at
/// `output` (which may be `input`: it is replaced atomically). Fails,
/// leaving `output` as it was, on a file of another version, a damaged
/// one, or one whose result does not validate.
pub fn upgrade(input: &Path, output: &Path) -> Result<Upgraded, ArchiveError> {
    let io_in = |e: std::io::Error| ArchiveError::Io { path: input.into(), source: e };
    let file = File::open(input).map_err(io_in)?;
    let (header, _) = read_structure_of(&file, input, Some(&[]))?;
    if header.version_write >= layout::OLDEST_READABLE && input == output {
        let len = header.file_length;
        return Ok(Upgraded { bytes_before: len, bytes_after: len, escapes: 0, already_current: true });
    }
    if header.version_write != layout::UPGRADABLE {
        return Err(match header.version_write {
            v if v >= layout::OLDEST_READABLE => ArchiveError::corrupt(format!(
                "{} is already in format version {v}: copy it instead of upgrading it",
                input.display()
            )),
            v => ArchiveError::Outdated { written: v },
        });
    }
    let (_, mut entries) = read_structure_of(&file, input, Some(&required_v6()))?;
    entries.sort_by_key(|e| e.offset);
    let io_out = |e: std::io::Error| ArchiveError::Io { path: output.into(), source: e };
    let dir = scratch::dir_of(output);
    std::fs::create_dir_all(dir).map_err(|e| ArchiveError::Io { path: dir.into(), source: e })?;
    let _ = scratch::remove_stale(output);
    let (tmp_file, tmp_path) = scratch::temp_file(output).map_err(io_out)?.into_parts();
    let mut w = SectionWriter::new(BufWriter::with_capacity(1 << 20, tmp_file)).map_err(io_out)?;
    // LCNX goes right after the last link column, where a build puts it
    // (by index: with no link ends, several sections share an offset).
    let link_columns = [tag::LINK_OTHER, tag::LINK_WEIGHT_V6, tag::LINK_DIRECTION, tag::LINK_BUCKET];
    let last_link_column = entries.iter().rposition(|e| link_columns.contains(&e.tag));
    let mut escapes: Vec<WeightEscape> = Vec::new();
    let mut buf = Vec::new();
    for (i, e) in entries.iter().enumerate() {
        if e.tag == tag::LINK_WEIGHT_V6 {
            copy_weights(&file, input, e, &mut w, &mut escapes, &mut buf)?;
        } else {
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
        if Some(i) == last_link_column {
            w.column(tag::LINK_ESCAPES, &escapes).map_err(io_out)?;
        }
    }
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
    drop(tmp_file);
    Ok(Upgraded {
        bytes_before: header.file_length,
        bytes_after,
        escapes: escapes.len() as u64,
        already_current: false,
    })
}

/// Writes `LWGT` (`e`) as `LCNT`, collecting the escapes.
fn copy_weights<W: Write + std::io::Seek>(
    file: &File,
    input: &Path,
    e: &SectionEntry,
    w: &mut SectionWriter<W>,
    escapes: &mut Vec<WeightEscape>,
    buf: &mut Vec<u8>,
) -> Result<(), ArchiveError> {
    if e.compression != compression::NONE || e.record_size != 4 {
        return Err(ArchiveError::corrupt("LWGT: not a stored column of f32"));
    }
    let ends = e.count;
    let mut hasher = Xxh3::new();
    let (mut counts, mut floats) = (Vec::new(), Vec::new());
    let mut first = 0u64;
    let mut bad = None;
    w.streamed(tag::LINK_COUNT, compression::NONE, ends, ends, ends, 1, |sink| {
        for_each_piece(file, e.offset, e.stored_length, buf, |piece| {
            hasher.update(piece);
            floats.clear();
            floats.extend(piece.chunks_exact(4).map(|x| f32::from_le_bytes([x[0], x[1], x[2], x[3]])));
            if bad.is_none() {
                bad = floats.iter().position(|w| !w.is_finite() || *w < 0.0).map(|i| first + i as u64);
            }
            counts.clear();
            weights::encode(&floats, first, &mut counts, escapes);
            first += floats.len() as u64;
            sink(&counts)
        })
    })
    .map_err(|x| ArchiveError::Io { path: input.into(), source: x })?;
    check_digest(e, hasher.digest())?;
    match bad {
        Some(i) => Err(ArchiveError::corrupt(format!("LWGT[{i}]: weight negative or non-finite"))),
        None => Ok(()),
    }
}

/// An I/O error of the copy: reading `input` or writing `output` (the
/// message of a short read names the input).
fn either(e: std::io::Error, input: &Path, output: &Path) -> ArchiveError {
    let path = if e.kind() == std::io::ErrorKind::UnexpectedEof { input } else { output };
    ArchiveError::Io { path: path.into(), source: e }
}
