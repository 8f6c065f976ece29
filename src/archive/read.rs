//! Opening archives: map, validate everything, then hand out zero-copy views.

use std::borrow::Cow;
use std::path::{Path, PathBuf};

use bytemuck::{Pod, pod_read_unaligned};
use xxhash_rust::xxh3::xxh3_64;

use super::invariants::{self, WeightSums};
use super::layout::{
    self, AnimationRecord, BuildRecord, CameraRecord, DeltaIndexRecord, DeltaRecord, DirectionRecord, HeaderRecord,
    InstanceRecord, MaterialRecord, NonDiffusePatchRecord, OrientationRecord, PrimitiveRecord, PrototypeRecord,
    SectionEntry, SurfaceRecord, Tag, WeightEscape, compression, tag,
};
use super::links::{IdCheck, LinkRows, LinkRuns, LinkSlices, Links, check_rows, check_run_offsets};
use super::presence::{self, FramePresence, FrameSpan};
use super::stream::{self, LinkStream};
use super::weights::{self, Weights};
use super::{ArchiveError, ArchiveMeta, tag_name};
use crate::limits::{MAX_COORDINATE, MAX_PATCH_AREA, MAX_RADIANCE};

enum Storage {
    Mapped(memmap2::Mmap),
    /// `u64` words keep owned bytes 8-byte aligned, as mapped pages are.
    Owned(Vec<u64>, usize),
    /// Every section but the link-end columns, copied out of the file
    /// (streamed archives): per section, its file offset and where its
    /// bytes start in `words`.
    Sparse {
        words: Vec<u64>,
        spans: Vec<(u64, usize)>,
    },
}

impl Storage {
    /// The bytes of the section stored at `offset`, `len` long (already
    /// checked to lie in the file).
    fn section(&self, offset: u64, len: u64) -> &[u8] {
        match self {
            Storage::Mapped(m) => &m[offset as usize..(offset + len) as usize],
            Storage::Owned(words, _) => &bytemuck::cast_slice(words)[offset as usize..(offset + len) as usize],
            Storage::Sparse { words, spans } => {
                let at = spans.iter().find(|s| s.0 == offset).map_or(usize::MAX, |s| s.1);
                // A section not copied (a link column) has no bytes here.
                bytemuck::cast_slice(words).get(at..at + len as usize).unwrap_or(&[])
            }
        }
    }
}

/// Tags of the link-end columns a streamed archive reads from disk with
/// each window (it holds `LOFF` and `LROF`).
const LINK_COLUMNS: [Tag; 4] = [tag::LINK_OTHER, tag::LINK_COUNT, tag::LINK_DIRECTION, tag::LINK_RUNS];

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
}

/// A section left on disk: read in pieces with `pread` (never mapped, so a
/// file cut short under a render is an error, not a SIGBUS).
pub struct OnDisk {
    file: std::fs::File,
    path: PathBuf,
    offset: u64,
    len: u64,
}

/// Where a sequence's `DELT` bytes are: in memory (a mapped or owned
/// archive), or on disk (a streamed one), read one frame at a time and
/// checked against that frame's checksum (`DIDX`) when read.
#[derive(Clone, Copy)]
pub enum DeltaBytes<'a> {
    /// The whole payload.
    Held(&'a [u8]),
    /// The payload in the file.
    OnDisk(&'a OnDisk),
}

impl DeltaBytes<'_> {
    /// Bytes in the payload.
    pub fn len(&self) -> u64 {
        match self {
            DeltaBytes::Held(b) => b.len() as u64,
            DeltaBytes::OnDisk(d) => d.len,
        }
    }

    /// True when the payload is empty.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// What an archive's header, section table and build record say, read
/// without reading the sections (to plan how to open it).
#[derive(Clone, Debug)]
pub struct ArchiveSummary {
    /// Total file size in bytes.
    pub file_length: u64,
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

/// Zero-copy, typed views of a validated archive's sections.
#[derive(Clone, Copy)]
pub struct InetView<'a> {
    /// `BILD`.
    pub build: &'a BuildRecord,
    /// `CAMR`.
    pub camera: &'a CameraRecord,
    /// `SURF`.
    pub surfaces: &'a [SurfaceRecord],
    /// `MATL`.
    pub materials: &'a [MaterialRecord],
    /// `PRIM`.
    pub primitives: &'a [PrimitiveRecord],
    /// `DIRS`.
    pub directions: &'a [DirectionRecord],
    /// `PCEN`.
    pub patch_centre: &'a [[f32; 3]],
    /// `PNRM`.
    pub patch_normal: &'a [[f32; 3]],
    /// `PARE`.
    pub patch_area: &'a [f32],
    /// `PPRM`.
    pub patch_primitive: &'a [u32],
    /// `PCOR`.
    pub patch_corners: &'a [[u32; 4]],
    /// `PHIT`.
    pub patch_hits: &'a [u32],
    /// `PEXP`.
    pub patch_expected_hits: &'a [f32],
    /// `PBAK`: per patch, of its `PHIT` rays those whose light meets a back
    /// face (`None` in files written before version 9).
    pub patch_back_hits: Option<&'a [u32]>,
    /// `VPOS`.
    pub vertex_position: &'a [[f32; 3]],
    /// Corner vertex ids of each grouped triangle (`TVTX`; empty when
    /// there are none), indexed by the triangle's `first_vertex`.
    pub grouped_triangles: &'a [[u32; 3]],
    /// `ADJO`.
    pub adjacency_offsets: &'a [u32],
    /// `ADJI`.
    pub adjacency: &'a [u32],
    /// `LOFF`.
    pub link_offsets: &'a [u64],
    /// `LOTH`, `LCNT` with `LCNX`, `LDIR` and `LBKT` (when present, written since
    /// version 2: the bucket of the light each link end's owner
    /// receives), in memory or streamed from disk.
    pub links: Links<'a>,
    /// The animation sections of a sequence archive.
    pub sequence: Option<SequenceView<'a>>,
    /// The reflectance sections, when some material is not diffuse.
    pub reflectance: Option<ReflectanceView<'a>>,
    /// The shading sections, when some primitive has shading normals or a
    /// texture (§5.15).
    pub shading: Option<ShadingView<'a>>,
}

/// Zero-copy views of the shading sections (§5.15).
#[derive(Clone, Copy)]
pub struct ShadingView<'a> {
    /// `PSHD`: one record per primitive.
    pub primitives: &'a [layout::ShadingRecord],
    /// `TXHD`.
    pub textures: &'a [layout::TextureRecord],
    /// `TXPX`.
    pub texels: &'a [u8],
}

/// Zero-copy views of the reflectance sections (§5.14).
#[derive(Clone, Copy)]
pub struct ReflectanceView<'a> {
    /// `PTAB`.
    pub prototypes: &'a [PrototypeRecord],
    /// `PROW`.
    pub rows: &'a [u32],
    /// `PODR`.
    pub outgoing: &'a [u32],
    /// `PFAC`.
    pub factors: &'a [f32],
    /// `ORNT`.
    pub orientations: &'a [OrientationRecord],
    /// `OMAP`.
    pub maps: &'a [u32],
    /// `NDPA`.
    pub patches: &'a [NonDiffusePatchRecord],
    /// `NDHC`.
    pub hits: &'a [u32],
    /// `NDBK` (`None` in files written before version 9).
    pub back_hits: Option<&'a [u32]>,
    direction_count: usize,
}

impl<'a> ReflectanceView<'a> {
    /// Table `t`'s row `i`: outgoing directions and `bands` factors per entry.
    pub fn row(&self, t: usize, i: usize) -> (&'a [u32], &'a [f32]) {
        let r = &self.prototypes[t];
        debug_assert!(i < self.direction_count);
        let base = r.first_row as usize;
        let (a, b) = (self.rows[base + i] as usize, self.rows[base + i + 1] as usize);
        let e0 = r.first_entry as usize;
        let f0 = r.first_factor as usize;
        let k = r.bands as usize;
        (&self.outgoing[e0 + a..e0 + b], &self.factors[f0 + a * k..f0 + b * k])
    }

    /// Orientation `o`'s map: actual direction → prototype direction.
    pub fn map(&self, o: usize) -> &'a [u32] {
        &self.maps[o * self.direction_count..(o + 1) * self.direction_count]
    }

    /// Non-diffuse patch `k`'s ray counts per direction pair.
    pub fn pair_hits(&self, k: usize) -> &'a [u32] {
        let pairs = self.direction_count / 2;
        &self.hits[k * pairs..(k + 1) * pairs]
    }
}

/// Zero-copy views of a sequence archive's animation sections (§5.13).
#[derive(Clone, Copy)]
pub struct SequenceView<'a> {
    /// `ANIM`.
    pub record: &'a AnimationRecord,
    /// `INST`.
    pub instances: &'a [InstanceRecord],
    /// `DIDX`.
    pub index: &'a [DeltaIndexRecord],
    /// `DELT` payload.
    pub payload: DeltaBytes<'a>,
    /// `CAMF`: the camera of every frame, when it moves.
    pub cameras: Option<&'a [CameraRecord]>,
    /// `EMIF`: frames × surfaces emitted radiances, when emission is keyed.
    pub emissions: Option<&'a [[f32; 3]]>,
    patch_count: u32,
    pair_count: u32,
    max_bucket: u8,
    /// The `DELT` table entry's `count` (one per frame).
    payload_count: u64,
    /// Version 5 and later: `DIDX.checksum` covers the stored bytes and
    /// blocks hold columns; before, the checksum covered the decompressed
    /// records, stored as they are.
    version_5: bool,
}

impl SequenceView<'_> {
    /// Frames in the sequence.
    pub fn frames(&self) -> u32 {
        self.record.frames
    }

    /// Frame `frame`'s stored `DELT` bytes (its blocks), not yet checked
    /// against its checksum: borrowed when held, read from the file when
    /// the archive is streamed.
    pub fn frame_stored(&self, frame: u32) -> Result<Cow<'_, [u8]>, ArchiveError> {
        let Some(ix) = self.index.get(frame as usize) else {
            return Err(ArchiveError::corrupt(format!("frame {frame} is outside the sequence 0..{}", self.frames())));
        };
        // Validated when the archive was opened; checked again here, as the
        // view's fields are public.
        let end = ix.offset.checked_add(ix.stored_length).filter(|&e| e <= self.payload.len());
        let Some(end) = end else {
            return Err(bad(format!("DIDX[{frame}]: outside DELT")));
        };
        let range = ix.offset as usize..end as usize;
        match self.payload {
            DeltaBytes::Held(b) => Ok(Cow::Borrowed(&b[range])),
            DeltaBytes::OnDisk(d) => {
                let mut buf = vec![0u8; range.len()];
                stream::read_at(&d.file, &mut buf, d.offset + ix.offset)
                    .map_err(|e| stream::short(&d.path, &format!("DELT frame {frame}"), e))?;
                Ok(Cow::Owned(buf))
            }
        }
    }

    /// Decodes and validates frame `frame`'s changes relative to frame 0.
    /// The frame's links are frame 0's plus these, less every link with an
    /// end at a patch absent from the frame (§5.13, step 2: since version 6
    /// the records leave such links out).
    pub fn frame_delta(&self, frame: u32) -> Result<Vec<DeltaRecord>, ArchiveError> {
        let Some(ix) = self.index.get(frame as usize) else {
            return Err(ArchiveError::corrupt(format!("frame {frame} is outside the sequence 0..{}", self.frames())));
        };
        if ix.count == 0 {
            return Ok(Vec::new());
        }
        let stored = self.frame_stored(frame)?;
        let stored = &stored[..];
        if self.version_5 && xxh3_64(stored) != ix.checksum {
            return Err(bad(format!("DELT frame {frame}: checksum mismatch")));
        }
        let records = super::deltas::decode(stored, ix.count, frame, self.version_5)?;
        if !self.version_5 && xxh3_64(bytemuck::cast_slice(&records)) != ix.checksum {
            return Err(bad(format!("DELT frame {frame}: checksum mismatch after decompression")));
        }
        let key = |d: &DeltaRecord| (d.pair, d.a, d.b, d.bucket_a, d.bucket_b);
        if records.windows(2).any(|w| key(&w[0]) >= key(&w[1])) {
            return Err(bad(format!("DELT frame {frame}: records not sorted and unique")));
        }
        for (i, d) in records.iter().enumerate() {
            if d.a >= self.patch_count
                || d.b >= self.patch_count
                || d.pair >= self.pair_count
                || d.bucket_a > self.max_bucket
                || d.bucket_b > self.max_bucket
                || d.count == 0
            {
                return Err(bad(format!("DELT frame {frame}, record {i}: index out of range")));
            }
        }
        Ok(records)
    }
}

impl<'a> InetView<'a> {
    /// Frame `frame`'s delta records (§5.13), decoded, validated
    /// ([`SequenceView::frame_delta`]) and checked against frame 0's links
    /// and the hit counts: no record moves more rays than cross its
    /// patches, no link is left a negative weight. Empty for frame 0.
    pub fn frame_links(&self, frame: u32) -> Result<Vec<DeltaRecord>, ArchiveError> {
        self.frame_links_with(frame, |_| ()).map(|(records, ())| records)
    }

    /// [`Self::frame_links`], with `f` of the records (decoded, their
    /// indices in range) run while they are checked against frame 0's
    /// links: its result is returned only if the check passes. For work
    /// that would otherwise wait on the check, such as a frame's overlay.
    pub fn frame_links_with<T: Send>(
        &self,
        frame: u32,
        f: impl FnOnce(&[DeltaRecord]) -> T + Send,
    ) -> Result<(Vec<DeltaRecord>, T), ArchiveError> {
        let Some(s) = &self.sequence else {
            return match frame {
                0 => Ok((Vec::new(), f(&[]))),
                _ => Err(ArchiveError::corrupt(format!("frame {frame} asked of a still archive"))),
            };
        };
        let records = s.frame_delta(frame)?;
        let (checked, made) = rayon::join(
            || invariants::check_frame(frame, &records, self.patch_hits, self.link_offsets, &self.links),
            || f(&records),
        );
        checked?;
        Ok((records, made))
    }

    /// Number of patches.
    pub fn patch_count(&self) -> usize {
        self.patch_area.len()
    }

    /// Per primitive, the frames it is present in (every frame of a still).
    pub fn primitive_spans(&self) -> Vec<FrameSpan> {
        match &self.sequence {
            None => vec![FrameSpan::all(1); self.primitives.len()],
            Some(s) => presence::primitive_spans(s.instances, self.primitives.len()),
        }
    }

    /// The camera of `frame`: a sequence's own per frame, else the
    /// archive's one camera.
    pub fn camera_at(&self, frame: u32) -> CameraRecord {
        *self.sequence.and_then(|s| s.cameras).and_then(|c| c.get(frame as usize)).unwrap_or(self.camera)
    }

    /// Which primitives and patches are present at `frame` (all of them in
    /// a still archive), and so which links are links of the frame.
    pub fn presence(&self, frame: u32) -> FramePresence {
        FramePresence::new(frame, &self.primitive_spans(), self.patch_primitive)
    }

    /// The keyed emitted radiance of every surface at `frame` (`EMIF`),
    /// when the archive keys emission.
    pub fn keyed_emission(&self, frame: u32) -> Option<&'a [[f32; 3]]> {
        let n = self.surfaces.len();
        self.sequence.and_then(|s| s.emissions).and_then(|e| e.get(frame as usize * n..(frame as usize + 1) * n))
    }

    /// Per primitive, whether it is temporal: present in only some frames.
    pub fn temporal_primitives(&self) -> Vec<bool> {
        let frames = self.sequence.map_or(1, |s| s.frames());
        self.primitive_spans().iter().map(|s| s.is_temporal(frames)).collect()
    }

    /// Link ends in all.
    pub fn link_end_count(&self) -> usize {
        self.link_offsets.last().map_or(0, |&e| e as usize)
    }

    /// The link ends of `patches` (see [`Links::rows`]).
    pub fn link_rows(&self, patches: &[u32]) -> Result<LinkRows, ArchiveError> {
        self.links.rows(self.link_offsets, patches)
    }
}

fn bad(msg: impl Into<String>) -> ArchiveError {
    ArchiveError::corrupt(msg)
}

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

impl Archive {
    /// Maps and validates the archive at `path`.
    pub fn open(path: &Path) -> Result<Self, ArchiveError> {
        let io = |e: std::io::Error| ArchiveError::Io { path: path.into(), source: e };
        let file = std::fs::File::open(path).map_err(io)?;
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
        Self::from_storage(Storage::Mapped(map))
    }

    /// Opens the archive at `path` with its link ends streamed from disk
    /// in windows of about `window_ends` ends (see [`LinkStream`]): memory
    /// holds every other section, a window per worker (at least two), and
    /// one checksum per column per 65 536 ends. Validation is that of [`Self::open`], the link
    /// columns read once, in chunks, without mapping the file.
    pub fn open_streamed(path: &Path, window_ends: usize) -> Result<Self, ArchiveError> {
        let io = |e: std::io::Error| ArchiveError::Io { path: path.into(), source: e };
        let file = std::fs::File::open(path).map_err(io)?;
        let (header, entries) = read_structure(&file, path)?;
        let mut words = Vec::new();
        let mut spans = Vec::new();
        // The link columns and `DELT` stay on disk; the stream holds `LCNX`
        // itself.
        let on_disk = |t: Tag| LINK_COLUMNS.contains(&t) || t == tag::LINK_ESCAPES || t == tag::DELTAS;
        for e in entries.iter().filter(|e| !on_disk(e.tag)) {
            let at = words.len() * 8;
            words.resize(words.len() + (e.stored_length as usize).div_ceil(8), 0u64);
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
        let file = std::fs::File::open(path).map_err(io)?;
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
        let camera: CameraRecord =
            pod_read_unaligned(&record(tag::CAMERA, size_of::<CameraRecord>())?[..size_of::<CameraRecord>()]);
        let (mut max_delta_records, mut max_delta_stored) = (0, 0);
        if let Some(e) = entries.iter().find(|e| e.tag == tag::DELTA_INDEX) {
            let mut buf = vec![0u8; e.stored_length as usize];
            stream_read(&file, &mut buf, e.offset).map_err(io)?;
            check_sum(e, &buf)?;
            let records =
                || buf.chunks_exact(size_of::<DeltaIndexRecord>()).map(pod_read_unaligned::<DeltaIndexRecord>);
            max_delta_records = records().map(|r| r.count).max().unwrap_or(0);
            // Capped by the payload: DIDX ranges are checked only at open.
            let payload = entries.iter().find(|e| e.tag == tag::DELTAS).map_or(0, |e| e.stored_length);
            max_delta_stored = records().map(|r| r.stored_length).max().unwrap_or(0).min(payload);
        }
        Ok(ArchiveSummary {
            file_length: header.file_length,
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
            Storage::Mapped(m) => &m[..],
            Storage::Owned(words, len) => &bytemuck::cast_slice(words)[..*len],
            Storage::Sparse { .. } => unreachable!("sparse storage is made by open_streamed"),
        };
        let (header, entries) = validate_structure(bytes)?;
        let mut archive =
            Self { storage, header, entries, meta: ArchiveMeta::default(), stream: None, deltas_on_disk: None };
        archive.meta = archive.read_meta()?;
        validate_contents(&archive.view_unchecked()?, &archive.meta, archive.header.version_read)?;
        Ok(archive)
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
            Storage::Mapped(_) => 0,
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

    fn view_unchecked(&self) -> Result<InetView<'_>, ArchiveError> {
        Ok(InetView {
            build: self.one(tag::BUILD)?,
            camera: self.one(tag::CAMERA)?,
            surfaces: self.column(tag::SURFACES)?,
            materials: self.column(tag::MATERIALS)?,
            primitives: self.column(tag::PRIMITIVES)?,
            directions: self.column(tag::DIRECTIONS)?,
            patch_centre: self.column(tag::PATCH_CENTRE)?,
            patch_normal: self.column(tag::PATCH_NORMAL)?,
            patch_area: self.column(tag::PATCH_AREA)?,
            patch_primitive: self.column(tag::PATCH_PRIMITIVE)?,
            patch_corners: self.column(tag::PATCH_CORNERS)?,
            patch_hits: self.column(tag::PATCH_HITS)?,
            patch_expected_hits: self.column(tag::PATCH_EXPECTED_HITS)?,
            patch_back_hits: self.optional_column(tag::PATCH_BACK_HITS)?,
            vertex_position: self.column(tag::VERTEX_POSITION)?,
            grouped_triangles: match self.entries.iter().any(|e| e.tag == tag::GROUPED_TRIANGLE_VERTICES) {
                true => self.column(tag::GROUPED_TRIANGLE_VERTICES)?,
                false => &[],
            },
            adjacency_offsets: self.column(tag::ADJACENCY_OFFSETS)?,
            adjacency: self.column(tag::ADJACENCY)?,
            link_offsets: self.column(tag::LINK_OFFSETS)?,
            links: match &self.stream {
                // Checked when the stream was opened; the runs come with
                // each window.
                Some(stream) => Links::Streamed(
                    stream,
                    LinkRuns::validated(self.column(tag::LINK_OFFSETS)?, self.column(tag::LINK_RUN_OFFSETS)?, &[], 0),
                ),
                None => {
                    let b: &BuildRecord = self.one(tag::BUILD)?;
                    // Checked by `validate_contents` (runs against `LOFF`,
                    // ids against runs) before any view leaves `open`.
                    let runs = LinkRuns::validated(
                        self.column(tag::LINK_OFFSETS)?,
                        self.column(tag::LINK_RUN_OFFSETS)?,
                        self.column(tag::LINK_RUNS)?,
                        0,
                    );
                    Links::Resident(LinkSlices::validated(
                        self.column(tag::LINK_OTHER)?,
                        // Every LCNX record, so that validation sees extras.
                        Weights::whole(self.column(tag::LINK_COUNT)?, self.column(tag::LINK_ESCAPES)?),
                        self.column(tag::LINK_DIRECTION)?,
                        runs,
                        b.patch_count as usize,
                    ))
                }
            },
            sequence: match self.entries.iter().any(|e| e.tag == tag::ANIMATION) {
                false => None,
                true => {
                    let b: &BuildRecord = self.one(tag::BUILD)?;
                    Some(SequenceView {
                        record: self.one(tag::ANIMATION)?,
                        instances: self.column(tag::INSTANCES)?,
                        index: self.column(tag::DELTA_INDEX)?,
                        payload: match &self.deltas_on_disk {
                            Some(d) => DeltaBytes::OnDisk(d),
                            None => DeltaBytes::Held(self.stored(self.entry(tag::DELTAS)?)),
                        },
                        payload_count: self.entry(tag::DELTAS)?.count,
                        cameras: match self.entries.iter().any(|e| e.tag == tag::FRAME_CAMERAS) {
                            true => Some(self.column(tag::FRAME_CAMERAS)?),
                            false => None,
                        },
                        emissions: match self.entries.iter().any(|e| e.tag == tag::FRAME_EMISSION) {
                            true => Some(self.column(tag::FRAME_EMISSION)?),
                            false => None,
                        },
                        patch_count: b.patch_count,
                        pair_count: b.direction_count / 2,
                        max_bucket: b.max_bucket.min(255) as u8,
                        version_5: self.header.version_write >= layout::VERSION_DELTA_BLOCKS,
                    })
                }
            },
            reflectance: match self.entries.iter().any(|e| e.tag == tag::PROTOTYPES) {
                false => None,
                true => Some(ReflectanceView {
                    prototypes: self.column(tag::PROTOTYPES)?,
                    rows: self.column(tag::PROTOTYPE_ROWS)?,
                    outgoing: self.column(tag::PROTOTYPE_DIRECTIONS)?,
                    factors: self.column(tag::PROTOTYPE_FACTORS)?,
                    orientations: self.column(tag::ORIENTATIONS)?,
                    maps: self.column(tag::ORIENTATION_MAPS)?,
                    patches: self.column(tag::NONDIFFUSE_PATCHES)?,
                    hits: self.column(tag::NONDIFFUSE_HITS)?,
                    back_hits: self.optional_column(tag::NONDIFFUSE_BACK_HITS)?,
                    direction_count: self.one::<BuildRecord>(tag::BUILD)?.direction_count as usize,
                }),
            },
            shading: match self.optional_column(tag::SHADING)? {
                None => None,
                Some(primitives) => Some(ShadingView {
                    primitives,
                    textures: self.column(tag::TEXTURES)?,
                    texels: self.column(tag::TEXELS)?,
                }),
            },
        })
    }

    /// Typed zero-copy views of every section.
    pub fn view(&self) -> InetView<'_> {
        self.view_unchecked().expect("sections were validated when the archive was opened")
    }
}

/// The header, table and section bounds of an archive held in `bytes`,
/// every section's checksum verified.
fn validate_structure(bytes: &[u8]) -> Result<(HeaderRecord, Vec<SectionEntry>), ArchiveError> {
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
fn read_structure(file: &std::fs::File, path: &Path) -> Result<(HeaderRecord, Vec<SectionEntry>), ArchiveError> {
    read_structure_of(file, path, None)
}

/// The sections every file since version 6 requires but for the link-end
/// columns and their runs (`LOFF` is among them): what
/// [`crate::archive::upgrade`] checks an old file's table against.
pub(super) fn required_common() -> Vec<(Tag, u32, u32)> {
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
pub(super) fn read_structure_of(
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

fn stream_read(file: &std::fs::File, buf: &mut [u8], offset: u64) -> std::io::Result<()> {
    stream::read_at(file, buf, offset)
}

/// Verifies a section's stored bytes against the table's checksum.
fn check_sum(e: &SectionEntry, stored: &[u8]) -> Result<(), ArchiveError> {
    check_digest(e, xxh3_64(stored))
}

/// Verifies a section's checksum against `sum`, its stored bytes' XXH3-64.
pub(super) fn check_digest(e: &SectionEntry, sum: u64) -> Result<(), ArchiveError> {
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

fn check(ok: bool, msg: impl FnOnce() -> String) -> Result<(), ArchiveError> {
    if ok { Ok(()) } else { Err(bad(msg())) }
}

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

/// Whether the primitives' patch blocks tile the patches `0..P` (§5.5):
/// blocks in primitive order are checked by where the last ended, with no
/// memory; from the first block out of that order on (a spatial patch
/// order, since version 11), by a bit per patch (P/8 bytes, 1/128 of the
/// distribution's per-patch state), so that no block overlaps another.
/// Blocks within 0..P that do not overlap and cover P patches in all tile
/// them.
struct BlockTiling {
    patches: u64,
    covered: u64,
    /// Set once a block comes out of primitive order: every patch of the
    /// blocks seen so far.
    seen: Option<Vec<u64>>,
}

impl BlockTiling {
    fn new(patches: u64) -> Self {
        Self { patches, covered: 0, seen: None }
    }

    /// Adds a block of `cells` patches from `first`: false when it lies
    /// beyond the patches or overlaps a block added before.
    fn add(&mut self, first: u64, cells: u64) -> bool {
        let Some(end) = first.checked_add(cells).filter(|&e| e <= self.patches) else { return false };
        if self.seen.is_none() {
            if first == self.covered {
                self.covered = end;
                return true;
            }
            // Out of order: the blocks so far cover 0..covered.
            let mut bits = vec![0u64; self.patches.div_ceil(64) as usize];
            for q in 0..self.covered {
                bits[(q / 64) as usize] |= 1 << (q % 64);
            }
            self.seen = Some(bits);
        }
        let bits = self.seen.as_mut().expect("set above");
        for q in first..end {
            let (w, b) = ((q / 64) as usize, 1u64 << (q % 64));
            if bits[w] & b != 0 {
                return false;
            }
            bits[w] |= b;
        }
        self.covered += cells;
        true
    }

    /// Patches the blocks cover (P when they tile them).
    fn covered(&self) -> u64 {
        self.covered
    }

    /// Whether every block so far began where the one before it ended.
    fn in_order(&self) -> bool {
        self.seen.is_none()
    }
}

/// Checks counts and every stored index, so that later code can index
/// without bounds surprises; `version_read` is the header's (rules that
/// depend on it).
fn validate_contents(v: &InetView<'_>, meta: &ArchiveMeta, version_read: u32) -> Result<(), ArchiveError> {
    let b = v.build;
    let (p, nv, nd) = (b.patch_count as usize, b.vertex_count as usize, b.direction_count as usize);
    let count = |name: &str, got: usize, want: usize| {
        check(got == want, || format!("section {name}: {got} records, expected {want}"))
    };
    count("SURF", v.surfaces.len(), b.surface_count as usize)?;
    count("MATL", v.materials.len(), b.material_count as usize)?;
    count("PRIM", v.primitives.len(), b.primitive_count as usize)?;
    count("DIRS", v.directions.len(), nd)?;
    let f = b.frequency as u64;
    let expected_dirs = match b.direction_set {
        0 if (1..=crate::limits::MAX_FREQUENCY as u64).contains(&f) => 10 * f * f + 2,
        1 if (1..=100).contains(&f) => 6 * f * f,
        _ => u64::MAX,
    };
    check(nd as u64 == expected_dirs, || {
        format!("BILD: direction set {} with frequency {f} does not give {nd} directions", b.direction_set)
    })?;
    check(b.max_bucket <= layout::MAX_BUCKET, || format!("BILD: max bucket {} out of range", b.max_bucket))?;
    for (name, n) in [
        ("PCEN", v.patch_centre.len()),
        ("PNRM", v.patch_normal.len()),
        ("PARE", v.patch_area.len()),
        ("PPRM", v.patch_primitive.len()),
        ("PCOR", v.patch_corners.len()),
        ("PHIT", v.patch_hits.len()),
        ("PEXP", v.patch_expected_hits.len()),
    ] {
        count(name, n, p)?;
    }
    if let Some(back) = v.patch_back_hits {
        count("PBAK", back.len(), p)?;
        if let Some(i) = back.iter().zip(v.patch_hits).position(|(b, h)| b > h) {
            return Err(bad(format!(
                "PBAK[{i}]: {} back-face rays, more than its {} PHIT rays",
                back[i], v.patch_hits[i]
            )));
        }
    }
    count("VPOS", v.vertex_position.len(), nv)?;
    count("ADJO", v.adjacency_offsets.len(), p + 1)?;
    count("LOFF", v.link_offsets.len(), p + 1)?;
    count("META surface names", meta.surface_names.len(), v.surfaces.len())?;
    count("META material names", meta.material_names.len(), v.materials.len())?;
    check(b.ray_spacing_m.is_finite() && b.ray_spacing_m > 0.0, || "BILD: ray spacing must be positive".into())?;

    let c = v.camera;
    check(camera_geometry(c), || "CAMR: position, look_at or up non-finite, beyond ±1e9 m or degenerate".into())?;
    check(c.fov_y_deg > 0.0 && c.fov_y_deg < 180.0, || format!("CAMR: field of view {}", c.fov_y_deg))?;
    check((1..=16384).contains(&c.width) && (1..=16384).contains(&c.height), || {
        "CAMR: image size out of range".into()
    })?;

    for (i, m) in v.materials.iter().enumerate() {
        use layout::model::{BROAD_SPECULAR, DIFFUSE, ROUGH_CONDUCTOR};
        check([DIFFUSE, ROUGH_CONDUCTOR, BROAD_SPECULAR].contains(&m.model), || {
            format!("MATL[{i}]: unknown model {}", m.model)
        })?;
        check(finite(&m.params), || format!("MATL[{i}]: non-finite parameter"))?;
        check(m.params[..6].iter().all(|r| (0.0..=1.0).contains(r)), || {
            format!("MATL[{i}]: reflectance outside [0, 1]")
        })?;
        check((0..3).all(|c| m.params[c] + m.params[3 + c] <= 1.0 + 1e-6), || {
            format!("MATL[{i}]: reflectance + specular above 1")
        })?;
    }
    for (i, s) in v.surfaces.iter().enumerate() {
        check((s.material as usize) < v.materials.len(), || {
            format!("SURF[{i}]: material {} out of range", s.material)
        })?;
        check(s.emission.iter().all(|e| (0.0..=MAX_RADIANCE).contains(e)), || {
            format!("SURF[{i}]: emission {:?} outside [0, {MAX_RADIANCE:e}]", s.emission)
        })?;
        check(s.first_primitive as u64 + s.primitive_count as u64 <= v.primitives.len() as u64, || {
            format!("SURF[{i}]: primitives out of range")
        })?;
    }
    // A material no surface's primitives use needs no tables (§5.14).
    for (i, s) in v.surfaces.iter().enumerate() {
        check(
            v.materials[s.material as usize].model == layout::model::DIFFUSE
                || s.primitive_count == 0
                || v.reflectance.is_some(),
            || format!("SURF[{i}]: a non-diffuse material needs the reflectance sections"),
        )?;
    }
    let (mut next_vertex, mut next_grouped) = (0u64, 0u64);
    // Each primitive's patch block: since version 11 in any order, tiling
    // the patches.
    let mut tiling = BlockTiling::new(p as u64);
    let tiles = |i: usize, first: u32, cells: u64, ok: bool| {
        check(ok, || {
            format!(
                "PRIM[{i}]: its patches {first}..{} overlap another primitive's or lie beyond the {p} patches \
                 (a grid's cells, or a grouped triangle's patch, new or its predecessor's)",
                first as u64 + cells
            )
        })
    };
    for (i, r) in v.primitives.iter().enumerate() {
        check(r.kind <= layout::kind::GROUPED_TRIANGLE, || format!("PRIM[{i}]: unknown kind {}", r.kind))?;
        check(
            (r.cell_order == layout::cell_order::ROWS
                || (r.kind == layout::kind::QUAD && r.cell_order == layout::cell_order::TILES))
                && r.reserved == 0,
            || format!("PRIM[{i}]: unknown cell order {} for kind {} (or reserved not zero)", r.cell_order, r.kind),
        )?;
        check((r.surface as usize) < v.surfaces.len(), || format!("PRIM[{i}]: surface out of range"))?;
        check(r.corners.iter().all(|c| within(c)), || format!("PRIM[{i}]: corner non-finite or beyond ±1e9 m"))?;
        let (gu, gv) = (r.grid_u as u64, r.grid_v as u64);
        if r.kind == layout::kind::GROUPED_TRIANGLE {
            // One cell: a new patch, or the patch of the previous
            // primitive, a grouped triangle of the same surface.
            let joins = i > 0 && {
                let q = &v.primitives[i - 1];
                q.kind == layout::kind::GROUPED_TRIANGLE && q.surface == r.surface && q.first_patch == r.first_patch
            };
            check(gu == 1 && gv == 1 && r.first_vertex as u64 == next_grouped, || {
                format!("PRIM[{i}]: a grouped triangle must have one cell and its TVTX row in order")
            })?;
            if !joins {
                tiles(i, r.first_patch, 1, tiling.add(r.first_patch as u64, 1))?;
            }
            next_grouped += 1;
            continue;
        }
        check(gu >= 1 && gv >= 1 && gu <= 1 << 16 && gv <= 1 << 16 && (r.kind == 0 || gu == gv), || {
            format!("PRIM[{i}]: bad grid {gu}×{gv}")
        })?;
        let (cells, verts) =
            if r.kind == 0 { (gu * gv, (gu + 1) * (gv + 1)) } else { (gu * gu, (gu + 1) * (gu + 2) / 2) };
        check(r.first_vertex as u64 == next_vertex, || format!("PRIM[{i}]: vertices not contiguous"))?;
        tiles(i, r.first_patch, cells, tiling.add(r.first_patch as u64, cells))?;
        next_vertex += verts;
    }
    check(tiling.covered() == p as u64, || {
        format!("PRIM: the primitives' patch blocks cover {} of the {p} patches", tiling.covered())
    })?;
    // A spatial patch order (§5.5): version 10 readers refuse it, so the
    // file must say it needs 11; a sequence's instances keep their
    // patches together (the warm starts pair an instance's patches with
    // its predecessor's as ranges).
    if !tiling.in_order() {
        check(version_read >= layout::VERSION_READ_SPATIAL, || {
            format!("PRIM: patch blocks out of primitive order in a file whose version_read is {version_read}, not 11")
        })?;
        check(v.sequence.is_none(), || "PRIM: patch blocks out of primitive order in a sequence archive".into())?;
    }
    // Grouped triangles' corners come after the grids' vertices.
    check(
        next_vertex <= nv as u64
            && (next_grouped > 0 || next_vertex == nv as u64)
            && next_grouped == v.grouped_triangles.len() as u64,
        || "PRIM: grids and grouped triangles do not cover all vertices and TVTX rows".into(),
    )?;
    for (i, t) in v.grouped_triangles.iter().enumerate() {
        check(t.iter().all(|&c| c as u64 >= next_vertex && (c as usize) < nv), || {
            format!("TVTX[{i}]: a corner is not a vertex after the grids' ({next_vertex}..{nv})")
        })?;
    }
    for (i, d) in v.directions.iter().enumerate() {
        check(finite(&d.direction), || format!("DIRS[{i}]: non-finite"))?;
        let len2: f32 = d.direction.iter().map(|x| x * x).sum();
        check((len2 - 1.0).abs() < 1e-3, || format!("DIRS[{i}]: not a unit vector"))?;
        check(d.solid_angle_sr.is_finite() && d.solid_angle_sr > 1e-9, || format!("DIRS[{i}]: bad solid angle"))?;
        check(d.neighbours.iter().all(|&n| n == u32::MAX || (n as usize) < nd), || {
            format!("DIRS[{i}]: neighbour out of range")
        })?;
    }
    for i in 0..p {
        check(
            within(&v.patch_centre[i])
                && finite(&v.patch_normal[i])
                && v.patch_area[i].is_finite()
                && v.patch_area[i] >= 0.0,
            || format!("patch {i}: non-finite geometry"),
        )?;
        check((v.patch_primitive[i] as usize) < v.primitives.len(), || format!("PPRM[{i}]: out of range"))?;
        check(v.patch_corners[i].iter().all(|&c| c == u32::MAX || (c as usize) < nv), || {
            format!("PCOR[{i}]: out of range")
        })?;
        check(v.patch_area[i] <= MAX_PATCH_AREA, || {
            format!("PARE[{i}]: area {} m² above {MAX_PATCH_AREA:e}", v.patch_area[i])
        })?;
        // PEXP = A·Σ_d max(0, n·d)·Ω_d/Ω̄/δ² ≤ A·N/δ² (the ray-space
        // baseline's is below it too): so A·H/PEXP ≥ H·δ²/N, the least
        // area the distribution divides by.
        let most = v.patch_area[i] as f64 * nd as f64 / (b.ray_spacing_m as f64).powi(2);
        check(
            v.patch_expected_hits[i].is_finite()
                && v.patch_expected_hits[i] >= 0.0
                && v.patch_expected_hits[i] as f64 <= most * (1.0 + 1e-3) + 1e-3,
            || {
                format!(
                    "PEXP[{i}]: {} expected hits, more than area {} m² can have ({most:.3e})",
                    v.patch_expected_hits[i], v.patch_area[i]
                )
            },
        )?;
    }
    check(v.vertex_position.iter().all(|x| within(x)), || "VPOS: vertex non-finite or beyond ±1e9 m".into())?;
    csr("ADJO", v.adjacency_offsets.iter().map(|&x| x as u64), v.adjacency.len())?;
    check(v.adjacency.iter().all(|&a| (a as usize) < p), || "ADJI: patch id out of range".into())?;
    // Ascending, no self-loops, symmetric (§5.9): bucket rings rely on it.
    let row = |q: usize| &v.adjacency[v.adjacency_offsets[q] as usize..v.adjacency_offsets[q + 1] as usize];
    for q in 0..p {
        let r = row(q);
        check(r.windows(2).all(|w| w[0] < w[1]) && !r.contains(&(q as u32)), || format!("ADJI[{q}]: not ascending"))?;
        check(r.iter().all(|&o| row(o as usize).binary_search(&(q as u32)).is_ok()), || {
            format!("ADJI[{q}]: adjacency not symmetric")
        })?;
    }
    match v.links {
        Links::Resident(l) => {
            let ends = l.local_ids().len();
            count("LCNT", l.weight.len(), ends)?;
            count("LDIR", l.direction.len(), ends)?;
            check(b.link_end_count == ends as u64, || "BILD: link end count disagrees with LOTH".into())?;
            csr("LOFF", v.link_offsets.iter().copied(), ends)?;
            let runs = l.runs.records();
            check_run_offsets(l.runs.offsets(), p, runs.len() as u64).map_err(bad)?;
            check_rows(v.link_offsets, l.runs.offsets(), 0..p, runs, b.max_bucket.min(255) as u8).map_err(bad)?;
            let mut ids = IdCheck::new(runs.iter().copied(), p);
            check(ids.add(l.local_ids()) && ids.done(), || "LOTH: patch id out of range".into())?;
            let escapes = l.weight.escapes();
            let mut next = 0;
            weights::check(l.weight.counts(), 0, escapes, &mut next).map_err(ArchiveError::Corrupt)?;
            check(next == escapes.len(), || {
                format!("LCNX: {} entries, but LCNT has {next} zero counts", escapes.len())
            })?;
            WeightSums::new(v.link_offsets, v.patch_hits).add(l.weight)?;
            check(l.direction.iter().all(|&d| (d as usize) < nd), || "LDIR: direction out of range".into())?;
        }
        // The stream checked its columns' lengths and content as it
        // opened them (`LinkStream::open`), and `LOFF` before that.
        Links::Streamed(s, _) => {
            check(b.link_end_count == s.ends() as u64, || "BILD: link end count disagrees with LOFF".into())?;
        }
    }
    if let Some(r) = &v.reflectance {
        validate_reflectance(v, r)?;
    }
    if let Some(sh) = &v.shading {
        validate_shading(v, sh)?;
    }
    if let Some(s) = &v.sequence {
        let frames = s.record.frames;
        check(frames >= 1, || "ANIM: no frames".into())?;
        check(s.record.fps.is_finite() && s.record.fps > 0.0, || "ANIM: fps must be positive".into())?;
        count("INST", s.instances.len(), s.record.instance_count as usize)?;
        count("DIDX", s.index.len(), frames as usize)?;
        check(s.payload_count == frames as u64, || {
            format!("section DELT: count {} in the table, expected {frames} frames", s.payload_count)
        })?;
        let mut next = 0u64;
        for (i, r) in s.instances.iter().enumerate() {
            check(r.first_primitive as u64 == next && r.primitive_count > 0, || {
                format!("INST[{i}]: primitives not contiguous")
            })?;
            next += r.primitive_count as u64;
            check(r.frame_first <= r.frame_last && r.frame_last < frames, || format!("INST[{i}]: bad frame range"))?;
            check((r.surface as usize) < v.surfaces.len(), || format!("INST[{i}]: surface out of range"))?;
        }
        check(next == v.primitives.len() as u64, || "INST: instances do not cover all primitives".into())?;
        if let Some(cams) = s.cameras {
            count("CAMF", cams.len(), frames as usize)?;
            for (f, c) in cams.iter().enumerate() {
                check(camera_geometry(c), || format!("CAMF[{f}]: non-finite, beyond ±1e9 m or degenerate"))?;
                check(c.fov_y_deg > 0.0 && c.fov_y_deg < 180.0, || format!("CAMF[{f}]: field of view"))?;
                check((c.width, c.height) == (v.camera.width, v.camera.height), || {
                    format!("CAMF[{f}]: image size differs from CAMR")
                })?;
            }
        }
        if let Some(e) = s.emissions {
            count("EMIF", e.len(), frames as usize * v.surfaces.len())?;
            check(e.iter().all(|x| x.iter().all(|c| (0.0..=MAX_RADIANCE).contains(c))), || {
                format!("EMIF: emission outside [0, {MAX_RADIANCE:e}]")
            })?;
        }
        for (f, ix) in s.index.iter().enumerate() {
            let end = ix.offset.checked_add(ix.stored_length);
            check(end.is_some_and(|e| e <= s.payload.len()), || format!("DIDX[{f}]: outside DELT"))?;
            check(
                ix.count <= u32::MAX as u64 && (ix.count == 0) == (ix.stored_length == 0) && (f > 0 || ix.count == 0),
                || format!("DIDX[{f}]: bad count"),
            )?;
        }
    }
    Ok(())
}

/// Largest texture side (texels) and coordinate magnitude (§5.15).
const MAX_TEXTURE_SIDE: u32 = 16384;
const MAX_UV: f32 = 1e6;
const MAX_TINT: f32 = 1e6;

/// §5.15: one `PSHD` record per primitive, flags and textures in range,
/// every float finite; each texture's texels inside `TXPX`.
fn validate_shading(v: &InetView<'_>, sh: &ShadingView<'_>) -> Result<(), ArchiveError> {
    check(sh.primitives.len() == v.primitives.len(), || {
        format!("PSHD: {} records, expected {} (one per primitive)", sh.primitives.len(), v.primitives.len())
    })?;
    for (i, t) in sh.textures.iter().enumerate() {
        let side = 1..=MAX_TEXTURE_SIDE;
        check(side.contains(&t.width) && side.contains(&t.height), || format!("TXHD[{i}]: size out of range"))?;
        check(t.wrap.iter().all(|&w| w <= 2) && t.filter <= 1, || format!("TXHD[{i}]: unknown wrap or filter"))?;
        let bytes = 3 * t.width as u64 * t.height as u64;
        check(t.first_byte.checked_add(bytes).is_some_and(|end| end <= sh.texels.len() as u64), || {
            format!("TXHD[{i}]: texels beyond TXPX's {} bytes", sh.texels.len())
        })?;
    }
    for (i, r) in sh.primitives.iter().enumerate() {
        use layout::shading_flags::{NORMALS, TEXTURE};
        check(r.flags & !(NORMALS | TEXTURE) == 0, || format!("PSHD[{i}]: unknown flags {:#x}", r.flags))?;
        check(r.flags & TEXTURE == 0 || (r.texture as usize) < sh.textures.len(), || {
            format!("PSHD[{i}]: texture {} out of range", r.texture)
        })?;
        check(r.tint.iter().all(|t| t.is_finite() && (0.0..=MAX_TINT).contains(t)), || {
            format!("PSHD[{i}]: tint negative, non-finite or above {MAX_TINT:e}")
        })?;
        check(r.normals.iter().flatten().all(|x| x.is_finite() && x.abs() <= 1.0 + 1e-3), || {
            format!("PSHD[{i}]: a normal is not a finite direction")
        })?;
        check(r.uvs.iter().flatten().all(|x| x.is_finite() && x.abs() <= MAX_UV), || {
            format!("PSHD[{i}]: a texture coordinate is non-finite or beyond ±{MAX_UV:e}")
        })?;
    }
    Ok(())
}

/// §5.14: tables well formed and energy-conserving, maps bijections,
/// exactly the non-diffuse patches listed.
fn validate_reflectance(v: &InetView<'_>, r: &ReflectanceView<'_>) -> Result<(), ArchiveError> {
    let n = v.directions.len();
    let (mut row, mut entry, mut factor) = (0u64, 0u64, 0u64);
    for (t, p) in r.prototypes.iter().enumerate() {
        check(finite(&[p.alpha_u, p.alpha_v, p.threshold]) && finite(&p.ior), || {
            format!("PTAB[{t}]: non-finite parameter")
        })?;
        check(p.ior.iter().all(|&x| x >= 0.0) && p.alpha_u >= 0.0 && p.alpha_v >= 0.0, || {
            format!("PTAB[{t}]: negative roughness or index of refraction")
        })?;
        check(p.model <= layout::table_model::GGX && (p.bands == 1 || p.bands == 3), || {
            format!("PTAB[{t}]: unknown model {} or bands {}", p.model, p.bands)
        })?;
        check(p.first_row == row && p.first_entry == entry && p.first_factor == factor, || {
            format!("PTAB[{t}]: tables not contiguous")
        })?;
        row += n as u64 + 1;
        entry = entry.checked_add(p.entry_count).ok_or_else(|| bad(format!("PTAB[{t}]: entry count overflows")))?;
        factor = p
            .entry_count
            .checked_mul(p.bands as u64)
            .and_then(|x| x.checked_add(factor))
            .ok_or_else(|| bad(format!("PTAB[{t}]: factor count overflows")))?;
        check(
            row <= r.rows.len() as u64 && entry <= r.outgoing.len() as u64 && factor <= r.factors.len() as u64,
            || format!("PTAB[{t}]: rows or entries outside PROW/PODR/PFAC"),
        )?;
        let rows = &r.rows[p.first_row as usize..row as usize];
        csr(&format!("PROW (table {t})"), rows.iter().map(|&x| x as u64), p.entry_count as usize)?;
    }
    check(row == r.rows.len() as u64 && entry == r.outgoing.len() as u64 && factor == r.factors.len() as u64, || {
        "PROW/PODR/PFAC hold more than the tables".into()
    })?;
    check(r.outgoing.iter().all(|&o| (o as usize) < n), || "PODR: direction out of range".into())?;
    for t in 0..r.prototypes.len() {
        for i in 0..n {
            check(r.row(t, i).0.windows(2).all(|w| w[0] < w[1]), || format!("PTAB[{t}]: row {i} not ascending"))?;
        }
    }
    check(r.factors.iter().all(|f| f.is_finite() && *f >= 0.0), || "PFAC: factor negative or non-finite".into())?;
    // No table returns more than it receives.
    for t in 0..r.prototypes.len() {
        let k = r.prototypes[t].bands as usize;
        for i in 0..n {
            let (_, f) = r.row(t, i);
            let mut sum = [0.0f64; 3];
            for e in f.chunks_exact(k) {
                for c in 0..k {
                    sum[c] += e[c] as f64;
                }
            }
            check(sum.iter().all(|&x| x <= 1.0 + 1e-4), || {
                format!("PTAB[{t}]: row {i} reflects more than it receives")
            })?;
        }
    }
    check(r.maps.len() == r.orientations.len() * n, || "OMAP: not one map of N entries per orientation".into())?;
    let mut seen = vec![0u32; n];
    for o in 0..r.orientations.len() {
        for &d in r.map(o) {
            check((d as usize) < n && seen[d as usize] != o as u32 + 1, || format!("OMAP[{o}]: not a bijection"))?;
            seen[d as usize] = o as u32 + 1;
        }
    }
    check(r.patches.windows(2).all(|w| w[0].patch < w[1].patch), || "NDPA: patches not ascending".into())?;
    let nd_patch = |q: usize| {
        let m =
            &v.materials[v.surfaces[v.primitives[v.patch_primitive[q] as usize].surface as usize].material as usize];
        m.model != layout::model::DIFFUSE
    };
    for (k, e) in r.patches.iter().enumerate() {
        check((e.patch as usize) < v.patch_centre.len() && nd_patch(e.patch as usize), || {
            format!("NDPA[{k}]: patch {} out of range or diffuse", e.patch)
        })?;
        check((e.prototype as usize) < r.prototypes.len() && (e.orientation as usize) < r.orientations.len(), || {
            format!("NDPA[{k}]: prototype or orientation out of range")
        })?;
        check(r.prototypes[e.prototype as usize].model == layout::table_model::GGX, || {
            format!("NDPA[{k}]: prototype is not a GGX lobe")
        })?;
    }
    let listed = (0..v.patch_centre.len()).filter(|&q| nd_patch(q)).count();
    check(listed == r.patches.len(), || format!("NDPA: {} patches listed, {listed} are non-diffuse", r.patches.len()))?;
    check(r.hits.len() == r.patches.len() * (n / 2), || "NDHC: not N/2 counts per non-diffuse patch".into())?;
    if let Some(back) = r.back_hits {
        check(back.len() == r.hits.len(), || format!("NDBK: {} records, expected {}", back.len(), r.hits.len()))?;
        check(back.iter().zip(r.hits).all(|(b, h)| b <= h), || "NDBK: more back-face rays than NDHC rays".into())?;
    }
    Ok(())
}

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

#[cfg(test)]
mod tests {
    use super::BlockTiling;

    /// Adds the blocks `(first, cells)` in turn: whether each was taken,
    /// and the patches covered.
    fn tile(patches: u64, blocks: &[(u64, u64)]) -> (Vec<bool>, u64) {
        let mut t = BlockTiling::new(patches);
        (blocks.iter().map(|&(f, c)| t.add(f, c)).collect(), t.covered())
    }

    #[test]
    fn blocks_tile_the_patches_in_any_order_and_never_overlap() {
        // In primitive order, and out of it (a spatial order).
        assert_eq!(tile(10, &[(0, 4), (4, 1), (5, 5)]), (vec![true; 3], 10));
        assert_eq!(tile(10, &[(6, 4), (0, 4), (4, 2)]), (vec![true; 3], 10));
        assert_eq!(tile(10, &[(0, 4), (7, 3), (4, 3)]), (vec![true; 3], 10));
        // Overlapping a block of the in-order stretch, or a later one.
        assert_eq!(tile(10, &[(0, 4), (7, 3), (3, 2)]).0, vec![true, true, false]);
        assert_eq!(tile(10, &[(5, 3), (0, 5), (7, 1)]).0, vec![true, true, false]);
        // Beyond the patches, or wrapping.
        assert_eq!(tile(10, &[(8, 3)]).0, vec![false]);
        assert_eq!(tile(10, &[(u64::MAX, 2)]).0, vec![false]);
        // A gap is left uncovered.
        assert_eq!(tile(10, &[(0, 4), (5, 5)]), (vec![true, true], 9));
    }
}
