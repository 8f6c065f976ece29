//! The zero-copy views of a validated archive's sections ([`InetView`]
//! and the views of its optional parts), what they answer (a frame's
//! links, presence, camera), and how an [`Archive`] makes them.

use std::borrow::Cow;

use xxhash_rust::xxh3::xxh3_64;

use super::{Archive, OnDisk, bad};
use crate::archive::ends::{LinkRows, Links};
use crate::archive::invariants;
use crate::archive::layout::{
    self, AnimationRecord, BuildRecord, CameraRecord, DeltaIndexRecord, DeltaRecord, DirectionRecord, InstanceRecord,
    MaterialRecord, NonDiffusePatchRecord, OrientationRecord, PrimitiveRecord, PrototypeRecord, SurfaceRecord, tag,
};
use crate::archive::links::{LinkRuns, LinkSlices};
use crate::archive::presence::{self, FramePresence, FrameSpan};
use crate::archive::stream;
use crate::archive::weights::Weights;
use crate::archive::{ArchiveError, deltas};

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
    pub(super) payload_count: u64,
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
        let records = deltas::decode(stored, ix.count, frame, self.version_5)?;
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

impl Archive {
    pub(super) fn view_unchecked(&self) -> Result<InetView<'_>, ArchiveError> {
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
