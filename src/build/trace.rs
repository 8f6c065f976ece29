//! Tracing: one bundle of parallel rays per antipodal direction pair.
//!
//! A bundle is a regular grid of ray lines, `δ` apart in the plane
//! perpendicular to the direction, covering the scene's projection. Grid
//! origins are shifted per direction by the R2 low-discrepancy sequence so
//! the grids of neighbouring directions do not alias with each other or with
//! axis-aligned patch edges.

use std::sync::atomic::{AtomicU32, Ordering};

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use crate::geodesic::DirectionSet;
use crate::geometry::Primitive;
use crate::geometry::accel::PrimitiveBvh;
use crate::patch::Patches;
use crate::progress::Progress;

/// Most rays one build may trace; beyond this the ray spacing is surely a mistake.
pub const MAX_RAYS: u64 = 1 << 34;

/// Links of one direction pair, merged: `a` faces along the pair's first
/// direction `d`, `b` faces back along `−d`, `w` parallel rays joined them.
/// Sorted by `(a, b)`.
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

/// Everything tracing produces.
pub struct Traced {
    /// One bundle per direction pair, in pair order.
    pub bundles: Vec<Bundle>,
    /// `H_p`: hits per patch.
    pub hits: Vec<u32>,
    /// Totals.
    pub stats: BundleStats,
}

/// The ray grid of one direction.
struct Grid {
    origin: Vec3,
    e1: Vec3,
    e2: Vec3,
    i0: i64,
    j0: i64,
    nu: u64,
    nv: u64,
    offset: Vec2,
}

fn grid_for(dir: Vec3, pair: u32, lo: Vec3, hi: Vec3, delta: f32) -> Grid {
    let centre = (lo + hi) * 0.5;
    let radius = (hi - lo).length() * 0.5;
    let (e1, e2) = dir.any_orthonormal_pair();
    // R2 sequence (Roberts 2018): plastic-number increments, fractional parts.
    const G: f64 = 1.324_717_957_244_746;
    let offset = Vec2::new(
        (0.5 + pair as f64 / G).fract() as f32,
        (0.5 + pair as f64 / (G * G)).fract() as f32,
    );
    let (mut u0, mut u1, mut v0, mut v1) = (f32::MAX, f32::MIN, f32::MAX, f32::MIN);
    for c in 0..8 {
        let p = Vec3::new(
            if c & 1 == 0 { lo.x } else { hi.x },
            if c & 2 == 0 { lo.y } else { hi.y },
            if c & 4 == 0 { lo.z } else { hi.z },
        ) - centre;
        u0 = u0.min(p.dot(e1));
        u1 = u1.max(p.dot(e1));
        v0 = v0.min(p.dot(e2));
        v1 = v1.max(p.dot(e2));
    }
    let i0 = ((u0 / delta - offset.x).floor() as i64) - 1;
    let i1 = ((u1 / delta - offset.x).ceil() as i64) + 1;
    let j0 = ((v0 / delta - offset.y).floor() as i64) - 1;
    let j1 = ((v1 / delta - offset.y).ceil() as i64) + 1;
    Grid {
        origin: centre - dir * (radius * 1.01 + delta),
        e1,
        e2,
        i0,
        j0,
        nu: (i1 - i0 + 1) as u64,
        nv: (j1 - j0 + 1) as u64,
        offset,
    }
}

/// Ray spacing for a direction whose Voronoi cell is `omega` sr: every ray
/// then carries the same étendue `δ_k²·Ω_k = δ²·Ω̄`, so each ray stands for
/// the same share of a patch's emitted power whatever the local density of
/// directions.
pub fn spacing(delta: f32, omega: f64, mean: f64) -> f32 {
    (delta as f64 * (mean / omega).sqrt()) as f32
}

#[derive(Clone, Copy)]
struct RayHitRecord {
    t: f32,
    primitive: u32,
    uv: Vec2,
}

/// Traces every direction pair; see the module docs.
pub fn trace_all(
    prims: &[Primitive],
    patches: &Patches,
    dirs: &DirectionSet,
    delta: f32,
    progress: &dyn Progress,
) -> Result<Traced, String> {
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for p in prims {
        let (a, b) = p.bounds();
        lo = lo.min(a);
        hi = hi.max(b);
    }
    let pairs = (dirs.len() / 2) as u32;
    let dir_of = |k: u32| Vec3::from(dirs.directions[2 * k as usize]);
    let mean = dirs.mean_solid_angle();
    let spacing_of = |k: u32| spacing(delta, dirs.solid_angle[2 * k as usize], mean);
    let total_rays: u64 = (0..pairs)
        .map(|k| {
            let g = grid_for(dir_of(k), k, lo, hi, spacing_of(k));
            g.nu * g.nv
        })
        .sum();
    if total_rays > MAX_RAYS {
        return Err(format!(
            "ray spacing {delta} m would trace {total_rays} rays (limit {MAX_RAYS}); use a larger spacing"
        ));
    }
    let bvh = PrimitiveBvh::new(prims);
    let normals: Vec<Vec3> = prims.iter().map(|p| p.normal()).collect();
    let hits: Vec<AtomicU32> = (0..patches.len()).map(|_| AtomicU32::new(0)).collect();
    let eps_t = (hi - lo).length() * 1e-6;
    progress.start("tracing direction bundles", pairs as u64);
    let results: Vec<(Bundle, BundleStats)> = (0..pairs)
        .into_par_iter()
        .map_init(
            || (Vec::<RayHitRecord>::new(), Vec::<u64>::new()),
            |(ray_hits, keys), k| {
                let d = dir_of(k);
                let delta = spacing_of(k);
                let g = grid_for(d, k, lo, hi, delta);
                let mut stats = BundleStats {
                    rays: g.nu * g.nv,
                    ..Default::default()
                };
                keys.clear();
                for jj in 0..g.nv {
                    let v = ((g.j0 + jj as i64) as f32 + g.offset.y) * delta;
                    for ii in 0..g.nu {
                        let u = ((g.i0 + ii as i64) as f32 + g.offset.x) * delta;
                        let origin = g.origin + g.e1 * u + g.e2 * v;
                        ray_hits.clear();
                        bvh.all_hits(origin, d, |h| {
                            ray_hits.push(RayHitRecord {
                                t: h.hit.t,
                                primitive: h.primitive,
                                uv: h.hit.uv,
                            })
                        });
                        if ray_hits.is_empty() {
                            continue;
                        }
                        ray_hits.sort_unstable_by(|x, y| {
                            x.t.total_cmp(&y.t).then(x.primitive.cmp(&y.primitive))
                        });
                        // Walk the hits in order: (patch, facing) of the previous kept hit.
                        let mut prev: Option<(u32, f32, u32, bool)> = None; // (patch, t, primitive, faces +d)
                        for h in ray_hits.iter() {
                            let cos = normals[h.primitive as usize].dot(d);
                            if cos == 0.0 {
                                continue;
                            }
                            let forward = cos > 0.0;
                            if let Some((_, pt, pp, pf)) = prev {
                                // One crossing reported twice (shared edge of one primitive
                                // set): keep the first.
                                if h.t - pt <= eps_t
                                    && pf == forward
                                    && pp != h.primitive
                                    && normals[pp as usize] == normals[h.primitive as usize]
                                {
                                    continue;
                                }
                            }
                            let pp = &patches.primitives[h.primitive as usize];
                            let patch = pp.first_patch + pp.grid.locate(h.uv).cell;
                            hits[patch as usize].fetch_add(1, Ordering::Relaxed);
                            stats.hits += 1;
                            // A link: the previous hit faces down the ray, this one faces back.
                            if let (Some((prev_patch, _, _, true)), false) = (prev, forward) {
                                keys.push(((prev_patch as u64) << 32) | patch as u64);
                            }
                            prev = Some((patch, h.t, h.primitive, forward));
                        }
                    }
                }
                stats.links = keys.len() as u64;
                keys.sort_unstable();
                let mut bundle = Bundle {
                    pair: k,
                    ..Default::default()
                };
                for run in keys.chunk_by(|x, y| x == y) {
                    bundle.a.push((run[0] >> 32) as u32);
                    bundle.b.push(run[0] as u32);
                    bundle.w.push(run.len() as u32);
                }
                progress.advance(1);
                (bundle, stats)
            },
        )
        .collect();
    progress.finish();
    let mut stats = BundleStats::default();
    let mut bundles = Vec::with_capacity(results.len());
    for (b, s) in results {
        stats.rays += s.rays;
        stats.hits += s.hits;
        stats.links += s.links;
        bundles.push(b);
    }
    Ok(Traced {
        bundles,
        hits: hits.into_iter().map(AtomicU32::into_inner).collect(),
        stats,
    })
}
