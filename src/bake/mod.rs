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
//!
//! `mod.rs` is the API: [`build`], [`build_sequence`] and its bounded and
//! verifying forms, [`BuildSettings`], [`Sequence`]. The stages are files:
//! `setup` (directions, instances cut into patches), `budget` (a bounded
//! build's memory plan), `trace` (the bundles), `links` and `spill` (frame
//! 0's link table, in memory or spilled and merged), `reflectance` (the
//! non-diffuse sections), `assemble` (the archive's contents); `bundle` is
//! the record they pass on, `instances` the temporal instances.

mod assemble;
mod budget;
mod bundle;
mod instances;
mod links;
mod reflectance;
mod settings;
mod setup;
pub mod shard;
mod spill;
mod trace;

use std::time::Instant;

pub use crate::patch::order::PatchOrder;
pub use bundle::BundleStats;
pub use instances::{Instance, instances};
pub use settings::{BuildSettings, DEFAULT_MAX_BUCKET, MAX_BUCKET, Quality, ray_space_divisions};
use spill::Spill;
pub use spill::SpilledLinks;
pub use trace::TraceMethod;

use crate::archive::ArchiveContents;
use crate::archive::presence::{FramePresence, FrameSpan};
use crate::progress::Progress;
use crate::scene::Scene;

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
                write!(
                    f,
                    "); raise --memory-budget, or use larger patches (--patch-size, or the scene's [build] patch_size) or a larger --ray-spacing"
                )
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

/// The build's pipeline: setup (directions, instances, patches), under a
/// budget the memory plan, tracing, frame 0's link table, the reflectance
/// sections, and the archive's contents assembled from them.
fn build_impl(
    scene: &Scene,
    settings: &BuildSettings,
    keep_links: bool,
    bound: Option<&MemoryBound>,
    progress: &dyn Progress,
) -> Result<(Sequence, Option<SpilledLinks>), BuildError> {
    // A build that keeps its links for verification is never bounded.
    let bound = bound.filter(|_| !keep_links);
    let prepared = prepare(scene, settings, bound)?;
    let spill = prepared.spill_plan(bound, settings)?;
    let t1 = Instant::now();
    let traced = prepared.trace(settings, spill.as_ref(), None, progress)?;
    let trace_s = t1.elapsed().as_secs_f64();

    let t2 = Instant::now();
    let trace::Traced { bundles, hits, nd_hits, backs, nd_backs, deltas, stats } = traced;
    let spilled_deltas = spill.as_ref().and_then(|s| s.delta_file());
    let links =
        assemble::link_table(bundles, spill, prepared.setup.patches.len(), settings.max_bucket, keep_links, progress)?;
    let counts = Counts { hits, nd_hits, backs, nd_backs, deltas, spilled_deltas, stats };
    let times = (trace_s, t2.elapsed().as_secs_f64());
    prepared.finish(scene, settings, links, counts, times, progress)
}

/// What a build has made before tracing: the setup, the ray grids'
/// bounds, the materials' lobes and which patches are non-diffuse. A
/// build, each shard of one and their merge make it alike.
struct Prepared {
    setup: setup::Setup,
    bounds: (glam::Vec3, glam::Vec3),
    frames: u32,
    lobes: Vec<Option<crate::reflectance::Lobe>>,
    nd_index: Vec<u32>,
    setup_s: f64,
    /// Resident before the build's own memory: the program and the scene
    /// (the budget's uncounted constant covers them).
    resident_before: Option<u64>,
}

/// What tracing counted, beside the links: from one build, or summed
/// over the shards of one.
struct Counts {
    hits: Vec<u32>,
    nd_hits: Vec<u32>,
    backs: Vec<u32>,
    nd_backs: Vec<u32>,
    deltas: Vec<Vec<crate::archive::deltas::Block>>,
    spilled_deltas: Option<crate::archive::deltas::SpillFile>,
    stats: bundle::BundleStats,
}

/// Directions, instances and patches for `scene`; under `bound`, a scene
/// of too many primitives refused before its patches are cut.
fn prepare(scene: &Scene, settings: &BuildSettings, bound: Option<&MemoryBound>) -> Result<Prepared, BuildError> {
    settings.validate()?;
    let resident_before = crate::memory::resident_now();
    let t0 = Instant::now();
    let dirs = setup::directions(settings)?;
    let instances = instances(scene);
    instances::check_placed(scene, &instances)?;
    // Under a budget, a scene of many primitives is refused before its
    // patches are cut (they are counted again, with the patches, below).
    if let Some(b) = bound {
        budget::refuse_many_primitives(b, &instances)?;
    }
    // And one whose patches it could not hold, before they are cut.
    let refuse_cut = |prims: usize, cut: crate::patch::CutSize| match bound {
        Some(b) => budget::refuse_many_patches(b, prims, cut),
        None => Ok(()),
    };
    let setup = setup::Setup::new(scene, settings, dirs, instances, bound.map(|_| &refuse_cut as &dyn Fn(_, _) -> _))?;
    let setup_s = t0.elapsed().as_secs_f64();
    let bounds = settings.grid_bounds.unwrap_or_else(|| crate::geometry::bounds_of(&setup.prims));
    let lobes = reflectance::primitive_lobes(scene, &setup.prim_surface);
    let nd_index = reflectance::nondiffuse_index(&setup.patches, &lobes);
    Ok(Prepared { setup, bounds, frames: scene.frame_count(), lobes, nd_index, setup_s, resident_before })
}

impl Prepared {
    /// Under `bound`: what the links may hold before workers spill them
    /// (spill::SpillPlan), or a refusal now.
    fn spill_plan(&self, bound: Option<&MemoryBound>, settings: &BuildSettings) -> Result<Option<Spill>, BuildError> {
        bound
            .map(|b| {
                let (setup, nd) = (&self.setup, &self.nd_index);
                budget::spill_within(b, setup, nd, self.frames, settings, self.bounds, self.resident_before)
            })
            .transpose()
    }

    /// Traces every pair, or the chunks `only`.
    fn trace(
        &self,
        settings: &BuildSettings,
        spill: Option<&Spill>,
        only: Option<std::ops::Range<u32>>,
        progress: &dyn Progress,
    ) -> Result<trace::Traced, BuildError> {
        let setup = &self.setup;
        let input = trace::TraceInput {
            prims: &setup.prims,
            active: &setup.active,
            sort_key: &setup.sort_key,
            frames: self.frames,
            bounds: self.bounds,
            method: settings.trace_method,
        };
        let (delta, bucket) = (settings.ray_spacing, settings.max_bucket);
        trace::trace_all(&input, &setup.patches, &setup.dirs, delta, bucket, &self.nd_index, spill, only, progress)
    }

    /// The reflectance sections and the archive's contents, from frame
    /// 0's links and the counts; `times` are tracing's and assembly's.
    fn finish(
        self,
        scene: &Scene,
        settings: &BuildSettings,
        links: assemble::FrameLinks,
        counts: Counts,
        (trace_s, assemble_s): (f64, f64),
        progress: &dyn Progress,
    ) -> Result<(Sequence, Option<SpilledLinks>), BuildError> {
        let assemble::FrameLinks { table, spilled, base } = links;
        let Counts { hits, nd_hits, backs, nd_backs, deltas, spilled_deltas, stats: traced_stats } = counts;
        let setup = self.setup;
        let t3 = Instant::now();
        let (reflectance_contents, rstats) =
            reflectance::sections(settings, &setup, &self.lobes, nd_hits, nd_backs, progress)?;
        let reflectance_s = t3.elapsed().as_secs_f64();

        let stats = BuildStats {
            directions: setup.dirs.len() as u32,
            patches: setup.patches.len() as u32,
            rays: traced_stats.rays,
            hits: traced_stats.hits,
            links: traced_stats.links,
            link_ends: table.offsets.last().copied().unwrap_or(0),
            setup_s: self.setup_s,
            trace_s,
            assemble_s,
            tables: rstats.tables as u32,
            tables_cached: rstats.tables_cached as u32,
            orientations: rstats.orientations as u32,
            nondiffuse_patches: reflectance_contents.as_ref().map_or(0, |r| r.patches.len() as u32),
            reflectance_s,
        };
        let made = assemble::Products {
            hits,
            backs,
            table,
            base,
            deltas,
            spilled_deltas,
            reflectance: reflectance_contents,
            bounds: self.bounds,
            warnings: rstats.warnings,
        };
        Ok((assemble::sequence(scene, settings, setup, made, stats)?, spilled))
    }
}
