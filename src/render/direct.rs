//! Direct light per image sample: the light that reaches a visible point
//! straight from the emitters, computed where the eye looks instead of
//! being quantised by the direction set and the patch grid.
//!
//! Every emitter is a planar, convex, one-sided polygon of uniform
//! radiance L (a primitive of an emitting surface). The irradiance it
//! gives a point x with normal n, unoccluded, has a closed form (Lambert's
//! polygon formula, after clipping the polygon to the hemisphere above x):
//! `E = L/2 · |Σ_i Θ_i (n · Γ_i)|`, with Θ_i the angle the edge
//! `v_i v_{i+1}` subtends at x and Γ_i the unit normal of the plane through
//! x and that edge. Occlusion is estimated with a *ratio estimator*
//! (Heitz et al. 2018): the same stratified samples y_j on the emitter
//! give both `Σ f_j V_j` and `Σ f_j` (f the unshadowed integrand over its
//! density, V the visibility of a shadow ray), and `E · Σ f_j V_j / Σ f_j`
//! is exact wherever the emitter is wholly visible or wholly hidden; only
//! penumbrae carry noise. A diffuse point then reflects `k_d/π · E`.
//!
//! Samples are seeded by frame, pixel and sample, so images are
//! deterministic and do not depend on the thread count.

use glam::{Vec2, Vec3};

use crate::archive::InetView;
use crate::geometry::accel::PrimitiveBvh;
use crate::geometry::{Primitive, PrimitiveKind};

/// Default light samples per emitter and image sample, along each axis.
pub const DEFAULT_LIGHT_SAMPLES: u32 = 2;

/// One emitting primitive of a frame.
#[derive(Debug, Clone, Copy)]
struct Emitter {
    prim: Primitive,
    normal: Vec3,
    radiance: Vec3,
}

/// The emitters of one frame and the reflectance of every primitive: what
/// the direct light of an image sample needs.
#[derive(Debug, Clone)]
pub struct DirectLight {
    emitters: Vec<Emitter>,
    /// `k_d` per primitive (archive order).
    kd: Vec<Vec3>,
    /// Light samples per emitter along each axis.
    samples: u32,
    /// Offset of shadow-ray origins along the normal (scale of the scene).
    epsilon: f32,
}

impl DirectLight {
    /// The emitters present at `frame` with `emission` (per surface) and
    /// `reflectance` (`k_d` per surface), sampled `samples × samples`
    /// times per image sample (clamped to 1..=16).
    pub fn new(v: &InetView<'_>, frame: u32, emission: &[[f32; 3]], reflectance: &[[f32; 3]], samples: u32) -> Self {
        let present = v.presence(frame).primitives;
        let mut emitters = Vec::new();
        let mut kd = Vec::with_capacity(v.primitives.len());
        let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
        for (i, r) in v.primitives.iter().enumerate() {
            let s = r.surface as usize;
            kd.push(reflectance.get(s).map_or(Vec3::ZERO, |&k| Vec3::from(k)));
            let kind = if r.kind == 0 { PrimitiveKind::Quad } else { PrimitiveKind::Triangle };
            let prim = Primitive { kind, p: r.corners.map(Vec3::from) };
            let (a, b) = prim.bounds();
            lo = lo.min(a);
            hi = hi.max(b);
            let radiance = emission.get(s).map_or(Vec3::ZERO, |&e| Vec3::from(e));
            if present[i] && radiance.max_element() > 0.0 && prim.area() > 0.0 {
                emitters.push(Emitter { prim, normal: prim.normal(), radiance });
            }
        }
        let epsilon = if lo.x <= hi.x { (hi - lo).max_element() * 1e-5 } else { 1e-6 };
        Self { emitters, kd, samples: samples.clamp(1, 16), epsilon }
    }

    /// Whether the frame has any emitter.
    pub fn is_empty(&self) -> bool {
        self.emitters.is_empty()
    }

    /// Radiance a diffuse point `x` with front normal `n` on primitive
    /// `prim` reflects of the emitters' direct light, shadow rays traced
    /// through `bvh` (the frame's present primitives). `pixel` seeds the
    /// light samples ([`pixel_key`]) and `(k, m)` place them: the image
    /// sample is number `k` of the pixel's `m × m`, and its light samples
    /// take every `m`-th stratum of an `m·s × m·s` grid on the emitter at
    /// an offset that a permutation of the pixel's own gives to `k`, so
    /// that the pixel's samples together cover the emitter `m·s × m·s`-fold
    /// stratified, with no tie between where in the pixel a sample lies
    /// and where on the emitter it looks (which darkened penumbrae).
    #[allow(clippy::too_many_arguments)]
    pub fn radiance(&self, x: Vec3, n: Vec3, prim: u32, bvh: &PrimitiveBvh, pixel: u64, (k, m): (u32, u32)) -> Vec3 {
        let kd = self.kd.get(prim as usize).copied().unwrap_or(Vec3::ZERO);
        if kd == Vec3::ZERO {
            return Vec3::ZERO;
        }
        let m = m.max(1);
        let offset = permute(k % (m * m), m * m, pixel);
        let key = mix(pixel ^ (k as u64).wrapping_mul(0xd6e8_feb8_6659_fd93));
        let mut total = Vec3::ZERO;
        for (e, em) in self.emitters.iter().enumerate() {
            // One-sided emitters light only what is in front of them.
            if (x - em.prim.p[0]).dot(em.normal) <= 0.0 {
                continue;
            }
            let unoccluded = polygon_irradiance(x, n, &em.prim.p[..em.prim.corner_count()]);
            if unoccluded <= 0.0 {
                continue;
            }
            let key = key ^ (e as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15);
            let seen = self.visibility(x, n, em, unoccluded, bvh, key, (offset, m));
            total += em.radiance * (unoccluded * seen);
        }
        kd * total * std::f32::consts::FRAC_1_PI
    }

    /// The fraction of `em`'s irradiance at `x` (`unoccluded`, the closed
    /// form) that is not shadowed: 1 when every shadow ray is clear, 0
    /// when none is, and in between the closed form less the Monte Carlo
    /// estimate of the shadowed part (unbiased; the ratio of shadowed to
    /// sampled integrand was 1% dark in penumbrae at 2×2 samples).
    #[allow(clippy::too_many_arguments)]
    fn visibility(
        &self,
        x: Vec3,
        n: Vec3,
        em: &Emitter,
        unoccluded: f32,
        bvh: &PrimitiveBvh,
        key: u64,
        (k, m): (u32, u32),
    ) -> f32 {
        let s = self.samples;
        let m = m.max(1);
        let (kx, ky) = ((k % m) as f32, ((k / m) % m) as f32);
        let cells = (m * s) as f32;
        let origin = x + n * self.epsilon;
        let (mut hidden, mut all, mut any_seen) = (0.0f32, 0.0f32, false);
        for j in 0..s * s {
            let h = mix(key ^ j as u64);
            let jitter = Vec2::new(unit(h), unit(h >> 32));
            let cell = Vec2::new((j % s) as f32 * m as f32 + kx, (j / s) as f32 * m as f32 + ky);
            let uv = (cell + jitter) / cells;
            let (y, jacobian) = sample_point(&em.prim, uv);
            let to = y - origin;
            let r2 = to.length_squared();
            if r2 <= 0.0 {
                continue;
            }
            let d = to / r2.sqrt();
            let (cos_x, cos_y) = (n.dot(d), -em.normal.dot(d));
            if cos_x <= 0.0 || cos_y <= 0.0 {
                continue;
            }
            let f = cos_x * cos_y / r2 * jacobian;
            all += f;
            if bvh.occluded(origin, d, 0.0, r2.sqrt() * (1.0 - 1e-4)) {
                hidden += f;
            } else {
                any_seen = true;
            }
        }
        // No sample in the part above x's horizon that the closed form
        // counts (a grazing emitter): nothing known of its shadow, so it
        // is taken as lit (the light at stake is a sliver).
        if all <= 0.0 || hidden == 0.0 {
            return 1.0;
        }
        if !any_seen {
            return 0.0;
        }
        // The samples estimate ∫ f over the emitter's uv square: the
        // shadowed irradiance is their mean over the s² strata.
        (1.0 - hidden / (s * s) as f32 / unoccluded).clamp(0.0, 1.0)
    }
}

/// A point of `p` at stratified coordinates `uv` ∈ [0, 1)², and the
/// Jacobian (area per unit of uv) there: bilinear over a quad, the
/// uniform square-root warp over a triangle.
fn sample_point(p: &Primitive, uv: Vec2) -> (Vec3, f32) {
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

/// Irradiance at `x` (normal `n`) from the planar polygon `poly` of unit
/// radiance, unoccluded: Lambert's formula over the part of the polygon
/// above the tangent plane of `x`. W·m⁻² per W·sr⁻¹·m⁻².
pub fn polygon_irradiance(x: Vec3, n: Vec3, poly: &[Vec3]) -> f32 {
    // Clip to n·(y − x) > 0 (Sutherland–Hodgman against one plane).
    let mut clipped = [Vec3::ZERO; 8];
    let mut m = 0;
    let k = poly.len();
    for i in 0..k {
        let (a, b) = (poly[i] - x, poly[(i + 1) % k] - x);
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
        let (a, b) = (clipped[i].as_dvec3(), clipped[(i + 1) % m].as_dvec3());
        let (la, lb) = (a.length(), b.length());
        if la == 0.0 || lb == 0.0 {
            continue;
        }
        let cross = a.cross(b);
        let cl = cross.length();
        if cl == 0.0 {
            continue;
        }
        let theta = cl.atan2(a.dot(b));
        sum += theta * n.as_dvec3().dot(cross / cl);
    }
    (0.5 * sum.abs()) as f32
}

/// splitmix64: a well-mixed 64-bit hash.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The top 24 bits of `h` as a float in [0, 1).
fn unit(h: u64) -> f32 {
    ((h as u32) >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
}

/// The seed of pixel `(x, y)`'s light samples at `frame`.
pub fn pixel_key(frame: u32, x: u32, y: u32) -> u64 {
    mix(mix(((frame as u64) << 32) | y as u64) ^ ((x as u64) << 32))
}

/// `i ↦ (a·i + b) mod n`, a permutation of `0..n` chosen by `key`
/// (`a` odd and coprime with `n`).
fn permute(i: u32, n: u32, key: u64) -> u32 {
    let h = mix(key);
    let (n64, b) = (n as u64, (h >> 32) % n as u64);
    let mut a = ((h as u32) % n.max(1)) as u64 | 1;
    while gcd(a, n64) != 1 {
        a += 2;
    }
    ((a * i as u64 + b) % n64) as u32
}

fn gcd(mut a: u64, mut b: u64) -> u64 {
    while b != 0 {
        (a, b) = (b, a % b);
    }
    a
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
