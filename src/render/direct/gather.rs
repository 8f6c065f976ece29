//! The one-bounce gather (`render --gather N`): image samples near other
//! geometry take their indirect light from rays of their own instead of
//! interpolating it between patch vertices.
//!
//! The I-net's indirect light is a per-patch value carried to the patch
//! vertices and interpolated (Gouraud). Where the light changes within a
//! patch it is wrong, most of all along concave edges and contacts: a
//! patch in the corner of two walls, or beside the foot of a box, holds
//! one mean of a light that falls steeply towards the edge, and its
//! interpolation shows a bright line there. The gather computes the
//! indirect light at the sample's own point,
//! `L(x) = k_d/π ∫ L_r(h(x, ω)) cos θ dω`, from cosine-distributed rays,
//! each looking up the light reflected at the point `h` it meets: the
//! emitters' direct light there computed exactly (closed form less a
//! shadow ray, unclamped so the mean stays unbiased) plus the I-net's
//! indirect light there, interpolated as for a camera ray. Emission is
//! left out (it reaches `x` as its direct light), and so is the I-net's
//! quantised direct light, whose blotches would otherwise come back one
//! bounce away.
//!
//! Gathered light is noisy where interpolated light is smooth, so the
//! gather goes where interpolation fails: near other geometry. Eight
//! fixed probe rays per pixel and primitive (30° above the surface, eight
//! azimuths) find the nearest geometry at distance `d`; the gather's weight
//! is 1 for `d` below `reach` patch sides, 0 beyond twice that, linear
//! between. The weight depends on geometry alone, never on the light the
//! rays find, so the blend is an unbiased mix of the two estimates.
//!
//! A pixel's `N` rays are spread over its image samples and stratified
//! over the hemisphere as a whole (a shifted rank-1 lattice, the R2
//! sequence, through the cosine map), seeded by frame and pixel:
//! deterministic, independent of the thread count.

use glam::{Vec2, Vec3};

use crate::archive::InetView;
use crate::distribute::Solution;
use crate::geometry::grid::NO_VERTEX;
use crate::render::detail::SurfaceDetail;
use crate::render::primary::RayHit;
use crate::render::sampling::{Permutation, r2_point, unit};
use crate::render::vertex::vertex_radiance_seen;

/// The gather's per-vertex light and where it applies.
#[derive(Debug, Clone)]
pub struct Gather {
    /// Rays per pixel, spread over its samples.
    rays: u32,
    /// Where the gather applies, in patch sides ([`Self::reach_weight`]).
    reach: f32,
    /// What rays look up where they land: per patch vertex, the radiance
    /// the patches around it reflect (emission excluded; a non-diffuse
    /// patch counts its cosine-weighted mean over directions, the radiance
    /// of a diffuse patch reflecting the same power).
    reflected: Reflected,
}

impl Gather {
    /// A gather of `rays` rays per pixel (clamped to 1..=4096) over the
    /// light of `solution`, for samples whose nearest geometry is within
    /// `reach` patch sides (fading out to twice that; infinite: every
    /// diffuse sample); `exact`: rays compute the direct light where they
    /// land (when the solution split it off).
    pub(crate) fn new(v: &InetView<'_>, solution: &Solution, rays: u32, reach: f32, exact: bool) -> Self {
        let emission = &solution.surface_emission;
        let mut per_patch: Vec<[f32; 3]> = solution
            .radiance
            .iter()
            .zip(v.patch_primitive)
            .map(|(l, &prim)| {
                let s = v.primitives[prim as usize].surface as usize;
                let e = emission.get(s).copied().unwrap_or([0.0; 3]);
                [0, 1, 2].map(|c| (l[c] - e[c]).max(0.0))
            })
            .collect();
        if let Some(d) = &solution.directional {
            for (k, &q) in d.patches.iter().enumerate() {
                let normal =
                    crate::render::primitive_of(&v.primitives[v.patch_primitive[q as usize] as usize]).0.normal();
                let mut sum = Vec3::ZERO;
                for (dir, l) in v.directions.iter().zip(d.of(k)) {
                    let c = normal.dot(Vec3::from(dir.direction)).max(0.0);
                    sum += Vec3::from(*l) * (c * dir.solid_angle_sr);
                }
                let mean = sum * std::f32::consts::FRAC_1_PI;
                let p = &mut per_patch[q as usize];
                *p = [0, 1, 2].map(|c| p[c] + mean[c]);
            }
        }
        let reflected = match solution.direct.as_ref().filter(|_| exact) {
            Some(direct) => {
                let less: Vec<[f32; 3]> =
                    per_patch.iter().zip(direct).map(|(l, d)| [0, 1, 2].map(|c| (l[c] - d[c]).max(0.0))).collect();
                Reflected::Indirect(vertex_radiance_seen(v, &less))
            }
            None => Reflected::All(vertex_radiance_seen(v, &per_patch)),
        };
        let reach = if reach.is_nan() { 0.0 } else { reach.max(0.0) };
        Self { rays: rays.clamp(1, 4096), reach, reflected }
    }

    /// Rays per pixel.
    pub fn rays(&self) -> u32 {
        self.rays
    }

    /// The gather's weight in the indirect light of points around `x`
    /// (face normal `n`, on a patch of side `size`): from the nearest
    /// geometry the probes meet, rays leaving `eps` above the face.
    /// `nearest(o, w, t_max)` is the distance along a ray to what it
    /// meets first if that is nearer than `t_max` (else anything not
    /// below it): the weight is 0 from twice the reach on, so a probe looks
    /// no farther, and asks for no more than a distance (a Cornell box
    /// render with one gather ray a sample: 0.372 s against 0.386 s when
    /// the probes found whole hits at any distance).
    pub(in crate::render) fn reach_weight(&self, x: Vec3, n: Vec3, size: f32, eps: f32, nearest: &Nearest<'_>) -> f32 {
        if self.reach.is_infinite() {
            return 1.0;
        }
        let near = self.reach * size;
        if near <= 0.0 {
            return 0.0;
        }
        let (t, b) = n.any_orthonormal_pair();
        let mut closest = 2.0 * near;
        for a in 0..PROBES {
            let (s, c) = (a as f32 * std::f32::consts::TAU / PROBES as f32).sin_cos();
            // 30° above the surface.
            let w = n * 0.5 + (t * c + b * s) * 0.866_025_4;
            closest = closest.min(nearest(x + n * eps, w, closest));
        }
        ((2.0 * near - closest) / near).clamp(0.0, 1.0)
    }

    /// The mean radiance reflected towards `x` (shading normal `n`, face
    /// normal `face`) by what its rays meet: its indirect irradiance over
    /// π. `x` is sample `k` of a pixel of `samples` seeded by `key`; it
    /// takes its share of the pixel's rays, stratified with the other
    /// samples'. `trace` finds what a ray from a point along a direction
    /// meets.
    #[allow(clippy::too_many_arguments)]
    pub(in crate::render) fn incoming(
        &self,
        x: Vec3,
        (n, face): (Vec3, Vec3),
        key: u64,
        (k, samples): (u32, u32),
        trace: &RayHit<'_>,
        detail: &SurfaceDetail<'_>,
        exact: ExactDirect<'_, '_>,
    ) -> Vec3 {
        let samples = samples.max(1);
        let each = self.rays.div_ceil(samples);
        let order = Permutation::new(each * samples, key);
        let shift = Vec2::new(unit(key), unit(key >> 32));
        let (t, b) = n.any_orthonormal_pair();
        let origin = x + face * exact.light.epsilon();
        let mut sum = Vec3::ZERO;
        for i in 0..each {
            let j = order.apply(k * each + i);
            let w = cosine_direction(r2_point(j, shift), (t, b, n));
            if w.dot(face) <= 0.0 {
                // Below the surface (a shading normal leaning past the face).
                continue;
            }
            let hit = trace(origin, w);
            if hit.vertices == [NO_VERTEX; 4] {
                // Nothing, or a back face: no light.
                continue;
            }
            let mut l = Vec3::ZERO;
            match &self.reflected {
                Reflected::All(all) => hit.add_radiance(all, &mut l),
                Reflected::Indirect(indirect) => {
                    hit.add_radiance(indirect, &mut l);
                    let y = origin + w * hit.t;
                    let at = exact.normals[hit.primitive as usize];
                    let ray_key = key ^ (j as u64 + 1).wrapping_mul(0x9e37_79b9_7f4a_7c15);
                    let (d, _) = exact.light.estimate_signed(
                        &[y],
                        (at, at),
                        hit.primitive,
                        exact.bvh,
                        ray_key,
                        1,
                        exact.emitters,
                    );
                    l += d;
                }
            }
            if detail.any() {
                l *= detail.albedo_scale(hit.primitive, Vec2::from(hit.uv));
            }
            sum += l;
        }
        (sum / each as f32).max(Vec3::ZERO)
    }
}

/// The distance along a ray from a point along a direction to what it
/// meets first when that is nearer than a bound (else any distance not
/// below the bound): what the gather's probes ask.
pub(in crate::render) type Nearest<'f> = dyn Fn(Vec3, Vec3, f32) -> f32 + Sync + 'f;

/// Probe rays per pixel and primitive that find how near other geometry is.
const PROBES: u32 = 8;

/// What the gather's rays look up where they land.
#[derive(Debug, Clone)]
enum Reflected {
    /// Per patch vertex, the I-net's reflected light less its direct part;
    /// the direct light is computed at each hit.
    Indirect(Vec<[f32; 3]>),
    /// Per patch vertex, all the I-net's reflected light (a solution
    /// without its direct part split off).
    All(Vec<[f32; 3]>),
}

/// What computes the direct light exactly where a gather ray lands: the
/// frame's emitters, shadow-ray BVH and face normals, and scratch space.
pub(in crate::render) struct ExactDirect<'a, 'e> {
    pub(in crate::render) light: &'a super::DirectLight,
    pub(in crate::render) bvh: &'a crate::geometry::accel::PrimitiveBvh,
    pub(in crate::render) normals: &'a [Vec3],
    pub(in crate::render) emitters: &'e mut Vec<(u32, f32)>,
}

/// The cosine-distributed direction about `n` (`t`, `b` completing its
/// frame) at lattice point `u` ∈ [0, 1)² (Malley's method: a uniform
/// point of the unit disc lifted to the hemisphere).
#[inline]
pub(crate) fn cosine_direction(u: Vec2, (t, b, n): (Vec3, Vec3, Vec3)) -> Vec3 {
    let r = u.x.sqrt();
    let (s, c) = (std::f32::consts::TAU * u.y).sin_cos();
    t * (r * c) + b * (r * s) + n * (1.0 - u.x).max(0.0).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lattice_directions_are_cosine_distributed() {
        // Over the hemisphere, E[cos θ] = 2/3 and E[cos² θ] = 1/2 under the
        // cosine density; the mean direction is the normal times 2/3.
        let frame = (Vec3::X, Vec3::Y, Vec3::Z);
        let n = 4096;
        let (mut c1, mut c2, mut mean) = (0.0f64, 0.0f64, Vec3::ZERO);
        for i in 0..n {
            let w = cosine_direction(r2_point(i, Vec2::new(0.3, 0.7)), frame);
            assert!((w.length() - 1.0).abs() < 1e-5 && w.z >= 0.0);
            c1 += w.z as f64;
            c2 += (w.z * w.z) as f64;
            mean += w;
        }
        let n = n as f64;
        assert!((c1 / n - 2.0 / 3.0).abs() < 1e-3, "{}", c1 / n);
        assert!((c2 / n - 0.5).abs() < 1e-3, "{}", c2 / n);
        let m = mean / n as f32;
        assert!(m.x.abs() < 2e-3 && m.y.abs() < 2e-3, "{m}");
    }

    #[test]
    fn reach_weight_falls_from_one_to_zero_between_reach_and_twice_it() {
        let gather = Gather { rays: 16, reach: 1.0, reflected: Reflected::All(Vec::new()) };
        // A wall x = d in front of a floor (normal +z) at the origin: the
        // probe leaving along +x (30° above the floor) meets it at d / cos 30°.
        let at = |d: f32| move |o: Vec3, w: Vec3, _: f32| if w.x > 0.0 { (d - o.x) / w.x } else { f32::INFINITY };
        let cos30 = 0.866_025_4;
        let weight = |d: f32| gather.reach_weight(Vec3::ZERO, Vec3::Z, 0.1, 0.0, &at(d));
        assert_eq!(weight(0.05 * cos30), 1.0);
        assert_eq!(weight(0.1 * cos30), 1.0);
        assert!((weight(0.15 * cos30) - 0.5).abs() < 1e-4);
        assert_eq!(weight(0.2 * cos30), 0.0);
        assert_eq!(weight(10.0), 0.0);
        let everywhere = Gather { reach: f32::INFINITY, ..gather.clone() };
        assert_eq!(everywhere.reach_weight(Vec3::ZERO, Vec3::Z, 0.1, 0.0, &at(10.0)), 1.0);
        let nowhere = Gather { reach: 0.0, ..gather };
        assert_eq!(nowhere.reach_weight(Vec3::ZERO, Vec3::Z, 0.1, 0.0, &at(0.0)), 0.0);
    }
}
