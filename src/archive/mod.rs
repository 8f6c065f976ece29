//! The I-net archive: one versioned, checksummed, memory-mapped file.
//!
//! Layout (normative text: `format-spec/archive.md`): a 128-byte header, then
//! section payloads (64-byte aligned; page-aligned from 64 KiB), then a
//! section table written last (single-pass writing). Every section has a
//! checksum in the table, outside the bytes it covers. Hot columns (patches,
//! links) are raw little-endian struct-of-arrays read zero-copy; the cold
//! `META` section is rkyv, zstd-compressed.
//!
//! [`write()`] writes to a temporary file in the destination directory and
//! renames it into place, so a crash never leaves a half-written archive
//! under the final name. [`Archive::open`] maps the file and validates every
//! byte that later code trusts (checksums, bounds, alignment, index ranges)
//! before any zero-copy view is handed out: a corrupt or truncated file is an
//! [`ArchiveError`], never a panic.
//!
//! Architecture invariant: this module knows nothing about how the data was
//! produced (build) or consumed (distribute, render).

pub mod deltas;
mod ends;
mod invariants;
pub mod layout;
mod links;
pub mod mapped;
pub mod presence;
mod read;
mod stream;
pub mod upgrade;
pub mod verify;
pub mod weights;
mod write;

use std::fmt;
use std::path::PathBuf;

pub use ends::{LinkRows, Links};
pub use links::{Columns, EndRun, LinkRuns, LinkSlices, LinkWindow, PatchIds};
pub use read::{Archive, ArchiveSummary, DeltaBytes, InetView, OnDisk, ReflectanceView, SequenceView, ShadingView};
pub use stream::{CHUNK_ENDS, LinkStream, bytes_per_end};
pub use weights::Weights;
pub use write::{LinkEndSink, LinkEndSource, reseal, write, write_to_vec, write_to_vec_with_links, write_with_links};

use layout::{BuildRecord, CameraRecord, DirectionRecord, MaterialRecord, PrimitiveRecord, SurfaceRecord, Tag};

/// Names and provenance: small, structured, cold. Stored with rkyv (validated
/// with bytecheck on read) inside a zstd frame.
#[derive(Debug, Clone, PartialEq, Eq, Default, rkyv::Archive, rkyv::Serialize, rkyv::Deserialize)]
pub struct ArchiveMeta {
    /// Program and version that wrote the file.
    pub generator: String,
    /// Scene name.
    pub scene: String,
    /// One name per surface.
    pub surface_names: Vec<String>,
    /// One name per material.
    pub material_names: Vec<String>,
}

/// Everything an archive holds, as owned columns: what a build produces and
/// [`write()`] stores. Field docs give the section each becomes.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ArchiveContents {
    /// `BILD`.
    pub build: BuildRecord,
    /// `CAMR`.
    pub camera: CameraRecord,
    /// `SURF`.
    pub surfaces: Vec<SurfaceRecord>,
    /// `MATL`.
    pub materials: Vec<MaterialRecord>,
    /// `PRIM`.
    pub primitives: Vec<PrimitiveRecord>,
    /// `DIRS`.
    pub directions: Vec<DirectionRecord>,
    /// `PCEN`.
    pub patch_centre: Vec<[f32; 3]>,
    /// `PNRM`.
    pub patch_normal: Vec<[f32; 3]>,
    /// `PARE`.
    pub patch_area: Vec<f32>,
    /// `PPRM`.
    pub patch_primitive: Vec<u32>,
    /// `PCOR`.
    pub patch_corners: Vec<[u32; 4]>,
    /// `PHIT`.
    pub patch_hits: Vec<u32>,
    /// `PEXP`.
    pub patch_expected_hits: Vec<f32>,
    /// `PBAK`: per patch, of its `PHIT` rays those whose light meets a back
    /// face; empty (and the section left out) when not counted.
    pub patch_back_hits: Vec<u32>,
    /// `VPOS`.
    pub vertex_position: Vec<[f32; 3]>,
    /// `TVTX`: per grouped triangle (`PRIM.kind` 2), its corners' vertex
    /// ids; empty (and the section left out) when there are none.
    pub grouped_triangles: Vec<[u32; 3]>,
    /// `ADJO`.
    pub adjacency_offsets: Vec<u32>,
    /// `ADJI`.
    pub adjacency: Vec<u32>,
    /// `LOFF`.
    pub link_offsets: Vec<u64>,
    /// `LOTH`.
    pub link_other: Vec<u32>,
    /// The link-end weights, stored as `LCNT` and `LCNX` (§5.10).
    pub link_weight: Vec<f32>,
    /// `LDIR`.
    pub link_direction: Vec<u32>,
    /// `LBKT`.
    pub link_bucket: Vec<u8>,
    /// `META`.
    pub meta: ArchiveMeta,
    /// `ANIM`, `INST`, `DIDX`, `DELT`: present for sequence archives.
    pub sequence: Option<SequenceContents>,
    /// `PTAB` … `NDHC`: present when some material is not diffuse.
    pub reflectance: Option<ReflectanceContents>,
    /// `PSHD`, `TXHD`, `TXPX`: present when some primitive has shading
    /// normals or a texture.
    pub shading: Option<ShadingContents>,
}

/// The shading sections (§5.15): per primitive, texture coordinates and
/// shading normals, and the textures they refer to.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ShadingContents {
    /// `PSHD`: one record per primitive.
    pub primitives: Vec<layout::ShadingRecord>,
    /// `TXHD`.
    pub textures: Vec<layout::TextureRecord>,
    /// `TXPX`: every texture's texels, 3 bytes each.
    pub texels: Vec<u8>,
}

/// The reflectance sections (§5.14): prototype tables, orientations with
/// their actual-to-prototype maps, and the non-diffuse patches.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ReflectanceContents {
    /// `PTAB`.
    pub prototypes: Vec<layout::PrototypeRecord>,
    /// `PROW`: per table, N + 1 row offsets relative to its first entry.
    pub rows: Vec<u32>,
    /// `PODR`.
    pub outgoing: Vec<u32>,
    /// `PFAC`.
    pub factors: Vec<f32>,
    /// `ORNT`.
    pub orientations: Vec<layout::OrientationRecord>,
    /// `OMAP`: per orientation, N prototype direction ids.
    pub maps: Vec<u32>,
    /// `NDPA`, ascending by patch.
    pub patches: Vec<layout::NonDiffusePatchRecord>,
    /// `NDHC`: per non-diffuse patch, N/2 ray counts (one per direction pair).
    pub hits: Vec<u32>,
    /// `NDBK`: of those, the rays whose light meets a back face; empty (and
    /// the section left out) when not counted.
    pub back_hits: Vec<u32>,
}

/// The animation sections of a sequence archive (§5.13).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SequenceContents {
    /// `ANIM`.
    pub record: layout::AnimationRecord,
    /// `INST`: every primitive belongs to exactly one instance.
    pub instances: Vec<layout::InstanceRecord>,
    /// Per frame, the changes of the link multiset relative to frame 0
    /// (frame 0's list is empty), compressed: `DIDX` + `DELT`.
    pub deltas: deltas::EncodedDeltas,
    /// `CAMF`: one camera per frame, or empty when the camera is still.
    pub cameras: Vec<layout::CameraRecord>,
    /// `EMIF`: frames × surfaces emitted radiances, or empty when no
    /// emission is keyed.
    pub emissions: Vec<[f32; 3]>,
}

/// Why an archive could not be written or opened.
#[derive(Debug)]
pub enum ArchiveError {
    /// Reading or writing the file failed.
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The bytes do not form a valid archive; the message says where.
    Corrupt(String),
    /// The file needs a newer reader.
    UnsupportedVersion {
        /// `version_read` in the file.
        needs: u32,
        /// What this build reads.
        supports: u32,
    },
    /// The file was written in an older format that this build reads only
    /// after `illumnet upgrade` rewrites it.
    Outdated {
        /// `version_write` in the file.
        written: u32,
    },
}

impl ArchiveError {
    pub(crate) fn corrupt(msg: impl Into<String>) -> Self {
        Self::Corrupt(msg.into())
    }
}

impl fmt::Display for ArchiveError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Io { path, source } => write!(f, "{}: {source}", path.display()),
            Self::Corrupt(m) => write!(f, "corrupt archive: {m}"),
            Self::UnsupportedVersion { needs, supports } => write!(
                f,
                "archive needs reader version {needs}, this illumnet reads up to version {supports}: upgrade illumnet"
            ),
            Self::Outdated { written } if (layout::UPGRADABLE..layout::OLDEST_READABLE).contains(written) => write!(
                f,
                "archive written in format version {written}; this illumnet reads version {}: rewrite it with \
                 `illumnet upgrade ARCHIVE` (the same light, a smaller file) or build it again",
                layout::VERSION_WRITE
            ),
            Self::Outdated { written } => write!(
                f,
                "archive written in format version {written}; this illumnet reads version {} and upgrades \
                 versions {} to {}: build it again",
                layout::VERSION_WRITE,
                layout::UPGRADABLE,
                layout::OLDEST_READABLE - 1
            ),
        }
    }
}

impl std::error::Error for ArchiveError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::Io { source, .. } => Some(source),
            _ => None,
        }
    }
}

/// Printable form of a tag (`b"LOTH"` → `LOTH`; non-ASCII bytes escaped).
pub fn tag_name(tag: Tag) -> String {
    tag.iter().map(|&b| if b.is_ascii_graphic() { (b as char).to_string() } else { format!("\\x{b:02x}") }).collect()
}
