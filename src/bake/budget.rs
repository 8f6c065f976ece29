//! A bounded build's memory plan: what the build needs whatever its
//! links (the patches, the primitives and their BVH, the tracers'
//! scratch), refused before any work when the budget is below it, and the
//! room left for links, which the tracers spill beyond ([`SpillPlan`]).

use glam::Vec3;

use super::setup::Setup;
use super::spill::{BUNDLE_BYTES_PER_LINK, RUN_WRITE_BUFFER, Spill, SpillPlan};
use super::{BuildError, Instance, MemoryBound, trace};
use crate::patch::{CutSize, Patches};

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
/// counted as it grows: [`Spill::hold_scratch`].)
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

/// Refuses, under `bound`, a scene of more primitives than the budget
/// could hold with the least the tracers and the links need, before its
/// patches are cut (they are counted again, with the patches, in
/// [`spill_within`]).
pub(super) fn refuse_many_primitives(bound: &MemoryBound, instances: &[Instance]) -> Result<(), BuildError> {
    let n: u64 = instances.iter().map(|i| i.primitives.len() as u64).sum();
    let threads = rayon::current_num_threads() as u64;
    let parts = vec![
        ("primitives and BVH", n * (SETUP_BYTES_PER_PRIMITIVE + BVH_BYTES_PER_PRIMITIVE)),
        ("tracers' scratch", threads * (4 << 20)),
        ("links", LEAST_LINKS),
    ];
    if bound.budget < parts.iter().map(|p| p.1).sum() {
        return Err(BuildError::OverBudget { budget: bound.budget, parts });
    }
    Ok(())
}

/// Resident bytes per patch while the patches are cut: their columns
/// (with their growth's slack), each patch's list of neighbours before the
/// lists are packed, the packed table, and the spatial order's copies.
/// Measured (docs/notebook/2026-12-07-coplanar-setup.md) as the setup's
/// peak above the scene's: 138 to 206 bytes a patch for the Cornell box
/// at 1 to 4 mm, 93 to 180 for rows of 25 000 to 100 000 long strips.
const CUT_BYTES_PER_PATCH: u64 = 224;

/// Resident bytes per vertex of the patches (12 bytes, and the growth's
/// slack of its column).
const CUT_BYTES_PER_VERTEX: u64 = 24;

/// Refuses, under `bound`, a cut of `cut` patches (of `prims` primitives)
/// that the budget could not hold with what tracing needs at least,
/// before any patch is cut: a patch size far below the scene's (10⁻⁴ m
/// in a 1 m room: 6·10⁸ patches) had cut until the allocator aborted
/// (issue 42 §4). What the cut made is counted again, as measured, in
/// [`spill_within`].
pub(super) fn refuse_many_patches(bound: &MemoryBound, prims: usize, cut: CutSize) -> Result<(), BuildError> {
    let threads = rayon::current_num_threads() as u64;
    let (p, v) = (cut.patches, cut.vertices);
    let parts = vec![
        ("primitives and BVH", prims as u64 * (SETUP_BYTES_PER_PRIMITIVE + BVH_BYTES_PER_PRIMITIVE)),
        (
            "patches as they are cut",
            p.saturating_mul(CUT_BYTES_PER_PATCH).saturating_add(v.saturating_mul(CUT_BYTES_PER_VERTEX)),
        ),
        ("tracers' scratch", threads.saturating_mul(p.saturating_mul(24))),
        ("links", LEAST_LINKS),
    ];
    if bound.budget < parts.iter().fold(0u64, |a, p| a.saturating_add(p.1)) {
        return Err(BuildError::OverBudget { budget: bound.budget, parts });
    }
    Ok(())
}

/// Under `b`: what the links may hold before workers spill them
/// ([`SpillPlan`]), as the [`Spill`] the tracers spill to, or a refusal
/// now when the budget is below what the build of `setup` (`nd_index` its
/// non-diffuse patches, `frames` frames, traced as `settings` say over
/// `bounds`) needs whatever its links. `resident_before` is what was
/// resident before the setup.
pub(super) fn spill_within(
    b: &MemoryBound,
    setup: &Setup,
    nd_index: &[u32],
    frames: u32,
    settings: &super::BuildSettings,
    bounds: (Vec3, Vec3),
    resident_before: Option<u64>,
) -> Result<Spill, BuildError> {
    let ray_spacing = settings.ray_spacing;
    let (patches, prims, dirs) = (&setup.patches, setup.prims.len(), &setup.dirs);
    let nd = nd_index.iter().filter(|&&i| i != u32::MAX).count();
    let mut parts = fixed_build_bytes(patches, prims, nd, dirs.len() / 2, frames);
    // What the setup left resident beyond its estimate (allocator
    // slack, its temporaries' pages: 70 MiB at 10⁶ patches) stays
    // while tracing: counted as measured. (Of the parts above, the
    // patches and the primitives are resident before tracing; the
    // BVH and the tracers' are not.)
    let setup_estimate = parts[0].1 + prims as u64 * SETUP_BYTES_PER_PRIMITIVE;
    let grown = match (resident_before, crate::memory::resident_now()) {
        (Some(before), Some(now)) => now.saturating_sub(before),
        _ => 0,
    };
    parts.push(("setup's resident memory beyond its estimate", grown.saturating_sub(setup_estimate)));
    // Every tracer may hold its largest pair's link keys at once,
    // and no spill frees them: fixed, like the counts.
    let workers = rayon::current_num_threads();
    let pair_rays = trace::largest_pair_rays(dirs, ray_spacing, bounds).unwrap_or(0);
    let pair_scratch = pair_rays.saturating_mul(trace::PAIR_BYTES_PER_RAY);
    parts.push(("a direction pair's link keys per tracer", pair_scratch.saturating_mul(workers as u64)));
    // And the bundle each makes of them while it still holds them
    // (counted with the held bundles only once made), at a link a ray.
    let making = pair_rays.saturating_mul(BUNDLE_BYTES_PER_LINK).saturating_mul(workers as u64);
    parts.push(("the bundle each tracer makes of them", making));
    parts.push(("a run writer's buffer per tracer", (RUN_WRITE_BUFFER * workers) as u64));
    // The scan converter's extent of every primitive it rasterises.
    let extents = trace::extent_bytes(&setup.prims, ray_spacing, settings.trace_method);
    parts.push(("the scan converter's extents per tracer", extents.saturating_mul(workers as u64)));
    let fixed: u64 = parts.iter().map(|p| p.1).sum();
    if b.budget < fixed.saturating_add(LEAST_LINKS) {
        parts.push(("links", LEAST_LINKS));
        return Err(BuildError::OverBudget { budget: b.budget, parts });
    }
    let plan = SpillPlan::new(b.budget - fixed, workers);
    Ok(Spill::new(&b.output, plan, patches.len(), pair_scratch, workers)?)
}
