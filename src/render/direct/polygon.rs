//! The closed forms of the direct light: Lambert's formula for the
//! irradiance a planar polygon of uniform radiance gives a point (clipped
//! to the hemisphere above it, and to the face's plane under a shading
//! normal), the fast arctangent it takes, and the points of an emitter
//! that shadow rays aim at, with their Jacobians.

use glam::{DVec3, Vec2, Vec3};

use crate::geometry::{Primitive, PrimitiveKind};

/// A point of `p` at stratified coordinates `uv` ∈ [0, 1)², and the
/// Jacobian (area per unit of uv) there: bilinear over a quad, the
/// uniform square-root warp over a triangle.
pub(super) fn sample_point(p: &Primitive, uv: Vec2) -> (Vec3, f32) {
    match p.kind {
        PrimitiveKind::Quad => {
            let (u, v) = (uv.x, uv.y);
            let y = p.point(uv);
            let du = (1.0 - v) * (p.p[1] - p.p[0]) + v * (p.p[2] - p.p[3]);
            let dv = (1.0 - u) * (p.p[3] - p.p[0]) + u * (p.p[2] - p.p[1]);
            (y, du.cross(dv).length())
        }
        PrimitiveKind::Triangle => {
            let r = uv.x.sqrt();
            let y = (1.0 - r) * p.p[0] + r * (1.0 - uv.y) * p.p[1] + r * uv.y * p.p[2];
            (y, p.area())
        }
    }
}

/// [`polygon_irradiance`] with shading normal `n` over the part of `poly`
/// above the plane of `x` with normal `face` (the geometry's), which a
/// shading normal leaning past it would otherwise see; `poly` as it is
/// when the two are equal.
pub(super) fn shaded_irradiance(x: Vec3, n: Vec3, face: Vec3, poly: &[Vec3]) -> f32 {
    if n == face {
        return polygon_irradiance(x, n, poly);
    }
    let mut clipped = [Vec3::ZERO; 8];
    let mut m = 0;
    let k = poly.len();
    for i in 0..k {
        let (a, b) = (poly[i], poly[if i + 1 == k { 0 } else { i + 1 }]);
        let (da, db) = (face.dot(a - x), face.dot(b - x));
        if da > 0.0 && m < clipped.len() {
            clipped[m] = a;
            m += 1;
        }
        if (da > 0.0) != (db > 0.0) && m < clipped.len() {
            clipped[m] = a + (b - a) * (da / (da - db));
            m += 1;
        }
    }
    if m < 3 { 0.0 } else { polygon_irradiance(x, n, &clipped[..m]) }
}

/// Irradiance at `x` (normal `n`) from the planar polygon `poly` of unit
/// radiance, unoccluded: Lambert's formula over the part of the polygon
/// above the tangent plane of `x`. W·m⁻² per W·sr⁻¹·m⁻².
pub fn polygon_irradiance(x: Vec3, n: Vec3, poly: &[Vec3]) -> f32 {
    // Clip to n·(y − x) > 0 (Sutherland–Hodgman against one plane).
    let mut clipped = [Vec3::ZERO; 8];
    let mut m = 0;
    let k = poly.len();
    for i in 0..k {
        let (a, b) = (poly[i] - x, poly[if i + 1 == k { 0 } else { i + 1 }] - x);
        let (da, db) = (n.dot(a), n.dot(b));
        if da > 0.0 {
            clipped[m] = a;
            m += 1;
        }
        if (da > 0.0) != (db > 0.0) && m < clipped.len() {
            let t = da / (da - db);
            clipped[m] = a + (b - a) * t;
            m += 1;
        }
    }
    if m < 3 {
        return 0.0;
    }
    let mut sum = 0.0f64;
    for i in 0..m {
        let (a, b) = (clipped[i].as_dvec3(), clipped[if i + 1 == m { 0 } else { i + 1 }].as_dvec3());
        if a == DVec3::ZERO || b == DVec3::ZERO {
            continue;
        }
        let cross = a.cross(b);
        let cl = cross.length();
        if cl == 0.0 {
            continue;
        }
        let theta = angle(cl, a.dot(b));
        sum += theta * n.as_dvec3().dot(cross / cl);
    }
    (0.5 * sum.abs()) as f32
}

/// The angle in [0, π] whose sine and cosine are in the ratio `s` : `c`
/// (`s` > 0): `s.atan2(c)` to within 10⁻¹⁰ of itself (unit test: 2.4·10⁻¹¹), at a
/// fraction of libm's cost, which the closed forms of every pixel and
/// every gather ray pay four times per emitter.
#[inline]
fn angle(s: f64, c: f64) -> f64 {
    use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};
    // tan(π/8): beyond it, atan t = π/4 + atan((t − 1)/(t + 1)).
    const TAN_PI_8: f64 = 0.414_213_562_373_095_05;
    let ac = c.abs();
    let steep = s > ac;
    // t = num / den ∈ [0, 1]; u = (t − 1)/(t + 1) in one division.
    let (num, den) = if steep { (ac, s) } else { (s, ac) };
    let (u, base) = if num > TAN_PI_8 * den { ((num - den) / (num + den), FRAC_PI_4) } else { (num / den, 0.0) };
    // atan u for |u| ≤ tan(π/8): its Taylor series to u²³ (the first
    // term left out is below 2·10⁻¹⁰ of u).
    const INV_ODD: [f64; 12] = [
        1.0,
        1.0 / 3.0,
        1.0 / 5.0,
        1.0 / 7.0,
        1.0 / 9.0,
        1.0 / 11.0,
        1.0 / 13.0,
        1.0 / 15.0,
        1.0 / 17.0,
        1.0 / 19.0,
        1.0 / 21.0,
        1.0 / 23.0,
    ];
    let u2 = u * u;
    let p = INV_ODD.iter().rev().fold(0.0, |p, &c| c - u2 * p);
    let a = base + u * p;
    let a = if steep { FRAC_PI_2 - a } else { a };
    if c < 0.0 { PI - a } else { a }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Irradiance of unit radiance from an a×b rectangle whose corner is
    /// straight above the point at height c, facing it: π·F with the
    /// point-to-rectangle form factor F (Howell's catalogue, B-3).
    fn corner_rectangle(a: f64, b: f64, c: f64) -> f64 {
        let (x, y) = (a / c, b / c);
        let (sx, sy) = ((1.0 + x * x).sqrt(), (1.0 + y * y).sqrt());
        let f = (x / sx * (y / sx).atan() + y / sy * (x / sy).atan()) / (2.0 * std::f64::consts::PI);
        std::f64::consts::PI * f
    }

    #[test]
    fn polygon_irradiance_matches_the_point_to_rectangle_form_factor() {
        let x = Vec3::ZERO;
        let n = Vec3::Y;
        for (a, b, c) in [(1.0f32, 1.0f32, 1.0f32), (0.3, 2.0, 0.5), (4.0, 0.1, 2.0)] {
            let quad = [Vec3::new(0.0, c, 0.0), Vec3::new(a, c, 0.0), Vec3::new(a, c, b), Vec3::new(0.0, c, b)];
            let got = polygon_irradiance(x, n, &quad) as f64;
            let want = corner_rectangle(a as f64, b as f64, c as f64);
            assert!((got - want).abs() < 1e-5 * want, "{a}×{b} at {c}: {got} vs {want}");
            // Winding does not matter.
            let rev = [quad[3], quad[2], quad[1], quad[0]];
            assert!((polygon_irradiance(x, n, &rev) as f64 - want).abs() < 1e-5 * want);
        }
        // A rectangle straddling the horizon counts only its upper part:
        // the same as the rectangle cut at the plane.
        let tall =
            [Vec3::new(1.0, -1.0, 0.0), Vec3::new(1.0, 1.0, 0.0), Vec3::new(1.0, 1.0, 1.0), Vec3::new(1.0, -1.0, 1.0)];
        let upper =
            [Vec3::new(1.0, 0.0, 0.0), Vec3::new(1.0, 1.0, 0.0), Vec3::new(1.0, 1.0, 1.0), Vec3::new(1.0, 0.0, 1.0)];
        let (t, u) = (polygon_irradiance(x, n, &tall), polygon_irradiance(x, n, &upper));
        assert!(t > 0.0 && (t - u).abs() < 1e-6, "{t} vs {u}");
        // Wholly below the horizon: nothing.
        let below = tall.map(|p| Vec3::new(p.x, p.y - 2.0, p.z));
        assert_eq!(polygon_irradiance(x, n, &below), 0.0);
        // The hemisphere: a huge square just above gives π (E = π·L).
        let s = 1e4;
        let sky = [Vec3::new(-s, 1e-3, -s), Vec3::new(s, 1e-3, -s), Vec3::new(s, 1e-3, s), Vec3::new(-s, 1e-3, s)];
        assert!((polygon_irradiance(x, n, &sky) - std::f32::consts::PI).abs() < 1e-3);
    }

    #[test]
    fn angle_is_atan2_over_the_half_plane() {
        let mut worst = 0.0f64;
        for i in 0..=20_000 {
            let phi = std::f64::consts::PI * i as f64 / 20_000.0;
            for r in [1e-6, 1.0, 3e4] {
                let (s, c) = (r * phi.sin(), r * phi.cos());
                if s > 0.0 {
                    let (got, want) = (angle(s, c), s.atan2(c));
                    worst = worst.max((got - want).abs() / want);
                }
            }
        }
        // Tiny angles, near 0 and near π, keep their relative precision.
        for s in [1e-300, 1e-12, 1e-7] {
            for c in [1.0, -1.0] {
                let (got, want) = (angle(s, c), s.atan2(c));
                worst = worst.max((got - want).abs() / want);
            }
        }
        eprintln!("angle: worst relative error {worst:e}");
        assert!(worst < 1e-10, "worst relative error {worst:e}");
    }

    #[test]
    fn sample_points_cover_the_primitive_with_its_area() {
        // Mean Jacobian over uv is the area, for a non-parallelogram quad
        // and a triangle.
        let quad =
            Primitive::quad([Vec3::ZERO, Vec3::new(2.0, 0.0, 0.0), Vec3::new(1.5, 0.0, 1.0), Vec3::new(0.0, 0.0, 1.0)]);
        let tri = Primitive::triangle(Vec3::ZERO, Vec3::new(1.0, 0.0, 0.0), Vec3::new(0.0, 0.0, 3.0));
        for p in [quad, tri] {
            let m = 64;
            let mut sum = 0.0;
            for i in 0..m * m {
                let uv = Vec2::new(((i % m) as f32 + 0.5) / m as f32, ((i / m) as f32 + 0.5) / m as f32);
                sum += sample_point(&p, uv).1 as f64;
            }
            let mean = sum / (m * m) as f64;
            assert!((mean - p.area() as f64).abs() < 1e-4 * p.area() as f64, "{mean} vs {}", p.area());
        }
    }
}
