//! Tracing: one bundle of parallel rays per antipodal direction pair.
//!
//! A bundle is a regular grid of ray lines, `δ` apart in the plane
//! perpendicular to the direction, covering the scene's projection. Grid
//! origins are shifted per direction by the R2 low-discrepancy sequence so
//! the grids of neighbouring directions do not alias with each other or with
//! axis-aligned patch edges.

use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use super::BuildError;
use crate::archive::deltas::{Block, BlockCompressor};
use crate::archive::layout::DeltaRecord;
use crate::archive::presence::FrameSpan;
use crate::geodesic::{DirectionSet, DirectionSetKind};
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

/// Links of one direction pair, merged: `a` faces along the pair's first
/// direction `d`, `b` faces back along `−d`, `w` parallel rays with the same
/// buckets joined them. Sorted by `(a, b, bucket_a, bucket_b)`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Bundle {
    /// Index `k` of the pair (directions `2k` and `2k+1`).
    pub pair: u32,
    /// Patch that sends along `d`.
    pub a: Vec<u32>,
    /// Patch that sends along `−d`.
    pub b: Vec<u32>,
    /// Number of rays merged into the link.
    pub w: Vec<u32>,
    /// Bucket of the end at `a` (light received by `a` over this link).
    pub bucket_a: Vec<u8>,
    /// Bucket of the end at `b`.
    pub bucket_b: Vec<u8>,
}

/// Counts from tracing.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BundleStats {
    /// Ray lines traced.
    pub rays: u64,
    /// Hits on surfaces.
    pub hits: u64,
    /// Links before merging.
    pub links: u64,
}

/// The ray grid of one direction: ray `(i, j)` starts at
/// `origin + e1·(i + offset.x)·step + e2·(j + offset.y)·step`.
struct Grid {
    origin: Vec3,
    e1: Vec3,
    e2: Vec3,
    step: f32,
    i0: i64,
    j0: i64,
    nu: u64,
    nv: u64,
    offset: Vec2,
}

/// How a direction's rays are laid out, and how many cross a unit area
/// perpendicular to the direction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BundleLayout {
    /// Spacing of the grid in its own plane (m).
    pub step: f32,
    /// For ray-space bundles, the axis of the common intercept plane.
    pub intercept_axis: Option<usize>,
    /// Rays per m² perpendicular to the direction.
    pub density: f64,
    /// Solid angle the direction stands for (sr).
    pub solid_angle: f64,
}

/// Ray spacing for a direction whose Voronoi cell is `omega` sr: every ray
/// then carries the same étendue `δ_k²·Ω_k = δ²·Ω̄`, so each ray stands for
/// the same share of a patch's emitted power whatever the local density of
/// directions.
pub fn spacing(delta: f32, omega: f64, mean: f64) -> f32 {
    (delta as f64 * (mean / omega).sqrt()) as f32
}

/// The layout of pair `k`'s bundle. Geodesic sets get a grid perpendicular
/// to the direction with the étendue-equalising [`spacing`]; the ray-space
/// baseline gets the 1989 layout, `δ` apart in the intercept plane normal to
/// the direction's cube axis, so its rays are denser by `1/cos` (§3.2).
pub fn layout(dirs: &DirectionSet, delta: f32, k: u32) -> BundleLayout {
    let d = dirs.directions[2 * k as usize];
    let omega = dirs.solid_angle[2 * k as usize];
    match dirs.kind {
        DirectionSetKind::Geodesic => {
            let step = spacing(delta, omega, dirs.mean_solid_angle());
            BundleLayout { step, intercept_axis: None, density: 1.0 / (step as f64).powi(2), solid_angle: omega }
        }
        DirectionSetKind::RaySpace => {
            let axis = (0..3).max_by(|&a, &b| d[a].abs().total_cmp(&d[b].abs())).unwrap_or(0);
            let cos = d[axis].abs() as f64;
            BundleLayout {
                step: delta,
                intercept_axis: Some(axis),
                density: 1.0 / ((delta as f64).powi(2) * cos),
                solid_angle: omega,
            }
        }
    }
}

/// Bytes of a tracer's per-pair scratch per ray it traces: the link keys,
/// reserved at one link a ray before the pair is traced and not freed
/// (nor spillable) until it is done. Rays that cross more surfaces need
/// more (counted as they grow, an eighth of the pair's rays at a time), so
/// this is the least a pair needs.
pub(super) const PAIR_BYTES_PER_RAY: u64 = size_of::<LinkKey>() as u64;

/// Rays of the largest direction pair's bundle within `bounds`, or `None`
/// when the whole build would trace more than its limit (which
/// [`trace_all`] refuses): what one tracer's per-pair scratch grows with,
/// so that a budget is checked against it before any ray is traced.
pub(super) fn largest_pair_rays(dirs: &DirectionSet, delta: f32, (lo, hi): (Vec3, Vec3)) -> Option<u64> {
    let layouts: Vec<BundleLayout> = (0..(dirs.len() / 2) as u32).map(|k| layout(dirs, delta, k)).collect();
    let estimate = estimated_rays(&layouts, (lo, hi));
    if !(lo.is_finite() && hi.is_finite()) || estimate.is_nan() || estimate > MAX_RAYS as f64 {
        return None;
    }
    let dir_of = |k: usize| Vec3::from(dirs.directions[2 * k]);
    layouts.iter().enumerate().map(|(k, lay)| grid_for(dir_of(k), k as u32, lo, hi, lay)).map(|g| g.nu * g.nv).max()
}

/// Rays the bundles of `layouts` would hold over `bounds`, at most,
/// counted in f64 (tiny spacings overflow integer grid sizes): what is
/// checked against [`MAX_RAYS`] before any grid is made.
fn estimated_rays(layouts: &[BundleLayout], (lo, hi): (Vec3, Vec3)) -> f64 {
    let diagonal = (hi - lo).length() as f64;
    layouts
        .iter()
        .map(|lay| {
            let extent = diagonal * if lay.intercept_axis.is_some() { 3.0 } else { 1.0 };
            (extent / lay.step as f64 + 3.0).powi(2)
        })
        .sum()
}

fn grid_for(dir: Vec3, pair: u32, lo: Vec3, hi: Vec3, layout: &BundleLayout) -> Grid {
    let centre = (lo + hi) * 0.5;
    let radius = (hi - lo).length() * 0.5;
    let step = layout.step;
    // For ray-space bundles, points are projected along the direction onto
    // the intercept plane through the centre (normal e_a): (e_a, d·e_a).
    let (e1, e2, offset, reach, intercept) = match layout.intercept_axis {
        None => {
            let (e1, e2) = dir.any_orthonormal_pair();
            // R2 sequence (Roberts 2018): plastic-number increments, fractional
            // parts; decorrelates the grids of neighbouring directions.
            const G: f64 = 1.324_717_957_244_746;
            let offset =
                Vec2::new((0.5 + pair as f64 / G).fract() as f32, (0.5 + pair as f64 / (G * G)).fract() as f32);
            (e1, e2, offset, radius, None)
        }
        Some(a) => {
            let mut axes = [Vec3::X, Vec3::Y, Vec3::Z];
            let ea = axes[a];
            axes.rotate_left(a);
            let cos = dir.dot(ea);
            // Common intercept points: every direction of a face uses one grid.
            // A ray through intercept point p passes closest to the centre up to
            // R·tan θ along d from p: start R·(1 + tan θ) before the plane.
            let tan = (1.0 - cos * cos).max(0.0).sqrt() / cos.abs();
            (axes[1], axes[2], Vec2::splat(0.5), radius * (1.0 + tan), Some((ea, cos)))
        }
    };
    let project = |p: Vec3| match intercept {
        None => p,
        Some((ea, cos)) => p - dir * (p.dot(ea) / cos),
    };
    let (mut u0, mut u1, mut v0, mut v1) = (f32::MAX, f32::MIN, f32::MAX, f32::MIN);
    for c in 0..8 {
        let p = Vec3::new(
            if c & 1 == 0 { lo.x } else { hi.x },
            if c & 2 == 0 { lo.y } else { hi.y },
            if c & 4 == 0 { lo.z } else { hi.z },
        ) - centre;
        let q = project(p);
        u0 = u0.min(q.dot(e1));
        u1 = u1.max(q.dot(e1));
        v0 = v0.min(q.dot(e2));
        v1 = v1.max(q.dot(e2));
    }
    let i0 = ((u0 / step - offset.x).floor() as i64) - 1;
    let i1 = ((u1 / step - offset.x).ceil() as i64) + 1;
    let j0 = ((v0 / step - offset.y).floor() as i64) - 1;
    let j1 = ((v1 / step - offset.y).ceil() as i64) + 1;
    Grid {
        origin: centre - dir * (reach * 1.01 + step),
        e1,
        e2,
        step,
        i0,
        j0,
        nu: (i1 - i0 + 1) as u64,
        nv: (j1 - j0 + 1) as u64,
        offset,
    }
}

/// Ring sizes of a square patch grid: patches within Manhattan distance `b`.
fn ring_size(b: u32) -> f64 {
    (2 * b * b + 2 * b + 1) as f64
}

/// The bucket (§3.4) of a link end: the widest ring of patches whose area
/// does not exceed the beam's footprint on the receiving patch. A ray stands
/// for a beam of cross-section `1/density` spreading over the direction's
/// solid angle `Ω`, so at distance `r` it covers about `(√(1/density) + r√Ω)²`,
/// divided by `|cos θ|` on the receiver; `width` is that beam width at the
/// receiver.
#[inline]
fn bucket_of_beam(width: f64, cos_receiver: f32, area_receiver: f32, max_bucket: u32) -> u8 {
    if max_bucket == 0 || area_receiver <= 0.0 {
        return 0;
    }
    let footprint = width * width / (cos_receiver.abs() as f64).max(1e-3);
    let patches = footprint / area_receiver as f64;
    let mut b = 0;
    while b < max_bucket && ring_size(b + 1) <= patches {
        b += 1;
    }
    b as u8
}

/// One hit of a ray, with what every frame's walk needs computed once
/// ([`Walk::prepare`]): the walk of a ray that meets temporal instances
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

/// A link as traced: `(a << 32 | b, bucket at a, bucket at b)`.
type LinkKey = (u64, u8, u8);

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
}

/// Direction pairs are traced in this many chunks (or one pair per chunk
/// when there are fewer pairs). Each chunk compresses its share of every
/// frame's delta as blocks (one per part, [`part_records`]), so the count
/// is fixed: the archive's bytes must not depend on the number of threads.
const CHUNKS: u32 = 64;

/// Per-frame link changes a chunk holds (over all frames) before it
/// compresses them as a part of its blocks: at least 128 Ki records
/// (2.5 MiB) and 512 per frame, so that a sequence's changes take little
/// memory while they are traced (the fan room's chunks held up to 14 MiB
/// each) and a long sequence's blocks do not shrink to a few records.
/// Fixed by the frame count alone, like [`CHUNKS`], so that the archive's
/// bytes depend on neither the threads nor the budget. (A part is cut
/// after a whole pair: it may exceed this by one pair's records.)
pub(super) fn part_records(frames: usize) -> usize {
    (1usize << 17).max(frames.saturating_mul(512))
}

/// Bytes a tracer holds per record of a part: the record (20), its
/// encoded columns (18) and compressed copy, and the slack of the
/// per-frame lists.
pub(super) const PART_BYTES_PER_RECORD: u64 = 56;

/// Scratch space of one chunk of pairs (reused through a pool).
#[derive(Default)]
struct Scratch {
    hits: Vec<RayHitRecord>,
    keys: Vec<LinkKey>,
    frame_links: Vec<LinkKey>,
    prev_links: Vec<LinkKey>,
    change_frames: Vec<u32>,
    /// Per frame, the current pair's changes at that frame (per ray, unmerged).
    changes: Vec<Vec<DeltaRecord>>,
    /// The current pair's changes relative to frame 0 at the previous frame,
    /// and the next frame's.
    cumulative: Vec<DeltaRecord>,
    next: Vec<DeltaRecord>,
    /// Per frame, the chunk's changes relative to frame 0, in pair order.
    chunk: Vec<Vec<DeltaRecord>>,
    compressor: Option<BlockCompressor>,
    counts: HitCounts,
    /// Per temporal ray: indices of its permanent hits, of its temporal hits
    /// by first frame, of the temporal hits present at the current change
    /// frame, and of all hits present there (each ascending in ray order
    /// but `by_first`).
    permanent: Vec<u32>,
    by_first: Vec<u32>,
    active: Vec<u32>,
    walk: Vec<u32>,
    /// Bytes of the per-pair buffers above reported to a bounded build's
    /// count ([`Scratch::grown`]).
    reported: u64,
}

impl Scratch {
    /// Bytes the per-pair buffers have grown by since last asked (they
    /// grow with a pair's rays and links, and are kept for the next pair).
    fn grown(&mut self) -> u64 {
        fn cap<T>(v: &Vec<T>) -> u64 {
            (v.capacity() * size_of::<T>()) as u64
        }
        let frames: u64 = self.changes.iter().map(cap).sum();
        let bytes = cap(&self.hits)
            + cap(&self.keys)
            + cap(&self.frame_links)
            + cap(&self.prev_links)
            + cap(&self.change_frames)
            + frames
            + cap(&self.cumulative)
            + cap(&self.next)
            + cap(&self.permanent)
            + cap(&self.by_first)
            + cap(&self.active)
            + cap(&self.walk);
        let grown = bytes.saturating_sub(self.reported);
        self.reported = self.reported.max(bytes);
        grown
    }
}

/// Hits per patch counted by one worker and added to the shared totals when
/// its chunk is done: one atomic addition per patch touched instead of one
/// per hit (two workers adding to the same patches' counters hit by hit
/// spent a quarter of the walks in contended atomics).
#[derive(Default)]
struct LocalCounts {
    count: Vec<u64>,
    touched: Vec<u32>,
}

impl LocalCounts {
    #[inline]
    fn add(&mut self, patch: u32) {
        let c = &mut self.count[patch as usize];
        if *c == 0 {
            self.touched.push(patch);
        }
        *c += 1;
    }

    fn flush(&mut self, totals: &[AtomicU64]) {
        for &p in &self.touched {
            totals[p as usize].fetch_add(std::mem::take(&mut self.count[p as usize]), Ordering::Relaxed);
        }
        self.touched.clear();
    }
}

/// A worker's per-patch counts: hits (`H_p`) and, of those, rays whose
/// light meets a back face.
#[derive(Default)]
struct HitCounts {
    hits: LocalCounts,
    backs: LocalCounts,
}

impl HitCounts {
    /// Counts for `patches` patches: 24 bytes a patch, all told (a bounded
    /// build counts them so, `fixed_build_bytes`).
    fn resize(&mut self, patches: usize) {
        for c in [&mut self.hits, &mut self.backs] {
            c.count.resize(patches, 0);
            c.touched.reserve_exact(patches.saturating_sub(c.touched.len()));
        }
    }
}

/// A [`Scratch`] borrowed from a pool, returned when dropped.
struct ScratchLease<'p> {
    pool: &'p std::sync::Mutex<Vec<Scratch>>,
    scratch: Option<Scratch>,
}

impl<'p> ScratchLease<'p> {
    fn take(pool: &'p std::sync::Mutex<Vec<Scratch>>) -> Self {
        let scratch = pool.lock().map(|mut p| p.pop()).unwrap_or_default().unwrap_or_default();
        Self { pool, scratch: Some(scratch) }
    }
}

impl std::ops::Deref for ScratchLease<'_> {
    type Target = Scratch;
    fn deref(&self) -> &Scratch {
        self.scratch.as_ref().expect("held until dropped")
    }
}

impl std::ops::DerefMut for ScratchLease<'_> {
    fn deref_mut(&mut self) -> &mut Scratch {
        self.scratch.as_mut().expect("held until dropped")
    }
}

impl Drop for ScratchLease<'_> {
    fn drop(&mut self) {
        if let (Ok(mut p), Some(s)) = (self.pool.lock(), self.scratch.take()) {
            p.push(s);
        }
    }
}

/// Shared, read-only state of one bundle's walk along its rays.
struct Walk<'a> {
    input: &'a TraceInput<'a>,
    patches: &'a Patches,
    normals: &'a [Vec3],
    dir: Vec3,
    eps_t: f32,
    max_bucket: u32,
    /// `√(1/density)` and `√Ω` of the layout (see [`bucket_of_beam`]).
    beam_width: f64,
    sqrt_solid_angle: f64,
    /// The bundle's direction pair, and the number of pairs.
    pair: u32,
    pairs: u32,
    /// Per patch, its index among non-diffuse patches (`u32::MAX`: diffuse).
    nd_index: &'a [u32],
    /// Per non-diffuse patch and pair, rays crossing it.
    nd_hits: &'a [AtomicU32],
    /// Per non-diffuse patch and pair, of those rays the ones whose light
    /// meets a back face.
    nd_backs: &'a [AtomicU32],
    /// Per patch, the frames it is present in.
    patch_active: &'a [FrameSpan],
}

impl Walk<'_> {
    /// Fills the per-hit fields the walks use.
    fn prepare(&self, hits: &mut [RayHitRecord]) {
        for h in hits {
            let pp = &self.patches.primitives[h.primitive as usize];
            h.active = self.input.active[h.primitive as usize];
            h.cos = self.normals[h.primitive as usize].dot(self.dir);
            h.patch = pp.first_patch + pp.grid.locate(h.uv).cell;
        }
    }

    /// Orders two copies of one surface that meet the ray at one place
    /// facing apart (a two-sided sheet: glTF `doubleSided`) so that the one
    /// facing back up the ray comes first: each side then links to what
    /// faces it, and the copies never link to each other (the tie-break by
    /// primitive would otherwise put either first).
    fn order_sheets(&self, hits: &mut [RayHitRecord]) {
        let surface = |h: &RayHitRecord| self.input.sort_key[h.primitive as usize] >> 32;
        let normal = |h: &RayHitRecord| self.normals[h.primitive as usize];
        for i in 1..hits.len() {
            let (a, b) = (&hits[i - 1], &hits[i]);
            // Opposite normals: not two faces meeting at an edge the ray grazes.
            if a.cos > 0.0
                && b.cos < 0.0
                && b.t - a.t <= self.eps_t
                && surface(a) == surface(b)
                && normal(a).dot(normal(b)) < -0.999
            {
                hits.swap(i - 1, i);
            }
        }
    }

    /// Walks `hits`, the hits present in `frame` in ray order: consecutive
    /// hits facing each other become links (appended to `links`). Hits count
    /// towards `H_p` in the first frame they are present in. Returns hits
    /// counted.
    ///
    /// A counted hit whose light along its facing direction next meets a
    /// back face (the next hit down the ray faces the same way) also counts
    /// towards the patch's back-face rays (`PBAK`, `NDBK`), so that the
    /// energy balance can tell light absorbed by back faces from light that
    /// left the scene.
    fn frame<'h>(
        &self,
        hits: impl Iterator<Item = &'h RayHitRecord>,
        frame: u32,
        links: &mut Vec<LinkKey>,
        counts: &mut HitCounts,
    ) -> u64 {
        let mut counted = 0;
        let mut prev: Option<(u32, f32, u32, bool, f32)> = None; // (patch, t, primitive, faces +d, cos)
        let mut prev_counted = false;
        for h in hits {
            let lo = h.active.first;
            let cos = h.cos;
            if cos == 0.0 {
                continue;
            }
            let forward = cos > 0.0;
            if let Some((_, pt, pp, pf, _)) = prev {
                // One crossing reported twice (shared edge of coplanar
                // primitives): keep the first.
                if h.t - pt <= self.eps_t
                    && pf == forward
                    && pp != h.primitive
                    && self.normals[pp as usize] == self.normals[h.primitive as usize]
                {
                    continue;
                }
            }
            let patch = h.patch;
            let counts_here = frame == lo;
            if counts_here {
                counts.hits.add(patch);
                counted += 1;
                let nd = self.nd_index[patch as usize];
                if nd != u32::MAX {
                    self.nd_hits[nd as usize * self.pairs as usize + self.pair as usize]
                        .fetch_add(1, Ordering::Relaxed);
                }
            }
            // Back faces: a hit facing down the ray followed by another
            // facing down it sends its light into that one's back; a hit
            // facing back up the ray after one facing back up it likewise.
            if let Some((prev_patch, _, _, prev_forward, _)) = prev
                && prev_forward == forward
            {
                if forward && prev_counted {
                    self.add_back(prev_patch, counts);
                } else if !forward && counts_here {
                    self.add_back(patch, counts);
                }
            }
            // A link: the previous hit faces down the ray, this one faces back.
            // (Two triangles of one grouped patch can face each other at
            // grazing incidence; light a patch sends itself is no link.)
            if let (Some((prev_patch, pt, _, true, pcos)), false) = (prev, forward)
                && prev_patch != patch
            {
                // Buckets: each end's footprint from its own incidence.
                let r = h.t - pt;
                let area = &self.patches.area;
                let width = self.beam_width + r as f64 * self.sqrt_solid_angle;
                let ba = bucket_of_beam(width, pcos, area[prev_patch as usize], self.max_bucket);
                let bb = bucket_of_beam(width, cos, area[patch as usize], self.max_bucket);
                links.push((((prev_patch as u64) << 32) | patch as u64, ba, bb));
            }
            prev = Some((patch, h.t, h.primitive, forward, cos));
            prev_counted = counts_here;
        }
        counted
    }

    /// Counts one ray of `patch` (counted in this frame) that meets a back face.
    #[inline]
    fn add_back(&self, patch: u32, counts: &mut HitCounts) {
        counts.backs.add(patch);
        let nd = self.nd_index[patch as usize];
        if nd != u32::MAX {
            self.nd_backs[nd as usize * self.pairs as usize + self.pair as usize].fetch_add(1, Ordering::Relaxed);
        }
    }

    /// One ray: frame 0's links go to `s.keys`; for rays that meet temporal
    /// instances, the changes at later frames go to `s.changes`.
    fn ray(&self, pair: u32, s: &mut Scratch) -> u64 {
        let last = self.input.frames - 1;
        self.prepare(&mut s.hits);
        self.order_sheets(&mut s.hits);
        let all = FrameSpan::all(self.input.frames);
        let present_at = |f: u32| move |h: &&RayHitRecord| h.active.contains(f);
        let temporal = s.hits.iter().any(|h| h.active != all);
        if !temporal {
            // Every hit is present in every frame.
            return self.frame(s.hits.iter(), 0, &mut s.keys, &mut s.counts);
        }
        // The active hits change only where an instance appears or leaves.
        s.change_frames.clear();
        for h in &s.hits {
            let FrameSpan { first: lo, last: hi } = h.active;
            if lo > 0 {
                s.change_frames.push(lo);
            }
            if hi < last {
                s.change_frames.push(hi + 1);
            }
        }
        s.change_frames.sort_unstable();
        s.change_frames.dedup();
        s.prev_links.clear();
        let mut counted = self.frame(s.hits.iter().filter(present_at(0)), 0, &mut s.prev_links, &mut s.counts);
        s.keys.extend_from_slice(&s.prev_links);
        s.prev_links.sort_unstable();
        // Each change frame walks only the hits present in it: the
        // permanent ones and the temporal ones whose frames it falls in
        // (about 4 of the 26 hits of a ray through the fan's disc), kept
        // as ray-ordered index lists rather than found by scanning all.
        s.permanent.clear();
        s.by_first.clear();
        for (i, h) in s.hits.iter().enumerate() {
            if h.active == all {
                s.permanent.push(i as u32);
            } else {
                s.by_first.push(i as u32);
            }
        }
        let hits = &s.hits;
        s.by_first.sort_unstable_by_key(|&i| hits[i as usize].active.first);
        s.active.clear();
        let mut next = 0;
        for i in 0..s.change_frames.len() {
            let f = s.change_frames[i];
            s.active.retain(|&k| hits[k as usize].active.last >= f);
            while next < s.by_first.len() && hits[s.by_first[next] as usize].active.first <= f {
                let k = s.by_first[next];
                if hits[k as usize].active.last >= f {
                    s.active.push(k);
                }
                next += 1;
            }
            s.active.sort_unstable();
            s.walk.clear();
            merge_sorted(&s.permanent, &s.active, &mut s.walk);
            s.frame_links.clear();
            counted += self.frame(s.walk.iter().map(|&k| &hits[k as usize]), f, &mut s.frame_links, &mut s.counts);
            s.frame_links.sort_unstable();
            let out = &mut s.changes[f as usize];
            // A link with an end at a patch absent from f is removed by rule
            // (§5.13): the removal of the links of an instance that has just
            // left needs no record, and the running sums drop what such
            // patches still hold (`accumulate_changes`).
            let present = |p: u32| self.patch_active[p as usize].contains(f);
            diff(&s.prev_links, &s.frame_links, |key, count| {
                let (a, b) = ((key.0 >> 32) as u32, key.0 as u32);
                if present(a) && present(b) {
                    out.push(DeltaRecord { pair, a, b, count, bucket_a: key.1, bucket_b: key.2, reserved: 0 })
                }
            });
            std::mem::swap(&mut s.prev_links, &mut s.frame_links);
        }
        counted
    }
}

/// Appends the union of two ascending lists to `out`, ascending.
fn merge_sorted(a: &[u32], b: &[u32], out: &mut Vec<u32>) {
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        if a[i] < b[j] {
            out.push(a[i]);
            i += 1;
        } else {
            out.push(b[j]);
            j += 1;
        }
    }
    out.extend_from_slice(&a[i..]);
    out.extend_from_slice(&b[j..]);
}

/// Calls `out(key, ±n)` for the multiset difference `new − old` (both sorted).
fn diff(old: &[LinkKey], new: &[LinkKey], mut out: impl FnMut(LinkKey, i32)) {
    let (mut i, mut j) = (0, 0);
    while i < old.len() || j < new.len() {
        let next = match (old.get(i), new.get(j)) {
            (Some(a), Some(b)) => *a.min(b),
            (Some(a), None) => *a,
            (None, Some(b)) => *b,
            (None, None) => unreachable!(),
        };
        let mut n = 0i32;
        while old.get(i) == Some(&next) {
            n -= 1;
            i += 1;
        }
        while new.get(j) == Some(&next) {
            n += 1;
            j += 1;
        }
        if n != 0 {
            out(next, n);
        }
    }
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

/// Traces every direction pair; see the module docs.
/// With `spill`, workers hand their bundles to it after each pair, which
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
    spill: Option<&super::spill::Spill>,
    progress: &dyn Progress,
) -> Result<Traced, BuildError> {
    let (lo, hi) = input.bounds;
    let pairs = (dirs.len() / 2) as u32;
    let dir_of = |k: u32| Vec3::from(dirs.directions[2 * k as usize]);
    let layouts: Vec<BundleLayout> = (0..pairs).map(|k| layout(dirs, delta, k)).collect();
    if !(lo.is_finite() && hi.is_finite()) {
        return Err(BuildError::Failed(
            "the scene's bounds are not finite (a transform or keyframe moved geometry to infinity)".into(),
        ));
    }
    let total_rays_f = estimated_rays(&layouts, (lo, hi));
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
    let prims = input.prims;
    let bvh = PrimitiveBvh::new(prims);
    let normals: Vec<Vec3> = prims.iter().map(|p| p.normal()).collect();
    // u64 while counting: a single patch could exceed u32 near MAX_RAYS.
    let hit_counts: Vec<AtomicU64> = (0..patches.len()).map(|_| AtomicU64::new(0)).collect();
    let nd_count = nd_index.iter().filter(|&&i| i != u32::MAX).count();
    let nd_hits: Vec<AtomicU32> = (0..nd_count * pairs as usize).map(|_| AtomicU32::new(0)).collect();
    let back_counts: Vec<AtomicU64> = (0..patches.len()).map(|_| AtomicU64::new(0)).collect();
    let nd_backs: Vec<AtomicU32> = (0..nd_count * pairs as usize).map(|_| AtomicU32::new(0)).collect();
    let eps_t = (hi - lo).length() * 1e-6;
    let frames = input.frames as usize;
    // Frames each patch is present in: links touching a patch absent from a
    // frame are left out of its changes (the format removes them anyway).
    let patch_active: Vec<FrameSpan> = patches.primitive.iter().map(|&p| input.active[p as usize]).collect();
    let per_chunk = pairs.div_ceil(CHUNKS).max(1);
    let chunks = pairs.div_ceil(per_chunk);
    let trace_pair = |s: &mut Scratch, k: u32| -> (Bundle, BundleStats) {
        let d = dir_of(k);
        let lay = &layouts[k as usize];
        let g = grid_for(d, k, lo, hi, lay);
        let walk = Walk {
            input,
            patches,
            normals: &normals,
            dir: d,
            eps_t,
            max_bucket,
            beam_width: (1.0 / lay.density).sqrt(),
            sqrt_solid_angle: lay.solid_angle.sqrt(),
            pair: k,
            pairs,
            nd_index,
            nd_hits: &nd_hits,
            nd_backs: &nd_backs,
            patch_active: &patch_active,
        };
        let mut stats = BundleStats { rays: g.nu * g.nv, ..Default::default() };
        s.keys.clear();
        // Room for a link a ray, counted before the pair is traced (what
        // more it needs is counted after it).
        s.keys.reserve_exact(usize::try_from(g.nu * g.nv).unwrap_or(usize::MAX));
        if let Some(spill) = spill {
            spill.hold_scratch(s.grown());
        }
        for jj in 0..g.nv {
            let v = ((g.j0 + jj as i64) as f32 + g.offset.y) * g.step;
            for ii in 0..g.nu {
                let u = ((g.i0 + ii as i64) as f32 + g.offset.x) * g.step;
                let origin = g.origin + g.e1 * u + g.e2 * v;
                s.hits.clear();
                bvh.all_hits(origin, d, |h| {
                    s.hits.push(RayHitRecord {
                        t: h.hit.t,
                        primitive: h.primitive,
                        uv: h.hit.uv,
                        active: FrameSpan::all(1),
                        cos: 0.0,
                        patch: 0,
                    })
                });
                if s.hits.is_empty() {
                    continue;
                }
                let key = input.sort_key;
                s.hits.sort_unstable_by(|x, y| {
                    x.t.total_cmp(&y.t).then_with(|| key[x.primitive as usize].cmp(&key[y.primitive as usize]))
                });
                // A ray gives a link at most per hit: more room for keys,
                // counted before it is taken, in steps of an eighth of
                // the pair's rays rather than by doubling.
                if s.keys.capacity() - s.keys.len() < s.hits.len() {
                    let more = usize::try_from(g.nu * g.nv / 8).unwrap_or(usize::MAX).max(s.hits.len());
                    s.keys.reserve_exact(more);
                    if let Some(spill) = spill {
                        spill.hold_scratch(s.grown());
                    }
                }
                stats.hits += walk.ray(k, s);
            }
        }
        stats.links = s.keys.len() as u64;
        s.keys.sort_unstable();
        let merged = s.keys.chunk_by(|x, y| x == y).count();
        let mut bundle = Bundle {
            pair: k,
            a: Vec::with_capacity(merged),
            b: Vec::with_capacity(merged),
            w: Vec::with_capacity(merged),
            bucket_a: Vec::with_capacity(merged),
            bucket_b: Vec::with_capacity(merged),
        };
        for run in s.keys.chunk_by(|x, y| x == y) {
            let (key, ba, bb) = run[0];
            bundle.a.push((key >> 32) as u32);
            bundle.b.push(key as u32);
            bundle.w.push(run.len() as u32);
            bundle.bucket_a.push(ba);
            bundle.bucket_b.push(bb);
        }
        accumulate_changes(s, &patch_active);
        progress.advance(1);
        crate::scratch::stop_point("trace");
        (bundle, stats)
    };
    let pool = std::sync::Mutex::new(Vec::new());
    progress.start("tracing direction bundles", pairs as u64);
    // Per chunk: its bundles, its parts (a block of every frame's changes
    // each), totals.
    type Chunk = (Vec<Bundle>, Vec<Vec<Block>>, BundleStats);
    let compress = |s: &mut Scratch| -> Result<Vec<Block>, BuildError> {
        let error = |e: std::io::Error| BuildError::Failed(format!("cannot compress the per-frame link changes: {e}"));
        if s.compressor.is_none() {
            s.compressor = Some(BlockCompressor::new().map_err(error)?);
        }
        let z = s.compressor.as_mut().expect("just made");
        let mut blocks = s
            .chunk
            .iter_mut()
            .map(|records| {
                let b = z.compress(records);
                records.clear();
                b
            })
            .collect::<std::io::Result<Vec<Block>>>()
            .map_err(error)?;
        if let Some(spill) = spill {
            spill.spill_deltas(&mut blocks)?;
        }
        Ok(blocks)
    };
    let results: Vec<Result<Chunk, BuildError>> = (0..chunks)
        .into_par_iter()
        .map(|c| {
            // Scratch space comes from a pool: rayon may split the work into
            // as many tasks as chunks, and fresh buffers per task would be
            // grown (and their pages faulted in) again and again.
            let mut s = ScratchLease::take(&pool);
            let s = &mut *s;
            if let Some(spill) = spill.filter(|_| s.reported == 0) {
                // A new tracer's first pair's keys were counted as fixed.
                s.reported = spill.scratch_credit();
            }
            s.changes.resize_with(frames, Vec::new);
            s.chunk.resize_with(frames, Vec::new);
            s.counts.resize(patches.len());
            let mut stats = BundleStats::default();
            let mut bundles = Vec::new();
            let mut parts = Vec::new();
            for k in c * per_chunk..((c + 1) * per_chunk).min(pairs) {
                let (b, st) = trace_pair(s, k);
                stats.rays += st.rays;
                stats.hits += st.hits;
                stats.links += st.links;
                bundles.push(b);
                if let Some(spill) = spill {
                    spill.hold_scratch(s.grown());
                    spill.hold(&mut bundles)?;
                }
                // The records held are bounded by a fixed count, not by the
                // budget, so that the blocks do not depend on it.
                if s.chunk.iter().map(Vec::len).sum::<usize>() >= part_records(frames) {
                    parts.push(compress(s)?);
                }
            }
            if let Some(spill) = spill {
                spill.end_chunk(&mut bundles)?;
            }
            s.counts.hits.flush(&hit_counts);
            s.counts.backs.flush(&back_counts);
            parts.push(compress(s)?);
            Ok((bundles, parts, stats))
        })
        .collect();
    progress.finish();
    let mut stats = BundleStats::default();
    let mut bundles = Vec::with_capacity(pairs as usize);
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
        hit_counts.into_iter().map(|h| u32::try_from(h.into_inner())).collect::<Result<_, _>>().map_err(|_| {
            "a patch is hit by more than 2³² rays: use smaller patches or a larger ray spacing".to_string()
        })?;
    let nd_hits = nd_hits.into_iter().map(AtomicU32::into_inner).collect();
    // At most H_p each, which fits.
    let backs = back_counts.into_iter().map(|b| b.into_inner().min(u32::MAX as u64) as u32).collect();
    let nd_backs = nd_backs.into_iter().map(AtomicU32::into_inner).collect();
    Ok(Traced { bundles, hits, nd_hits, backs, nd_backs, deltas, stats })
}

/// Turns the current pair's per-ray changes (`s.changes`, per frame) into
/// its changes relative to frame 0 at every frame, appended to `s.chunk`:
/// frame `f`'s list is frame `f − 1`'s merged with the changes at `f`, less
/// the records with an end at a patch that has left before `f`. The format
/// removes links with an end at an absent patch from every frame (§5.13),
/// so neither their removal when a patch leaves (`Walk::ray` writes none)
/// nor frame 0's links of instances that have left need records (they were
/// 35–40% of the fan room's); every record kept has both ends present.
/// Pairs whose links never change append nothing.
fn accumulate_changes(s: &mut Scratch, patch_active: &[FrameSpan]) {
    s.cumulative.clear();
    for f in 1..s.changes.len() {
        let changes = &mut s.changes[f];
        if changes.is_empty() && s.cumulative.is_empty() {
            continue;
        }
        let frame = f as u32;
        // Patches never return once they leave (instances span one run of
        // frames): what the sum holds for them is dropped for good.
        let gone = |d: &DeltaRecord| patch_active[d.a as usize].last < frame || patch_active[d.b as usize].last < frame;
        // Sum the rays' changes of one link.
        changes.sort_unstable_by_key(record_key);
        let mut n = 0;
        for i in 0..changes.len() {
            if n > 0 && record_key(&changes[n - 1]) == record_key(&changes[i]) {
                changes[n - 1].count += changes[i].count;
            } else {
                changes[n] = changes[i];
                n += 1;
            }
        }
        changes.truncate(n);
        s.next.clear();
        let (prev, add) = (&s.cumulative, &*changes);
        let (mut i, mut j) = (0, 0);
        while i < prev.len() || j < add.len() {
            let d = match (prev.get(i), add.get(j)) {
                (Some(p), Some(c)) => match record_key(p).cmp(&record_key(c)) {
                    std::cmp::Ordering::Less => {
                        i += 1;
                        *p
                    }
                    std::cmp::Ordering::Greater => {
                        j += 1;
                        *c
                    }
                    std::cmp::Ordering::Equal => {
                        i += 1;
                        j += 1;
                        DeltaRecord { count: p.count + c.count, ..*p }
                    }
                },
                (Some(p), None) => {
                    i += 1;
                    *p
                }
                (None, Some(c)) => {
                    j += 1;
                    *c
                }
                (None, None) => unreachable!(),
            };
            if d.count != 0 && !gone(&d) {
                s.next.push(d);
            }
        }
        changes.clear();
        std::mem::swap(&mut s.cumulative, &mut s.next);
        debug_assert!(
            s.cumulative.iter().all(|d| [d.a, d.b].iter().all(|&p| patch_active[p as usize].contains(frame)))
        );
        s.chunk[f].extend_from_slice(&s.cumulative);
    }
}

/// The order of one pair's records: `(a, b, bucket_a, bucket_b)`.
#[inline]
fn record_key(d: &DeltaRecord) -> u128 {
    ((d.a as u128) << 48) | ((d.b as u128) << 16) | ((d.bucket_a as u128) << 8) | d.bucket_b as u128
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geodesic::ray_space;

    /// Rays of pair `k`'s bundle that cross a square of side `side` centred at
    /// the origin, perpendicular to the direction.
    fn rays_through_square(dirs: &DirectionSet, delta: f32, k: u32, side: f32) -> (u64, Vec3) {
        let d = Vec3::from(dirs.directions[2 * k as usize]);
        let (lo, hi) = (Vec3::splat(-1.0), Vec3::splat(1.0));
        let lay = layout(dirs, delta, k);
        let g = grid_for(d, k, lo, hi, &lay);
        let (e1, e2) = d.any_orthonormal_pair();
        let mut n = 0;
        for j in 0..g.nv {
            for i in 0..g.nu {
                let o = g.origin
                    + g.e1 * ((g.i0 + i as i64) as f32 + g.offset.x) * g.step
                    + g.e2 * ((g.j0 + j as i64) as f32 + g.offset.y) * g.step;
                // Where the ray crosses the plane through the origin perpendicular to d.
                let x = o - d * o.dot(d);
                if x.dot(e1).abs() < side / 2.0 && x.dot(e2).abs() < side / 2.0 {
                    n += 1;
                }
            }
        }
        (n, d)
    }

    #[test]
    fn ray_space_rays_are_denser_by_one_over_cos_on_oblique_directions() {
        // See: issue #3. §3.2: common intercept points make oblique rays denser.
        let dirs = ray_space(8).unwrap();
        let delta = 0.01;
        let side = 1.0;
        // The most oblique direction and the most normal one.
        let cos_of = |k: u32| {
            let d = dirs.directions[2 * k as usize];
            d.iter().fold(0.0f32, |m, x| m.max(x.abs()))
        };
        let pairs = dirs.len() as u32 / 2;
        let oblique = (0..pairs).min_by(|&a, &b| cos_of(a).total_cmp(&cos_of(b))).unwrap();
        let normal = (0..pairs).max_by(|&a, &b| cos_of(a).total_cmp(&cos_of(b))).unwrap();
        let (n_obl, _) = rays_through_square(&dirs, delta, oblique, side);
        let (n_nrm, _) = rays_through_square(&dirs, delta, normal, side);
        let expect = |k: u32| side * side / (delta * delta * cos_of(k));
        for (n, k) in [(n_obl, oblique), (n_nrm, normal)] {
            assert!((n as f32 / expect(k) - 1.0).abs() < 0.02, "pair {k}: {n} rays, predicted {}", expect(k));
        }
        // The bias between the two: 1/cos θ of the oblique direction (≈ 1.6 here).
        let predicted = cos_of(normal) / cos_of(oblique);
        let measured = n_obl as f32 / n_nrm as f32;
        assert!(predicted > 1.5, "{predicted}");
        assert!((measured / predicted - 1.0).abs() < 0.03, "bias {measured}, predicted {predicted}");

        // Geodesic bundles: the same density 1/δ_k² in every direction.
        let geo = DirectionSet::new(8).unwrap();
        for k in [0, 77, 160] {
            let (n, _) = rays_through_square(&geo, delta, k, side);
            let lay = layout(&geo, delta, k);
            assert!((n as f64 / lay.density - 1.0).abs() < 0.02, "geodesic pair {k}: {n} vs {}", lay.density);
        }
    }
}
