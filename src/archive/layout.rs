//! On-disk records of the archive format (version 11).
//!
//! Every type here is `#[repr(C)]`, made of little-endian `u32`/`u64`/`f32`
//! fields with no implicit padding, and is read zero-copy with `bytemuck`
//! after validation. Sizes are asserted at compile time. The normative
//! description is `format-spec/archive.md`; section numbers below refer to it.

use bytemuck::{Pod, Zeroable};

/// File magic, bytes 0..8 (§3).
pub const MAGIC: [u8; 8] = *b"ILLUMNET";
/// The format version this code writes (§3, `version_write`).
pub const VERSION_WRITE: u32 = 11;
/// `version_read` of the archives this code writes: version 10 stores a
/// link end's other patch in 16 bits, local to the sender chunk of its
/// run (`LOTH`, `LROF`, `LRUN`, §5.10), which older readers would take for
/// 32-bit ids.
pub const VERSION_READ: u32 = 10;
/// `version_read` of archives whose primitives' patch blocks are not in
/// primitive order (a spatial patch order, since version 11, §5.5), which
/// version 10 readers would refuse as not contiguous.
pub const VERSION_READ_SPATIAL: u32 = 11;
/// The oldest `version_write` this code reads: older files are rewritten
/// by `illumnet upgrade` ([`super::upgrade`]).
pub const OLDEST_READABLE: u32 = 10;
/// The `version_write` of the oldest files [`super::upgrade`] rewrites
/// (every version from it to [`OLDEST_READABLE`] − 1).
pub const UPGRADABLE: u32 = 6;
/// Files written from this version on store link-end weights as `LCNT`
/// and `LCNX`; older ones as `LWGT` (§8).
pub const VERSION_COUNTS: u32 = 7;
/// Patches per sender chunk: a link end's `LOTH` is its other patch minus
/// its run's `chunk · 2¹⁶` (§5.10).
pub const CHUNK_PATCHES: usize = 1 << 16;
/// Files written before this version store each frame's delta as plain
/// records in one zstd frame, checksummed after decompression; from it on,
/// as blocks of columns, checksummed as stored (§5.13).
pub const VERSION_DELTA_BLOCKS: u32 = 5;
/// The highest `version_read` this code can read (§6).
pub const READER_VERSION: u32 = 11;
/// Header size in bytes (§3).
pub const HEADER_SIZE: usize = 128;
/// Section table entry size in bytes (§4).
pub const ENTRY_SIZE: usize = 64;
/// Every section starts at a multiple of this (§2).
pub const SECTION_ALIGN: u64 = 64;
/// Sections of at least [`LARGE_SECTION`] bytes start at a multiple of this (§2).
pub const PAGE_ALIGN: u64 = 4096;
/// Size from which a section is page-aligned (§2).
pub const LARGE_SECTION: u64 = 64 * 1024;

/// Widest bucket a valid archive may record (§5.1, `max_bucket`).
pub const MAX_BUCKET: u32 = crate::limits::MAX_BUCKET;

/// The most a zstd frame expands its stored bytes (a 4-byte RLE block
/// holds at most 128 KiB, so no frame passes 2¹⁵): a section or frame
/// declaring more is forged, and its declared length would be planned or
/// allocated before anything is decompressed (issue 42, §5).
pub const MAX_ZSTD_EXPANSION: u64 = 1 << 16;

/// Section compression codes (§4).
pub mod compression {
    /// Stored as is; readable zero-copy.
    pub const NONE: u32 = 0;
    /// One zstd frame.
    pub const ZSTD: u32 = 1;
}

/// Material model codes (§5.4).
pub mod model {
    /// Lambertian; `params[0..3]` is the RGB reflectance.
    pub const DIFFUSE: u32 = 0;
    /// Rough conductor: `params[3..6]` `k_s`, `[6]` `α_u`, `[7]` `α_v`,
    /// `[8..11]` index of refraction per band (0: Fresnel = 1).
    pub const ROUGH_CONDUCTOR: u32 = 1;
    /// Broad specular: `params[0..3]` `k_d`, the rest as [`ROUGH_CONDUCTOR`].
    pub const BROAD_SPECULAR: u32 = 2;
}

/// Prototype table model codes (§5.14).
pub mod table_model {
    /// `f = 1/π`.
    pub const LAMBERTIAN: u32 = 0;
    /// The GGX rough-conductor lobe without `k_s`.
    pub const GGX: u32 = 1;
}

/// Link-merging policies recorded in [`BuildRecord::link_merge`] (§5.1).
pub mod merge {
    /// One entry per ray.
    pub const NONE: u32 = 0;
    /// Parallel rays of one direction joining the same two patches are one
    /// entry whose weight is their count.
    pub const PATCH_PAIR_DIRECTION: u32 = 1;
}

/// A section tag: four ASCII bytes, stored as is (§4).
pub type Tag = [u8; 4];

/// Section tags (§5).
pub mod tag {
    use super::Tag;
    /// Build parameters and counts (§5.1).
    pub const BUILD: Tag = *b"BILD";
    /// The camera (§5.2).
    pub const CAMERA: Tag = *b"CAMR";
    /// Surfaces (§5.3).
    pub const SURFACES: Tag = *b"SURF";
    /// Materials (§5.4).
    pub const MATERIALS: Tag = *b"MATL";
    /// Primitives and their patch grids (§5.5).
    pub const PRIMITIVES: Tag = *b"PRIM";
    /// Geodesic directions with neighbours (§5.6).
    pub const DIRECTIONS: Tag = *b"DIRS";
    /// Patch centres (§5.7).
    pub const PATCH_CENTRE: Tag = *b"PCEN";
    /// Patch normals (§5.7).
    pub const PATCH_NORMAL: Tag = *b"PNRM";
    /// Patch areas (§5.7).
    pub const PATCH_AREA: Tag = *b"PARE";
    /// Patch primitive ids (§5.7).
    pub const PATCH_PRIMITIVE: Tag = *b"PPRM";
    /// Patch corner vertex ids (§5.7).
    pub const PATCH_CORNERS: Tag = *b"PCOR";
    /// Patch ray-hit counts `H_p` (§5.7).
    pub const PATCH_HITS: Tag = *b"PHIT";
    /// Patch expected hit counts from geometry (§5.7).
    pub const PATCH_EXPECTED_HITS: Tag = *b"PEXP";
    /// Vertex positions (§5.8).
    pub const VERTEX_POSITION: Tag = *b"VPOS";
    /// Corner vertex ids of grouped triangles (§5.8, since version 8).
    pub const GROUPED_TRIANGLE_VERTICES: Tag = *b"TVTX";
    /// Patch adjacency offsets (§5.9).
    pub const ADJACENCY_OFFSETS: Tag = *b"ADJO";
    /// Patch adjacency ids (§5.9).
    pub const ADJACENCY: Tag = *b"ADJI";
    /// Link-end offsets per patch (§5.10).
    pub const LINK_OFFSETS: Tag = *b"LOFF";
    /// Link-end other patch, local to its run's sender chunk (§5.10).
    pub const LINK_OTHER: Tag = *b"LOTH";
    /// Per patch, its first link-end run (§5.10, since version 10).
    pub const LINK_RUN_OFFSETS: Tag = *b"LROF";
    /// Link-end runs: a bucket and sender chunk each (§5.10, since version 10).
    pub const LINK_RUNS: Tag = *b"LRUN";
    /// Link-end weight as f32, in files written before version 7 (§8;
    /// `illumnet upgrade` rewrites it as `LCNT` and `LCNX`).
    pub const LINK_WEIGHT_V6: Tag = *b"LWGT";
    /// Link-end weight as a one-byte ray count, 0 for one kept in `LCNX`
    /// (§5.10).
    pub const LINK_COUNT: Tag = *b"LCNT";
    /// Link-end weights that are not a count in 1..=255 (§5.10).
    pub const LINK_ESCAPES: Tag = *b"LCNX";
    /// Link-end outgoing direction (§5.10).
    pub const LINK_DIRECTION: Tag = *b"LDIR";
    /// Link-end bucket, in files written before version 10 (§8; the
    /// buckets are in `LRUN` since).
    pub const LINK_BUCKET_V9: Tag = *b"LBKT";
    /// Names and provenance, rkyv + zstd (§5.11).
    pub const META: Tag = *b"META";
    /// Sequence parameters (§5.13).
    pub const ANIMATION: Tag = *b"ANIM";
    /// Temporal instances (§5.13).
    pub const INSTANCES: Tag = *b"INST";
    /// Per-frame delta index (§5.13).
    pub const DELTA_INDEX: Tag = *b"DIDX";
    /// Per-frame link deltas, one zstd frame each (§5.13).
    pub const DELTAS: Tag = *b"DELT";
    /// Per-frame cameras (§5.13, optional).
    pub const FRAME_CAMERAS: Tag = *b"CAMF";
    /// Per-frame, per-surface emission (§5.13, optional).
    pub const FRAME_EMISSION: Tag = *b"EMIF";
    /// Prototype table directory (§5.14).
    pub const PROTOTYPES: Tag = *b"PTAB";
    /// Prototype row offsets (§5.14).
    pub const PROTOTYPE_ROWS: Tag = *b"PROW";
    /// Prototype entries' outgoing directions (§5.14).
    pub const PROTOTYPE_DIRECTIONS: Tag = *b"PODR";
    /// Prototype entries' factors (§5.14).
    pub const PROTOTYPE_FACTORS: Tag = *b"PFAC";
    /// Surface orientations (§5.14).
    pub const ORIENTATIONS: Tag = *b"ORNT";
    /// Actual-to-prototype maps (§5.14).
    pub const ORIENTATION_MAPS: Tag = *b"OMAP";
    /// Non-diffuse patches (§5.14).
    pub const NONDIFFUSE_PATCHES: Tag = *b"NDPA";
    /// Rays crossing each non-diffuse patch per direction pair (§5.14).
    pub const NONDIFFUSE_HITS: Tag = *b"NDHC";
    /// Per patch, its rays whose light meets a back face (§5.7, since version 9).
    pub const PATCH_BACK_HITS: Tag = *b"PBAK";
    /// Per non-diffuse patch and direction pair, likewise (§5.14, since version 9).
    pub const NONDIFFUSE_BACK_HITS: Tag = *b"NDBK";
    /// Per primitive, texture coordinates, shading normals and texture
    /// (§5.15, since version 9).
    pub const SHADING: Tag = *b"PSHD";
    /// Texture headers (§5.15, since version 9).
    pub const TEXTURES: Tag = *b"TXHD";
    /// Texels, 8-bit sRGB (§5.15, since version 9).
    pub const TEXELS: Tag = *b"TXPX";
}

/// The file header at offset 0 (§3).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Pod, Zeroable)]
pub struct HeaderRecord {
    /// [`MAGIC`].
    pub magic: [u8; 8],
    /// Format version of the writer.
    pub version_write: u32,
    /// Lowest reader version that can read the file.
    pub version_read: u32,
    /// [`HEADER_SIZE`].
    pub header_size: u32,
    /// Reserved, zero.
    pub flags: u32,
    /// Total file length in bytes.
    pub file_length: u64,
    /// Offset of the section table.
    pub table_offset: u64,
    /// Number of section table entries.
    pub section_count: u32,
    /// [`ENTRY_SIZE`].
    pub entry_size: u32,
    /// XXH3-64 (seed 0) of the section table bytes.
    pub table_checksum: u64,
    /// Reserved, zero.
    pub reserved: [u64; 8],
    /// XXH3-64 (seed 0) of header bytes 0..120.
    pub header_checksum: u64,
}

/// One section table entry (§4).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Pod, Zeroable)]
pub struct SectionEntry {
    /// Four ASCII bytes naming the section.
    pub tag: Tag,
    /// [`compression`] code.
    pub compression: u32,
    /// Offset of the stored bytes from the start of the file.
    pub offset: u64,
    /// Stored (possibly compressed) length in bytes.
    pub stored_length: u64,
    /// Length after decompression (equal to `stored_length` when stored as is).
    pub length: u64,
    /// Number of records.
    pub count: u64,
    /// Size of one record in bytes (0 for unstructured sections such as META).
    pub record_size: u32,
    /// Reserved, zero.
    pub flags: u32,
    /// XXH3-64 (seed 0) of the stored bytes.
    pub checksum: u64,
    /// Reserved, zero.
    pub reserved: u64,
}

/// Build parameters and totals (§5.1).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, Pod, Zeroable)]
pub struct BuildRecord {
    /// Geodesic frequency `f`.
    pub frequency: u32,
    /// Number of directions, `10f² + 2`.
    pub direction_count: u32,
    /// Number of patches.
    pub patch_count: u32,
    /// Number of patch vertices.
    pub vertex_count: u32,
    /// Number of primitives.
    pub primitive_count: u32,
    /// Number of surfaces.
    pub surface_count: u32,
    /// Number of materials.
    pub material_count: u32,
    /// Link-merging policy ([`merge`]).
    pub link_merge: u32,
    /// Distance between parallel rays `δ` (m).
    pub ray_spacing_m: f32,
    /// Target patch size used (m).
    pub patch_size_m: f32,
    /// Direction set: 0 = geodesic (`10f²+2` directions), 1 = ray-space
    /// baseline (`6m²` directions, `m` stored in `frequency`).
    pub direction_set: u32,
    /// Widest bucket in `LBKT` (0 = buckets off).
    pub max_bucket: u32,
    /// Rays traced (one per ray line; each serves both directions of a pair).
    pub ray_count: u64,
    /// Undirected links before merging (one per facing hit pair on a ray).
    pub link_count: u64,
    /// Link ends stored (two per merged link).
    pub link_end_count: u64,
    /// Sum of all patch hit counts.
    pub hit_count: u64,
    /// Reserved, zero.
    pub reserved1: [u64; 6],
}

/// The pinhole camera (§5.2).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, Pod, Zeroable)]
pub struct CameraRecord {
    /// Eye position (m).
    pub position: [f32; 3],
    /// Point looked at (m).
    pub look_at: [f32; 3],
    /// Up vector.
    pub up: [f32; 3],
    /// Vertical field of view (degrees).
    pub fov_y_deg: f32,
    /// Image width (pixels).
    pub width: u32,
    /// Image height (pixels).
    pub height: u32,
}

/// A surface (§5.3).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, Pod, Zeroable)]
pub struct SurfaceRecord {
    /// Material index.
    pub material: u32,
    /// First primitive index.
    pub first_primitive: u32,
    /// Number of primitives.
    pub primitive_count: u32,
    /// Reserved, zero.
    pub reserved0: u32,
    /// Emitted radiance, linear RGB (W·sr⁻¹·m⁻²).
    pub emission: [f32; 3],
    /// Reserved, zero.
    pub reserved1: f32,
}

/// A material (§5.4).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, Pod, Zeroable)]
pub struct MaterialRecord {
    /// [`model`] code.
    pub model: u32,
    /// Reserved, zero.
    pub reserved: u32,
    /// Model parameters; unused ones are zero.
    pub params: [f32; 14],
}

/// A primitive and its patch grid (§5.5).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, Pod, Zeroable)]
pub struct PrimitiveRecord {
    /// 0 = quad, 1 = triangle.
    pub kind: u32,
    /// Surface index.
    pub surface: u32,
    /// Grid cells along u (triangles: subdivision k).
    pub grid_u: u32,
    /// Grid cells along v (triangles: equal to `grid_u`).
    pub grid_v: u32,
    /// Global id of the first patch.
    pub first_patch: u32,
    /// Global id of the first vertex; for a grouped triangle, its row in
    /// `TVTX`.
    pub first_vertex: u32,
    /// How the quad's cells are numbered: [`cell_order::ROWS`] or
    /// [`cell_order::TILES`] (since version 7; triangles: rows).
    pub cell_order: u32,
    /// Reserved, zero.
    pub reserved: u32,
    /// Corners (m); the fourth equals the third for triangles.
    pub corners: [[f32; 3]; 4],
}

/// `PRIM.kind` values (§5.5).
pub mod kind {
    /// A planar convex quad with its own grid of patches.
    pub const QUAD: u32 = 0;
    /// A triangle with its own grid of patches.
    pub const TRIANGLE: u32 = 1;
    /// A triangle of a group of small triangles that make one patch
    /// (since version 8).
    pub const GROUPED_TRIANGLE: u32 = 2;
}

/// `PRIM.cell_order` values (§5.5).
pub mod cell_order {
    /// Row by row: cell `(i, j)` is `j·n_u + i`.
    pub const ROWS: u32 = 0;
    /// Tiles of 8×8 cells, row by row; a tile's cells row by row.
    pub const TILES: u32 = 1;
}

/// A link end whose weight is not a whole number of rays in 1..=255, so
/// that `LCNT` holds 0 for it (§5.10).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, Pod, Zeroable)]
pub struct WeightEscape {
    /// The link end (an index into `LOTH`).
    pub end: u64,
    /// Its weight.
    pub weight: f32,
    /// Reserved, zero.
    pub reserved: u32,
}

/// A run of a patch's link ends with one bucket and one sender chunk
/// (§5.10): the ends' other patches are `chunk · 2¹⁶ + LOTH`.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Pod, Zeroable)]
pub struct LinkRunRecord {
    /// The sender chunk: the other patches' ids divided by 2¹⁶.
    pub chunk: u16,
    /// The bucket (§5.12) of the light the owner receives over the ends.
    pub bucket: u8,
    /// Reserved, zero.
    pub reserved: u8,
    /// Link ends in the run, at least one.
    pub length: u32,
}

/// A direction of the geodesic set (§5.6).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, Pod, Zeroable)]
pub struct DirectionRecord {
    /// Unit vector.
    pub direction: [f32; 3],
    /// Solid angle of the direction's spherical Voronoi cell (sr).
    pub solid_angle_sr: f32,
    /// Neighbour ids counter-clockwise seen from outside; `u32::MAX` = none.
    pub neighbours: [u32; 6],
}

/// Sequence parameters (§5.13).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, Pod, Zeroable)]
pub struct AnimationRecord {
    /// Frames in the sequence.
    pub frames: u32,
    /// Frame rate.
    pub fps: f32,
    /// Number of `INST` records.
    pub instance_count: u32,
    /// Reserved, zero.
    pub reserved: [u32; 5],
}

/// A set of primitives present over a range of frames (§5.13).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, Pod, Zeroable)]
pub struct InstanceRecord {
    /// Surface index.
    pub surface: u32,
    /// First primitive index.
    pub first_primitive: u32,
    /// Number of primitives.
    pub primitive_count: u32,
    /// First frame present.
    pub frame_first: u32,
    /// Last frame present (inclusive).
    pub frame_last: u32,
    /// Reserved, zero.
    pub reserved: [u32; 3],
}

/// Where frame `f`'s delta lies in `DELT` (§5.13).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, Pod, Zeroable)]
pub struct DeltaIndexRecord {
    /// Offset of the frame's blocks (zstd frames) within the `DELT` payload.
    pub offset: u64,
    /// Their stored length (0 when the frame has no changes).
    pub stored_length: u64,
    /// Number of [`DeltaRecord`]s they decode to.
    pub count: u64,
    /// XXH3-64 of the stored bytes (before version 5: of the decoded records).
    pub checksum: u64,
}

/// One change of the active link multiset relative to frame 0 (§5.13): the
/// decoded form (version 5 stores blocks of difference-coded columns; version
/// 4 stored these 20-byte records as they are).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Pod, Zeroable)]
pub struct DeltaRecord {
    /// Direction pair k (directions 2k, 2k+1).
    pub pair: u32,
    /// Patch facing along direction 2k.
    pub a: u32,
    /// Patch facing back.
    pub b: u32,
    /// Signed number of rays added (> 0) or removed (< 0).
    pub count: i32,
    /// Bucket at `a`.
    pub bucket_a: u8,
    /// Bucket at `b`.
    pub bucket_b: u8,
    /// Reserved, zero.
    pub reserved: u16,
}

/// A prototype reflectance table (§5.14).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, Pod, Zeroable)]
pub struct PrototypeRecord {
    /// [`table_model`] code.
    pub model: u32,
    /// Factors per entry: 1 (generic) or 3 (per band).
    pub bands: u32,
    /// GGX roughness along the grain (0 for Lambertian).
    pub alpha_u: f32,
    /// GGX roughness across the grain.
    pub alpha_v: f32,
    /// Index of refraction per band; 0 = Fresnel 1.
    pub ior: [f32; 3],
    /// Relative threshold the table was built with.
    pub threshold: f32,
    /// First of the table's N + 1 row offsets in `PROW`.
    pub first_row: u64,
    /// First entry in `PODR`.
    pub first_entry: u64,
    /// Number of entries.
    pub entry_count: u64,
    /// First factor in `PFAC` (the table holds `entry_count × bands`).
    pub first_factor: u64,
}

/// A surface orientation with an actual-to-prototype map (§5.14).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, Pod, Zeroable)]
pub struct OrientationRecord {
    /// Unit normal.
    pub normal: [f32; 3],
    /// Unit grain direction, perpendicular to the normal.
    pub grain: [f32; 3],
    /// Mean angular error of the map over the directions above the surface (rad).
    pub error_mean_rad: f32,
    /// Largest angular error of the map (rad).
    pub error_max_rad: f32,
}

/// A patch with a non-diffuse material (§5.14).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, Pod, Zeroable)]
pub struct NonDiffusePatchRecord {
    /// Patch id.
    pub patch: u32,
    /// Prototype table index.
    pub prototype: u32,
    /// Orientation index.
    pub orientation: u32,
    /// Reserved, zero.
    pub reserved: u32,
}

/// A primitive's shading detail (§5.15): what an image sample on it needs
/// beyond its patches' light.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, Pod, Zeroable)]
pub struct ShadingRecord {
    /// Bit 0: `normals` hold shading normals; bit 1: `texture` is a texture.
    pub flags: u32,
    /// Index into `TXHD` (`u32::MAX`: none).
    pub texture: u32,
    /// Multiplies the texel's linear RGB.
    pub tint: [f32; 3],
    /// Reserved, zero.
    pub reserved: u32,
    /// Shading normals at corners 0..4 in the primitive's own frame (x
    /// along `p1 − p0`, z the face normal, y = z × x).
    pub normals: [[f32; 3]; 4],
    /// Texture coordinates at corners 0..4.
    pub uvs: [[f32; 2]; 4],
}

/// [`ShadingRecord::flags`] bits.
pub mod shading_flags {
    /// The record's normals are used.
    pub const NORMALS: u32 = 1;
    /// The record's texture is used.
    pub const TEXTURE: u32 = 2;
}

/// A texture's header (§5.15).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, Pod, Zeroable)]
pub struct TextureRecord {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// Wrap along u and v: 0 = clamp, 1 = repeat, 2 = mirrored repeat.
    pub wrap: [u32; 2],
    /// Offset of its first texel's byte in `TXPX`.
    pub first_byte: u64,
    /// Magnification filter: 0 = bilinear, 1 = nearest texel.
    pub filter: u32,
    /// Reserved, zero.
    pub reserved: u32,
}

const _: () = {
    assert!(size_of::<ShadingRecord>() == 104);
    assert!(size_of::<TextureRecord>() == 32);
    assert!(size_of::<PrototypeRecord>() == 64);
    assert!(size_of::<OrientationRecord>() == 32);
    assert!(size_of::<NonDiffusePatchRecord>() == 16);
    assert!(size_of::<AnimationRecord>() == 32);
    assert!(size_of::<InstanceRecord>() == 32);
    assert!(size_of::<DeltaIndexRecord>() == 32);
    assert!(size_of::<DeltaRecord>() == 20);
    assert!(size_of::<HeaderRecord>() == HEADER_SIZE);
    assert!(size_of::<SectionEntry>() == ENTRY_SIZE);
    assert!(size_of::<BuildRecord>() == 128);
    assert!(size_of::<CameraRecord>() == 48);
    assert!(size_of::<SurfaceRecord>() == 32);
    assert!(size_of::<MaterialRecord>() == 64);
    assert!(size_of::<PrimitiveRecord>() == 80);
    assert!(size_of::<DirectionRecord>() == 40);
    assert!(size_of::<WeightEscape>() == 16);
    assert!(size_of::<LinkRunRecord>() == 8);
};
