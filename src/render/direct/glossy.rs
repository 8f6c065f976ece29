//! Glossy highlights per image sample: the emitters' light reflected by a
//! rough-conductor lobe towards each sample's own view direction.
//!
//! The paper's rendering (§3.5) takes a non-diffuse patch's radiance
//! towards the eye from the I-net, one value per patch for the ray to its
//! centre, interpolated between the directions of the set: a highlight
//! narrower than a patch or than the spacing of the directions comes out
//! blocky and too bright or too dim. Here the direct part is integrated at
//! every image sample instead, with the material's exact lobe
//! ([`crate::reflectance::model::Lobe`]) at the sample's exact view
//! direction, and the I-net keeps only the indirect light
//! ([`crate::distribute::DirectionalRadiance::direct`] taken off).
//!
//! Estimator: multiple importance sampling (the balance heuristic) of two
//! strategies per sample: [`LIGHT_POINTS`] points on the emitters (laid end to
//! end in proportion to their unshadowed light, stratified across the
//! pixel's samples, uniform in each emitter's parameters) and
//! [`LOBE_RAYS`] directions drawn from the lobe's distribution of visible
//! normals (Heitz 2018), each traced to the nearest surface. Light points
//! serve wide lobes and small emitters; lobe directions serve narrow lobes
//! (a near mirror) and large emitters; the heuristic takes each where it is
//! good. Seeds follow the pixel and primitive, as for the diffuse light.

use glam::{Vec2, Vec3};

use super::DirectLight;
use super::polygon::sample_point;
use crate::archive::InetView;
use crate::archive::layout::table_model;
use crate::geometry::accel::PrimitiveBvh;
use crate::reflectance::model::Lobe;
use crate::render::sampling::{Permutation, mix, r2_point, unit};

/// Points on the emitters per image sample for the unshadowed highlight
/// (no rays: a pixel of 4×4 samples takes 256, stratified across its
/// samples).
pub const LIGHT_POINTS: u32 = 16;

/// Shadow rays per image sample towards points on the emitters, for the
/// part of the highlight that occluders take.
pub const SHADOW_RAYS: u32 = 2;

/// Directions drawn from the lobe per image sample.
pub const LOBE_RAYS: u32 = 1;

/// A primitive's glossy lobe in world space.
#[derive(Debug, Clone, Copy)]
pub(super) struct GlossyFrame {
    /// Specular colour `k_s`.
    pub ks: Vec3,
    /// The lobe without its colour.
    pub lobe: Lobe,
    /// Tangent (the grain), bitangent `n × t` and normal.
    pub t: Vec3,
    pub b: Vec3,
    pub n: Vec3,
}

impl GlossyFrame {
    /// `w` in the local frame `(ω·t, ω·b, ω·n)`.
    fn local(&self, w: Vec3) -> Vec3 {
        Vec3::new(w.dot(self.t), w.dot(self.b), w.dot(self.n))
    }

    fn world(&self, l: Vec3) -> Vec3 {
        (self.t * l.x + self.b * l.y + self.n * l.z).normalize_or_zero()
    }

    /// GGX `D(h)` (local half vector; `h.z > 0`).
    #[inline]
    fn distribution(&self, h: Vec3) -> f32 {
        let (au, av) = (self.lobe.alpha_u, self.lobe.alpha_v);
        let s = (h.x / au).powi(2) + (h.y / av).powi(2) + h.z * h.z;
        1.0 / (std::f32::consts::PI * au * av * s * s)
    }

    /// Smith's `G₁(ω)` (local; `ω.z > 0`).
    #[inline]
    fn g1(&self, w: Vec3) -> f32 {
        let (au, av) = (self.lobe.alpha_u, self.lobe.alpha_v);
        let a2_tan2 = ((w.x * au).powi(2) + (w.y * av).powi(2)) / (w.z * w.z);
        2.0 / (1.0 + (1.0 + a2_tan2).sqrt())
    }

    /// `k_s · f(ω_i, ω_o)` per band (the model of
    /// [`crate::reflectance::model`], in f32) and the density with which
    /// [`Self::sample`] draws `ω_i` for `ω_o`, `G₁(ω_o)·D(h) / (4 cos θ_o)`;
    /// local directions.
    fn brdf_and_pdf(&self, wi: Vec3, wo: Vec3) -> (Vec3, f32) {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return (Vec3::ZERO, 0.0);
        }
        let h = (wi + wo).normalize();
        let (d, g1o) = (self.distribution(h), self.g1(wo));
        let pdf = g1o * d / (4.0 * wo.z);
        let f = d * self.g1(wi) * g1o / (4.0 * wi.z * wo.z);
        let colour = match self.lobe.ior {
            None => self.ks * f,
            Some(eta) => {
                let c5 = (1.0 - wi.dot(h).clamp(0.0, 1.0)).powi(5);
                let schlick = |n: f32| {
                    let f0 = ((n - 1.0) / (n + 1.0)).powi(2);
                    f0 + (1.0 - f0) * c5
                };
                self.ks * f * Vec3::new(schlick(eta[0]), schlick(eta[1]), schlick(eta[2]))
            }
        };
        (colour, pdf)
    }

    /// A direction reflected about a normal drawn from the distribution of
    /// normals visible from `wo` (Heitz 2018, "Sampling the GGX
    /// distribution of visible normals"), for `u` ∈ [0, 1)²; `None` below
    /// the surface.
    fn sample(&self, wo: Vec3, u: Vec2) -> Option<Vec3> {
        let (au, av) = (self.lobe.alpha_u, self.lobe.alpha_v);
        let vh = Vec3::new(au * wo.x, av * wo.y, wo.z).normalize();
        let len2 = vh.x * vh.x + vh.y * vh.y;
        let t1 = if len2 > 0.0 { Vec3::new(-vh.y, vh.x, 0.0) / len2.sqrt() } else { Vec3::X };
        let t2 = vh.cross(t1);
        let r = u.x.sqrt();
        let phi = 2.0 * std::f32::consts::PI * u.y;
        let p1 = r * phi.cos();
        let s = 0.5 * (1.0 + vh.z);
        let p2 = (1.0 - s) * (1.0 - p1 * p1).max(0.0).sqrt() + s * r * phi.sin();
        let p3 = (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt();
        let nh = p1 * t1 + p2 * t2 + p3 * vh;
        let h = Vec3::new(au * nh.x, av * nh.y, nh.z.max(1e-7)).normalize();
        let wi = 2.0 * wo.dot(h) * h - wo;
        (wi.z > 0.0).then_some(wi)
    }
}

/// One pixel's glossy points on one primitive and what their highlight
/// needs: the view, the lobe, the shadow BVH and the emitters in front of
/// them with their total weight.
#[derive(Clone, Copy)]
struct Highlight<'h> {
    points: &'h [Vec3],
    n: Vec3,
    eye: Vec3,
    frame: &'h GlossyFrame,
    bvh: &'h PrimitiveBvh,
    lit: &'h [(u32, f32)],
    weight: f32,
}

impl DirectLight {
    /// Whether primitive `prim` has a glossy lobe whose highlights are
    /// computed per sample.
    pub(crate) fn is_glossy(&self, prim: u32) -> bool {
        self.glossy_of.get(prim as usize).is_some_and(|&g| g != u32::MAX)
    }

    /// The summed radiance that the glossy points `points` (one pixel's
    /// image samples on primitive `prim`, front normal `n`), seen from
    /// `eye`, reflect of the emitters' direct light, with shadows from
    /// `bvh`. `lit` is scratch space.
    ///
    /// A difference of two estimates, as for the diffuse light: the
    /// unshadowed highlight (no rays: [`LIGHT_POINTS`] points on the
    /// emitters and [`LOBE_RAYS`] lobe directions met with the emitters'
    /// own polygons), less the part that occluders take (shadow rays: a
    /// second, smaller set of [`SHADOW_RAYS`] points, and the lobe
    /// directions traced through the BVH). Each is unbiased; the first is
    /// cheap, so it takes many points, and the second is zero wherever
    /// nothing is in the way.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn glossy_estimate(
        &self,
        points: &[Vec3],
        n: Vec3,
        eye: Vec3,
        prim: u32,
        bvh: &PrimitiveBvh,
        key: u64,
        lit: &mut Vec<(u32, f32)>,
    ) -> Vec3 {
        let Some(&g) = self.glossy_of.get(prim as usize).filter(|&&g| g != u32::MAX) else {
            return Vec3::ZERO;
        };
        let frame = &self.glossy[g as usize];
        if points.is_empty() || frame.ks == Vec3::ZERO {
            return Vec3::ZERO;
        }
        let mean = points.iter().copied().sum::<Vec3>() / points.len() as f32;
        self.lit_by(points, mean, (n, n), lit);
        let weight: f32 = lit.iter().map(|l| self.weight_of(l)).sum();
        if weight <= 0.0 {
            return Vec3::ZERO;
        }
        let key = mix(key ^ 0x2545_f491_4f6c_dd1d);
        let h = Highlight { points, n, eye, frame, bvh, lit: lit.as_slice(), weight };
        let unshadowed = self.light_points(&h, LIGHT_POINTS, mix(key ^ 1), false);
        let shadowed = self.light_points(&h, SHADOW_RAYS, mix(key ^ 2), true);
        let (u, s) = self.lobe_directions(&h, mix(key ^ 3));
        (unshadowed + u - shadowed - s).max(Vec3::ZERO)
    }

    /// The chance that a light point falls on emitter `e`.
    fn chance(&self, (lit, weight): (&[(u32, f32)], f32), e: u32) -> f32 {
        lit.iter().find(|l| l.0 == e).map_or(0.0, |l| self.weight_of(l) / weight)
    }

    /// `per_point` light points for each of `points` on the emitters `lit`
    /// (laid end to end in proportion to their weight; stratum q of all of
    /// them goes to point permute(q mod count)), weighted against the lobe
    /// directions by the balance heuristic: the summed estimate of the
    /// highlight, or, when `shadowed`, of the part of it whose shadow rays
    /// are blocked.
    fn light_points(&self, h: &Highlight<'_>, per_point: u32, key: u64, shadowed: bool) -> Vec3 {
        let Highlight { points, n, eye, frame, bvh, lit, weight } = *h;
        let count = points.len() as u32;
        let shift = Vec2::new(unit(key), unit(key >> 32));
        let (nl, nb) = (per_point as f32, LOBE_RAYS as f32);
        let rays = count * per_point;
        let order = Permutation::new(count, key);
        let (mut next, mut below, mut within) = (0usize, 0.0f32, 0u32);
        let mut sum = Vec3::ZERO;
        for q in 0..rays {
            let target = (q as f32 + unit(mix(key ^ q as u64))) / rays as f32 * weight;
            while next + 1 < lit.len() && below + self.weight_of(&lit[next]) <= target {
                below += self.weight_of(&lit[next]);
                next += 1;
                within = 0;
            }
            let e = lit[next].0;
            let em = &self.emitters[e as usize];
            let uv = r2_point(within, shift + Vec2::splat(e as f32 * 0.618_034));
            within += 1;
            let x = points[order.apply(q % count) as usize];
            let origin = x + n * self.epsilon;
            let wo = frame.local((eye - x).normalize_or_zero());
            if wo.z <= 0.0 {
                continue;
            }
            let (y, jacobian) = sample_point(&em.prim, uv);
            let to = y - origin;
            let r2 = to.length_squared();
            if r2 <= 0.0 || jacobian <= 0.0 {
                continue;
            }
            let d = to / r2.sqrt();
            let cos_y = -em.normal.dot(d);
            let wi = frame.local(d);
            if cos_y <= 0.0 || wi.z <= 0.0 || n.dot(d) <= 0.0 {
                continue;
            }
            let (f, pdf_lobe) = frame.brdf_and_pdf(wi, wo);
            if f == Vec3::ZERO {
                continue;
            }
            if shadowed && !bvh.occluded(origin, d, 0.0, r2.sqrt() * (1.0 - 1e-4)) {
                continue;
            }
            let pdf_light = self.chance((lit, weight), e) * r2 / (jacobian * cos_y);
            let mis = nl * pdf_light / (nl * pdf_light + nb * pdf_lobe);
            sum += em.radiance * f * (wi.z * mis / (pdf_light * nl));
        }
        sum
    }

    /// [`LOBE_RAYS`] lobe directions for each of `points`, each met with
    /// the lit emitters' polygons (the nearest) and traced through the BVH
    /// to that distance: their summed estimates of the highlight (weighted
    /// against [`LIGHT_POINTS`] light points) and of its blocked part
    /// (weighted against [`SHADOW_RAYS`]).
    fn lobe_directions(&self, h: &Highlight<'_>, key: u64) -> (Vec3, Vec3) {
        let Highlight { points, n, eye, frame, bvh, lit, weight } = *h;
        let count = points.len() as u32;
        let shift = Vec2::new(unit(key), unit(key >> 32));
        let (nu, ns, nb) = (LIGHT_POINTS as f32, SHADOW_RAYS as f32, LOBE_RAYS as f32);
        let (mut unshadowed, mut shadowed) = (Vec3::ZERO, Vec3::ZERO);
        let order = Permutation::new(count, key);
        for (k, &x) in points.iter().enumerate() {
            let origin = x + n * self.epsilon;
            let wo = frame.local((eye - x).normalize_or_zero());
            if wo.z <= 0.0 {
                continue;
            }
            for j in 0..LOBE_RAYS {
                let index = order.apply(k as u32) * LOBE_RAYS + j;
                let Some(wi) = frame.sample(wo, r2_point(index, shift)) else { continue };
                let d = frame.world(wi);
                if n.dot(d) <= 0.0 {
                    continue;
                }
                // The nearest lit emitter along d, met from its front.
                let mut nearest: Option<(u32, f32, Vec2)> = None;
                for &(e, _) in lit {
                    let em = &self.emitters[e as usize];
                    if em.normal.dot(d) >= 0.0 {
                        continue;
                    }
                    let far = nearest.map_or(f32::INFINITY, |h| h.1);
                    if let Some(hit) = em.prim.intersect(origin, d, 0.0, far) {
                        nearest = Some((e, hit.t, hit.uv));
                    }
                }
                let Some((e, t, uv)) = nearest else { continue };
                let em = &self.emitters[e as usize];
                let (f, pdf_lobe) = frame.brdf_and_pdf(wi, wo);
                let jacobian = sample_point(&em.prim, uv).1;
                let cos_y = -em.normal.dot(d);
                if pdf_lobe <= 0.0 || jacobian <= 0.0 || cos_y <= 0.0 {
                    continue;
                }
                let pdf_light = self.chance((lit, weight), e) * t * t / (jacobian * cos_y);
                let c = em.radiance * f * (wi.z / (pdf_lobe * nb));
                unshadowed += c * (nb * pdf_lobe / (nu * pdf_light + nb * pdf_lobe));
                if bvh.occluded(origin, d, 0.0, t * (1.0 - 1e-4)) {
                    shadowed += c * (nb * pdf_lobe / (ns * pdf_light + nb * pdf_lobe));
                }
            }
        }
        (unshadowed, shadowed)
    }
}

/// Per primitive, the index of its lobe in the returned list (`u32::MAX`
/// for diffuse primitives): the archive's prototype (GGX roughness and
/// Fresnel) and orientation (normal and grain) of its non-diffuse patches,
/// and `k_s` per surface. A primitive's patches share one material and one
/// orientation; Lambertian test prototypes are left to the I-net.
pub(super) fn glossy_frames(v: &InetView<'_>, specular: &[[f32; 3]]) -> (Vec<u32>, Vec<GlossyFrame>) {
    let mut of = vec![u32::MAX; v.primitives.len()];
    let mut frames = Vec::new();
    let Some(r) = &v.reflectance else { return (of, frames) };
    for rec in r.patches {
        let Some(&prim) = v.patch_primitive.get(rec.patch as usize) else { continue };
        let (Some(proto), Some(o)) =
            (r.prototypes.get(rec.prototype as usize), r.orientations.get(rec.orientation as usize))
        else {
            continue;
        };
        if of[prim as usize] != u32::MAX || proto.model != table_model::GGX {
            continue;
        }
        let surface = v.primitives[prim as usize].surface as usize;
        let ks = specular.get(surface).map_or(Vec3::ZERO, |&k| Vec3::from(k));
        let ior = (proto.ior != [0.0; 3]).then_some(proto.ior);
        // Validation checks the roughness finite and not negative, not the
        // scene's range, nor the frame unit: keep a forged archive finite.
        let n = Vec3::from(o.normal).normalize_or_zero();
        let t = (Vec3::from(o.grain) - n * n.dot(Vec3::from(o.grain))).normalize_or_zero();
        if n == Vec3::ZERO || t == Vec3::ZERO || !ks.is_finite() {
            continue;
        }
        let lobe = Lobe { alpha_u: proto.alpha_u.clamp(1e-3, 1e3), alpha_v: proto.alpha_v.clamp(1e-3, 1e3), ior };
        of[prim as usize] = frames.len() as u32;
        frames.push(GlossyFrame { ks, lobe, t, b: n.cross(t), n });
    }
    (of, frames)
}

#[cfg(test)]
mod tests {
    use super::super::Emitter;
    use super::*;
    use crate::geometry::Primitive;

    /// A plate at y = 0 (normal +y, grain +x) with `lobe`, a square
    /// emitter of side `side` and radiance 10 centred at `centre`, facing
    /// the origin, and `blockers`; the light, and the BVH of them all.
    fn plate_and_lamp(lobe: Lobe, centre: Vec3, side: f32, blockers: &[Primitive]) -> (DirectLight, PrimitiveBvh) {
        let plate = Primitive::quad([
            Vec3::new(-1.0, 0.0, 1.0),
            Vec3::new(1.0, 0.0, 1.0),
            Vec3::new(1.0, 0.0, -1.0),
            Vec3::new(-1.0, 0.0, -1.0),
        ]);
        let f = -centre.normalize();
        let u = Vec3::X;
        let v = f.cross(u).normalize();
        let h = 0.5 * side;
        let mut q = [centre - h * u - h * v, centre + h * u - h * v, centre + h * u + h * v, centre - h * u + h * v];
        if (q[1] - q[0]).cross(q[2] - q[0]).dot(f) < 0.0 {
            q.reverse();
        }
        let lamp = Primitive::quad(q);
        let corners = &lamp.p[..4];
        let lamp_centre = corners.iter().copied().sum::<Vec3>() / 4.0;
        let emitter = Emitter {
            prim: lamp,
            normal: lamp.normal(),
            radiance: Vec3::splat(10.0),
            centre: lamp_centre,
            radius: corners.iter().map(|c| c.distance(lamp_centre)).fold(0.0, f32::max),
        };
        let mut all = vec![plate, lamp];
        all.extend_from_slice(blockers);
        let light = DirectLight {
            emitters: vec![emitter],
            kd: vec![Vec3::ZERO; all.len()],
            glossy_of: std::iter::once(0).chain(std::iter::repeat_n(u32::MAX, all.len() - 1)).collect(),
            glossy: vec![GlossyFrame { ks: Vec3::ONE, lobe, t: Vec3::X, b: Vec3::Y.cross(Vec3::X), n: Vec3::Y }],
            samples: 8,
            epsilon: 1e-5,
            gather: None,
        };
        (light, PrimitiveBvh::new(&all))
    }

    /// `∫ f(ω_i, ω_o) L V cos θ_i dω_i` over the emitter by a fine midpoint
    /// rule over its area, visibility V from a ray to each point.
    fn brute_force(light: &DirectLight, bvh: &PrimitiveBvh, x: Vec3, eye: Vec3, m: usize) -> f64 {
        let (em, frame) = (&light.emitters[0], &light.glossy[0]);
        let wo = frame.local((eye - x).normalize());
        let mut sum = 0.0;
        for i in 0..m * m {
            let uv = Vec2::new(((i % m) as f32 + 0.5) / m as f32, ((i / m) as f32 + 0.5) / m as f32);
            let (y, jacobian) = sample_point(&em.prim, uv);
            let to = (y - x).as_dvec3();
            let r2 = to.length_squared();
            let d = to / r2.sqrt();
            let cos_y = -em.normal.as_dvec3().dot(d);
            let wi = frame.local(d.as_vec3());
            let origin = x + Vec3::Y * light.epsilon;
            if cos_y > 0.0 && wi.z > 0.0 && !bvh.occluded(origin, d.as_vec3(), 0.0, r2.sqrt() as f32 * 0.9999) {
                // The model's own f64 evaluation, not the renderer's f32 one.
                let f = frame.lobe.eval(0, wi.as_dvec3().to_array(), wo.as_dvec3().to_array());
                sum += f * wi.z as f64 * cos_y / r2 * jacobian as f64;
            }
        }
        10.0 * sum / (m * m) as f64
    }

    /// The estimator is unbiased for wide and narrow lobes, small and
    /// large emitters, with and without a blocker half across the light
    /// (MIS weights that sum to one in both of its estimates), and its
    /// single estimates (16 samples) are within a few per cent where the
    /// lobe is wide and nothing blocks.
    #[test]
    fn glossy_estimate_matches_a_brute_force_integral() {
        let eye = Vec3::new(0.0, 0.7, -1.5);
        let lamp = Vec3::new(0.0, 0.85, 1.8);
        // A wall between the plate's centre and the lamp, its top edge
        // through the middle of the lamp's image.
        let edge = lamp * 0.5;
        let blocker = Primitive::quad([
            Vec3::new(-1.0, 0.0, edge.z),
            Vec3::new(-1.0, edge.y, edge.z),
            Vec3::new(1.0, edge.y, edge.z),
            Vec3::new(1.0, 0.0, edge.z),
        ]);
        for (lobe, side, blockers, bar_single) in [
            (Lobe { alpha_u: 0.05, alpha_v: 0.3, ior: None }, 0.2, vec![], 0.08),
            (Lobe { alpha_u: 0.3, alpha_v: 0.3, ior: None }, 0.2, vec![], 0.03),
            (Lobe { alpha_u: 0.02, alpha_v: 0.02, ior: None }, 0.6, vec![], 0.6),
            (Lobe { alpha_u: 0.05, alpha_v: 0.3, ior: None }, 0.2, vec![blocker], 0.5),
            (Lobe { alpha_u: 0.3, alpha_v: 0.3, ior: None }, 0.2, vec![blocker], 0.5),
        ] {
            let (light, bvh) = plate_and_lamp(lobe, lamp, side, &blockers);
            for x in [Vec3::ZERO, Vec3::new(0.05, 0.0, 0.02), Vec3::new(-0.1, 0.0, -0.1)] {
                let want = brute_force(&light, &bvh, x, eye, 1024);
                let points = [x; 16];
                let (mut sum, mut worst) = (0.0f64, 0.0f64);
                // Shadows cancel most of the unshadowed estimate: more runs.
                let runs = if blockers.is_empty() { 400 } else { 4000 };
                let mut lit = Vec::new();
                for k in 0..runs {
                    let got = light.glossy_estimate(&points, Vec3::Y, eye, 0, &bvh, mix(k), &mut lit).x as f64
                        / points.len() as f64;
                    sum += got;
                    worst = worst.max((got - want).abs());
                }
                let mean = sum / runs as f64;
                let scale = want.max(1e-3);
                let shadow = if blockers.is_empty() { "" } else { ", half blocked" };
                assert!(
                    (mean - want).abs() < 0.01 * scale,
                    "{lobe:?}, side {side}{shadow}, x {x}: mean {mean} vs brute force {want}"
                );
                if want > 1.0 {
                    assert!(worst < bar_single * want, "{lobe:?}{shadow}, x {x}: worst single {worst} vs {want}");
                }
            }
        }
    }

    /// Directions drawn by `sample` have the density `brdf_and_pdf` says
    /// (the albedo by sampling equals the model's quadrature), and its f32
    /// BRDF is the model's f64 one (with Fresnel too).
    #[test]
    fn lobe_sampling_has_the_density_it_states() {
        let schlick = GlossyFrame {
            ks: Vec3::ONE,
            lobe: Lobe { alpha_u: 0.07, alpha_v: 0.4, ior: Some([1.5, 2.0, 2.5]) },
            t: Vec3::X,
            b: Vec3::Y,
            n: Vec3::Z,
        };
        for (wi, wo) in [([0.3, 0.1, 0.9], [-0.2, -0.1, 0.95]), ([0.6, -0.3, 0.5], [-0.5, 0.35, 0.6])] {
            let (wi, wo) = (Vec3::from_array(wi).normalize(), Vec3::from_array(wo).normalize());
            let (f, _) = schlick.brdf_and_pdf(wi, wo);
            for c in 0..3 {
                let want = schlick.lobe.eval(c, wi.as_dvec3().to_array(), wo.as_dvec3().to_array());
                assert!((f[c] as f64 - want).abs() < 1e-5 * want, "band {c}: {} vs {want}", f[c]);
            }
        }
        let frame = GlossyFrame {
            ks: Vec3::ONE,
            lobe: Lobe { alpha_u: 0.1, alpha_v: 0.35, ior: None },
            t: Vec3::X,
            b: Vec3::Y,
            n: Vec3::Z,
        };
        for wo in [[0.0, 0.0, 1.0], [0.5, 0.2, 0.84], [-0.7, 0.5, 0.5]] {
            let wo = Vec3::from_array(wo).normalize();
            // ∫ f cos θ_i dω_i (the albedo) by sampling, against quadrature.
            let m = 256;
            let mut s = 0.0;
            for i in 0..m * m {
                let u = Vec2::new(((i % m) as f32 + 0.5) / m as f32, ((i / m) as f32 + 0.5) / m as f32);
                if let Some(wi) = frame.sample(wo, u) {
                    let (f, pdf) = frame.brdf_and_pdf(wi, wo);
                    s += (f.x * wi.z / pdf) as f64;
                }
            }
            let sampled = s / (m * m) as f64;
            let quadrature = frame.lobe.albedo(0, wo.as_dvec3().to_array(), 256);
            assert!((sampled - quadrature).abs() < 3e-3, "ω_o {wo:?}: sampled {sampled}, quadrature {quadrature}");
        }
    }
}
