//! The original scene primitives: planar quads and triangles.
//!
//! Tracing and rendering intersect these few primitives, never the patches:
//! a hit's surface coordinates `(u, v)` name the patch through the
//! primitive's [`grid::PatchGrid`] (§3.3 of the paper traces "the scene", and
//! a scene of a few dozen quads traces far faster than one of 10⁴ patches).
//!
//! Parameterisation:
//! * quad `p0 p1 p2 p3` (planar, convex, counter-clockwise seen from the
//!   front): bilinear, `P(u,v) = (1-u)(1-v)p0 + u(1-v)p1 + uv p2 + (1-u)v p3`;
//! * triangle `p0 p1 p2`: barycentric, `P(u,v) = p0 + u(p1-p0) + v(p2-p0)`.
//!
//! The front face is the side the geometric normal `(p1-p0)×(p2-p0)` points
//! to (for quads, the normal of the diagonals `(p2-p0)×(p3-p1)`, equal for a
//! planar quad and better conditioned). Surfaces are one-sided.

pub mod accel;
pub mod grid;

use glam::{Vec2, Vec3};

/// Which parameterisation a [`Primitive`] uses. The discriminants are the
/// on-disk values (`format-spec/archive.md`, section `PRIM`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum PrimitiveKind {
    /// A planar convex quadrilateral with a bilinear parameterisation.
    Quad = 0,
    /// A triangle with a barycentric parameterisation.
    Triangle = 1,
}

/// One original primitive of the scene, in world space (metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Primitive {
    /// Quad or triangle.
    pub kind: PrimitiveKind,
    /// Corner positions; `p[3]` is unused (equal to `p[2]`) for triangles.
    pub p: [Vec3; 4],
}

/// Axis-aligned bounds of a set of primitives (inverted, `MAX..MIN`, when empty).
pub fn bounds_of<'a>(primitives: impl IntoIterator<Item = &'a Primitive>) -> (Vec3, Vec3) {
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for p in primitives {
        let (a, b) = p.bounds();
        lo = lo.min(a);
        hi = hi.max(b);
    }
    (lo, hi)
}

/// A ray-primitive intersection: distance and surface coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceHit {
    /// Ray parameter of the hit (distance when the direction is unit).
    pub t: f32,
    /// Surface coordinates of the hit, each in `[0, 1]`.
    pub uv: Vec2,
}

impl Primitive {
    /// A quad from four corners, counter-clockwise seen from the front.
    pub fn quad(p: [Vec3; 4]) -> Self {
        Self { kind: PrimitiveKind::Quad, p }
    }

    /// A triangle from three corners, counter-clockwise seen from the front.
    pub fn triangle(a: Vec3, b: Vec3, c: Vec3) -> Self {
        Self { kind: PrimitiveKind::Triangle, p: [a, b, c, c] }
    }

    /// Unnormalised normal whose length is twice the area for triangles and
    /// for parallelograms; only its direction is used.
    fn raw_normal(&self) -> Vec3 {
        match self.kind {
            PrimitiveKind::Quad => (self.p[2] - self.p[0]).cross(self.p[3] - self.p[1]),
            PrimitiveKind::Triangle => (self.p[1] - self.p[0]).cross(self.p[2] - self.p[0]),
        }
    }

    /// Unit geometric normal of the front face (zero for a degenerate primitive).
    pub fn normal(&self) -> Vec3 {
        self.raw_normal().normalize_or_zero()
    }

    /// The primitive's own orthonormal frame: x along its first edge
    /// (`p1 − p0`, made perpendicular to the normal), y = z × x, z its
    /// front normal. Mesh detail keeps shading normals in it (format
    /// §5.15), so that they follow the primitive through rigid motion.
    pub fn own_frame(&self) -> [Vec3; 3] {
        let z = self.normal();
        let x = (self.p[1] - self.p[0]).normalize_or_zero();
        let x = (x - z * x.dot(z)).normalize_or_zero();
        [x, z.cross(x), z]
    }

    /// Surface area in m².
    pub fn area(&self) -> f32 {
        // For a planar quad, half the cross product of the diagonals is exact.
        0.5 * self.raw_normal().length()
    }

    /// The point at surface coordinates `uv`.
    pub fn point(&self, uv: Vec2) -> Vec3 {
        let (u, v) = (uv.x, uv.y);
        match self.kind {
            PrimitiveKind::Quad => {
                (1.0 - u) * (1.0 - v) * self.p[0]
                    + u * (1.0 - v) * self.p[1]
                    + u * v * self.p[2]
                    + (1.0 - u) * v * self.p[3]
            }
            PrimitiveKind::Triangle => self.p[0] + u * (self.p[1] - self.p[0]) + v * (self.p[2] - self.p[0]),
        }
    }

    /// Axis-aligned bounds.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let n = self.corner_count();
        let mut lo = self.p[0];
        let mut hi = self.p[0];
        for q in &self.p[1..n] {
            lo = lo.min(*q);
            hi = hi.max(*q);
        }
        (lo, hi)
    }

    /// 4 for quads, 3 for triangles.
    pub fn corner_count(&self) -> usize {
        match self.kind {
            PrimitiveKind::Quad => 4,
            PrimitiveKind::Triangle => 3,
        }
    }

    /// [`Primitive::intersect`] with a quad's precomputed [`QuadFilter`]
    /// (ignored for triangles): the same hits, fewer operations per miss.
    /// Always inlined: left to the compiler, an unrelated change elsewhere
    /// in the crate once moved it out of line and made every build's trace
    /// 13% slower (the fan room's still frame, 0.83 → 0.95 s).
    #[inline(always)]
    pub fn intersect_filtered(
        &self,
        filter: &QuadFilter,
        origin: Vec3,
        dir: Vec3,
        t_min: f32,
        t_max: f32,
    ) -> Option<SurfaceHit> {
        if self.kind == PrimitiveKind::Triangle || !filter.usable {
            return self.intersect(origin, dir, t_min, t_max);
        }
        // As intersect_quad, with the plane normal precomputed.
        let n = filter.n;
        let denom = dir.dot(n);
        if denom == 0.0 || !denom.is_finite() {
            return None;
        }
        let t = (self.p[0] - origin).dot(n) / denom;
        if !(t > t_min && t < t_max) {
            return None;
        }
        let x = origin + t * dir;
        // Rounding of x is at most a few ulps of the magnitudes involved;
        // 1e-6 of them is ~16 ulps. Plus 10⁻³ of the quad's own size.
        let slack = 1e-6 * (origin.abs().max_element() + t.abs() + filter.extent);
        let h = x - self.p[0];
        let (u, v) = (h.dot(filter.du), h.dot(filter.dv));
        let mu = 1e-3 + slack * filter.du_len + filter.warp_u;
        let mv = 1e-3 + slack * filter.dv_len + filter.warp_v;
        if u < filter.lo.x - mu || u > filter.hi.x + mu || v < filter.lo.y - mv || v > filter.hi.y + mv {
            return None;
        }
        quad_uv(&self.p, n, x, t)
    }

    /// Intersects the full line `origin + t·dir` for `t` in `(t_min, t_max)`,
    /// from either side. Returns `None` on a miss or a ray parallel to the plane.
    #[inline]
    pub fn intersect(&self, origin: Vec3, dir: Vec3, t_min: f32, t_max: f32) -> Option<SurfaceHit> {
        match self.kind {
            PrimitiveKind::Triangle => intersect_triangle(self.p[0], self.p[1], self.p[2], origin, dir, t_min, t_max),
            PrimitiveKind::Quad => intersect_quad(&self.p, self.raw_normal(), origin, dir, t_min, t_max),
        }
    }
}

/// What a quad's hit test can compute once: its plane normal and an affine
/// frame `(p0; p1 − p0, p3 − p0)` with the box `[lo, hi]` that holds the
/// whole quad in that frame. A crossing point outside the box (plus a margin
/// well above rounding) cannot be a hit, and is rejected with two dot
/// products instead of the bilinear inversion; points inside go through the
/// same code as [`Primitive::intersect`], so hits are bit for bit the same.
/// (In the fan room, 3.5 quads are tested per hit found: most tests miss.)
#[derive(Debug, Clone, Copy, Default)]
pub struct QuadFilter {
    /// `(p2 − p0) × (p3 − p1)`, as `raw_normal`.
    n: Vec3,
    /// Dual basis: `(x − p0)·du` and `(x − p0)·dv` are the affine coordinates.
    du: Vec3,
    dv: Vec3,
    lo: Vec2,
    hi: Vec2,
    /// `|du|`, `|dv|`: affine units per metre, to scale position rounding.
    du_len: f32,
    dv_len: f32,
    /// Largest coordinate magnitude of the corners.
    extent: f32,
    /// Affine-unit slack for corners off the frame's plane: the bilinear
    /// inversion works in a projection that places off-plane points a
    /// little differently (the scene format accepts corners 10⁻⁴ × size
    /// off their plane).
    warp_u: f32,
    warp_v: f32,
    /// False when the frame is too ill-conditioned to trust: test everything.
    usable: bool,
}

impl QuadFilter {
    /// The filter of a quad (unusable for triangles and slivers).
    pub fn new(prim: &Primitive) -> Self {
        if prim.kind != PrimitiveKind::Quad {
            return Self::default();
        }
        let [p0, p1, p2, p3] = prim.p;
        let (e, f) = (p1 - p0, p3 - p0);
        let m = e.cross(f);
        let du = f.cross(m) / e.dot(f.cross(m));
        let dv = m.cross(e) / f.dot(m.cross(e));
        let c = p2 - p0;
        let (a, b) = (c.dot(du), c.dot(dv));
        let lo = Vec2::new(a.min(0.0), b.min(0.0));
        let hi = Vec2::new(a.max(1.0), b.max(1.0));
        let diameter = (p2 - p0).length().max((p3 - p1).length()).max(e.length()).max(f.length());
        let (du_len, dv_len) = (du.length(), dv.length());
        let extent = prim.p.iter().fold(0.0f32, |m, q| m.max(q.abs().max_element()));
        // How far the corners lie off the frame's plane.
        let unit = m.normalize_or_zero();
        let off = prim.p.iter().fold(0.0f32, |h, q| h.max((*q - p0).dot(unit).abs()));
        let (warp_u, warp_v) = (4.0 * off * du_len, 4.0 * off * dv_len);
        // Aspect ratios beyond 10³, warped quads or non-finite frames are
        // not filtered.
        let usable = [du, dv].iter().all(|v| v.is_finite())
            && lo.is_finite()
            && hi.is_finite()
            && du_len * diameter < 1e3
            && dv_len * diameter < 1e3
            && warp_u.max(warp_v) < 1e-2;
        Self { n: prim.raw_normal(), du, dv, lo, hi, du_len, dv_len, extent, warp_u, warp_v, usable }
    }
}

/// Möller–Trumbore, two-sided, returning barycentrics `(b1, b2)` as `uv`.
#[inline]
fn intersect_triangle(p0: Vec3, p1: Vec3, p2: Vec3, o: Vec3, d: Vec3, t_min: f32, t_max: f32) -> Option<SurfaceHit> {
    let e1 = p1 - p0;
    let e2 = p2 - p0;
    let pv = d.cross(e2);
    let det = e1.dot(pv);
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let inv = 1.0 / det;
    let tv = o - p0;
    let u = tv.dot(pv) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let qv = tv.cross(e1);
    let v = d.dot(qv) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = e2.dot(qv) * inv;
    (t > t_min && t < t_max).then_some(SurfaceHit { t, uv: Vec2::new(u, v) })
}

/// Plane intersection followed by the inverse of the bilinear map.
#[inline]
fn intersect_quad(p: &[Vec3; 4], n: Vec3, o: Vec3, d: Vec3, t_min: f32, t_max: f32) -> Option<SurfaceHit> {
    let denom = d.dot(n);
    if denom == 0.0 || !denom.is_finite() {
        return None;
    }
    let t = (p[0] - o).dot(n) / denom;
    if !(t > t_min && t < t_max) {
        return None;
    }
    let x = o + t * d;
    quad_uv(p, n, x, t)
}

/// The hit at `x` on the quad's plane, if `x` lies inside the quad.
#[inline]
fn quad_uv(p: &[Vec3; 4], n: Vec3, x: Vec3, t: f32) -> Option<SurfaceHit> {
    // Project onto the plane's dominant 2D axes (drop the largest normal component).
    let an = n.abs();
    let (ax, ay) = if an.x >= an.y && an.x >= an.z {
        (1, 2)
    } else if an.y >= an.z {
        (2, 0)
    } else {
        (0, 1)
    };
    let to2 = |v: Vec3| Vec2::new(v[ax], v[ay]);
    let uv = inverse_bilinear(to2(x), to2(p[0]), to2(p[1]), to2(p[2]), to2(p[3]))?;
    Some(SurfaceHit { t, uv })
}

fn cross2(a: Vec2, b: Vec2) -> f32 {
    a.x * b.y - a.y * b.x
}

/// Inverts `P(u,v) = a + u·e + v·f + uv·g` for a point in the quad's plane;
/// returns `None` when the point lies outside `[0,1]²`.
fn inverse_bilinear(x: Vec2, a: Vec2, b: Vec2, c: Vec2, d: Vec2) -> Option<Vec2> {
    let e = b - a;
    let f = d - a;
    let g = a - b + c - d;
    let h = x - a;
    let k2 = cross2(g, f);
    let k1 = cross2(e, f) + cross2(h, g);
    let k0 = cross2(h, e);
    const EPS: f32 = 1e-6;
    let in_range = |s: f32| (-EPS..=1.0 + EPS).contains(&s);
    let solve_u = |v: f32| {
        let den = e + g * v;
        if den.x.abs() >= den.y.abs() { (h.x - f.x * v) / den.x } else { (h.y - f.y * v) / den.y }
    };
    let candidates: [f32; 2] = if k2.abs() <= 1e-7 * k1.abs().max(f32::MIN_POSITIVE) {
        // Parallelogram (g = 0) or nearly so: the equation in v is linear.
        if k1 == 0.0 {
            return None;
        }
        [-k0 / k1, f32::NAN]
    } else {
        let w = k1 * k1 - 4.0 * k0 * k2;
        if w < 0.0 {
            return None;
        }
        let w = w.sqrt();
        // Numerically stable roots of k2 v² + k1 v + k0 = 0.
        let q = -0.5 * (k1 + k1.signum() * w);
        [q / k2, if q != 0.0 { k0 / q } else { f32::NAN }]
    };
    for v in candidates {
        if v.is_finite() && in_range(v) {
            let u = solve_u(v);
            if u.is_finite() && in_range(u) {
                return Some(Vec2::new(u.clamp(0.0, 1.0), v.clamp(0.0, 1.0)));
            }
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    proptest::proptest! {
        /// The filter rejects only misses: filtered and unfiltered tests
        /// agree bit for bit, for convex quads of any shape (aspect ratios
        /// to 100:1, corners up to 10⁻⁴ × size off their plane), size and
        /// position, and rays that cross them anywhere (edges included).
        #[test]
        fn quad_filter_changes_no_hit(
            centre in proptest::array::uniform3(-100.0f32..100.0),
            size in 1e-3f32..5.0,
            stretch in 0.01f32..1.0,
            skew in -0.9f32..0.9,
            taper in -0.4f32..0.4,
            angle in 0.0f32..std::f32::consts::TAU,
            tilt in 0.0f32..std::f32::consts::PI,
            at in proptest::array::uniform2(-0.1f32..1.1),
            edge in 0usize..5,
            dir in proptest::array::uniform3(-1.0f32..1.0),
            back in 0.1f32..50.0,
            warp in proptest::array::uniform4(-1e-4f32..1e-4),
        ) {
            // A trapezoid-ish convex quad in the xy plane, then rotated.
            let corners = [
                Vec2::new(0.0, 0.0),
                Vec2::new(1.0, 0.0),
                Vec2::new(1.0 + skew + taper, stretch),
                Vec2::new(skew - taper, stretch),
            ];
            let rot = glam::Quat::from_rotation_z(angle) * glam::Quat::from_rotation_x(tilt);
            let c = Vec3::from(centre);
            // Corners up to 10⁻⁴ × size off the plane, as the scene format allows.
            let mut k = 0;
            let p = corners.map(|q| {
                k += 1;
                c + rot * (Vec3::new(q.x, q.y, warp[k - 1]) * size)
            });
            let prim = Primitive::quad(p);
            let d = Vec3::from(dir);
            proptest::prop_assume!(d.length() > 0.1 && prim.area() > 0.0);
            let d = d.normalize();
            // A point on or near the quad (often within 1% of an edge), and a
            // ray through it from `back` away.
            let mut at = at;
            match edge {
                0 => at[1] *= 0.01,
                1 => at[1] = 1.0 - at[1] * 0.01,
                2 => at[0] *= 0.01,
                3 => at[0] = 1.0 - at[0] * 0.01,
                _ => {}
            }
            let target = prim.point(Vec2::new(at[0].clamp(0.0, 1.0), at[1].clamp(0.0, 1.0)))
                + rot * Vec3::new(at[0] - at[0].clamp(0.0, 1.0), at[1] - at[1].clamp(0.0, 1.0), 0.0) * size;
            let origin = target - d * back;
            let filter = QuadFilter::new(&prim);
            let plain = prim.intersect(origin, d, 0.0, f32::INFINITY);
            let filtered = prim.intersect_filtered(&filter, origin, d, 0.0, f32::INFINITY);
            proptest::prop_assert_eq!(plain, filtered);
        }
    }

    #[test]
    fn quad_inverse_bilinear_round_trips_on_a_general_quad() {
        // The short block's top face: planar, not a parallelogram.
        let q = Primitive::quad([
            Vec3::new(0.13, 0.165, 0.065),
            Vec3::new(0.082, 0.165, 0.225),
            Vec3::new(0.24, 0.165, 0.272),
            Vec3::new(0.29, 0.165, 0.114),
        ]);
        assert!(q.normal().y > 0.999);
        for i in 0..=10 {
            for j in 0..=10 {
                let uv = Vec2::new(i as f32 / 10.0, j as f32 / 10.0);
                let x = q.point(uv);
                let hit = q.intersect(x + Vec3::Y, -Vec3::Y, 0.0, 10.0).expect("hit");
                assert!((hit.t - 1.0).abs() < 1e-5);
                assert!((hit.uv - uv).abs().max_element() < 1e-4, "{uv} -> {}", hit.uv);
            }
        }
        assert!(q.intersect(Vec3::new(0.0, 1.0, 0.0), -Vec3::Y, 0.0, 10.0).is_none());
    }

    #[test]
    fn triangle_hits_and_misses() {
        let t = Primitive::triangle(Vec3::ZERO, Vec3::X, Vec3::Z);
        assert!((t.area() - 0.5).abs() < 1e-6);
        assert!(t.normal().y < -0.999, "x × z = -y");
        let h = t.intersect(Vec3::new(0.25, 1.0, 0.5), -Vec3::Y, 0.0, 5.0).unwrap();
        assert!((h.uv - Vec2::new(0.25, 0.5)).length() < 1e-6);
        assert!(t.intersect(Vec3::new(0.75, 1.0, 0.5), -Vec3::Y, 0.0, 5.0).is_none());
    }
}
