//! Direct light per pixel: the light that reaches the visible points
//! straight from the emitters, computed where the eye looks instead of
//! being quantised by the direction set and the patch grid.
//!
//! Every emitter is a planar, convex, one-sided polygon of uniform
//! radiance L (a primitive of an emitting surface). The irradiance it
//! gives a point x with normal n, unoccluded, has a closed form (Lambert's
//! polygon formula, after clipping the polygon to the hemisphere above x):
//! `E = L/2 · |Σ_i Θ_i (n · Γ_i)|`, with Θ_i the angle the edge
//! `v_i v_{i+1}` subtends at x and Γ_i the unit normal of the plane through
//! x and that edge. Occlusion is estimated by difference: stratified
//! shadow rays towards points y_j of the emitter estimate the *shadowed*
//! part `Σ f_j (1 − V_j) / N` (f the unshadowed integrand over its
//! density, V the ray's visibility), which is subtracted from the closed
//! form, so the result is exact wherever the emitter is wholly visible and
//! only shadows carry noise. A diffuse point then reflects `k_d/π · E`.
//!
//! The work is per pixel and primitive, not per image sample: a pixel's
//! samples on one primitive share one closed form (at their centre) and
//! one set of shadow rays (leaving from the samples in turn), shared by all
//! the emitters. Four rays give every pixel a first estimate; pixels within
//! two of one whose first rays were blocked are estimated again with many
//! (the renderer's two passes), aimed only at the emitters those rays found
//! blocked. Where every ray is blocked (umbrae) the
//! estimate is noise around zero clamped at zero: a slight lift, where the
//! per-sample version returned exactly zero. Rays are seeded by frame,
//! pixel and primitive, so images are deterministic and do not depend on
//! the thread count.

pub(super) mod gather;
mod glossy;
mod polygon;

use glam::{Vec2, Vec3};

/// The seed of a pixel's light samples (`super::sampling`'s, named here
/// where it has always been).
pub use super::sampling::pixel_key;
use super::sampling::{Permutation, mix, r2_point, unit};
use crate::archive::InetView;
use crate::distribute::Solution;
use crate::geometry::accel::PrimitiveBvh;
use crate::geometry::{Primitive, PrimitiveKind};
use gather::Gather;
pub use glossy::{
    LIGHT_POINTS as GLOSSY_LIGHT_POINTS, LOBE_RAYS as GLOSSY_LOBE_RAYS, SHADOW_RAYS as GLOSSY_SHADOW_RAYS,
};
pub use polygon::polygon_irradiance;
use polygon::{sample_point, shaded_irradiance};

/// Default light samples: `8 × 8` shadow rays per pixel and primitive in
/// the second pass (pixels near a blocked first ray), shared by all
/// emitters in proportion to their light, of which those that no blocked
/// ray nearby aimed at are not traced; the first pass takes four.
pub const DEFAULT_LIGHT_SAMPLES: u32 = 8;

/// Largest spread of a pixel's points, relative to their distance from an
/// emitter, for which the closed form at their mean stands for its mean
/// over them (beyond it, the points are taken one by one): 5% keeps the
/// difference (the second-order term) below 1e-3, measured 3e-4. The mean
/// over the points is itself a quadrature of the pixel, no truer than the
/// closed form at their centre: the Cornell box's error is the same either
/// way, and taking every point costs twice the time.
const SPREAD: f32 = 0.05;

/// Rays per pixel of the one-bounce gather ([`Gather`]) that a render of a
/// single frame takes by default: on the Cornell box, 256 take the relative
/// error from 1.60% to 1.34% (the reference's noise removed) for 1.3 s more
/// at 256×256 (`docs/GATHER.md`).
pub const DEFAULT_GATHER_RAYS: u32 = 256;

/// Most emitters for which a gather ray computes the direct light exactly
/// where it lands (its cost grows with them: every ray takes Lambert's
/// closed form of each emitter in front); beyond, it looks up the I-net's.
pub const GATHER_EXACT_EMITTERS: usize = 16;

/// Shadow rays of a pixel's first estimate, shared by all the emitters.
pub(crate) const FIRST_RAYS: u32 = 4;

/// One emitting primitive of a frame.
#[derive(Debug, Clone, Copy)]
struct Emitter {
    prim: Primitive,
    normal: Vec3,
    radiance: Vec3,
    /// Centre of its corners and the largest distance from it to one.
    centre: Vec3,
    radius: f32,
}

/// The emitters of one frame and the reflectance of every primitive: what
/// the direct light of an image sample needs.
#[derive(Debug, Clone)]
pub struct DirectLight {
    emitters: Vec<Emitter>,
    /// `k_d` per primitive (archive order).
    kd: Vec<Vec3>,
    /// Per primitive, its lobe's index in `glossy` (`u32::MAX`: diffuse).
    glossy_of: Vec<u32>,
    glossy: Vec<glossy::GlossyFrame>,
    /// Second-pass shadow rays per pixel and primitive: this squared.
    samples: u32,
    /// Offset of shadow-ray origins along the normal (scale of the scene).
    epsilon: f32,
    /// The one-bounce gather of indirect light, when asked for, and per
    /// primitive whether its samples take it (diffuse, not emitting).
    gather: Option<(Gather, Vec<bool>)>,
}

impl DirectLight {
    /// The emitters present at the frame `solution` solved, with its
    /// emission, `k_d` and `k_s` per surface, and `samples × samples`
    /// shadow rays per pixel and primitive in the second pass (clamped to
    /// 1..=64). Glossy primitives take their highlights per sample too
    /// (`glossy.rs`), with the archive's lobes and orientations.
    pub fn new(v: &InetView<'_>, solution: &Solution, samples: u32) -> Self {
        let (emission, reflectance) = (&solution.surface_emission, &solution.surface_reflectance);
        let present = v.presence(solution.frame()).primitives;
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
                let corners = &prim.p[..prim.corner_count()];
                let centre = corners.iter().copied().sum::<Vec3>() / corners.len() as f32;
                let radius = corners.iter().map(|c| c.distance(centre)).fold(0.0, f32::max);
                emitters.push(Emitter { prim, normal: prim.normal(), radiance, centre, radius });
            }
        }
        let (glossy_of, glossy) = glossy::glossy_frames(v, &solution.surface_specular);
        let epsilon = if lo.x <= hi.x { (hi - lo).max_element() * 1e-5 } else { 1e-6 };
        Self { emitters, kd, glossy_of, glossy, samples: samples.clamp(1, 64), epsilon, gather: None }
    }

    /// This direct light with a one-bounce gather ([`Gather`]) of `rays`
    /// rays per pixel over the light of `solution`, which diffuse,
    /// non-emitting samples whose nearest geometry is within `reach` patch
    /// sides take their indirect light from (fading out to twice that;
    /// infinite: every such sample). Where the rays land, the emitters'
    /// direct light is computed exactly when the frame has at most
    /// [`GATHER_EXACT_EMITTERS`] emitters, else taken from the I-net.
    pub fn with_gather(mut self, v: &InetView<'_>, solution: &Solution, rays: u32, reach: f32) -> Self {
        let exact = self.emitters.len() <= GATHER_EXACT_EMITTERS;
        let gather = Gather::new(v, solution, rays, reach, exact);
        let emission = &solution.surface_emission;
        let takes = v
            .primitives
            .iter()
            .enumerate()
            .map(|(i, r)| {
                let emits = emission.get(r.surface as usize).is_some_and(|e| e.iter().any(|&c| c > 0.0));
                self.kd[i] != Vec3::ZERO && !emits && !self.is_glossy(i as u32)
            })
            .collect();
        self.gather = Some((gather, takes));
        self
    }

    /// The one-bounce gather, when there is one.
    pub fn gather(&self) -> Option<&Gather> {
        self.gather.as_ref().map(|g| &g.0)
    }

    /// The gather, when primitive `prim`'s samples take one, and what the
    /// gathered light is multiplied by (`k_d`).
    #[inline]
    pub(crate) fn gather_for(&self, prim: u32) -> Option<(&Gather, Vec3)> {
        let (g, takes) = self.gather.as_ref()?;
        takes.get(prim as usize).copied().unwrap_or(false).then(|| (g, self.kd[prim as usize]))
    }

    /// Offset of ray origins above a face (the scene's scale × 10⁻⁵).
    pub(crate) fn epsilon(&self) -> f32 {
        self.epsilon
    }

    /// Shadow rays of a pixel's second estimate, in and near penumbrae
    /// (the light samples squared).
    pub(crate) fn refined_rays(&self) -> u32 {
        self.samples * self.samples
    }

    /// Whether the frame has any emitter.
    pub fn is_empty(&self) -> bool {
        self.emitters.is_empty()
    }

    /// The emitters in front of `points` (mean `mean`, normal `n`) with
    /// their closed-form irradiance averaged over the points, into `lit`.
    /// The closed form at the mean stands for the average (exact to second
    /// order) unless the points spread over more than [`SPREAD`] of their
    /// distance to the emitter.
    ///
    /// With a shading normal `n` other than the face normal `face`, only
    /// the part of each emitter above the face's plane counts: light from
    /// behind the surface cannot reach it, however the normal leans.
    fn lit_by(&self, points: &[Vec3], mean: Vec3, (n, face): (Vec3, Vec3), lit: &mut Vec<(u32, f32)>) {
        lit.clear();
        let spread = points.iter().map(|p| p.distance_squared(mean)).fold(0.0f32, f32::max).sqrt();
        for (e, em) in self.emitters.iter().enumerate() {
            // One-sided emitters light only what is in front of them.
            if (mean - em.prim.p[0]).dot(em.normal) <= 0.0 {
                continue;
            }
            let poly = &em.prim.p[..em.prim.corner_count()];
            let near = mean.distance(em.centre) - em.radius;
            let unoccluded = if points.len() > 1 && spread > SPREAD * near {
                points.iter().map(|&p| shaded_irradiance(p, n, face, poly)).sum::<f32>() / points.len() as f32
            } else {
                shaded_irradiance(mean, n, face, poly)
            };
            if unoccluded > 0.0 {
                lit.push((e as u32, unoccluded));
            }
        }
    }

    /// An estimate of the mean radiance that the diffuse points `points`
    /// (one pixel's image samples on primitive `prim`, shading normal `n`
    /// and face normal `face`, equal but for meshes with vertex normals)
    /// reflect of the emitters' direct light, from `rays` shadow rays
    /// through `bvh` (the frame's present primitives) seeded by `key`
    /// ([`pixel_key`]); and the emitters a ray to which was blocked (a
    /// mask of [`emitter_bit`]s). `lit` is scratch space.
    ///
    /// The unoccluded irradiance is the closed form at the points' mean
    /// (exact to second order in the pixel's footprint). The rays serve all
    /// the emitters together: ray q takes stratum q of the emitters laid
    /// end to end in proportion to the light each gives, leaves from the
    /// points in turn, and aims at a point of its emitter from a shifted
    /// rank-1 lattice (the R2 sequence), so each emitter's rays cover it
    /// evenly. The shadowed part they estimate is subtracted from the
    /// closed form: unbiased, exact wherever no ray is blocked, and a lit
    /// pixel costs `rays` rays however many emitters light it.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn estimate(
        &self,
        points: &[Vec3],
        (n, face): (Vec3, Vec3),
        prim: u32,
        bvh: &PrimitiveBvh,
        key: u64,
        rays: u32,
        lit: &mut Vec<(u32, f32)>,
    ) -> (Vec3, u64) {
        let (l, blocked) = self.estimate_signed(points, (n, face), prim, bvh, key, rays, lit);
        (l.max(Vec3::ZERO), blocked)
    }

    /// [`Self::estimate`] without clamping at zero: negative where the
    /// rays find more shadow than the mean holds. Unbiased, so a mean of
    /// many such estimates (the gather's) is too; clamping each one would
    /// lift every umbra.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn estimate_signed(
        &self,
        points: &[Vec3],
        (n, face): (Vec3, Vec3),
        prim: u32,
        bvh: &PrimitiveBvh,
        key: u64,
        rays: u32,
        lit: &mut Vec<(u32, f32)>,
    ) -> (Vec3, u64) {
        let Some((kd, unshadowed)) = self.unshadowed(points, (n, face), prim, rays, lit) else {
            return (Vec3::ZERO, 0);
        };
        let (shadowed, blocked) = self.shadowed(points, (n, face), lit, bvh, key, rays, u64::MAX);
        (kd * std::f32::consts::FRAC_1_PI * (unshadowed - shadowed), blocked)
    }

    /// The second estimate of a pixel whose neighbours' first estimates
    /// found the emitters `near` (an [`emitter_bit`] mask) blocked:
    /// [`Self::estimate`] afresh for those emitters, with as many of
    /// `rays` as their share of the light (each emitter keeps the density
    /// of rays it would have had among all of them), and, for the others,
    /// the part of the pixel's own first estimate (seeded by the same
    /// `key`) that their rays gave. Which emitters are estimated afresh
    /// depends on the neighbours' rays only, so the sum stays unbiased; a
    /// pixel in the shadow of one lamp among several traces rays to that
    /// lamp only. With one emitter, this is [`Self::estimate`] with `rays`
    /// rays seeded by `!key`.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn estimate_refined(
        &self,
        points: &[Vec3],
        (n, face): (Vec3, Vec3),
        prim: u32,
        bvh: &PrimitiveBvh,
        key: u64,
        (rays, near): (u32, u64),
        lit: &mut Vec<(u32, f32)>,
    ) -> Vec3 {
        let Some((kd, unshadowed)) = self.unshadowed(points, (n, face), prim, rays, lit) else {
            return Vec3::ZERO;
        };
        // The first estimate's rays to the emitters left out.
        let (kept, _) = self.shadowed(points, (n, face), lit, bvh, key, FIRST_RAYS, !near);
        let weight: f32 = lit.iter().map(|l| self.weight_of(l)).sum();
        lit.retain(|&(e, _)| emitter_bit(e) & near != 0);
        let share: f32 = lit.iter().map(|l| self.weight_of(l)).sum();
        let fresh = if share > 0.0 {
            let m = ((rays as f32 * (share / weight)).ceil() as u32).clamp(1, rays);
            self.shadowed(points, (n, face), lit, bvh, !key, m, u64::MAX).0
        } else {
            Vec3::ZERO
        };
        (kd * std::f32::consts::FRAC_1_PI * (unshadowed - kept - fresh)).max(Vec3::ZERO)
    }

    /// The weight by which rays are shared among the emitters: the light
    /// (summed over colour) that `lit`'s emitter gives unoccluded.
    #[inline]
    fn weight_of(&self, &(e, u): &(u32, f32)) -> f32 {
        self.emitters[e as usize].radiance.element_sum() * u
    }

    /// `k_d` of `prim` and the unoccluded irradiance-weighted radiance of
    /// the emitters in front of `points` (listed with their closed forms
    /// into `lit`); `None` when there is nothing to estimate.
    fn unshadowed(
        &self,
        points: &[Vec3],
        (n, face): (Vec3, Vec3),
        prim: u32,
        rays: u32,
        lit: &mut Vec<(u32, f32)>,
    ) -> Option<(Vec3, Vec3)> {
        let kd = self.kd.get(prim as usize).copied().unwrap_or(Vec3::ZERO);
        if kd == Vec3::ZERO || points.is_empty() || rays == 0 {
            return None;
        }
        let mean = points.iter().copied().sum::<Vec3>() / points.len() as f32;
        self.lit_by(points, mean, (n, face), lit);
        let weight: f32 = lit.iter().map(|l| self.weight_of(l)).sum();
        if weight <= 0.0 {
            return None;
        }
        Some((kd, lit.iter().map(|&(e, u)| self.emitters[e as usize].radiance * u).sum()))
    }

    /// The shadowed part of the light of the emitters `lit` (nonempty
    /// weights), estimated by `rays` rays shared among them in proportion
    /// to their light and seeded by `key`, of which only those aimed at
    /// emitters in `traced` (an [`emitter_bit`] mask) are traced and
    /// counted; and the emitters a counted ray to which was blocked.
    #[allow(clippy::too_many_arguments)]
    fn shadowed(
        &self,
        points: &[Vec3],
        (n, face): (Vec3, Vec3),
        lit: &[(u32, f32)],
        bvh: &PrimitiveBvh,
        key: u64,
        rays: u32,
        traced: u64,
    ) -> (Vec3, u64) {
        let weight: f32 = lit.iter().map(|l| self.weight_of(l)).sum();
        let count = points.len() as u32;
        let key = mix(key ^ 0x4f1b_bcdc_bfa5_3e0b);
        let order = Permutation::new(count, key);
        let shift = Vec2::new(unit(key), unit(key >> 32));
        // Running position along the emitters laid end to end, and the
        // index of the current ray within its emitter.
        let (mut next, mut below, mut within) = (0usize, 0.0f32, 0u32);
        let (mut shadowed, mut blocked) = (Vec3::ZERO, 0u64);
        let mut hint = u32::MAX;
        for q in 0..rays {
            let h = mix(key ^ q as u64);
            let target = (q as f32 + unit(h)) / rays as f32 * weight;
            // The emitter whose share of the weight holds `target`.
            while next + 1 < lit.len() && below + self.weight_of(&lit[next]) <= target {
                below += self.weight_of(&lit[next]);
                next += 1;
                within = 0;
            }
            let (e, _) = lit[next];
            let em = &self.emitters[e as usize];
            let uv = r2_point(within, shift + Vec2::splat(e as f32 * 0.618_034));
            within += 1;
            if emitter_bit(e) & traced == 0 {
                continue;
            }
            let x = points[order.apply(q % count) as usize];
            if let Some((f, true)) = self.shadow_ray(x, (n, face), em, uv, bvh, &mut hint) {
                // f over the chance of this emitter (its share of the weight).
                shadowed += em.radiance * (f * weight / self.weight_of(&lit[next]));
                blocked |= emitter_bit(e);
            }
        }
        (shadowed / rays as f32, blocked)
    }

    /// The unshadowed integrand (over uv) of the shadow ray from `x`
    /// (shading normal `n`, face normal `face`) to the point `uv` of `em`,
    /// and whether the ray is blocked; `None` when that point is below
    /// either horizon of `x` (as in [`Self::lit_by`]) or `x` behind the
    /// emitter.
    #[inline]
    fn shadow_ray(
        &self,
        x: Vec3,
        (n, face): (Vec3, Vec3),
        em: &Emitter,
        uv: Vec2,
        bvh: &PrimitiveBvh,
        hint: &mut u32,
    ) -> Option<(f32, bool)> {
        let origin = x + face * self.epsilon;
        let (y, jacobian) = sample_point(&em.prim, uv);
        let to = y - origin;
        let r2 = to.length_squared();
        if r2 <= 0.0 {
            return None;
        }
        let d = to / r2.sqrt();
        let (cos_x, cos_y) = (n.dot(d), -em.normal.dot(d));
        if cos_x <= 0.0 || cos_y <= 0.0 || (face != n && face.dot(y - x) <= 0.0) {
            return None;
        }
        let f = cos_x * cos_y / r2 * jacobian;
        Some((f, bvh.occluded_hinted(origin, d, 0.0, r2.sqrt() * (1.0 - 1e-4), hint)))
    }
}

/// Emitter `e`'s bit in a mask of a frame's emitters; emitters from 63 on
/// share the last bit.
#[inline]
pub(crate) fn emitter_bit(e: u32) -> u64 {
    1 << e.min(63)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A quad emitter facing down of radiance `l` over `[x0, x1] × [z0, z1]`
    /// at height `y`.
    fn ceiling_emitter((x0, x1): (f32, f32), (z0, z1): (f32, f32), y: f32, l: f32) -> Emitter {
        let prim =
            Primitive::quad([Vec3::new(x0, y, z0), Vec3::new(x1, y, z0), Vec3::new(x1, y, z1), Vec3::new(x0, y, z1)]);
        let centre = Vec3::new(0.5 * (x0 + x1), y, 0.5 * (z0 + z1));
        Emitter { prim, normal: prim.normal(), radiance: Vec3::splat(l), centre, radius: prim.p[0].distance(centre) }
    }

    /// The first and the refined estimates are unbiased whichever emitters
    /// the neighbours found blocked: a point lit by two emitters, a
    /// blocker hiding part of the first. The refined estimate keeps the
    /// first estimate's part of the emitters it leaves out, so leaving out
    /// the blocked one must still give its shadow; and it traces rays
    /// only to the emitters it estimates afresh.
    #[test]
    fn refined_estimates_are_unbiased_whichever_emitters_they_refine() {
        let a = ceiling_emitter((-0.5, 0.5), (-0.5, 0.5), 1.0, 10.0);
        let b = ceiling_emitter((1.0, 1.6), (-0.3, 0.3), 1.0, 6.0);
        let floor = Primitive::quad([
            Vec3::new(-2.0, 0.0, -2.0),
            Vec3::new(-2.0, 0.0, 2.0),
            Vec3::new(2.0, 0.0, 2.0),
            Vec3::new(2.0, 0.0, -2.0),
        ]);
        // At half height over the point: its shadow on the light's plane
        // is [0, 0.4] × [-0.2, 0.2], inside emitter a.
        let blocker = Primitive::quad([
            Vec3::new(0.0, 0.5, -0.1),
            Vec3::new(0.2, 0.5, -0.1),
            Vec3::new(0.2, 0.5, 0.1),
            Vec3::new(0.0, 0.5, 0.1),
        ]);
        let (x, n) = (Vec3::ZERO, Vec3::Y);
        let shadow =
            [Vec3::new(0.0, 1.0, -0.2), Vec3::new(0.4, 1.0, -0.2), Vec3::new(0.4, 1.0, 0.2), Vec3::new(0.0, 1.0, 0.2)];
        let irradiance = |e: &Emitter| polygon_irradiance(x, n, &e.prim.p) as f64;
        let kd = 0.5;
        let want = kd / std::f64::consts::PI
            * (10.0 * (irradiance(&a) - polygon_irradiance(x, n, &shadow) as f64) + 6.0 * irradiance(&b));
        let light = DirectLight {
            emitters: vec![a, b],
            kd: vec![Vec3::splat(kd as f32), Vec3::ZERO],
            glossy_of: vec![u32::MAX; 2],
            glossy: Vec::new(),
            samples: 8,
            epsilon: 1e-5,
            gather: None,
        };
        let bvh = PrimitiveBvh::new(&[floor, blocker]);
        let points = [x; 4];
        let mut lit = Vec::new();
        let runs = 4000;
        let first =
            (0..runs).map(|k| light.estimate(&points, (n, n), 0, &bvh, mix(k), FIRST_RAYS, &mut lit).0.x as f64);
        let mean = first.sum::<f64>() / runs as f64;
        assert!((mean - want).abs() < 5e-3 * want, "first estimates: mean {mean} vs {want}");
        for near in [emitter_bit(0), emitter_bit(1), emitter_bit(0) | emitter_bit(1)] {
            let refined = (0..runs)
                .map(|k| light.estimate_refined(&points, (n, n), 0, &bvh, mix(k), (64, near), &mut lit).x as f64);
            let mean = refined.sum::<f64>() / runs as f64;
            assert!((mean - want).abs() < 5e-3 * want, "refining {near:b}: mean {mean} vs {want}");
        }
        // Emitter b is never blocked here: refining it alone changes no
        // estimate, refining a alone traces no ray to b.
        for k in 0..64 {
            let first = light.estimate(&points, (n, n), 0, &bvh, mix(k), FIRST_RAYS, &mut lit).0;
            let only_b = light.estimate_refined(&points, (n, n), 0, &bvh, mix(k), (64, emitter_bit(1)), &mut lit);
            assert!((first - only_b).abs().max_element() < 1e-5 * want as f32, "{first} vs {only_b}");
        }
    }
}
