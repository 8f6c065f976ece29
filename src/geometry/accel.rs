//! A BVH (obvhs `Bvh2`) over the scene's primitives, shared by the build's
//! ray bundles and the renderer's primary rays.
//!
//! Primitives are reordered once into the BVH's leaf order so traversal
//! indexes them directly; hits report original primitive indices.

use std::time::Duration;

use glam::{Vec3, Vec3A};
use obvhs::BvhBuildParams;
use obvhs::aabb::Aabb;
use obvhs::bvh2::Bvh2;
use obvhs::bvh2::builder::build_bvh2;
use obvhs::ray::{Ray, RayHit};

use super::{Primitive, QuadFilter, SurfaceHit};

/// A hit reported by [`PrimitiveBvh`]: original primitive index and surface hit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PrimitiveHit {
    /// Index of the primitive in the order given to [`PrimitiveBvh::new`].
    pub primitive: u32,
    /// Distance and surface coordinates.
    pub hit: SurfaceHit,
}

/// Bounding volume hierarchy over primitives.
pub struct PrimitiveBvh {
    bvh: Bvh2,
    /// Primitives in BVH leaf order.
    ordered: Vec<Primitive>,
    /// Their quad filters.
    filters: Vec<QuadFilter>,
    /// Original index of each ordered primitive.
    original: Vec<u32>,
    /// Their padded boxes, as the BVH was built from.
    boxes: Vec<Aabb>,
}

impl PrimitiveBvh {
    /// Builds the BVH. Bounds are padded slightly so that flat, axis-aligned
    /// primitives have non-empty boxes.
    pub fn new(primitives: &[Primitive]) -> Self {
        let (lo, hi) = super::bounds_of(primitives);
        let pad = ((hi - lo).max_element() * 1e-6).max(1e-9);
        let aabbs: Vec<Aabb> = primitives
            .iter()
            .map(|p| {
                let (a, b) = p.bounds();
                Aabb::new(Vec3A::from(a - pad), Vec3A::from(b + pad))
            })
            .collect();
        let bvh = build_bvh2(&aabbs, BvhBuildParams::medium_build(), &mut Duration::default());
        let original = bvh.primitive_indices.clone();
        let ordered: Vec<Primitive> = original.iter().map(|&i| primitives[i as usize]).collect();
        let filters = ordered.iter().map(QuadFilter::new).collect();
        let boxes = original.iter().map(|&i| aabbs[i as usize]).collect();
        Self { bvh, ordered, filters, original, boxes }
    }

    /// Calls `out` for every intersection of the full line through `origin`
    /// along `dir` with `t > 0`, in no particular order.
    #[inline]
    pub fn all_hits(&self, origin: Vec3, dir: Vec3, mut out: impl FnMut(PrimitiveHit)) {
        let ray = Ray::new(origin.into(), dir.into(), 0.0, f32::INFINITY);
        self.bvh.ray_traverse_anyhit(ray, |r, id| {
            let prim = &self.ordered[id];
            if let Some(hit) = prim.intersect_filtered(&self.filters[id], origin, dir, r.tmin, r.tmax) {
                out(PrimitiveHit { primitive: self.original[id], hit });
            }
        });
    }

    /// Whether any primitive meets the ray with `t` in `(t_min, t_max)`,
    /// from either side (a shadow ray): traversal stops at the first hit.
    #[inline]
    pub fn occluded(&self, origin: Vec3, dir: Vec3, t_min: f32, t_max: f32) -> bool {
        let mut no_hint = u32::MAX;
        self.occluded_hinted(origin, dir, t_min, t_max, &mut no_hint)
    }

    /// [`Self::occluded`], trying first the primitive that blocked the
    /// last ray given the same `hint` (start with `u32::MAX`), which is
    /// updated: rays from one pixel towards one light are mostly blocked
    /// by the same thing. The same answer as [`Self::occluded`]: the hint
    /// counts only where its box meets the ray, as traversal would have
    /// reached it (its leaf's box holds its box).
    #[inline]
    pub fn occluded_hinted(&self, origin: Vec3, dir: Vec3, t_min: f32, t_max: f32, hint: &mut u32) -> bool {
        let ray = Ray::new(origin.into(), dir.into(), t_min, t_max);
        let h = *hint as usize;
        if h < self.ordered.len()
            && self.boxes[h].intersect_ray(&ray) < ray.tmax
            && self.ordered[h].intersect_filtered(&self.filters[h], origin, dir, t_min, t_max).is_some()
        {
            return true;
        }
        let mut found = None;
        let mut rh = RayHit::none();
        self.bvh.ray_traverse(ray, &mut rh, |r, id| {
            if found.is_some() {
                return f32::NEG_INFINITY;
            }
            match self.ordered[id].intersect_filtered(&self.filters[id], origin, dir, r.tmin, r.tmax) {
                Some(_) => {
                    found = Some(id as u32);
                    f32::NEG_INFINITY
                }
                None => f32::INFINITY,
            }
        });
        if let Some(id) = found {
            *hint = id;
        }
        found.is_some()
    }

    /// The closest intersection with `t` in `(t_min, ∞)`, from either side.
    #[inline]
    pub fn closest_hit(&self, origin: Vec3, dir: Vec3, t_min: f32) -> Option<PrimitiveHit> {
        let ray = Ray::new(origin.into(), dir.into(), t_min, f32::INFINITY);
        let mut best: Option<PrimitiveHit> = None;
        let mut rh = RayHit::none();
        self.bvh.ray_traverse(ray, &mut rh, |r, id| {
            match self.ordered[id].intersect_filtered(&self.filters[id], origin, dir, r.tmin, r.tmax) {
                Some(hit) => {
                    best = Some(PrimitiveHit { primitive: self.original[id], hit });
                    hit.t
                }
                None => f32::INFINITY,
            }
        });
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_hinted_shadow_ray_answers_as_an_unhinted_one() {
        // A closed box, a slab and a few tilted quads and triangles inside,
        // rays between random points, the hint carried from ray to ray as
        // a pixel's rays carry it.
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut unit = move || {
            state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        let v = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
        let mut prims = vec![
            Primitive::quad([v(0., 0., 0.), v(4., 0., 0.), v(4., 0., 4.), v(0., 0., 4.)]),
            Primitive::quad([v(0., 4., 0.), v(0., 4., 4.), v(4., 4., 4.), v(4., 4., 0.)]),
            Primitive::quad([v(1., 2., 1.), v(3., 2., 1.), v(3., 2., 3.), v(1., 2., 3.)]),
        ];
        for _ in 0..12 {
            let c = v(0.5 + 3.0 * unit(), 0.5 + 3.0 * unit(), 0.5 + 3.0 * unit());
            let (a, b) = (v(unit() - 0.5, unit() - 0.5, unit() - 0.5), v(unit() - 0.5, unit() - 0.5, unit() - 0.5));
            prims.push(Primitive::quad([c, c + a, c + a + b, c + b]));
            prims.push(Primitive::triangle(c, c - a, c - b));
        }
        let bvh = PrimitiveBvh::new(&prims);
        let (mut hint, mut blocked, mut by_hint) = (u32::MAX, 0, 0);
        for i in 0..20_000 {
            if i % 64 == 0 {
                hint = u32::MAX; // a new pixel
            }
            let o = v(4.0 * unit(), 4.0 * unit(), 4.0 * unit());
            let to = v(4.0 * unit(), 4.0 * unit(), 4.0 * unit()) - o;
            let (d, t) = (to.normalize(), to.length());
            let before = hint;
            let want = bvh.occluded(o, d, 0.0, t);
            let got = bvh.occluded_hinted(o, d, 0.0, t, &mut hint);
            assert_eq!(got, want, "ray {i}");
            blocked += want as u32;
            by_hint += (got && hint == before && before != u32::MAX) as u32;
        }
        assert!(blocked > 2_000 && by_hint > 500, "{blocked} blocked, {by_hint} by the blocker of the ray before");
    }
}
