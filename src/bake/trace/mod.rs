//! Tracing: one bundle of parallel rays per antipodal direction pair.
//!
//! A bundle is a regular grid of ray lines, `δ` apart in the plane
//! perpendicular to the direction, covering the scene's projection. Grid
//! origins are shifted per direction by the R2 low-discrepancy sequence so
//! the grids of neighbouring directions do not alias with each other or with
//! axis-aligned patch edges.
//!
//! The work is split by concept: `layout` (how a direction's rays are laid
//! out, and the grids of ray origins), `walk` (the walk along one ray: hits
//! to links, hit counts, and for temporal instances the changes at every
//! frame), `changes` (a pair's per-ray changes summed per frame and
//! compressed in parts), `scratch` (a worker's reused buffers and hit
//! counts). This file is the parallel driver, [`trace_all`], and the
//! records the others share.

mod changes;
mod layout;
mod raster;
mod scratch;
mod sort;
mod walk;

use std::sync::Mutex;
use std::sync::atomic::{AtomicU32, AtomicU64};

use glam::{Vec2, Vec3};
use rayon::prelude::*;

pub(super) use changes::{PART_BYTES_PER_RECORD, part_records};
use changes::{accumulate_changes, compress_part};
pub use layout::layout;
use layout::{BundleLayout, estimated_rays, grid_for};
pub(super) use layout::{largest_pair_rays, pair_rays};
use scratch::{Scratch, ScratchLease};
use walk::Walk;

use super::BuildError;
use super::bundle::{Bundle, BundleStats};
use super::spill::Spill;
use crate::archive::deltas::Block;
use crate::archive::presence::FrameSpan;
use crate::geodesic::DirectionSet;
use crate::geometry::Primitive;
use crate::geometry::accel::PrimitiveBvh;
use crate::patch::Patches;
use crate::progress::Progress;

/// Most rays one build may trace; beyond this the ray spacing is surely a mistake.
pub const MAX_RAYS: u64 = 1 << 34;

/// Builds tracing this many rays or more say what they will cost first.
pub const LARGE_RAYS: u64 = 2_000_000_000;

/// `secs` as a rough human duration.
fn duration(secs: f64) -> String {
    match secs {
        s if s < 120.0 => format!("{s:.0} s"),
        s if s < 7200.0 => format!("{:.0} min", s / 60.0),
        s => format!("{:.1} h", s / 3600.0),
    }
}

/// One hit of a ray, with what every frame's walk needs computed once
/// ([`Walk::prepare`](walk::Walk::prepare)): the walk of a ray that meets temporal instances
/// runs once per frame where its hits change (15 times on average in the
/// fan room), so the patch lookup is not repeated per frame.
#[derive(Clone, Copy)]
struct RayHitRecord {
    t: f32,
    primitive: u32,
    uv: Vec2,
    /// Frames the primitive is present in.
    active: FrameSpan,
    /// `normal · d`.
    cos: f32,
    /// Patch hit.
    patch: u32,
}

/// A hit as the BVH reports it, before the walk prepares it (its patch
/// [`UNPREPARED`]).
#[inline]
fn record(h: crate::geometry::accel::PrimitiveHit) -> RayHitRecord {
    RayHitRecord {
        t: h.hit.t,
        primitive: h.primitive,
        uv: h.hit.uv,
        active: FrameSpan::all(1),
        cos: 0.0,
        patch: UNPREPARED,
    }
}

/// Primitives smaller than this many squares of the ray spacing are not
/// scan-converted but tested by the rays that reach their BVH: projecting
/// a primitive onto every pair's grid costs about as much as a few rays'
/// hit tests, and a primitive this small is crossed by fewer than one ray
/// of a pair on average (a mesh of 10⁶ triangles traced 10× slower by
/// rasterisation alone: docs/notebook/2026-12-07-scan-conversion.md). The
/// choice is the primitive's alone, so a sequence and a from-scratch build
/// of one of its frames make it alike.
const RASTER_MIN_AREA: f32 = 1.0;

/// The BVH the rays are tested against: of all primitives for the BVH
/// tracer; for the scan converter, of those it does not rasterise
/// (`rasterised` lists the others), if any.
fn traced_by_bvh(input: &TraceInput<'_>, rasterised: &[u32]) -> Option<PrimitiveBvh> {
    match input.method {
        TraceMethod::Bvh => Some(PrimitiveBvh::for_bundles(input.prims)),
        TraceMethod::Scan => {
            let mut raster = rasterised.iter().peekable();
            let small: Vec<u32> = (0..input.prims.len() as u32).filter(|i| raster.next_if_eq(&i).is_none()).collect();
            (!small.is_empty()).then(|| PrimitiveBvh::of_subset(input.prims, &small))
        }
    }
}

/// Bytes a tracer holds per pair for the primitives it rasterises (their
/// extents on the grid, `raster::Extent`), built with `method` and rays
/// `delta` apart: fixed while it traces.
pub(super) fn extent_bytes(prims: &[Primitive], delta: f32, method: TraceMethod) -> u64 {
    let rasterised = match method {
        TraceMethod::Scan => prims.iter().filter(|p| rasterised(p, delta)).count(),
        TraceMethod::Bvh => 0,
    };
    (rasterised * size_of::<raster::Extent>()) as u64
}

/// Whether the scan converter rasterises `prim` (else the rays test it
/// through the BVH): [`RASTER_MIN_AREA`].
fn rasterised(prim: &Primitive, delta: f32) -> bool {
    prim.area() >= RASTER_MIN_AREA * delta * delta
}

/// The patch of a hit the walk has not prepared yet.
const UNPREPARED: u32 = u32::MAX;

/// A placeholder record (overwritten before it is read).
const EMPTY_HIT: RayHitRecord =
    RayHitRecord { t: 0.0, primitive: 0, uv: Vec2::ZERO, active: FrameSpan { first: 0, last: 0 }, cos: 0.0, patch: 0 };

/// Hits a ray holds in its own slots while a band is scan-converted, at
/// first and at most (more go to an overflow list): a band whose overflow
/// holds more than a hit for every fourth ray doubles them for the next
/// band of the pair (never past 16 hits a ray of a full band).
const SLOTS: (usize, usize) = (4, 64);

/// Puts hit `h` of ray `r` of a band in the ray's next slot of
/// `slots_per_ray`, or in the overflow.
#[inline]
fn place(s: &mut Scratch, slots_per_ray: usize, r: usize, h: RayHitRecord) {
    let n = &mut s.slot_count[r];
    if (*n as usize) < slots_per_ray {
        s.slots[r * slots_per_ray + *n as usize] = h;
    } else {
        s.overflow.push((r as u32, h));
    }
    *n = n.saturating_add(1);
}

/// A link as traced: `(a << 32 | b, bucket at a, bucket at b)`.
type LinkKey = (u64, u8, u8);

/// Bytes of a tracer's per-pair scratch per ray it traces: the link keys,
/// reserved at one link a ray before the pair is traced and not freed
/// (nor spillable) until it is done, and their sort's second buffer
/// (`sort.rs`: the tuples' own, or the keys packed in words and their
/// second half, 16 bytes a key either way). Rays that cross more surfaces
/// need more (counted as they grow, an eighth of the pair's rays at a
/// time), so this is the least a pair needs.
pub(super) const PAIR_BYTES_PER_RAY: u64 = 2 * size_of::<LinkKey>() as u64;

/// How a pair's rays find their hits: the same hits but for rays within
/// rounding of an edge (`raster.rs`); what differs is the cost.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TraceMethod {
    /// Every ray traverses the BVH: the reference the scan converter is
    /// tested against.
    Bvh,
    /// Each primitive is projected onto the pair's ray grid and rasterised
    /// by a watertight fill rule, its distance and surface coordinates
    /// affine along a row (issue 41): no per-ray hit test. The default.
    #[default]
    Scan,
}

/// What to trace: primitives with the frames each is present in.
pub struct TraceInput<'a> {
    /// All primitives: permanent ones and temporal instances.
    pub prims: &'a [Primitive],
    /// Frames each primitive is present in.
    pub active: &'a [FrameSpan],
    /// Build-independent tie-break for hits at equal distance
    /// (`surface << 32 | index within surface`), so that an animated build and
    /// a from-scratch build of one frame order coincident hits alike.
    pub sort_key: &'a [u64],
    /// Frames in the sequence (1 for a still).
    pub frames: u32,
    /// Bounds the ray grids cover (all frames' geometry).
    pub bounds: (Vec3, Vec3),
    /// How rays find their hits.
    pub method: TraceMethod,
}

/// Direction pairs are traced in this many chunks (or one pair per chunk
/// when there are fewer pairs). Each chunk compresses its share of every
/// frame's delta as blocks (one per part, [`part_records`]), so the count
/// is fixed: the archive's bytes must not depend on the number of threads.
const CHUNKS: u32 = 64;

/// Pairs per chunk, and chunks, for `pairs` direction pairs: fixed by the
/// pair count alone, so that shards of a build agree on them.
pub(super) fn chunking(pairs: u32) -> (u32, u32) {
    let per_chunk = pairs.div_ceil(CHUNKS).max(1);
    (per_chunk, pairs.div_ceil(per_chunk))
}

/// Everything tracing produces.
pub struct Traced {
    /// One bundle per direction pair, in pair order: the links of frame 0.
    pub bundles: Vec<Bundle>,
    /// `H_p`: hits per patch.
    pub hits: Vec<u32>,
    /// Per non-diffuse patch and direction pair, rays crossing it.
    pub nd_hits: Vec<u32>,
    /// Per patch, of its `H_p` rays those whose light meets a back face
    /// (in the frame the patch first appears in).
    pub backs: Vec<u32>,
    /// Per non-diffuse patch and direction pair, likewise.
    pub nd_backs: Vec<u32>,
    /// Per part of a chunk of direction pairs (in pair order), per frame,
    /// the changes of the link multiset relative to frame 0, compressed
    /// (`archive::deltas::EncodedDeltas::from_blocks` assembles them); frame
    /// 0's blocks are empty, and stills have just those.
    pub deltas: Vec<Vec<Block>>,
    /// Totals.
    pub stats: BundleStats,
}

/// Per chunk of pairs: its bundles, its parts (a block of every frame's
/// changes each), totals.
type Chunk = (Vec<Bundle>, Vec<Vec<Block>>, BundleStats);

/// Traces every direction pair, or the pairs of the chunks `only` (a
/// shard's: the other pairs are left untraced, their counts zero); see
/// the module docs. With `spill`, workers hand their bundles to it after each pair, which
/// spills them to disk when the build holds too many (`spill.rs`); the
/// bundles returned are those never spilled.
#[allow(clippy::too_many_arguments)]
pub fn trace_all(
    input: &TraceInput<'_>,
    patches: &Patches,
    dirs: &DirectionSet,
    delta: f32,
    max_bucket: u32,
    nd_index: &[u32],
    spill: Option<&Spill>,
    only: Option<std::ops::Range<u32>>,
    progress: &dyn Progress,
) -> Result<Traced, BuildError> {
    let (lo, hi) = input.bounds;
    let pairs = (dirs.len() / 2) as u32;
    let layouts: Vec<BundleLayout> = (0..pairs).map(|k| layout(dirs, delta, k)).collect();
    check_ray_count(input, dirs, &layouts, delta, progress)?;
    let prims = input.prims;
    let nd_count = nd_index.iter().filter(|&&i| i != u32::MAX).count();
    let rasterised: Vec<u32> = match input.method {
        TraceMethod::Scan => (0..prims.len() as u32).filter(|&i| rasterised(&prims[i as usize], delta)).collect(),
        TraceMethod::Bvh => Vec::new(),
    };
    let tracer = Tracer {
        input,
        patches,
        dirs,
        layouts,
        max_bucket,
        packing: sort::Packing::new(patches.len(), max_bucket),
        nd_index,
        spill,
        progress,
        bvh: traced_by_bvh(input, &rasterised),
        normals: prims.iter().map(|p| p.normal()).collect(),
        hit_counts: (0..patches.len()).map(|_| AtomicU64::new(0)).collect(),
        nd_hits: (0..nd_count * pairs as usize).map(|_| AtomicU32::new(0)).collect(),
        back_counts: (0..patches.len()).map(|_| AtomicU64::new(0)).collect(),
        nd_backs: (0..nd_count * pairs as usize).map(|_| AtomicU32::new(0)).collect(),
        eps_t: (hi - lo).length() * 1e-6,
        // Links touching a patch absent from a frame are left out of its
        // changes (the format removes them anyway).
        patch_active: patches.primitive.iter().map(|&p| input.active[p as usize]).collect(),
        rasterised,
        pairs,
        per_chunk: chunking(pairs).0,
    };
    let chunks = only.unwrap_or(0..chunking(pairs).1);
    let traced = (chunks.start * tracer.per_chunk).min(pairs)..(chunks.end * tracer.per_chunk).min(pairs);
    let pool = Mutex::new(Vec::new());
    progress.start("tracing direction bundles", traced.len() as u64);
    let results: Vec<Result<Chunk, BuildError>> =
        chunks.clone().into_par_iter().map(|c| tracer.chunk(c, &pool)).collect();
    progress.finish();
    tracer.finish(results, chunks.len() as u32)
}

/// Refuses a build whose bounds are not finite or that would trace more
/// than [`MAX_RAYS`] rays, before any grid is made; a build of
/// [`LARGE_RAYS`] or more says what it will cost first.
fn check_ray_count(
    input: &TraceInput<'_>,
    dirs: &DirectionSet,
    layouts: &[BundleLayout],
    delta: f32,
    progress: &dyn Progress,
) -> Result<(), BuildError> {
    let (lo, hi) = input.bounds;
    let pairs = layouts.len() as u32;
    let dir_of = |k: u32| Vec3::from(dirs.directions[2 * k as usize]);
    if !(lo.is_finite() && hi.is_finite()) {
        return Err(BuildError::Failed(
            "the scene's bounds are not finite (a transform or keyframe moved geometry to infinity)".into(),
        ));
    }
    let total_rays_f = estimated_rays(layouts, (lo, hi));
    if total_rays_f.is_nan() || total_rays_f > MAX_RAYS as f64 {
        return Err(BuildError::Failed(format!(
            "ray spacing {delta} m would trace about {total_rays_f:.3e} rays (limit {MAX_RAYS}); use a larger spacing"
        )));
    }
    let total_rays: u64 = (0..pairs)
        .map(|k| {
            let g = grid_for(dir_of(k), k, lo, hi, &layouts[k as usize]);
            g.nu * g.nv
        })
        .sum();
    if total_rays > MAX_RAYS {
        return Err(BuildError::Failed(format!(
            "ray spacing {delta} m would trace {total_rays} rays (limit {MAX_RAYS}); use a larger spacing"
        )));
    }
    if total_rays >= LARGE_RAYS {
        // Rates measured on the CI kind of machine (docs/PERFORMANCE.md):
        // about 3 M rays/s per thread for the Cornell box.
        let threads = rayon::current_num_threads().max(1) as f64;
        let secs = total_rays as f64 / (3e6 * threads);
        progress.note(&format!(
            "this build traces {:.2e} rays over {pairs} direction pairs ({} frame{}): roughly {} on {threads} \
             threads; a larger --ray-spacing or a lower --frequency makes it cheaper",
            total_rays as f64,
            input.frames,
            if input.frames == 1 { "" } else { "s" },
            duration(secs),
        ));
    }
    Ok(())
}

/// What every worker shares while tracing: the scene's BVH and normals,
/// the pairs' layouts, and the totals the workers add their counts to.
struct Tracer<'a> {
    input: &'a TraceInput<'a>,
    patches: &'a Patches,
    dirs: &'a DirectionSet,
    layouts: Vec<BundleLayout>,
    max_bucket: u32,
    /// How a pair's link keys pack into words for their sort, when they fit.
    packing: Option<sort::Packing>,
    /// Per patch, its index among non-diffuse patches (`u32::MAX`: diffuse).
    nd_index: &'a [u32],
    spill: Option<&'a Spill>,
    progress: &'a dyn Progress,
    /// The BVH of the primitives rays are tested against
    /// ([`traced_by_bvh`]).
    bvh: Option<PrimitiveBvh>,
    /// Per primitive, its unit normal.
    normals: Vec<Vec3>,
    /// `H_p`, in u64 while counting: a single patch could exceed u32 near
    /// [`MAX_RAYS`].
    hit_counts: Vec<AtomicU64>,
    /// Per non-diffuse patch and pair, rays crossing it.
    nd_hits: Vec<AtomicU32>,
    /// Per patch, of its `H_p` rays those whose light meets a back face.
    back_counts: Vec<AtomicU64>,
    /// Per non-diffuse patch and pair, likewise.
    nd_backs: Vec<AtomicU32>,
    /// Hits closer than this along a ray are one crossing.
    eps_t: f32,
    /// Per patch, the frames it is present in.
    patch_active: Vec<FrameSpan>,
    /// The primitives the scan converter rasterises ([`RASTER_MIN_AREA`]).
    rasterised: Vec<u32>,
    /// Direction pairs, and pairs per chunk.
    pairs: u32,
    per_chunk: u32,
}

impl Tracer<'_> {
    /// The first direction of pair `k`.
    fn dir(&self, k: u32) -> Vec3 {
        Vec3::from(self.dirs.directions[2 * k as usize])
    }

    /// Traces chunk `c` of the pairs with scratch from `pool`: its bundles
    /// (those a bounded build did not spill), its parts of per-frame
    /// changes, totals. Its hit counts go to the shared totals at its end.
    fn chunk(&self, c: u32, pool: &Mutex<Vec<Scratch>>) -> Result<Chunk, BuildError> {
        let frames = self.input.frames as usize;
        // Scratch space comes from a pool: rayon may split the work into
        // as many tasks as chunks, and fresh buffers per task would be
        // grown (and their pages faulted in) again and again.
        let mut s = ScratchLease::take(pool);
        let s = &mut *s;
        if let Some(spill) = self.spill.filter(|_| s.reported == 0) {
            // A new tracer's first pair's keys were counted as fixed.
            s.reported = spill.scratch_credit();
        }
        s.changes.resize_with(frames, Vec::new);
        s.chunk.resize_with(frames, Vec::new);
        s.counts.resize(self.patches.len());
        let mut stats = BundleStats::default();
        let mut bundles = Vec::new();
        let mut parts = Vec::new();
        for k in c * self.per_chunk..((c + 1) * self.per_chunk).min(self.pairs) {
            let (b, st) = self.pair(s, k);
            stats.rays += st.rays;
            stats.hits += st.hits;
            stats.links += st.links;
            bundles.push(b);
            if let Some(spill) = self.spill {
                spill.hold_scratch(s.grown());
                spill.hold(&mut bundles)?;
            }
            // The records held are bounded by a fixed count, not by the
            // budget, so that the blocks do not depend on it.
            if s.chunk.iter().map(Vec::len).sum::<usize>() >= part_records(frames) {
                parts.push(compress_part(s, self.spill)?);
            }
        }
        if let Some(spill) = self.spill {
            spill.end_chunk(&mut bundles)?;
        }
        s.counts.hits.flush(&self.hit_counts);
        s.counts.backs.flush(&self.back_counts);
        parts.push(compress_part(s, self.spill)?);
        Ok((bundles, parts, stats))
    }

    /// Traces pair `k`'s bundle in scratch `s`: every ray of its grid
    /// walked along its hits, frame 0's links merged into the bundle, the
    /// later frames' changes added to the chunk's (`s.chunk`).
    /// Sorts the hits of one ray (`hits`, in any order) along it and
    /// walks them into links and counts; the hits walked.
    fn walk_ray(&self, hits: &mut [RayHitRecord], s: &mut Scratch, g: &layout::Grid, walk: &Walk<'_>, k: u32) -> u64 {
        if hits.is_empty() {
            return 0;
        }
        if hits[0].patch == UNPREPARED {
            walk.prepare(hits);
        }
        let key = self.input.sort_key;
        // By distance, ties by the build-independent key, then by the
        // first frame present (instances of one surface share its keys).
        // Rays meet few surfaces: an insertion sort (stable, like the
        // fallback for many), so hits the order cannot tell apart stay in
        // the order they were found.
        let order = |x: &RayHitRecord, y: &RayHitRecord| {
            x.t.total_cmp(&y.t)
                .then_with(|| key[x.primitive as usize].cmp(&key[y.primitive as usize]))
                .then(x.active.first.cmp(&y.active.first))
        };
        if hits.len() > 32 {
            hits.sort_by(order);
        } else {
            for i in 1..hits.len() {
                let mut j = i;
                while j > 0 && order(&hits[j], &hits[j - 1]).is_lt() {
                    hits.swap(j, j - 1);
                    j -= 1;
                }
            }
        }
        // A ray gives a link at most per hit: more room for keys,
        // counted before it is taken, in steps of an eighth of the
        // pair's rays rather than by doubling.
        if s.keys.capacity() - s.keys.len() < hits.len() {
            let more = usize::try_from(g.nu * g.nv / 8).unwrap_or(usize::MAX).max(hits.len());
            s.keys.reserve_exact(more);
            if let Some(spill) = self.spill {
                spill.hold_scratch(s.grown());
            }
        }
        walk.ray(k, hits, s)
    }

    /// The rays of pair `k`'s grid `g` by scan conversion (`raster.rs`), a
    /// band of rows at a time, each walked in the BVH tracer's order; the
    /// hits walked.
    fn scan(&self, s: &mut Scratch, g: &layout::Grid, d: Vec3, walk: &Walk<'_>, k: u32) -> u64 {
        let frame = raster::GridFrame::new(g, d);
        s.extents.clear();
        s.extents.reserve_exact(self.rasterised.len());
        if let Some(spill) = self.spill {
            spill.hold_scratch(s.grown());
        }
        if let Some(frame) = &frame {
            frame.extents(self.input.prims, &self.rasterised, &mut s.extents);
        }
        let extents = std::mem::take(&mut s.extents);
        // The primitives a band's rows may meet, projected as they start.
        let mut active = std::mem::take(&mut s.projected);
        active.clear();
        let band = (raster::BAND_RAYS / g.nu.max(1)).clamp(1, g.nv.max(1));
        // Slots per ray start anew each pair (so that which hits overflow
        // depends on the pair alone), and hold at most 16 × BAND_RAYS hits.
        s.slots_per_ray = SLOTS.0;
        let (mut next, mut hits) = (0, 0);
        for b0 in (0..g.nv).step_by(band as usize) {
            let b1 = (b0 + band).min(g.nv);
            while next < extents.len() && extents[next].rows.0 < b1 {
                let id = extents[next].primitive;
                if let Some(p) = frame.as_ref().and_then(|f| f.project(id, &self.input.prims[id as usize])) {
                    active.push(p);
                }
                next += 1;
            }
            active.retain(|f| f.rows.1 >= b0);
            // Each ray's hits in its slots, those past them in the
            // overflow.
            let rays = ((b1 - b0) * g.nu) as usize;
            let slots_per_ray = s.slots_per_ray;
            s.slot_count.clear();
            s.slot_count.resize(rays, 0);
            if s.slots.len() < rays * slots_per_ray {
                s.slots.resize(rays * slots_per_ray, EMPTY_HIT);
            }
            s.overflow.clear();
            if let Some(spill) = self.spill {
                spill.hold_scratch(s.grown());
            }
            for f in &active {
                let primitive = f.primitive;
                let p = walk.prepared(primitive);
                let hit = RayHitRecord { primitive, active: p.active, cos: p.cos, ..EMPTY_HIT };
                for jj in f.rows.0.max(b0)..=f.rows.1.min(b1 - 1) {
                    let Some(span) = f.span(jj, g.nu) else { continue };
                    let row = ((jj - b0) * g.nu) as usize;
                    f.row(jj, span, |ii, t, uv| {
                        let h = RayHitRecord { t, uv, patch: p.first_patch + p.grid.cell_at(uv), ..hit };
                        place(s, slots_per_ray, row + ii as usize, h);
                    });
                }
            }
            // The small primitives, by the rays that reach their BVH.
            if let Some(bvh) = &self.bvh {
                for jj in b0..b1 {
                    for ii in 0..g.nu {
                        let r = ((jj - b0) * g.nu + ii) as usize;
                        bvh.all_hits(raster::ray_origin(g, ii, jj), d, |h| {
                            let mut h = record(h);
                            walk.prepare(std::slice::from_mut(&mut h));
                            place(s, slots_per_ray, r, h);
                        });
                    }
                }
            }
            if let Some(spill) = self.spill {
                spill.hold_scratch(s.grown());
            }
            // The overflow by ray (a ray's hits are sorted as it is walked).
            s.overflow.sort_by_key(|o| o.0);
            let most = (SLOTS.1.min(16 * raster::BAND_RAYS as usize / rays.max(1))).max(SLOTS.0);
            if s.overflow.len() * 4 > rays {
                s.slots_per_ray = (slots_per_ray * 2).min(most);
            }
            let mut slots = std::mem::take(&mut s.slots);
            let mut over = 0;
            for r in 0..rays {
                let n = s.slot_count[r] as usize;
                if n == 0 {
                    continue;
                }
                if n <= slots_per_ray {
                    let at = r * slots_per_ray;
                    hits += self.walk_ray(&mut slots[at..at + n], s, g, walk, k);
                } else {
                    let mut many = std::mem::take(&mut s.hits);
                    many.clear();
                    many.extend_from_slice(&slots[r * slots_per_ray..(r + 1) * slots_per_ray]);
                    while over < s.overflow.len() && s.overflow[over].0 == r as u32 {
                        many.push(s.overflow[over].1);
                        over += 1;
                    }
                    hits += self.walk_ray(&mut many, s, g, walk, k);
                    s.hits = many;
                }
            }
            s.slots = slots;
        }
        s.extents = extents;
        s.projected = active;
        hits
    }

    fn pair(&self, s: &mut Scratch, k: u32) -> (Bundle, BundleStats) {
        let (lo, hi) = self.input.bounds;
        let d = self.dir(k);
        let lay = &self.layouts[k as usize];
        let g = grid_for(d, k, lo, hi, lay);
        let walk = Walk {
            input: self.input,
            patches: self.patches,
            normals: &self.normals,
            dir: d,
            eps_t: self.eps_t,
            max_bucket: self.max_bucket,
            beam_width: (1.0 / lay.density).sqrt(),
            sqrt_solid_angle: lay.solid_angle.sqrt(),
            pair: k,
            pairs: self.pairs,
            nd_index: self.nd_index,
            nd_hits: &self.nd_hits,
            nd_backs: &self.nd_backs,
            patch_active: &self.patch_active,
        };
        let mut stats = BundleStats { rays: g.nu * g.nv, ..Default::default() };
        s.keys.clear();
        // Room for a link a ray, counted before the pair is traced (what
        // more it needs is counted after it).
        s.keys.reserve_exact(usize::try_from(g.nu * g.nv).unwrap_or(usize::MAX));
        if let Some(spill) = self.spill {
            spill.hold_scratch(s.grown());
        }
        match self.input.method {
            TraceMethod::Bvh => {
                for jj in 0..g.nv {
                    for ii in 0..g.nu {
                        let mut hits = std::mem::take(&mut s.hits);
                        hits.clear();
                        if let Some(bvh) = &self.bvh {
                            bvh.all_hits(raster::ray_origin(&g, ii, jj), d, |h| hits.push(record(h)));
                        }
                        stats.hits += self.walk_ray(&mut hits, s, &g, &walk, k);
                        s.hits = hits;
                    }
                }
            }
            TraceMethod::Scan => stats.hits += self.scan(s, &g, d, &walk, k),
        }
        stats.links = s.keys.len() as u64;
        let bundle = sort::merged_bundle(k, &mut s.keys, self.packing, &mut s.words, &mut s.sort_buffer);
        accumulate_changes(s, &self.patch_active);
        self.progress.advance(1);
        crate::scratch::stop_point("trace");
        (bundle, stats)
    }

    /// The chunks' results in pair order, and the totals the workers
    /// counted: the first error of a chunk, or everything tracing produces.
    fn finish(self, results: Vec<Result<Chunk, BuildError>>, chunks: u32) -> Result<Traced, BuildError> {
        let mut stats = BundleStats::default();
        let mut bundles = Vec::with_capacity(self.pairs as usize);
        let mut deltas = Vec::with_capacity(chunks as usize);
        for r in results {
            let (b, d, s) = r?;
            stats.rays += s.rays;
            stats.hits += s.hits;
            stats.links += s.links;
            bundles.extend(b);
            deltas.extend(d);
        }
        let hits: Vec<u32> =
            self.hit_counts.into_iter().map(|h| u32::try_from(h.into_inner())).collect::<Result<_, _>>().map_err(
                |_| "a patch is hit by more than 2³² rays: use smaller patches or a larger ray spacing".to_string(),
            )?;
        let nd_hits = self.nd_hits.into_iter().map(AtomicU32::into_inner).collect();
        // At most H_p each, which fits.
        let backs = self.back_counts.into_iter().map(|b| b.into_inner().min(u32::MAX as u64) as u32).collect();
        let nd_backs = self.nd_backs.into_iter().map(AtomicU32::into_inner).collect();
        Ok(Traced { bundles, hits, nd_hits, backs, nd_backs, deltas, stats })
    }
}
