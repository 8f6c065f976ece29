//! Bundle layouts and ray grids: how far apart a direction's parallel
//! rays are ([`layout`], [`spacing`]), the grid of ray origins that covers
//! the scene's bounds ([`grid_for`]), and how many rays a build would trace,
//! checked before any is ([`estimated_rays`], [`largest_pair_rays`]).
//!
//! Grid origins are shifted per direction by the R2 low-discrepancy
//! sequence so the grids of neighbouring directions do not alias with each
//! other or with axis-aligned patch edges.

use glam::{Vec2, Vec3};

use super::MAX_RAYS;
use crate::geodesic::{DirectionSet, DirectionSetKind};

/// The ray grid of one direction: ray `(i, j)` starts at
/// `origin + e1·(i + offset.x)·step + e2·(j + offset.y)·step`.
pub(super) struct Grid {
    pub(super) origin: Vec3,
    pub(super) e1: Vec3,
    pub(super) e2: Vec3,
    pub(super) step: f32,
    pub(super) i0: i64,
    pub(super) j0: i64,
    pub(super) nu: u64,
    pub(super) nv: u64,
    pub(super) offset: Vec2,
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

/// Rays of the largest direction pair's bundle within `bounds`, or `None`
/// when the whole build would trace more than its limit (which
/// [`trace_all`](super::trace_all) refuses): what one tracer's per-pair scratch grows with,
/// so that a budget is checked against it before any ray is traced.
pub(in crate::bake) fn largest_pair_rays(dirs: &DirectionSet, delta: f32, (lo, hi): (Vec3, Vec3)) -> Option<u64> {
    let layouts: Vec<BundleLayout> = (0..(dirs.len() / 2) as u32).map(|k| layout(dirs, delta, k)).collect();
    let estimate = estimated_rays(&layouts, (lo, hi));
    if !(lo.is_finite() && hi.is_finite()) || estimate.is_nan() || estimate > MAX_RAYS as f64 {
        return None;
    }
    let dir_of = |k: usize| Vec3::from(dirs.directions[2 * k]);
    layouts.iter().enumerate().map(|(k, lay)| grid_for(dir_of(k), k as u32, lo, hi, lay)).map(|g| g.nu * g.nv).max()
}

/// Rays each pair's bundle traces over `bounds` (its grid's size): the
/// work a sharded build balances. Call after the ray count was checked.
pub(in crate::bake) fn pair_rays(dirs: &DirectionSet, delta: f32, (lo, hi): (Vec3, Vec3)) -> Vec<u64> {
    let dir_of = |k: u32| Vec3::from(dirs.directions[2 * k as usize]);
    (0..(dirs.len() / 2) as u32)
        .map(|k| {
            let g = grid_for(dir_of(k), k, lo, hi, &layout(dirs, delta, k));
            g.nu * g.nv
        })
        .collect()
}

/// Rays the bundles of `layouts` would hold over `bounds`, at most,
/// counted in f64 (tiny spacings overflow integer grid sizes): what is
/// checked against [`MAX_RAYS`] before any grid is made.
pub(super) fn estimated_rays(layouts: &[BundleLayout], (lo, hi): (Vec3, Vec3)) -> f64 {
    let diagonal = (hi - lo).length() as f64;
    layouts
        .iter()
        .map(|lay| {
            let extent = diagonal * if lay.intercept_axis.is_some() { 3.0 } else { 1.0 };
            (extent / lay.step as f64 + 3.0).powi(2)
        })
        .sum()
}

/// The ray grid of pair `pair`'s bundle, direction `dir`, laid out as
/// `layout` says over the bounds `lo`..`hi`.
pub(super) fn grid_for(dir: Vec3, pair: u32, lo: Vec3, hi: Vec3, layout: &BundleLayout) -> Grid {
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
