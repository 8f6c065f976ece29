//! Tracing a direction pair's bundle by scan conversion (`--tracer scan`,
//! issue 41): instead of traversing the BVH once per ray, each BVH
//! reference (a primitive, or a strip of a long quad) is projected onto
//! the pair's ray grid, and only the rays its leaf box can meet are tested
//! against it, a band of grid rows at a time.
//!
//! The hits of a ray are then exactly those [`PrimitiveBvh::all_hits`]
//! finds: traversal reaches a reference exactly when the line meets its
//! leaf's box, and [`PrimitiveBvh::reference_hit`] makes that test and the
//! reference's own with the same code on the same line (the rays' origins
//! computed as the BVH tracer computes them, [`ray_origin`]). The
//! projection only has to be conservative: a candidate the box test turns
//! down costs a test, nothing more. So the links, counts and frame deltas,
//! and the archive, are the BVH tracer's byte for byte (tested), and a ray
//! that crosses nothing costs nothing.

use glam::{DVec2, DVec3, Vec3};

use super::layout::Grid;
use crate::geometry::accel::PrimitiveBvh;

/// Cells of margin around a projected box: the projection is computed in
/// f64 from f32 corners, far closer than this to the rays' own f32
/// arithmetic; the box test on each candidate decides.
const MARGIN: f64 = 1.5;

/// Rays a band holds at most (its rows × the grid's columns): the
/// fragments of about this many rays are held at once, some megabytes.
pub(super) const BAND_RAYS: u64 = 1 << 16;

/// The origin of ray `(ii, jj)` of grid `g`: the one expression both
/// tracers use, so that their lines are the same bit for bit.
#[inline]
pub(super) fn ray_origin(g: &Grid, ii: u64, jj: u64) -> Vec3 {
    let v = ((g.j0 + jj as i64) as f32 + g.offset.y) * g.step;
    let u = ((g.i0 + ii as i64) as f32 + g.offset.x) * g.step;
    g.origin + g.e1 * u + g.e2 * v
}

/// A reference's footprint on a pair's grid: the convex hull of its leaf
/// box's corners in cell coordinates (x along `e1`, y along `e2`, ray
/// `(ii, jj)` at `(ii, jj)`), and the rows it may cover.
pub(super) struct Footprint {
    /// The reference (`PrimitiveBvh` order).
    pub(super) id: u32,
    /// First and last row it may cover (within the grid).
    pub(super) rows: (u64, u64),
    hull: Vec<DVec2>,
}

impl Footprint {
    /// Columns of row `jj` the reference may cover (within `0..nu`), or
    /// `None`.
    pub(super) fn span(&self, jj: u64, nu: u64) -> Option<(u64, u64)> {
        let (y0, y1) = (jj as f64 - MARGIN, jj as f64 + MARGIN);
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        let n = self.hull.len();
        for i in 0..n {
            let (a, b) = (self.hull[i], self.hull[(i + 1) % n]);
            if a.y >= y0 && a.y <= y1 {
                lo = lo.min(a.x);
                hi = hi.max(a.x);
            }
            for y in [y0, y1] {
                if (a.y - y) * (b.y - y) < 0.0 {
                    let x = a.x + (b.x - a.x) * (y - a.y) / (b.y - a.y);
                    lo = lo.min(x);
                    hi = hi.max(x);
                }
            }
        }
        // Nothing collected (or NaN): the row misses the hull.
        if lo.partial_cmp(&hi).is_none_or(|o| o == std::cmp::Ordering::Greater) {
            return None;
        }
        let (lo, hi) = ((lo - MARGIN).floor().max(0.0), (hi + MARGIN).ceil());
        if hi < 0.0 || lo > (nu - 1) as f64 {
            return None;
        }
        Some((lo as u64, (hi as u64).min(nu - 1)))
    }
}

/// The footprints of every reference of `bvh` on grid `g` (direction
/// `d`) that meets it, ordered by their first row.
pub(super) fn footprints(bvh: &PrimitiveBvh, g: &Grid, d: Vec3) -> Vec<Footprint> {
    let (e1, e2, d) = (g.e1.as_dvec3(), g.e2.as_dvec3(), d.as_dvec3());
    let origin = g.origin.as_dvec3();
    // Lines run along `d` through the grid's plane (spanned by e1 and e2,
    // perpendicular to d or, for ray-space bundles, to an axis).
    let n = e1.cross(e2);
    let dn = d.dot(n);
    let step = g.step as f64;
    let cell = |p: DVec3| {
        let q = p - origin;
        let q = q - d * (q.dot(n) / dn);
        DVec2::new(
            q.dot(e1) / step - g.offset.x as f64 - g.i0 as f64,
            q.dot(e2) / step - g.offset.y as f64 - g.j0 as f64,
        )
    };
    let mut out = Vec::new();
    for id in 0..bvh.references() {
        let (lo, hi) = bvh.leaf_bounds(id);
        let (lo, hi) = (lo.as_dvec3(), hi.as_dvec3());
        if !(lo.is_finite() && hi.is_finite() && lo.cmple(hi).all()) {
            continue;
        }
        let corners: Vec<DVec2> = (0..8)
            .map(|c| {
                cell(DVec3::new(
                    if c & 1 == 0 { lo.x } else { hi.x },
                    if c & 2 == 0 { lo.y } else { hi.y },
                    if c & 4 == 0 { lo.z } else { hi.z },
                ))
            })
            .collect();
        let (y0, y1) = corners.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), c| (a.min(c.y), b.max(c.y)));
        let (first, last) = ((y0 - MARGIN).floor().max(0.0), (y1 + MARGIN).ceil());
        let empty = first.partial_cmp(&last).is_none_or(|o| o == std::cmp::Ordering::Greater);
        if empty || last < 0.0 || first > (g.nv - 1) as f64 {
            continue;
        }
        let rows = (first as u64, (last as u64).min(g.nv - 1));
        out.push(Footprint { id: id as u32, rows, hull: hull(corners) });
    }
    out.sort_by_key(|f| (f.rows.0, f.id));
    out
}

/// The convex hull of `points`, counter-clockwise (Andrew's monotone
/// chain); a degenerate set gives its extreme points.
fn hull(mut points: Vec<DVec2>) -> Vec<DVec2> {
    points.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    points.dedup();
    if points.len() < 3 {
        return points;
    }
    let cross = |o: DVec2, a: DVec2, b: DVec2| (a - o).perp_dot(b - o);
    let mut h: Vec<DVec2> = Vec::with_capacity(2 * points.len());
    // The lower chain left to right, then the upper one back.
    let chain = |h: &mut Vec<DVec2>, p: DVec2, start: usize| {
        while h.len() >= start + 2 && cross(h[h.len() - 2], h[h.len() - 1], p) <= 0.0 {
            h.pop();
        }
        h.push(p);
    };
    for &p in &points {
        chain(&mut h, p, 0);
    }
    h.pop();
    let start = h.len();
    for &p in points.iter().rev() {
        chain(&mut h, p, start);
    }
    h.pop();
    h
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_hull_holds_its_points_and_a_span_its_row() {
        let pts = vec![
            DVec2::new(0.0, 0.0),
            DVec2::new(4.0, 1.0),
            DVec2::new(1.0, 5.0),
            DVec2::new(2.0, 2.0),
            DVec2::new(4.0, 1.0),
        ];
        let h = hull(pts);
        assert_eq!(h.len(), 3, "{h:?}");
        let f = Footprint { id: 0, rows: (0, 5), hull: h };
        // Row 3: the triangle spans x in about [0.6, 2.8] there, with the
        // margin's rows around it.
        let (a, b) = f.span(3, 100).unwrap();
        assert!(a == 0 && (4..=6).contains(&b), "{a}..{b}");
        assert!(f.span(9, 100).is_none());
        // Clamped to the grid's columns.
        assert_eq!(f.span(3, 2), Some((0, 1)));
    }
}
