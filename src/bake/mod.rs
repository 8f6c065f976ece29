//! The build stage: scene → patches → traced ray bundles → links → archive
//! contents.
//!
//! For every antipodal direction pair of the geodesic set, one bundle of
//! parallel rays, spaced `δ` apart in the plane perpendicular to the
//! direction (the paper's 1/cos φ correction, §3.3), crosses the scene. Each
//! ray reports all its hits in order; consecutive hits whose surfaces face
//! each other become a link (§2, Table 1), which carries light both ways. Every
//! hit counts towards its patch's `H_p` (§3.4).
//!
//! Determinism: bundles are traced in parallel but their results are merged
//! in direction order, hit counts are integer sums and links are sorted
//! within each bundle, so the archive bytes do not depend on thread count.

mod links;
mod reflectance;
mod settings;
mod spill;
mod trace;

use std::time::Instant;

use rayon::prelude::*;

pub use crate::patch::order::PatchOrder;
pub use settings::{BuildSettings, DEFAULT_MAX_BUCKET, MAX_BUCKET, Quality, ray_space_divisions};
pub use spill::SpilledLinks;
pub use trace::BundleStats;

use crate::archive::layout::{
    self, BuildRecord, CameraRecord, DirectionRecord, MaterialRecord, PrimitiveRecord, SurfaceRecord,
};
use crate::archive::layout::{AnimationRecord, InstanceRecord};
use crate::archive::presence::{FramePresence, FrameSpan};
use crate::archive::{ArchiveContents, ArchiveMeta, SequenceContents};
use crate::geodesic::{DirectionSet, DirectionSetKind};
use crate::geometry::Primitive;
use crate::geometry::grid::CellOrder;
use crate::patch::Patches;
use crate::progress::Progress;
use crate::scene::texture::Shading;
use crate::scene::{ReflectanceModel, Scene};

/// What a build measured.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BuildStats {
    /// Directions in the set.
    pub directions: u32,
    /// Patches made.
    pub patches: u32,
    /// Ray lines traced (each serves a direction and its antipode).
    pub rays: u64,
    /// Ray-surface hits.
    pub hits: u64,
    /// Links before merging (one per facing hit pair on a ray).
    pub links: u64,
    /// Link ends stored after merging (two per merged link).
    pub link_ends: u64,
    /// Seconds spent cutting patches and building the direction set.
    pub setup_s: f64,
    /// Seconds spent tracing.
    pub trace_s: f64,
    /// Seconds spent assembling the link tables.
    pub assemble_s: f64,
    /// Prototype tables used (non-diffuse materials), and how many of them
    /// the prototype library already held.
    pub tables: u32,
    /// Tables read from the prototype library.
    pub tables_cached: u32,
    /// Distinct orientations of non-diffuse surfaces (one map each).
    pub orientations: u32,
    /// Non-diffuse patches.
    pub nondiffuse_patches: u32,
    /// Seconds spent on prototype tables and maps.
    pub reflectance_s: f64,
}

/// Builds the I-net of a still `scene` with `settings`. Animated scenes go
/// through [`build_sequence`] (or [`Scene::at_frame`] for one frame).
pub fn build(
    scene: &Scene,
    settings: &BuildSettings,
    progress: &dyn Progress,
) -> Result<(ArchiveContents, BuildStats), String> {
    if scene.is_animated() {
        return Err("the scene is animated: build one frame (Scene::at_frame, `--frame N`) or a sequence".into());
    }
    let seq = build_sequence(scene, settings, progress)?;
    Ok((seq.contents, seq.stats))
}

/// A primitive set present over a range of frames: a permanent surface
/// (all frames) or one temporal instance of a moving surface (§2).
#[derive(Debug, Clone, PartialEq)]
pub struct Instance {
    /// Surface index.
    pub surface: u32,
    /// The frames it is present in.
    pub frames: FrameSpan,
    /// The surface's primitives placed for those frames.
    pub primitives: Vec<Primitive>,
    /// The surface's grain placed for those frames.
    pub grain: Option<glam::Vec3>,
    /// The surface's shading detail placed with the primitives (empty for
    /// none).
    pub shading: Vec<Shading>,
}

/// The shading sections (§5.15) for the archive's primitives, instance by
/// instance: each primitive's surface's shading detail (texture
/// coordinates, normals in the primitive's own frame and texture, which
/// rigid motion leaves as they are), and the scene's textures; `None` when
/// no surface has any.
fn shading_contents(scene: &Scene, instances: &[Instance]) -> Option<crate::archive::ShadingContents> {
    use crate::archive::layout::{ShadingRecord, TextureRecord, shading_flags};
    use crate::scene::texture::Wrap;
    if scene.surfaces.iter().all(|s| s.shading.is_empty()) {
        return None;
    }
    let mut primitives = Vec::with_capacity(instances.iter().map(|i| i.primitives.len()).sum());
    // What the format allows (§5.15): finite coordinates within ±10⁶, a
    // tint in [0, 10⁶], normal components within ±1.
    let clean = |x: f32, bound: f32| if x.is_finite() { x.clamp(-bound, bound) } else { 0.0 };
    for inst in instances {
        for i in 0..inst.primitives.len() {
            let sh = if inst.shading.len() == inst.primitives.len() { inst.shading[i] } else { Shading::FLAT };
            let has_normals = sh.normal.iter().any(|n| *n != glam::Vec3::ZERO);
            let has_texture = (sh.texture as usize) < scene.textures.len();
            primitives.push(ShadingRecord {
                flags: if has_normals { shading_flags::NORMALS } else { 0 }
                    | if has_texture { shading_flags::TEXTURE } else { 0 },
                texture: if has_texture { sh.texture } else { u32::MAX },
                tint: if has_texture { sh.tint.map(|t| clean(t, 1e6).max(0.0)) } else { [1.0; 3] },
                reserved: 0,
                normals: sh.normal.map(|n| n.to_array().map(|c| clean(c, 1.0))),
                uvs: sh.uv.map(|u| u.to_array().map(|c| clean(c, 1e6))),
            });
        }
    }
    let mut textures = Vec::with_capacity(scene.textures.len());
    let mut texels = Vec::with_capacity(scene.textures.iter().map(|t| t.srgb.len()).sum());
    for t in &scene.textures {
        let wrap = t.wrap.map(|w| match w {
            Wrap::Clamp => 0,
            Wrap::Repeat => 1,
            Wrap::Mirror => 2,
        });
        textures.push(TextureRecord {
            width: t.width,
            height: t.height,
            wrap,
            first_byte: texels.len() as u64,
            filter: u32::from(t.nearest),
            reserved: 0,
        });
        texels.extend_from_slice(&t.srgb);
    }
    Some(crate::archive::ShadingContents { primitives, textures, texels })
}

/// One merged link of frame 0.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub struct LinkRecord {
    /// Direction pair.
    pub pair: u32,
    /// Patch facing along the pair's first direction.
    pub a: u32,
    /// Patch facing back.
    pub b: u32,
    /// Bucket at `a`.
    pub bucket_a: u8,
    /// Bucket at `b`.
    pub bucket_b: u8,
    /// Rays merged.
    pub weight: u32,
}

/// An I-net built for a whole sequence in one trace (§2): permanent
/// surfaces once, moving surfaces once per run of frames with the same
/// transform, frame 0's links in `contents`, later frames as deltas.
#[derive(Debug, Clone)]
pub struct Sequence {
    /// Archive contents with frame 0's links.
    pub contents: ArchiveContents,
    /// Build measurements.
    pub stats: BuildStats,
    /// Frames in the sequence.
    pub frames: u32,
    /// The instances, in primitive order.
    pub instances: Vec<Instance>,
    /// Frame 0's links, by pair, when kept for verification
    /// ([`build_sequence_with_links`]; about 20 bytes per link).
    pub base: Option<Vec<LinkRecord>>,
    /// Per patch: (surface, primitive index within its surface, cell), the
    /// same in every build of the same surfaces and resolution.
    pub patch_identity: Vec<(u32, u32, u32)>,
    /// Bounds the ray grids covered.
    pub bounds: (glam::Vec3, glam::Vec3),
    /// Problems that did not stop the build (for example, the prototype
    /// library could not be written).
    pub warnings: Vec<String>,
}

/// A bounded build's limits: its memory budget, and the archive it
/// builds, next to which it spills runs of link ends when over it.
#[derive(Clone, Debug)]
pub struct MemoryBound {
    /// Bytes the build may keep resident (see [`crate::memory`]).
    pub budget: u64,
    /// The archive's path: scratch goes in a `.illumnet-<name>.<pid>-*.spill`
    /// directory next to it ([`crate::scratch`]).
    pub output: std::path::PathBuf,
}

/// Why a bounded build did not finish.
#[derive(Debug)]
pub enum BuildError {
    /// The scene or the settings cannot be built (the message says why).
    Failed(String),
    /// Writing or reading the bounded build's scratch files failed (a
    /// full disk, most often): an I/O failure, not a fault of the scene.
    Scratch(String),
    /// The budget is below what the build needs at least, found before
    /// tracing: the parts of that least, in bytes.
    OverBudget {
        /// The budget.
        budget: u64,
        /// What the build needs at least, by part.
        parts: Vec<(&'static str, u64)>,
    },
}

impl std::fmt::Display for BuildError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        use crate::memory::Bytes;
        match self {
            Self::Failed(m) | Self::Scratch(m) => f.write_str(m),
            Self::OverBudget { budget, parts } => {
                let needed: u64 = parts.iter().map(|p| p.1).sum();
                write!(
                    f,
                    "the build needs at least {} of memory, more than the budget of {} (",
                    Bytes(needed),
                    Bytes(*budget)
                )?;
                for (i, (name, b)) in parts.iter().enumerate() {
                    write!(f, "{}{name} {}", if i > 0 { ", " } else { "" }, Bytes(*b))?;
                }
                write!(f, "); raise --memory-budget, or use larger patches or a larger --ray-spacing")
            }
        }
    }
}

impl std::error::Error for BuildError {}

impl From<String> for BuildError {
    fn from(m: String) -> Self {
        Self::Failed(m)
    }
}

/// A link keyed by build-independent patch identities.
pub type LinkIdentity = (u32, (u32, u32, u32), (u32, u32, u32), u8, u8);

impl Sequence {
    /// The multiset of links active at `frame`: frame 0's links plus the
    /// frame's changes (decoded from the archive contents), less the links
    /// with an end at a patch absent from the frame (§5.13), keyed by patch
    /// identity, with ray counts. `None` when the links were not kept or
    /// the frame is outside the sequence.
    pub fn active_links(&self, frame: u32) -> Option<std::collections::BTreeMap<LinkIdentity, i64>> {
        if frame >= self.frames {
            return None;
        }
        let present = self.present_patches(frame);
        let mut by_patch = std::collections::BTreeMap::new();
        for l in self.base.as_ref()? {
            *by_patch.entry((l.pair, l.a, l.b, l.bucket_a, l.bucket_b)).or_insert(0i64) += l.weight as i64;
        }
        if let Some(seq) = &self.contents.sequence {
            let deltas = seq.deltas.frame(frame as usize).ok()?;
            for d in deltas {
                *by_patch.entry((d.pair, d.a, d.b, d.bucket_a, d.bucket_b)).or_insert(0) += d.count as i64;
            }
        }
        let id = |p: u32| self.patch_identity[p as usize];
        let mut m = std::collections::BTreeMap::new();
        for ((pair, a, b, ba, bb), n) in by_patch {
            if n != 0 && present[a as usize] && present[b as usize] {
                *m.entry((pair, id(a), id(b), ba, bb)).or_insert(0) += n;
            }
        }
        Some(m)
    }

    /// Per patch, whether it is present at `frame`.
    fn present_patches(&self, frame: u32) -> Vec<bool> {
        let spans: Vec<FrameSpan> =
            self.instances.iter().flat_map(|i| std::iter::repeat_n(i.frames, i.primitives.len())).collect();
        FramePresence::new(frame, &spans, &self.contents.patch_primitive).patches
    }
}

/// The instances of `scene`: each still surface once; each moving surface
/// once per run of consecutive frames with bitwise the same transform.
pub fn instances(scene: &Scene) -> Vec<Instance> {
    let last = scene.frame_count() - 1;
    let mut out = Vec::new();
    for (s, surf) in scene.surfaces.iter().enumerate() {
        match &surf.motion {
            None => out.push(Instance {
                surface: s as u32,
                frames: FrameSpan { first: 0, last },
                primitives: surf.primitives.clone(),
                grain: surf.grain,
                shading: surf.shading.clone(),
            }),
            Some(m) => {
                let mut f0 = 0;
                for f in 1..=last + 1 {
                    if f == last + 1 || !m.same_transform(f0, f) {
                        let primitives = m.apply(f0, &surf.primitives);
                        out.push(Instance {
                            surface: s as u32,
                            frames: FrameSpan { first: f0, last: f - 1 },
                            shading: m.apply_shading(f0, &surf.primitives, &primitives, &surf.shading),
                            primitives,
                            grain: surf.grain.map(|g| m.apply_direction(f0, g)),
                        });
                        f0 = f;
                    }
                }
            }
        }
    }
    out
}

/// The animation sections for an animated scene: instances and, per frame,
/// the link changes relative to frame 0 (so that any frame is reached by
/// decoding one entry; see `format-spec/archive.md` §5.13), assembled from
/// the blocks tracing compressed.
fn sequence_sections(
    scene: &Scene,
    instances: &[Instance],
    blocks: Vec<Vec<crate::archive::deltas::Block>>,
    spilled: Option<crate::archive::deltas::SpillFile>,
) -> Result<Option<SequenceContents>, BuildError> {
    let Some(anim) = scene.animation.filter(|_| scene.is_animated()) else {
        return Ok(None);
    };
    let mut first = 0;
    let records = instances
        .iter()
        .map(|i| {
            let r = InstanceRecord {
                surface: i.surface,
                first_primitive: first,
                primitive_count: i.primitives.len() as u32,
                frame_first: i.frames.first,
                frame_last: i.frames.last,
                reserved: [0; 3],
            };
            first += i.primitives.len() as u32;
            r
        })
        .collect();
    let deltas = crate::archive::deltas::EncodedDeltas::from_blocks(anim.frames as usize, blocks, spilled)
        .map_err(|e| BuildError::Scratch(format!("cannot read back the spilled per-frame link changes: {e}")))?;
    let cameras = match scene.camera_keys.is_empty() {
        true => Vec::new(),
        false => (0..anim.frames).map(|f| camera_record(&scene.camera_at(f))).collect(),
    };
    let emissions = match scene.surfaces.iter().all(|s| s.emission_keys.is_empty()) {
        true => Vec::new(),
        false => (0..anim.frames).flat_map(|f| scene.surfaces.iter().map(move |s| s.emission_at(f))).collect(),
    };
    Ok(Some(SequenceContents {
        record: AnimationRecord {
            frames: anim.frames,
            fps: anim.fps,
            instance_count: instances.len() as u32,
            reserved: [0; 5],
        },
        instances: records,
        deltas,
        cameras,
        emissions,
    }))
}

fn camera_record(c: &crate::scene::Camera) -> CameraRecord {
    CameraRecord {
        position: c.position.to_array(),
        look_at: c.look_at.to_array(),
        up: c.up.to_array(),
        fov_y_deg: c.fov_y_deg,
        width: c.width,
        height: c.height,
    }
}

/// Builds `scene` (still or animated) in one trace; see [`Sequence`].
pub fn build_sequence(scene: &Scene, settings: &BuildSettings, progress: &dyn Progress) -> Result<Sequence, String> {
    build_impl(scene, settings, false, None, progress).map(|(s, _)| s).map_err(|e| e.to_string())
}

/// [`build_sequence`] within `bound`: when the links traced would take the
/// build over its budget, workers spill them as sorted runs to a scratch
/// directory, and the links come back as a [`SpilledLinks`] to merge into
/// the archive as it is written ([`crate::archive::write_with_links`]; the
/// contents' link-end columns are then empty). The archive's bytes are
/// those of an unbounded build. A budget below what the build needs at
/// least (the scene, its patches and BVH, the tracers' scratch, the merge)
/// is refused before tracing.
pub fn build_sequence_bounded(
    scene: &Scene,
    settings: &BuildSettings,
    bound: &MemoryBound,
    progress: &dyn Progress,
) -> Result<(Sequence, Option<SpilledLinks>), BuildError> {
    build_impl(scene, settings, false, Some(bound), progress)
}

/// [`build_sequence`], also keeping frame 0's link list in
/// [`Sequence::base`] so that [`Sequence::active_links`] can verify frames.
pub fn build_sequence_with_links(
    scene: &Scene,
    settings: &BuildSettings,
    progress: &dyn Progress,
) -> Result<Sequence, String> {
    build_impl(scene, settings, true, None, progress).map(|(s, _)| s).map_err(|e| e.to_string())
}

/// Resident bytes a build holds per primitive before tracing: the parsed
/// scene, its instances' and the build's columns, the patches'
/// per-primitive records, a grouped mesh's shared vertices and welding
/// map, and their peaks while being made. Measured with a building of 18
/// rooms holding 4.2·10⁶ triangles of meshes (tools/gen_building.py
/// --mesh, docs/notebook/2026-12-02-meshes.md): 418 bytes at its peak before tracing.
const SETUP_BYTES_PER_PRIMITIVE: u64 = 420;

/// Resident bytes per primitive of the BVH while it is built (the same
/// building: 186 bytes above the setup's peak) and of the per-primitive
/// normals tracing keeps.
const BVH_BYTES_PER_PRIMITIVE: u64 = 200;

/// Links held while tracing, at least; the merge's buffers (after
/// tracing, in the tracers' place) fit in as much.
const LEAST_LINKS: u64 = 16 << 20;

/// Resident bytes a build needs whatever its links: per patch (geometry,
/// adjacency, hit counts and each tracer's counts: hits and back hits in
/// u64 and the list of patches it touched), per vertex and per primitive
/// (with the BVH), each tracer's part of a sequence's per-frame link
/// changes, the non-diffuse hit counts. (The tracers' per-pair scratch
/// grows with the rays of a pair: each tracer's link keys for the largest
/// pair are fixed too, added by the caller, and what grows past them is
/// counted as it grows: [`spill::Spill::hold_scratch`].)
fn fixed_build_bytes(
    patches: &Patches,
    prims: usize,
    nd_patches: usize,
    pairs: usize,
    frames: u32,
) -> Vec<(&'static str, u64)> {
    let threads = rayon::current_num_threads() as u64;
    let p = patches.len() as u64;
    let changes = match frames {
        0 | 1 => 0,
        f => trace::part_records(f as usize) as u64 * trace::PART_BYTES_PER_RECORD,
    };
    vec![
        ("patches", p * (12 + 12 + 4 + 4 + 16 + 16 + 8 + 4 + 4) + patches.vertex_position.len() as u64 * 12),
        ("primitives and BVH", prims as u64 * (SETUP_BYTES_PER_PRIMITIVE + BVH_BYTES_PER_PRIMITIVE)),
        ("tracers' scratch", threads * (p * 24 + changes)),
        ("non-diffuse hit counts", (nd_patches * pairs) as u64 * 8),
    ]
}

fn build_impl(
    scene: &Scene,
    settings: &BuildSettings,
    keep_links: bool,
    bound: Option<&MemoryBound>,
    progress: &dyn Progress,
) -> Result<(Sequence, Option<SpilledLinks>), BuildError> {
    settings.validate()?;
    // Resident before the build's own memory: the program and the scene
    // (the budget's uncounted constant covers them).
    let resident_before = crate::memory::resident_now();
    let t0 = Instant::now();
    let dirs = match settings.direction_set {
        DirectionSetKind::Geodesic => DirectionSet::new(settings.frequency)?,
        DirectionSetKind::RaySpace => crate::geodesic::ray_space(ray_space_divisions(settings.frequency))?,
    };
    let mut instances = instances(scene);
    // Motion is applied after parsing checked the base geometry: check again.
    for inst in &instances {
        for p in &inst.primitives {
            if !(p.p.iter().all(|v| v.is_finite()) && p.area() > 0.0) {
                return Err(BuildError::Failed(format!(
                    "surface `{}` at frames {}..={}: keyframed motion makes a primitive degenerate or infinite (a scale through 0?)",
                    scene.surfaces[inst.surface as usize].name, inst.frames.first, inst.frames.last
                )));
            }
            if !p.p.iter().all(|v| v.abs().max_element() <= crate::limits::MAX_COORDINATE) {
                return Err(BuildError::Failed(format!(
                    "surface `{}` at frames {}..={}: keyframed motion moves a corner beyond ±{:e} m, the most an \
                     archive holds",
                    scene.surfaces[inst.surface as usize].name,
                    inst.frames.first,
                    inst.frames.last,
                    crate::limits::MAX_COORDINATE
                )));
            }
        }
    }
    // Under a budget, a scene of many primitives is refused before its
    // patches are cut (they are counted again, with the patches, below).
    if let Some(b) = bound.filter(|_| !keep_links) {
        let n: u64 = instances.iter().map(|i| i.primitives.len() as u64).sum();
        let threads = rayon::current_num_threads() as u64;
        let parts = vec![
            ("primitives and BVH", n * (SETUP_BYTES_PER_PRIMITIVE + BVH_BYTES_PER_PRIMITIVE)),
            ("tracers' scratch", threads * (4 << 20)),
            ("links", LEAST_LINKS),
        ];
        if b.budget < parts.iter().map(|p| p.1).sum() {
            return Err(BuildError::OverBudget { budget: b.budget, parts });
        }
    }
    // Small triangles of still, diffuse surfaces become patches of several
    // (patch::mesh), their instance's primitives reordered group by group.
    let mut triangle_group = Vec::with_capacity(instances.iter().map(|i| i.primitives.len()).sum());
    for inst in &mut instances {
        let surface = &scene.surfaces[inst.surface as usize];
        let diffuse = matches!(scene.materials[surface.material as usize].model, ReflectanceModel::Diffuse { .. });
        if settings.group_triangles && surface.motion.is_none() && !surface.moved && diffuse {
            let g = crate::patch::mesh::group_triangles(&inst.primitives, settings.patch_size);
            inst.primitives = g.order.iter().map(|&i| inst.primitives[i as usize]).collect();
            if inst.shading.len() == g.order.len() {
                inst.shading = g.order.iter().map(|&i| inst.shading[i as usize]).collect();
            }
            triangle_group.extend_from_slice(&g.group);
        } else {
            triangle_group.extend(std::iter::repeat_n(crate::patch::mesh::UNGROUPED, inst.primitives.len()));
        }
    }
    // Columns of exactly the primitives' count: a mesh of 10⁶ triangles
    // must not hold twice its columns while they grow.
    let n_prims: usize = instances.iter().map(|i| i.primitives.len()).sum();
    let mut prims: Vec<Primitive> = Vec::with_capacity(n_prims);
    let mut prim_grain = Vec::with_capacity(n_prims);
    let mut prim_surface = Vec::with_capacity(n_prims);
    let mut active = Vec::with_capacity(n_prims);
    let mut sort_key = Vec::with_capacity(n_prims);
    for inst in &instances {
        for (i, p) in inst.primitives.iter().enumerate() {
            prims.push(*p);
            prim_grain.push(inst.grain);
            prim_surface.push(inst.surface);
            active.push(inst.frames);
            sort_key.push(((inst.surface as u64) << 32) | i as u64);
        }
    }
    // Adjacency may cross primitive edges only within one instance: two
    // instances of a surface are never present in the same frame.
    let prim_instance: Vec<u32> = instances
        .iter()
        .enumerate()
        .flat_map(|(i, inst)| std::iter::repeat_n(i as u32, inst.primitives.len()))
        .collect();
    let mut patches =
        Patches::with_groups(&prims, &prim_instance, &triangle_group, settings.patch_size, settings.cell_order)?;
    // A spatial patch order for still scenes. Sequences keep primitive
    // order (an instance's patches stay together, and frames are compared
    // by patch id), and so do the stills compared with them: a frame of a
    // sequence (moved surfaces), or one built on a sequence's ray grid.
    let still = scene.animation.is_none()
        && settings.grid_bounds.is_none()
        && scene.surfaces.iter().all(|s| s.motion.is_none() && !s.moved);
    if settings.patch_order == crate::patch::order::PatchOrder::Spatial && still {
        patches.renumber(&crate::patch::order::spatial_order(&prims, &patches));
    }
    if let Some(p) = patches.area.iter().position(|&a| a > crate::limits::MAX_PATCH_AREA) {
        return Err(format!(
            "patch {p} has an area of {:e} m², above the {:e} an archive holds: use a smaller --patch-size",
            patches.area[p],
            crate::limits::MAX_PATCH_AREA
        )
        .into());
    }
    let setup_s = t0.elapsed().as_secs_f64();
    let bounds = settings.grid_bounds.unwrap_or_else(|| crate::geometry::bounds_of(&prims));
    let input =
        trace::TraceInput { prims: &prims, active: &active, sort_key: &sort_key, frames: scene.frame_count(), bounds };

    let lobes = reflectance::primitive_lobes(scene, &prim_surface);
    let nd_index = reflectance::nondiffuse_index(&patches, &lobes);
    // Under a budget: what the links may hold before workers spill them
    // (spill::SpillPlan), or a refusal now.
    let spill = match bound {
        Some(b) if !keep_links => {
            let nd = nd_index.iter().filter(|&&i| i != u32::MAX).count();
            let mut parts = fixed_build_bytes(&patches, prims.len(), nd, dirs.len() / 2, scene.frame_count());
            // What the setup left resident beyond its estimate (allocator
            // slack, its temporaries' pages: 70 MiB at 10⁶ patches) stays
            // while tracing: counted as measured. (Of the parts above, the
            // patches and the primitives are resident before tracing; the
            // BVH and the tracers' are not.)
            let setup = parts[0].1 + prims.len() as u64 * SETUP_BYTES_PER_PRIMITIVE;
            let grown = match (resident_before, crate::memory::resident_now()) {
                (Some(before), Some(now)) => now.saturating_sub(before),
                _ => 0,
            };
            parts.push(("setup's resident memory beyond its estimate", grown.saturating_sub(setup)));
            // Every tracer may hold its largest pair's link keys at once,
            // and no spill frees them: fixed, like the counts.
            let workers = rayon::current_num_threads();
            let pair_rays = trace::largest_pair_rays(&dirs, settings.ray_spacing, bounds).unwrap_or(0);
            let pair_scratch = pair_rays.saturating_mul(trace::PAIR_BYTES_PER_RAY);
            parts.push(("a direction pair's link keys per tracer", pair_scratch.saturating_mul(workers as u64)));
            // And the bundle each makes of them while it still holds them
            // (counted with the held bundles only once made), at a link a ray.
            let making = pair_rays.saturating_mul(spill::BUNDLE_BYTES_PER_LINK).saturating_mul(workers as u64);
            parts.push(("the bundle each tracer makes of them", making));
            parts.push(("a run writer's buffer per tracer", (spill::RUN_WRITE_BUFFER * workers) as u64));
            let fixed: u64 = parts.iter().map(|p| p.1).sum();
            if b.budget < fixed.saturating_add(LEAST_LINKS) {
                parts.push(("links", LEAST_LINKS));
                return Err(BuildError::OverBudget { budget: b.budget, parts });
            }
            let plan = spill::SpillPlan::new(b.budget - fixed, workers);
            Some(spill::Spill::new(&b.output, plan, patches.len(), pair_scratch, workers)?)
        }
        _ => None,
    };
    let t1 = Instant::now();
    let traced = trace::trace_all(
        &input,
        &patches,
        &dirs,
        settings.ray_spacing,
        settings.max_bucket,
        &nd_index,
        spill.as_ref(),
        progress,
    )?;
    let trace_s = t1.elapsed().as_secs_f64();

    let t2 = Instant::now();
    let trace::Traced {
        bundles,
        hits: traced_hits,
        nd_hits,
        backs,
        nd_backs,
        deltas: traced_deltas,
        stats: traced_stats,
    } = traced;
    let spilled_any = spill.as_ref().is_some_and(|s| s.run_count() > 0);
    let spilled_deltas = spill.as_ref().and_then(|s| s.delta_file());
    let (table, spilled, bundles) = match spill {
        Some(sp) if spilled_any => {
            // What was never spilled goes too, in runs of consecutive pairs.
            let mut rest = bundles;
            let mut group: Vec<trace::Bundle> = Vec::new();
            for b in rest.drain(..) {
                if group.last().is_some_and(|l| l.pair + 1 != b.pair) {
                    sp.spill(&mut group)?;
                }
                group.push(b);
            }
            sp.spill(&mut group)?;
            let (merge, offsets) = sp.finish(progress)?;
            let table = links::LinkTable {
                offsets,
                other: Vec::new(),
                weight: Vec::new(),
                direction: Vec::new(),
                bucket: Vec::new(),
            };
            (table, Some(merge), Vec::new())
        }
        _ => (links::assemble(&bundles, patches.len(), settings.max_bucket), None, bundles),
    };
    crate::scratch::stop_point("links");
    let base = keep_links.then(|| {
        bundles
            .iter()
            .flat_map(|b| {
                (0..b.a.len()).map(move |i| LinkRecord {
                    pair: b.pair,
                    a: b.a[i],
                    b: b.b[i],
                    bucket_a: b.bucket_a[i],
                    bucket_b: b.bucket_b[i],
                    weight: b.w[i],
                })
            })
            .collect()
    });
    drop(bundles); // the link table now holds them
    let assemble_s = t2.elapsed().as_secs_f64();

    let t3 = Instant::now();
    let library = settings.prototype_library.as_ref().map(crate::reflectance::library::Library::new);
    let (reflectance_contents, rstats) = reflectance::assemble(
        reflectance::Input {
            dirs: &dirs,
            prims: &prims,
            grain: &prim_grain,
            lobes: &lobes,
            patches: &patches,
            nd_hits,
            nd_backs,
            library: library.as_ref(),
            map_method: settings.map_method,
            threshold: settings.table_threshold,
        },
        progress,
    )?;
    let reflectance_s = t3.elapsed().as_secs_f64();

    // Expected hits from geometry: a patch of area A and normal n is crossed
    // by A·|n·d_k|·density_k rays of pair k (both directions of the pair).
    let densities: Vec<f64> =
        (0..dirs.len() as u32 / 2).map(|k| trace::layout(&dirs, settings.ray_spacing, k).density).collect();
    let coverage: Vec<f64> = prims
        .par_iter()
        .map(|p| {
            let n = p.normal().as_dvec3();
            densities
                .iter()
                .enumerate()
                .map(|(k, rho)| n.dot(glam::DVec3::from(dirs.directions[2 * k].map(f64::from))).abs() * rho)
                .sum()
        })
        .collect();
    // A grouped patch sums its triangles', each with its own normal.
    let mut expected = vec![0.0f64; patches.len()];
    for (pi, pp) in patches.primitives.iter().enumerate() {
        if pp.grouped() {
            expected[pp.first_patch as usize] += prims[pi].area() as f64 * coverage[pi];
        } else {
            for p in pp.first_patch..pp.first_patch + pp.grid.cell_count() {
                expected[p as usize] += patches.area[p as usize] as f64 * coverage[pi];
            }
        }
    }
    let expected: Vec<f32> = expected.into_iter().map(|e| e as f32).collect();

    let mut surfaces = Vec::with_capacity(scene.surfaces.len());
    let mut first = 0u32;
    for (si, s) in scene.surfaces.iter().enumerate() {
        let n = instances.iter().filter(|i| i.surface == si as u32).map(|i| i.primitives.len() as u32).sum::<u32>();
        surfaces.push(SurfaceRecord {
            material: s.material,
            first_primitive: first,
            primitive_count: n,
            reserved0: 0,
            emission: s.emission,
            reserved1: 0.0,
        });
        first += n;
    }
    let materials = scene
        .materials
        .iter()
        .map(|m| {
            let mut params = [0.0; 14];
            params[..3].copy_from_slice(&m.model.diffuse());
            if let Some((ks, lobe)) = m.model.lobe() {
                params[3..6].copy_from_slice(&ks);
                params[6] = lobe.alpha_u;
                params[7] = lobe.alpha_v;
                params[8..11].copy_from_slice(&lobe.ior.unwrap_or([0.0; 3]));
            }
            let model = match m.model {
                ReflectanceModel::Diffuse { .. } => layout::model::DIFFUSE,
                ReflectanceModel::RoughConductor { .. } => layout::model::ROUGH_CONDUCTOR,
                ReflectanceModel::BroadSpecular { .. } => layout::model::BROAD_SPECULAR,
            };
            MaterialRecord { model, reserved: 0, params }
        })
        .collect();
    let seq_primitives = patches.primitives.clone();
    let primitives = prims
        .iter()
        .zip(&patches.primitives)
        .zip(&prim_surface)
        .map(|((p, pp), &s)| PrimitiveRecord {
            kind: if pp.grouped() { layout::kind::GROUPED_TRIANGLE } else { p.kind as u32 },
            surface: s,
            grid_u: pp.grid.n_u,
            grid_v: pp.grid.n_v,
            first_patch: pp.first_patch,
            first_vertex: pp.first_vertex,
            cell_order: match pp.grid.order {
                CellOrder::Rows => layout::cell_order::ROWS,
                CellOrder::Tiles => layout::cell_order::TILES,
            },
            reserved: 0,
            corners: p.p.map(|v| v.to_array()),
        })
        .collect();
    let directions = dirs
        .directions
        .iter()
        .zip(&dirs.neighbours)
        .zip(&dirs.solid_angle)
        .map(|((d, n), &w)| DirectionRecord { direction: *d, solid_angle_sr: w as f32, neighbours: *n })
        .collect();
    let c = &scene.camera;
    let stats = BuildStats {
        directions: dirs.len() as u32,
        patches: patches.len() as u32,
        rays: traced_stats.rays,
        hits: traced_stats.hits,
        links: traced_stats.links,
        link_ends: table.offsets.last().copied().unwrap_or(0),
        setup_s,
        trace_s,
        assemble_s,
        tables: rstats.tables as u32,
        tables_cached: rstats.tables_cached as u32,
        orientations: rstats.orientations as u32,
        nondiffuse_patches: reflectance_contents.as_ref().map_or(0, |r| r.patches.len() as u32),
        reflectance_s,
    };
    let contents = ArchiveContents {
        build: BuildRecord {
            frequency: dirs.frequency,
            direction_count: dirs.len() as u32,
            patch_count: patches.len() as u32,
            vertex_count: patches.vertex_position.len() as u32,
            primitive_count: prims.len() as u32,
            surface_count: scene.surfaces.len() as u32,
            material_count: scene.materials.len() as u32,
            link_merge: layout::merge::PATCH_PAIR_DIRECTION,
            direction_set: dirs.kind as u32,
            max_bucket: settings.max_bucket,
            ray_spacing_m: settings.ray_spacing,
            patch_size_m: settings.patch_size,
            ray_count: traced_stats.rays,
            link_count: traced_stats.links,
            link_end_count: table.offsets.last().copied().unwrap_or(0),
            hit_count: traced_stats.hits,
            reserved1: [0; 6],
        },
        camera: camera_record(c),
        surfaces,
        materials,
        primitives,
        directions,
        patch_centre: patches.centre,
        patch_normal: patches.normal,
        patch_area: patches.area,
        patch_primitive: patches.primitive,
        patch_corners: patches.corners,
        patch_hits: traced_hits,
        patch_expected_hits: expected,
        patch_back_hits: backs,
        vertex_position: patches.vertex_position,
        grouped_triangles: patches.mesh_triangles,
        adjacency_offsets: patches.adjacency_offsets,
        adjacency: patches.adjacency,
        link_offsets: table.offsets,
        link_other: table.other,
        link_weight: table.weight,
        link_direction: table.direction,
        link_bucket: table.bucket,
        meta: ArchiveMeta {
            generator: format!("illumnet {}", env!("CARGO_PKG_VERSION")),
            scene: scene.name.clone(),
            surface_names: scene.surfaces.iter().map(|s| s.name.clone()).collect(),
            material_names: scene.materials.iter().map(|m| m.name.clone()).collect(),
        },
        sequence: sequence_sections(scene, &instances, traced_deltas, spilled_deltas)?,
        reflectance: reflectance_contents,
        shading: shading_contents(scene, &instances),
    };
    // Indexed by patch id, whatever order the patches are numbered in.
    let n_patches: usize = seq_primitives.iter().map(|pp| pp.owned_patches() as usize).sum();
    let mut patch_identity = vec![(0, 0, 0); n_patches];
    for (pi, pp) in seq_primitives.iter().enumerate() {
        for cell in 0..pp.owned_patches() {
            patch_identity[(pp.first_patch + cell) as usize] =
                (prim_surface[pi], (sort_key[pi] & 0xffff_ffff) as u32, cell);
        }
    }
    Ok((
        Sequence {
            contents,
            stats,
            frames: scene.frame_count(),
            instances,
            base,
            patch_identity,
            bounds,
            warnings: rstats.warnings,
        },
        spilled,
    ))
}
