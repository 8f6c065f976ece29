//! The file's structure (§7, steps 1 to 4): the header, the section
//! table and every entry's bounds, alignment, record size and
//! compression, the sections that must (or may only together) appear, and
//! the checksums. Nothing in a section is trusted before these hold.

use std::path::Path;

use bytemuck::pod_read_unaligned;
use xxhash_rust::xxh3::xxh3_64;

use super::bad;
use crate::archive::layout::{
    self, AnimationRecord, BuildRecord, CameraRecord, DeltaIndexRecord, DirectionRecord, HeaderRecord, InstanceRecord,
    MaterialRecord, NonDiffusePatchRecord, OrientationRecord, PrimitiveRecord, PrototypeRecord, SectionEntry,
    SurfaceRecord, Tag, WeightEscape, compression, tag,
};
use crate::archive::stream;
use crate::archive::{ArchiveError, tag_name};

/// Required sections: tag, record size, compression.
const REQUIRED: [(Tag, u32, u32); 24] = [
    (tag::BUILD, size_of::<BuildRecord>() as u32, compression::NONE),
    (tag::CAMERA, size_of::<CameraRecord>() as u32, compression::NONE),
    (tag::MATERIALS, size_of::<MaterialRecord>() as u32, compression::NONE),
    (tag::SURFACES, size_of::<SurfaceRecord>() as u32, compression::NONE),
    (tag::PRIMITIVES, size_of::<PrimitiveRecord>() as u32, compression::NONE),
    (tag::DIRECTIONS, size_of::<DirectionRecord>() as u32, compression::NONE),
    (tag::PATCH_CENTRE, 12, compression::NONE),
    (tag::PATCH_NORMAL, 12, compression::NONE),
    (tag::PATCH_AREA, 4, compression::NONE),
    (tag::PATCH_PRIMITIVE, 4, compression::NONE),
    (tag::PATCH_CORNERS, 16, compression::NONE),
    (tag::PATCH_HITS, 4, compression::NONE),
    (tag::PATCH_EXPECTED_HITS, 4, compression::NONE),
    (tag::VERTEX_POSITION, 12, compression::NONE),
    (tag::ADJACENCY_OFFSETS, 4, compression::NONE),
    (tag::ADJACENCY, 4, compression::NONE),
    (tag::LINK_OFFSETS, 8, compression::NONE),
    (tag::LINK_OTHER, 2, compression::NONE),
    (tag::LINK_COUNT, 1, compression::NONE),
    (tag::LINK_RUN_OFFSETS, 8, compression::NONE),
    (tag::LINK_RUNS, size_of::<layout::LinkRunRecord>() as u32, compression::NONE),
    (tag::LINK_ESCAPES, size_of::<WeightEscape>() as u32, compression::NONE),
    (tag::LINK_DIRECTION, 4, compression::NONE),
    (tag::META, 0, compression::ZSTD),
];

/// Optional sections, when present: tag, record size, compression.
const OPTIONAL: [(Tag, u32, u32); 20] = [
    (tag::GROUPED_TRIANGLE_VERTICES, 12, compression::NONE),
    (tag::SHADING, size_of::<layout::ShadingRecord>() as u32, compression::NONE),
    (tag::TEXTURES, size_of::<layout::TextureRecord>() as u32, compression::NONE),
    (tag::TEXELS, 1, compression::NONE),
    (tag::PATCH_BACK_HITS, 4, compression::NONE),
    (tag::NONDIFFUSE_BACK_HITS, 4, compression::NONE),
    (tag::PROTOTYPES, size_of::<PrototypeRecord>() as u32, compression::NONE),
    (tag::PROTOTYPE_ROWS, 4, compression::NONE),
    (tag::PROTOTYPE_DIRECTIONS, 4, compression::NONE),
    (tag::PROTOTYPE_FACTORS, 4, compression::NONE),
    (tag::ORIENTATIONS, size_of::<OrientationRecord>() as u32, compression::NONE),
    (tag::ORIENTATION_MAPS, 4, compression::NONE),
    (tag::NONDIFFUSE_PATCHES, size_of::<NonDiffusePatchRecord>() as u32, compression::NONE),
    (tag::NONDIFFUSE_HITS, 4, compression::NONE),
    (tag::ANIMATION, size_of::<AnimationRecord>() as u32, compression::NONE),
    (tag::INSTANCES, size_of::<InstanceRecord>() as u32, compression::NONE),
    (tag::DELTA_INDEX, size_of::<DeltaIndexRecord>() as u32, compression::NONE),
    (tag::DELTAS, 0, compression::NONE),
    (tag::FRAME_CAMERAS, size_of::<CameraRecord>() as u32, compression::NONE),
    (tag::FRAME_EMISSION, 12, compression::NONE),
];

/// The header, table and section bounds of an archive held in `bytes`,
/// every section's checksum verified.
pub(super) fn validate_structure(bytes: &[u8]) -> Result<(HeaderRecord, Vec<SectionEntry>), ArchiveError> {
    let len = bytes.len() as u64;
    if bytes.len() < layout::HEADER_SIZE {
        return Err(bad(format!("file is {len} bytes, shorter than the header (truncated?)")));
    }
    let header = parse_header(&bytes[..layout::HEADER_SIZE], len, false)?;
    let table_end = header.table_offset + header.section_count as u64 * layout::ENTRY_SIZE as u64;
    let entries = parse_table(&header, &bytes[header.table_offset as usize..table_end as usize])?;
    check_entries(&header, &entries, &REQUIRED)?;
    for e in &entries {
        check_sum(e, &bytes[e.offset as usize..(e.offset + e.stored_length) as usize])?;
    }
    Ok((header, entries))
}

/// Like [`validate_structure`], read from `file` without the sections
/// (their checksums are the caller's to verify as it reads them).
pub(super) fn read_structure(
    file: &std::fs::File,
    path: &Path,
) -> Result<(HeaderRecord, Vec<SectionEntry>), ArchiveError> {
    read_structure_of(file, path, None)
}

/// The sections every file since version 6 requires but for the link-end
/// columns and their runs (`LOFF` is among them): what
/// [`crate::archive::upgrade`] checks an old file's table against.
pub(in crate::archive) fn required_common() -> Vec<(Tag, u32, u32)> {
    let link = [
        tag::LINK_OTHER,
        tag::LINK_COUNT,
        tag::LINK_ESCAPES,
        tag::LINK_DIRECTION,
        tag::LINK_RUN_OFFSETS,
        tag::LINK_RUNS,
    ];
    REQUIRED.iter().copied().filter(|(t, _, _)| !link.contains(t)).collect()
}

/// [`read_structure`], or, given `required`, the same for a file of any
/// `version_write` with those required sections (for upgrades).
pub(in crate::archive) fn read_structure_of(
    file: &std::fs::File,
    path: &Path,
    required: Option<&[(Tag, u32, u32)]>,
) -> Result<(HeaderRecord, Vec<SectionEntry>), ArchiveError> {
    let io = |e: std::io::Error| ArchiveError::Io { path: path.into(), source: e };
    let len = file.metadata().map_err(io)?.len();
    if len < layout::HEADER_SIZE as u64 {
        return Err(bad(format!("file is {len} bytes, shorter than the header (truncated?)")));
    }
    let mut head = [0u8; layout::HEADER_SIZE];
    stream_read(file, &mut head, 0).map_err(io)?;
    let header = parse_header(&head, len, required.is_some())?;
    let mut table = vec![0u8; header.section_count as usize * layout::ENTRY_SIZE];
    stream_read(file, &mut table, header.table_offset).map_err(io)?;
    let entries = parse_table(&header, &table)?;
    check_entries(&header, &entries, required.unwrap_or(&REQUIRED))?;
    Ok((header, entries))
}

pub(super) fn stream_read(file: &std::fs::File, buf: &mut [u8], offset: u64) -> std::io::Result<()> {
    stream::read_at(file, buf, offset)
}

/// Verifies a section's stored bytes against the table's checksum.
pub(super) fn check_sum(e: &SectionEntry, stored: &[u8]) -> Result<(), ArchiveError> {
    check_digest(e, xxh3_64(stored))
}

/// Verifies a section's checksum against `sum`, its stored bytes' XXH3-64.
pub(in crate::archive) fn check_digest(e: &SectionEntry, sum: u64) -> Result<(), ArchiveError> {
    if sum != e.checksum {
        return Err(bad(format!(
            "section {}: checksum mismatch (stored {:#018x}, computed {sum:#018x})",
            tag_name(e.tag),
            e.checksum
        )));
    }
    Ok(())
}

/// The header's rules (§7, step 1, bar the checksums of sections) for a
/// file of `len` bytes, and that its table lies in the file.
fn parse_header(bytes: &[u8], len: u64, outdated_ok: bool) -> Result<HeaderRecord, ArchiveError> {
    let header: HeaderRecord = pod_read_unaligned(&bytes[..layout::HEADER_SIZE]);
    if header.magic != layout::MAGIC {
        return Err(bad(format!("not an illumnet archive (magic {:02x?})", header.magic)));
    }
    let sum = xxh3_64(&bytes[..120]);
    if sum != header.header_checksum {
        return Err(bad(format!(
            "header checksum mismatch (stored {:#018x}, computed {sum:#018x})",
            header.header_checksum
        )));
    }
    if header.version_read > layout::READER_VERSION {
        return Err(ArchiveError::UnsupportedVersion { needs: header.version_read, supports: layout::READER_VERSION });
    }
    if header.version_read == 0 || header.version_write < header.version_read {
        return Err(bad(format!(
            "header: versions (write {}, read {}) must be at least 1, write no older than read",
            header.version_write, header.version_read
        )));
    }
    if header.version_write < layout::OLDEST_READABLE && !outdated_ok {
        return Err(ArchiveError::Outdated { written: header.version_write });
    }
    if header.header_size as usize != layout::HEADER_SIZE || header.entry_size as usize != layout::ENTRY_SIZE {
        return Err(bad(format!("unexpected header size {} or entry size {}", header.header_size, header.entry_size)));
    }
    if header.flags != 0 || header.reserved != [0; 8] {
        return Err(bad("reserved header fields are not zero"));
    }
    if header.file_length != len {
        return Err(bad(format!(
            "header says the file is {} bytes but it is {len} (truncated or appended to)",
            header.file_length
        )));
    }
    let table_len = header.section_count as u64 * layout::ENTRY_SIZE as u64;
    let table_end = header.table_offset.checked_add(table_len).ok_or_else(|| bad("section table offset overflows"))?;
    if header.table_offset < layout::HEADER_SIZE as u64 || !header.table_offset.is_multiple_of(8) || table_end > len {
        return Err(bad(format!(
            "section table ({} entries at offset {}) lies outside the file ({len} bytes)",
            header.section_count, header.table_offset
        )));
    }
    Ok(header)
}

/// The section table's checksum (§7, step 2) and its entries.
fn parse_table(header: &HeaderRecord, table: &[u8]) -> Result<Vec<SectionEntry>, ArchiveError> {
    let sum = xxh3_64(table);
    if sum != header.table_checksum {
        return Err(bad(format!(
            "section table checksum mismatch (stored {:#018x}, computed {sum:#018x})",
            header.table_checksum
        )));
    }
    Ok(table.chunks_exact(layout::ENTRY_SIZE).map(pod_read_unaligned::<SectionEntry>).collect())
}

/// The table's rules for every entry (§7, steps 3 and 4, bar checksums).
fn check_entries(
    header: &HeaderRecord,
    entries: &[SectionEntry],
    required: &[(Tag, u32, u32)],
) -> Result<(), ArchiveError> {
    let mut spans: Vec<(u64, u64, Tag)> = Vec::new();
    for (i, e) in entries.iter().enumerate() {
        let name = tag_name(e.tag);
        let end =
            e.offset.checked_add(e.stored_length).ok_or_else(|| bad(format!("section {name}: length overflows")))?;
        if e.offset < layout::HEADER_SIZE as u64 || end > header.table_offset {
            return Err(bad(format!(
                "section {name}: bytes {}..{end} lie outside the data area {}..{}",
                e.offset,
                layout::HEADER_SIZE,
                header.table_offset
            )));
        }
        if e.offset % layout::SECTION_ALIGN != 0 {
            return Err(bad(format!(
                "section {name}: offset {} is not {}-byte aligned",
                e.offset,
                layout::SECTION_ALIGN
            )));
        }
        if entries[..i].iter().any(|o| o.tag == e.tag) {
            return Err(bad(format!("section {name} appears twice")));
        }
        match e.compression {
            compression::NONE if e.length != e.stored_length => {
                return Err(bad(format!(
                    "section {name}: uncompressed but length {} ≠ stored {}",
                    e.length, e.stored_length
                )));
            }
            compression::ZSTD if e.length > e.stored_length.saturating_mul(layout::MAX_ZSTD_EXPANSION) => {
                return Err(bad(format!(
                    "section {name}: length {} is more than its {} stored bytes can hold",
                    e.length, e.stored_length
                )));
            }
            compression::NONE | compression::ZSTD => {}
            c => return Err(bad(format!("section {name}: unknown compression code {c}"))),
        }
        if e.record_size > 0 && e.count.checked_mul(e.record_size as u64) != Some(e.length) {
            return Err(bad(format!(
                "section {name}: {} records of {} bytes ≠ length {}",
                e.count, e.record_size, e.length
            )));
        }
        spans.push((e.offset, end, e.tag));
    }
    spans.sort_unstable();
    for w in spans.windows(2) {
        if w[1].0 < w[0].1 {
            return Err(bad(format!("sections {} and {} overlap", tag_name(w[0].2), tag_name(w[1].2))));
        }
    }
    for (t, size, comp) in OPTIONAL {
        if let Some(e) = entries.iter().find(|e| e.tag == t)
            && (e.record_size != size || e.compression != comp)
        {
            return Err(bad(format!(
                "section {}: record size {} / compression {} (expected {size} / {comp})",
                tag_name(t),
                e.record_size,
                e.compression
            )));
        }
    }
    let has = |t: Tag| entries.iter().any(|e| e.tag == t);
    let animated = [tag::ANIMATION, tag::INSTANCES, tag::DELTA_INDEX, tag::DELTAS].map(has);
    if animated.iter().any(|&x| x) && !animated.iter().all(|&x| x) {
        return Err(bad("sequence sections ANIM, INST, DIDX and DELT must appear together"));
    }
    let reflectance = [
        tag::PROTOTYPES,
        tag::PROTOTYPE_ROWS,
        tag::PROTOTYPE_DIRECTIONS,
        tag::PROTOTYPE_FACTORS,
        tag::ORIENTATIONS,
        tag::ORIENTATION_MAPS,
        tag::NONDIFFUSE_PATCHES,
        tag::NONDIFFUSE_HITS,
    ]
    .map(has);
    if has(tag::NONDIFFUSE_BACK_HITS) && !has(tag::NONDIFFUSE_HITS) {
        return Err(bad("NDBK without the reflectance sections it counts rays of (NDHC)"));
    }
    let shading = [tag::SHADING, tag::TEXTURES, tag::TEXELS].map(has);
    if shading.iter().any(|&x| x) && !shading.iter().all(|&x| x) {
        return Err(bad("shading sections PSHD, TXHD and TXPX must appear together"));
    }
    if reflectance.iter().any(|&x| x) && !reflectance.iter().all(|&x| x) {
        return Err(bad("reflectance sections PTAB, PROW, PODR, PFAC, ORNT, OMAP, NDPA and NDHC must appear together"));
    }
    if let Some(e) = entries.iter().find(|e| e.tag == tag::META)
        && e.count != 1
    {
        return Err(bad(format!("section META: count {} (expected 1)", e.count)));
    }
    for &(t, size, comp) in required {
        let e =
            entries.iter().find(|e| e.tag == t).ok_or_else(|| bad(format!("section {} is missing", tag_name(t))))?;
        if e.record_size != size || e.compression != comp {
            return Err(bad(format!(
                "section {}: record size {} / compression {} (expected {size} / {comp})",
                tag_name(t),
                e.record_size,
                e.compression
            )));
        }
    }
    Ok(())
}
