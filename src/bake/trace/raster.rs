//! Tracing a direction pair's bundle by scan conversion (`--tracer scan`,
//! issue 41). A bundle's rays are parallel, so what they meet is an
//! orthographic projection of the scene onto the grid's plane: each
//! primitive is projected once per pair ([`Projected`]), rasterised onto
//! the ray grid row by row, and its distance and surface coordinates along
//! a row are affine in the column (a plane, and the parameterisation of a
//! triangle or parallelogram; a general quad's bilinear coordinates are
//! inverted per ray). No ray is tested against anything.
//!
//! **Fill rule.** A ray belongs to a primitive when its grid point lies
//! inside the projected polygon by a half-open rule: rows from the
//! polygon's lowest `y` included to its highest excluded, and in a row the
//! columns from the left crossing included to the right one excluded. Each
//! crossing is computed from its edge's two projected endpoints in a fixed
//! order (lower endpoint first), so two primitives sharing an edge compute
//! the same crossing bit for bit, and a ray on their common edge belongs
//! to exactly one of them: a closed mesh lets no ray through (the BVH
//! tracer's floating-point tests let a few slip through the seams,
//! `tests/tracer.rs`). That holds between rasterised primitives: those
//! smaller than the ray spacing squared are left to the rays, through a
//! BVH of them (`super::RASTER_MIN_AREA`), and a seam between one of those
//! and a rasterised one is as tight as the BVH tracer's.
//!
//! **The difference from the BVH tracer.** Both find the same hits except
//! for rays within rounding of an edge (the fill rule decides where the
//! BVH's f32 tests did), and distances and coordinates that differ in
//! their last bits (f64 affine forms rather than f32 per-ray tests). The
//! archives differ only in the link ends of such rays: counted against
//! the BVH tracer in `tests/tracer.rs`.

use glam::{DVec2, DVec3, Vec2, Vec3};

use super::layout::Grid;
use crate::geometry::{Primitive, PrimitiveKind};

/// Rays a band holds at most (its rows × the grid's columns): the
/// fragments of about this many rays are held at once, some megabytes.
pub(super) const BAND_RAYS: u64 = 1 << 12;

/// The origin of ray `(ii, jj)` of grid `g`, as the BVH tracer computes it.
#[inline]
pub(super) fn ray_origin(g: &Grid, ii: u64, jj: u64) -> Vec3 {
    let v = ((g.j0 + jj as i64) as f32 + g.offset.y) * g.step;
    let u = ((g.i0 + ii as i64) as f32 + g.offset.x) * g.step;
    g.origin + g.e1 * u + g.e2 * v
}

/// `c + a·x + b·y`: a quantity affine in the grid's cell coordinates.
#[derive(Debug, Clone, Copy, Default)]
struct Affine {
    c: f64,
    a: f64,
    b: f64,
}

impl Affine {
    /// The form restricted to row `y`: `(value at column 0, per column)`.
    #[inline]
    fn row(&self, y: f64) -> (f64, f64) {
        (self.c + self.b * y, self.a)
    }
}

/// How a projected primitive's surface coordinates follow the grid.
#[derive(Debug, Clone, Copy)]
enum Param {
    /// Affine: a triangle's barycentrics, or a parallelogram's coordinates.
    Affine(Affine, Affine),
    /// A general quad: its projected corners (`Projected::corners`),
    /// inverted per ray.
    Bilinear,
}

/// A primitive projected onto a pair's ray grid, in cell coordinates (ray
/// `(ii, jj)` at `(ii, jj)`).
#[derive(Debug, Clone, Copy)]
pub(super) struct Projected {
    /// The primitive.
    pub(super) primitive: u32,
    /// First and last grid row it covers.
    pub(super) rows: (u64, u64),
    /// Its projected corners (3 or 4 used), in the primitive's order.
    corners: [DVec2; 4],
    n: usize,
    /// Distance along the rays from their origins to its plane.
    t: Affine,
    param: Param,
}

impl Projected {
    /// The columns `lo..hi` of row `jj` the fill rule gives the primitive
    /// (within `0..nu`), or `None`.
    #[inline]
    pub(super) fn span(&self, jj: u64, nu: u64) -> Option<(u64, u64)> {
        let y = jj as f64;
        let (mut lo, mut hi, mut crossings) = (f64::INFINITY, f64::NEG_INFINITY, 0);
        for i in 0..self.n {
            let (p, q) = (self.corners[i], self.corners[(i + 1) % self.n]);
            // The lower endpoint first, so that both primitives sharing
            // this edge compute its crossing by the same operations.
            let (p, q) = if (p.y, p.x) <= (q.y, q.x) { (p, q) } else { (q, p) };
            if p.y <= y && y < q.y {
                let x = p.x + (q.x - p.x) * ((y - p.y) / (q.y - p.y));
                lo = lo.min(x);
                hi = hi.max(x);
                crossings += 1;
            }
        }
        if crossings < 2 {
            return None;
        }
        let (a, b) = (lo.ceil().max(0.0), hi.ceil().min(nu as f64));
        (a < b).then_some((a as u64, b as u64))
    }

    /// Calls `out(column, t, uv)` for each ray of row `jj`'s columns
    /// `lo..hi` (a [`Self::span`]).
    #[inline]
    pub(super) fn row(&self, jj: u64, (lo, hi): (u64, u64), mut out: impl FnMut(u64, f32, Vec2)) {
        let y = jj as f64;
        let (t0, dt) = self.t.row(y);
        match self.param {
            Param::Affine(u, v) => {
                let ((u0, du), (v0, dv)) = (u.row(y), v.row(y));
                for ii in lo..hi {
                    let x = ii as f64;
                    let t = t0 + dt * x;
                    if t > 0.0 {
                        out(ii, t as f32, Vec2::new((u0 + du * x) as f32, (v0 + dv * x) as f32));
                    }
                }
            }
            Param::Bilinear => {
                let c = self.corners;
                for ii in lo..hi {
                    let x = ii as f64;
                    let t = t0 + dt * x;
                    if t > 0.0 {
                        out(ii, t as f32, inverse_bilinear(DVec2::new(x, y), c).as_vec2());
                    }
                }
            }
        }
    }
}

/// Where a primitive falls on a pair's grid, in 24 bytes: what a pair
/// holds for every primitive it rasterises (the full projection, some
/// 190 bytes, is made only for the band of rows it covers).
#[derive(Debug, Clone, Copy)]
pub(super) struct Extent {
    /// First and last grid row it covers.
    pub(super) rows: (u64, u64),
    /// The primitive.
    pub(super) primitive: u32,
}

/// A pair's grid as the projection sees it: ray `(x, y)` is the line
/// `O + x·E1 + y·E2 + t·D`, and `(p − O)·A = x`, `(p − O)·B = y`.
pub(super) struct GridFrame {
    o: DVec3,
    e1: DVec3,
    e2: DVec3,
    d: DVec3,
    a: Dual,
    nv: u64,
}

/// The dual basis of a [`GridFrame`].
struct Dual {
    x: DVec3,
    y: DVec3,
}

impl GridFrame {
    /// The frame of grid `g` (direction `d`), or `None` for a degenerate
    /// grid (no rays to rasterise onto).
    pub(super) fn new(g: &Grid, d: Vec3) -> Option<Self> {
        let (d, step) = (d.as_dvec3(), g.step as f64);
        let (e1, e2) = (g.e1.as_dvec3() * step, g.e2.as_dvec3() * step);
        let o = g.origin.as_dvec3() + e1 * (g.i0 as f64 + g.offset.x as f64) + e2 * (g.j0 as f64 + g.offset.y as f64);
        let det = e1.dot(e2.cross(d));
        if det == 0.0 || !det.is_finite() {
            return None;
        }
        let a = Dual { x: e2.cross(d) / det, y: d.cross(e1) / det };
        Some(Self { o, e1, e2, d, a, nv: g.nv })
    }

    /// Point `p` in cell coordinates.
    #[inline]
    fn cell(&self, p: DVec3) -> DVec2 {
        let q = p - self.o;
        DVec2::new(q.dot(self.a.x), q.dot(self.a.y))
    }

    /// The corners of `prim` projected, and the grid rows they cover
    /// (`None`: seen edge on, or no row of the grid).
    fn corners(&self, prim: &Primitive) -> Option<([DVec2; 4], (u64, u64))> {
        let n = prim.corner_count();
        let mut corners = [DVec2::ZERO; 4];
        for i in 0..n {
            corners[i] = self.cell(prim.p[i].as_dvec3());
        }
        // Twice the projected area (a fan from the first corner, on
        // differences so that it keeps its precision far from the grid's
        // origin): none, no rays.
        let area2: f64 = (1..n - 1).map(|i| (corners[i] - corners[0]).perp_dot(corners[i + 1] - corners[0])).sum();
        if area2.is_nan() || area2.abs() <= 1e-12 {
            return None;
        }
        let (y0, y1) =
            corners[..n].iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), c| (a.min(c.y), b.max(c.y)));
        let (first, last) = (y0.ceil().max(0.0), (y1.ceil() - 1.0).min(self.nv as f64 - 1.0));
        if first.is_nan() || last.is_nan() || first > last {
            return None;
        }
        Some((corners, (first as u64, last as u64)))
    }

    /// The extents of primitives `ids` of `prims` on this grid, into
    /// `out`, ordered by their first row; primitives that cover no row
    /// are left out.
    pub(super) fn extents(&self, prims: &[Primitive], ids: &[u32], out: &mut Vec<Extent>) {
        out.clear();
        for &id in ids {
            if let Some((_, rows)) = self.corners(&prims[id as usize]) {
                out.push(Extent { rows, primitive: id });
            }
        }
        out.sort_by_key(|e| (e.rows.0, e.primitive));
    }

    /// Primitive `id` (`prim`) projected onto this grid, or `None` when
    /// it covers no ray.
    pub(super) fn project(&self, id: u32, prim: &Primitive) -> Option<Projected> {
        let (corners, rows) = self.corners(prim)?;
        let n = prim.corner_count();
        let p: [DVec3; 4] = prim.p.map(|q| q.as_dvec3());
        // The plane: n·(O + x·E1 + y·E2 + t·D − p0) = 0.
        let normal = match prim.kind {
            PrimitiveKind::Quad => (p[2] - p[0]).cross(p[3] - p[1]),
            PrimitiveKind::Triangle => (p[1] - p[0]).cross(p[2] - p[0]),
        };
        let nd = normal.dot(self.d);
        if nd == 0.0 || !nd.is_finite() {
            return None;
        }
        let t =
            Affine { c: normal.dot(p[0] - self.o) / nd, a: -normal.dot(self.e1) / nd, b: -normal.dot(self.e2) / nd };
        // Surface coordinates: (x, y) = P0 + u·(P1 − P0) + v·(P_last − P0)
        // for a triangle (P2) or a parallelogram (P3).
        let (c0, e) = (corners[0], corners[1] - corners[0]);
        let f = corners[n - 1] - corners[0];
        let skew = corners[0] - corners[1] + corners[2] - corners[3];
        let param = if n == 3 || skew.length() <= 1e-9 * (e.length() + f.length()) {
            let det = e.perp_dot(f);
            if det == 0.0 || !det.is_finite() {
                return None;
            }
            let u = Affine { c: (c0.y * f.x - c0.x * f.y) / det, a: f.y / det, b: -f.x / det };
            let v = Affine { c: (c0.x * e.y - c0.y * e.x) / det, a: -e.y / det, b: e.x / det };
            Param::Affine(u, v)
        } else {
            Param::Bilinear
        };
        Some(Projected { primitive: id, rows, corners, n, t, param })
    }
}

/// The bilinear coordinates of `x` in the quad of corners `c`
/// (`P(u,v) = c0 + u·e + v·f + uv·g`), clamped to `[0, 1]²`: the root
/// nearest the square when rounding puts a point on the edge just outside.
fn inverse_bilinear(x: DVec2, c: [DVec2; 4]) -> DVec2 {
    let (e, f, g, h) = (c[1] - c[0], c[3] - c[0], c[0] - c[1] + c[2] - c[3], x - c[0]);
    let (k2, k1, k0) = (g.perp_dot(f), e.perp_dot(f) + h.perp_dot(g), h.perp_dot(e));
    let roots = if k2.abs() <= 1e-12 * k1.abs() {
        [-k0 / k1, f64::NAN]
    } else {
        let w = (k1 * k1 - 4.0 * k0 * k2).max(0.0).sqrt();
        let q = -0.5 * (k1 + k1.signum() * w);
        [q / k2, k0 / q]
    };
    let outside = |s: f64| if s.is_finite() { (s - s.clamp(0.0, 1.0)).abs() } else { f64::INFINITY };
    let v = if outside(roots[0]) <= outside(roots[1]) { roots[0] } else { roots[1] };
    let den = e + g * v;
    let u = if den.x.abs() >= den.y.abs() { (h.x - f.x * v) / den.x } else { (h.y - f.y * v) / den.y };
    let clamp = |s: f64| if s.is_finite() { s.clamp(0.0, 1.0) } else { 0.0 };
    DVec2::new(clamp(u), clamp(v))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A projected polygon with the given corners (no plane, no
    /// parameterisation: spans only).
    fn polygon(c: &[DVec2]) -> Projected {
        let mut corners = [DVec2::ZERO; 4];
        corners[..c.len()].copy_from_slice(c);
        let zero = Affine::default();
        Projected { primitive: 0, rows: (0, 0), corners, n: c.len(), t: zero, param: Param::Affine(zero, zero) }
    }

    #[test]
    fn two_triangles_sharing_an_edge_cover_every_ray_once() {
        // A quad split along a skew diagonal, in both windings, on a grid
        // whose rows and columns pass through the corners.
        let q = [DVec2::new(0.3, -0.5), DVec2::new(17.0, 1.0), DVec2::new(15.5, 12.0), DVec2::new(-2.0, 9.0)];
        let (a, b) = (polygon(&[q[0], q[1], q[2]]), polygon(&[q[2], q[3], q[0]]));
        let whole = polygon(&q);
        for jj in 0..14 {
            let mut covered = vec![0; 20];
            for t in [&a, &b] {
                if let Some((lo, hi)) = t.span(jj, 20) {
                    (lo..hi).for_each(|i| covered[i as usize] += 1);
                }
            }
            let mut expected = vec![0; 20];
            if let Some((lo, hi)) = whole.span(jj, 20) {
                (lo..hi).for_each(|i| expected[i as usize] = 1);
            }
            assert_eq!(covered, expected, "row {jj}");
        }
    }

    #[test]
    fn rays_on_a_shared_edge_belong_to_one_triangle() {
        // A diagonal through grid points ((0, 0), (4, 3), (8, 6), ...),
        // and a horizontal edge lying on row 12 shared by a triangle below
        // and a quad above: every ray of the union is covered once.
        let (a, b, c, d) = (DVec2::new(0.0, 0.0), DVec2::new(16.0, 0.0), DVec2::new(16.0, 12.0), DVec2::new(0.0, 12.0));
        let (top_l, top_r) = (DVec2::new(-1.0, 18.0), DVec2::new(17.0, 18.0));
        let pieces = [polygon(&[a, b, c]), polygon(&[c, d, a]), polygon(&[d, c, top_r, top_l])];
        let union = [polygon(&[a, b, c, d]), polygon(&[d, c, top_r, top_l])];
        for jj in 0..20 {
            let count = |ps: &[Projected]| {
                let mut n = vec![0; 20];
                for p in ps {
                    if let Some((lo, hi)) = p.span(jj, 20) {
                        (lo..hi).for_each(|i| n[i as usize] += 1);
                    }
                }
                n
            };
            assert!(count(&pieces).iter().all(|&n| n <= 1), "row {jj}: {:?}", count(&pieces));
            assert_eq!(count(&pieces), count(&union), "row {jj}");
        }
    }

    #[test]
    fn bilinear_inversion_finds_the_coordinates_of_a_point() {
        let c = [DVec2::new(0.0, 0.0), DVec2::new(4.0, 0.5), DVec2::new(5.0, 3.0), DVec2::new(-0.5, 2.0)];
        for (u, v) in [(0.25, 0.5), (0.9, 0.1), (0.0, 1.0), (0.5, 0.999)] {
            let x = c[0] * (1.0 - u) * (1.0 - v) + c[1] * u * (1.0 - v) + c[2] * u * v + c[3] * (1.0 - u) * v;
            let uv = inverse_bilinear(x, c);
            assert!((uv - DVec2::new(u, v)).abs().max_element() < 1e-12, "{u} {v}: {uv}");
        }
    }
}
