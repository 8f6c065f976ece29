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
        Self { bvh, ordered, filters, original }
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
        let ray = Ray::new(origin.into(), dir.into(), t_min, t_max);
        let mut found = false;
        let mut rh = RayHit::none();
        self.bvh.ray_traverse(ray, &mut rh, |r, id| {
            if found {
                return f32::NEG_INFINITY;
            }
            match self.ordered[id].intersect_filtered(&self.filters[id], origin, dir, r.tmin, r.tmax) {
                Some(_) => {
                    found = true;
                    // Below every box's entry distance: nothing more is visited.
                    f32::NEG_INFINITY
                }
                None => f32::INFINITY,
            }
        });
        found
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
