//! A BVH (obvhs `Bvh2`) over the scene's primitives, shared by the build's
//! ray bundles and the renderer's primary rays.
//!
//! Primitives are reordered once into the BVH's leaf order so traversal
//! indexes them directly; hits report original primitive indices.
//!
//! A long, thin quad lying across the axes (a fan blade turned 45°) has
//! a box far larger than itself, and where many such quads overlap (a
//! sequence's blade in every frame) every ray near them tests them all.
//! Such quads enter the BVH as several references, each the box of a
//! strip of the quad (`pieces`); a hit counts only in the strip that
//! holds its surface coordinate, so each is reported once.

use std::time::Duration;

use glam::{Vec2, Vec3, Vec3A};
use obvhs::BvhBuildParams;
use obvhs::aabb::Aabb;
use obvhs::bvh2::Bvh2;
use obvhs::bvh2::builder::build_bvh2;
use obvhs::cwbvh::CwBvh;
use obvhs::cwbvh::builder::build_cwbvh;
use obvhs::ray::{Ray, RayHit};

use super::{Primitive, PrimitiveKind, QuadFilter, SurfaceHit};

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
    /// Primitives of the references in BVH leaf order (a split quad once
    /// per strip).
    ordered: Vec<Primitive>,
    /// Their quad filters.
    filters: Vec<QuadFilter>,
    /// Original index of each reference's primitive.
    original: Vec<u32>,
    /// Their padded boxes, as the BVH was built from.
    boxes: Vec<Aabb>,
    /// The strip of its quad that each reference stands for.
    strips: Vec<Strip>,
    /// The same references in an eight-wide BVH, for single rays in no
    /// particular direction (the render's closest hits and shadow rays),
    /// with the position in `ordered` of each of its leaves' references
    /// (traversed as [`wide_ray`] says).
    wide: Option<(Vec<u32>, CwBvh)>,
}

/// Strip `index` of `count` equal strips of a flat quad across its surface
/// coordinate `axis` (0: u, 1: v); `count` 1 for a whole primitive.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Strip {
    axis: u8,
    index: u8,
    count: u8,
}

impl Strip {
    const WHOLE: Strip = Strip { axis: 0, index: 0, count: 1 };

    /// Whether a hit at surface coordinates `uv` belongs to this strip:
    /// to exactly one of a quad's strips, whatever its rounding.
    #[inline]
    fn holds(self, uv: Vec2) -> bool {
        self.count == 1 || {
            let k = (uv[self.axis as usize] * self.count as f32).floor();
            k.clamp(0.0, (self.count - 1) as f32) as u8 == self.index
        }
    }
}

/// The strips quad `p` enters the BVH as, with their bounds: 2, 4 or 8
/// across its longer side, as long as each halving of the strips' width
/// cuts the summed half-areas of their boxes by at least 15% (a long
/// quad lying across the axes); else the whole primitive. Axis-aligned
/// quads and triangles stay whole.
fn pieces(p: &Primitive) -> Vec<(Strip, Vec3, Vec3)> {
    let (lo, hi) = p.bounds();
    let whole = vec![(Strip::WHOLE, lo, hi)];
    // Hits lie on the plane through p0 (the intersection's), up to `warp`
    // off the bilinear surface the strips' corners are on: each strip's
    // box is widened by it, and the quad kept whole unless nearly flat.
    let n = p.raw_normal().normalize_or_zero();
    let size = (hi - lo).max_element();
    let warp = p.p.iter().map(|&q| n.dot(q - p.p[0]).abs()).fold(0.0, f32::max);
    if p.kind != PrimitiveKind::Quad || n == Vec3::ZERO || warp > 1e-5 * size {
        return whole;
    }
    let (lu, lv) =
        (p.p[0].distance(p.p[1]) + p.p[3].distance(p.p[2]), p.p[0].distance(p.p[3]) + p.p[1].distance(p.p[2]));
    let axis = if lu >= lv { 0 } else { 1 };
    let strips = |count: u8| -> Vec<(Strip, Vec3, Vec3)> {
        (0..count)
            .map(|index| {
                // The strip and 10⁻³ of the quad around it, so that a hit's
                // coordinate rounded across a cut or an edge is still in
                // the box of the strip that `holds` it.
                const MARGIN: f32 = 1e-3;
                let (a, b) = (index as f32 / count as f32 - MARGIN, (index + 1) as f32 / count as f32 + MARGIN);
                let at = |s: f32, t: f32| p.point(if axis == 0 { Vec2::new(s, t) } else { Vec2::new(t, s) });
                let c = [at(a, -MARGIN), at(b, -MARGIN), at(b, 1.0 + MARGIN), at(a, 1.0 + MARGIN)];
                let (lo, hi) = (c.iter().fold(c[0], |m, &q| m.min(q)), c.iter().fold(c[0], |m, &q| m.max(q)));
                (Strip { axis, index, count }, lo - warp, hi + warp)
            })
            .collect()
    };
    let half_area = |lo: Vec3, hi: Vec3| Aabb::new(Vec3A::from(lo), Vec3A::from(hi)).half_area();
    let cost = |s: &[(Strip, Vec3, Vec3)]| s.iter().map(|&(_, lo, hi)| half_area(lo, hi)).sum::<f32>();
    let (mut best, mut best_cost) = (whole, half_area(lo, hi));
    for count in [2, 4, 8] {
        let split = strips(count);
        let c = cost(&split);
        if c > best_cost * 0.85 {
            break;
        }
        (best, best_cost) = (split, c);
    }
    best
}

impl PrimitiveBvh {
    /// Builds the BVH for every query, and for the render's single rays
    /// an eight-wide one besides (its closest hits and shadow rays take
    /// 0.85 of the time they take in the binary BVH: a Cornell box
    /// render's gather). Bounds are padded slightly so that flat,
    /// axis-aligned primitives have non-empty boxes.
    pub fn new(primitives: &[Primitive]) -> Self {
        Self::build(primitives, 0..primitives.len() as u32, true)
    }

    /// The binary BVH alone, for the build's bundles of parallel rays
    /// ([`Self::all_hits`]), which traverse it faster than the wide one
    /// (~40%, as coherent rays); other queries work, more slowly.
    pub fn for_bundles(primitives: &[Primitive]) -> Self {
        Self::build(primitives, 0..primitives.len() as u32, false)
    }

    /// [`Self::for_bundles`] of the primitives `ids` of `primitives` alone
    /// (hits name them by their index in `primitives`), without copying
    /// them: the scan converter's BVH of the primitives it does not
    /// rasterise.
    pub fn of_subset(primitives: &[Primitive], ids: &[u32]) -> Self {
        Self::build(primitives, ids.iter().copied(), false)
    }

    /// The BVH of primitives `ids` of `primitives`, and the wide one if `wide`.
    fn build(primitives: &[Primitive], ids: impl Iterator<Item = u32> + Clone, wide: bool) -> Self {
        let (lo, hi) = super::bounds_of(ids.clone().map(|i| &primitives[i as usize]));
        let pad = ((hi - lo).max_element() * 1e-6).max(1e-9);
        let mut aabbs = Vec::with_capacity(ids.size_hint().0);
        let mut refs = Vec::with_capacity(ids.size_hint().0);
        for i in ids {
            for (strip, a, b) in pieces(&primitives[i as usize]) {
                aabbs.push(Aabb::new(Vec3A::from(a - pad), Vec3A::from(b + pad)));
                refs.push((i, strip));
            }
        }
        let bvh = build_bvh2(&aabbs, BvhBuildParams::medium_build(), &mut Duration::default());
        let leaf = &bvh.primitive_indices;
        let original: Vec<u32> = leaf.iter().map(|&r| refs[r as usize].0).collect();
        let strips = leaf.iter().map(|&r| refs[r as usize].1).collect();
        let ordered: Vec<Primitive> = original.iter().map(|&i| primitives[i as usize]).collect();
        let filters = ordered.iter().map(QuadFilter::new).collect();
        let boxes = leaf.iter().map(|&r| aabbs[r as usize]).collect();
        let wide = wide.then(|| {
            let cw = build_cwbvh(&aabbs, BvhBuildParams::medium_build(), &mut Duration::default());
            // Its leaves name references as given; ours are in `leaf` order.
            let mut at = vec![0u32; leaf.len()];
            for (k, &r) in leaf.iter().enumerate() {
                at[r as usize] = k as u32;
            }
            (cw.primitive_indices.iter().map(|&r| at[r as usize]).collect(), cw)
        });
        // obvhs traverses it with a stack of 32 groups, and past that
        // would skip subtrees: a deeper one (degenerate input) is not used.
        let wide = wide.filter(|(_, cw)| wide_depth(cw) < WIDE_STACK);
        Self { bvh, ordered, filters, original, boxes, strips, wide }
    }

    /// References in the BVH: the primitives, with a long quad lying
    /// across the axes counted once per strip.
    pub fn references(&self) -> usize {
        self.ordered.len()
    }

    /// Calls `out` for every intersection of the full line through `origin`
    /// along `dir` with `t > 0`, in no particular order.
    #[inline]
    pub fn all_hits(&self, origin: Vec3, dir: Vec3, mut out: impl FnMut(PrimitiveHit)) {
        let ray = Ray::new(origin.into(), dir.into(), 0.0, f32::INFINITY);
        self.bvh.ray_traverse_anyhit(ray, |r, id| {
            let prim = &self.ordered[id];
            if let Some(hit) = prim.intersect_filtered(&self.filters[id], origin, dir, r.tmin, r.tmax)
                && self.strips[id].holds(hit.uv)
            {
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
        // The first hit found ends the traversal (the binary BVH's leaf
        // loop still calls on: every call after it answers at once).
        let mut test = |id: usize| {
            if found.is_none() {
                if self.ordered[id].intersect_filtered(&self.filters[id], origin, dir, t_min, t_max).is_none() {
                    return f32::INFINITY;
                }
                found = Some(id as u32);
            }
            f32::NEG_INFINITY
        };
        match &self.wide {
            Some((slots, cw)) => {
                cw.ray_traverse_miss(wide_ray(origin, dir, t_max), |_, slot| test(slots[slot] as usize));
            }
            None => {
                self.bvh.ray_traverse(ray, &mut RayHit::none(), |_, id| test(id));
            }
        }
        if let Some(id) = found {
            *hint = id;
        }
        found.is_some()
    }

    /// The closest intersection with `t` in `(t_min, ∞)`, from either side.
    #[inline]
    pub fn closest_hit(&self, origin: Vec3, dir: Vec3, t_min: f32) -> Option<PrimitiveHit> {
        self.closest_hit_within(origin, dir, t_min, f32::INFINITY)
    }

    /// The closest intersection with `t` in `(t_min, t_max)`, from either
    /// side: [`Self::closest_hit`] when that is nearer than `t_max`, found
    /// without visiting what lies beyond it. Of primitives met at the same
    /// distance (an edge two walls share, a light inset in a ceiling) the
    /// first in the order given to [`Self::new`] is the answer, whatever
    /// order the traversal meets them in.
    #[inline]
    pub fn closest_hit_within(&self, origin: Vec3, dir: Vec3, t_min: f32, t_max: f32) -> Option<PrimitiveHit> {
        let mut best: Option<PrimitiveHit> = None;
        // Distances the traversal's ray counts from its origin: 0 for the
        // binary BVH, `WIDE_SHIFT` for the wide one (`wide_ray`).
        let mut visit = |id: usize, shift: f32| {
            // Once there is a best hit, up to its distance inclusive, so
            // that a hit tied with it is seen.
            let bound = best.map_or(t_max, |b| b.hit.t.next_up());
            let Some(hit) = self.ordered[id].intersect_filtered(&self.filters[id], origin, dir, t_min, bound) else {
                return f32::INFINITY;
            };
            let primitive = self.original[id];
            if best.is_none_or(|b| hit.t < b.hit.t || (hit.t == b.hit.t && primitive < b.primitive)) {
                best = Some(PrimitiveHit { primitive, hit });
            }
            // The traversal's bound: never below the hit (rounded up when
            // shifted), so that nothing as near is passed over.
            if shift == 0.0 { hit.t } else { (hit.t + shift).next_up() }
        };
        let mut rh = RayHit::none();
        match &self.wide {
            Some((slots, cw)) => cw
                .ray_traverse(wide_ray(origin, dir, t_max), &mut rh, |_, slot| visit(slots[slot] as usize, WIDE_SHIFT)),
            None => self
                .bvh
                .ray_traverse(Ray::new(origin.into(), dir.into(), t_min, t_max), &mut rh, |_, id| visit(id, 0.0)),
        };
        best
    }
}

/// Stack entries obvhs's eight-wide traversal holds.
const WIDE_STACK: u32 = 32;

/// How far back along the ray (in its own distance) the wide BVH's
/// traversal starts: obvhs's node test counts from 10⁻⁴ whatever the
/// ray's `t_min`, so a box the ray leaves nearer than that (a wall 0.05
/// mm ahead) would be passed over; started this far back, every box from
/// the true origin on is tested.
const WIDE_SHIFT: f32 = 2e-4;

/// The ray the wide BVH is traversed with for a query from `origin` along
/// `dir` up to `t_max`: started [`WIDE_SHIFT`] back, and with each `-0.0`
/// of the direction made `+0.0` (obvhs picks a box's near face by
/// `dir < 0` but inverts `-0.0` to `-1/ε`, which culls every box the ray
/// starts inside). Primitives are still tested along the query's own ray.
#[inline]
fn wide_ray(origin: Vec3, dir: Vec3, t_max: f32) -> Ray {
    let d = dir + Vec3::ZERO;
    Ray::new((origin - d * WIDE_SHIFT).into(), d.into(), 0.0, t_max + WIDE_SHIFT)
}

/// Levels of the eight-wide BVH `cw` (1 for a root of leaves alone).
fn wide_depth(cw: &CwBvh) -> u32 {
    if cw.nodes.is_empty() {
        return 0;
    }
    let (mut deepest, mut stack) = (0, vec![(0u32, 1u32)]);
    while let Some((node, depth)) = stack.pop() {
        deepest = deepest.max(depth);
        let n = &cw.nodes[node as usize];
        for child in (0..8).filter(|&c| !n.is_child_empty(c) && !n.is_leaf(c)) {
            stack.push((n.child_node_index(child), depth + 1));
        }
    }
    deepest
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fan of long, thin quads turned about one axis (a blade in every
    /// frame of a sequence) over a floor: the blades enter as strips, the
    /// floor whole, and every query answers as a test of every primitive.
    #[test]
    fn split_quads_answer_as_whole_ones() {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut unit = move || {
            state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        let floor = Primitive::quad([
            Vec3::new(-2.0, 0.0, -2.0),
            Vec3::new(-2.0, 0.0, 2.0),
            Vec3::new(2.0, 0.0, 2.0),
            Vec3::new(2.0, 0.0, -2.0),
        ]);
        let mut prims = vec![floor];
        for k in 0..60 {
            let a = k as f32 * 0.37;
            let (along, across) = (Vec3::new(a.cos(), 0.0, a.sin()), Vec3::new(-a.sin(), 0.0, a.cos()));
            let (c, h) = (Vec3::new(0.0, 1.0 + 0.001 * k as f32, 0.0) + along * 0.1, across * 0.04);
            prims.push(Primitive::quad([c - h, c + along * 0.7 - h, c + along * 0.7 + h, c + h]));
        }
        // A long diagonal strip across the scene, one corner lifted
        // within the flatness allowed (its hits are on the plane through
        // p0, off its strips' corners).
        let (c, along, across) = (Vec3::new(-1.8, 0.5, -1.7), Vec3::new(3.4, 0.0, 3.2), Vec3::new(-0.05, 0.0, 0.05));
        let mut warped = Primitive::quad([c, c + along, c + along + across, c + across]);
        warped.p[1].y += 3e-5;
        assert_eq!(pieces(&warped).len(), 8, "a long warped strip is split");
        prims.push(warped);
        assert_eq!(pieces(&floor).len(), 1, "an axis-aligned quad stays whole");
        assert_eq!(pieces(&prims[3]).len(), 4, "a blade across the axes (at 42°) is split");
        let bvh = PrimitiveBvh::new(&prims);
        let binary = PrimitiveBvh::for_bundles(&prims);
        assert!(bvh.references() > 3 * prims.len(), "{} references", bvh.references());
        let filters: Vec<QuadFilter> = prims.iter().map(QuadFilter::new).collect();
        let (mut hits, mut through_blades) = (0, 0);
        for i in 0..20_000 {
            let o = Vec3::new(2.0 * unit() - 1.0, 0.5 + unit(), 2.0 * unit() - 1.0);
            let d = Vec3::new(unit() - 0.5, unit() - 0.5, unit() - 0.5).normalize();
            // The line from 10 back, so that all its hits are ahead.
            let back = o - d * 10.0;
            let every = |from: Vec3, t_max: f32| {
                let hit = |(p, (prim, f)): (usize, (&Primitive, &QuadFilter))| {
                    prim.intersect_filtered(f, from, d, 0.0, t_max).map(|h| (p as u32, h.t, h.uv))
                };
                prims.iter().zip(&filters).enumerate().filter_map(hit).collect::<Vec<_>>()
            };
            let mut want = every(back, f32::INFINITY);
            let mut got = Vec::new();
            bvh.all_hits(back, d, |h| got.push((h.primitive, h.hit.t, h.hit.uv)));
            want.sort_by_key(|w| w.0);
            got.sort_by_key(|g| g.0);
            assert_eq!(got, want, "ray {i}");
            hits += got.len();
            through_blades += got.iter().filter(|g| g.0 > 0).count();
            // The nearest hit ahead of o, and whether anything lies within 1.
            let ahead = every(o, f32::INFINITY).iter().map(|w| w.1).fold(f32::INFINITY, f32::min);
            assert_eq!(bvh.closest_hit(o, d, 0.0).map_or(f32::INFINITY, |h| h.hit.t), ahead, "ray {i}");
            assert_eq!(bvh.occluded(o, d, 0.0, 1.0), !every(o, 1.0).is_empty(), "ray {i}");
            // The binary BVH alone answers alike.
            assert_eq!(binary.closest_hit(o, d, 0.0), bvh.closest_hit(o, d, 0.0), "ray {i}");
            assert_eq!(binary.occluded(o, d, 0.0, 1.0), bvh.occluded(o, d, 0.0, 1.0), "ray {i}");
        }
        assert!(hits > 20_000 && through_blades > 2_000, "{hits} hits, {through_blades} on blades");
    }

    #[test]
    fn the_wide_bvh_meets_what_lies_within_its_epsilon_and_along_negative_zeros() {
        // A floor, and a wall standing on it: queries from points 0.05 mm
        // off them (obvhs's node test counts from 0.1 mm), and along
        // directions with -0.0 components (which its node test took as
        // culling every box the ray starts inside).
        let v = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
        let floor = Primitive::quad([v(0., 0., 0.), v(0., 0., 1.), v(1., 0., 1.), v(1., 0., 0.)]);
        let wall = Primitive::quad([v(0.5, 0., 0.), v(0.5, 1., 0.), v(0.5, 1., 1.), v(0.5, 0., 1.)]);
        for prims in [vec![floor], vec![floor, wall]] {
            let (wide, binary) = (PrimitiveBvh::new(&prims), PrimitiveBvh::for_bundles(&prims));
            assert!(wide.wide.is_some());
            let queries = [
                (v(0.25, 5e-5, 0.5), v(0.0, -1.0, 0.0), 5e-5),
                (v(0.25, 5e-5, 0.5), v(-0.0, -1.0, -0.0), 5e-5),
                (v(0.25, 1.0, 0.5), -Vec3::Y, 1.0),
                (v(0.45, 0.5, 0.5), v(-0.6, -0.8, 0.0), 0.625),
                (v(0.5 - 5e-5, 0.5, 0.5), v(1.0, 0.0, -0.0), 5e-5),
            ];
            for (i, &(o, d, t)) in queries.iter().enumerate() {
                let want = binary.closest_hit(o, d, 0.0).map(|h| h.hit.t);
                let (len, t_got) = (prims.len(), wide.closest_hit(o, d, 0.0).map(|h| h.hit.t));
                if len == 1 && i == 4 {
                    assert_eq!(t_got, None, "no wall, query {i}");
                    continue;
                }
                assert!(want.is_some_and(|w| (w - t).abs() < 1e-6), "{len} primitives, query {i}: binary {want:?}");
                assert_eq!(t_got, want, "{len} primitives, query {i}");
                assert!(wide.occluded(o, d, 0.0, 2.0 * t), "{len} primitives, query {i}");
                assert!(!wide.occluded(o, d, 0.0, 0.5 * t), "{len} primitives, query {i}");
            }
        }
    }

    #[test]
    fn of_primitives_met_at_one_distance_the_first_given_is_the_closest_hit() {
        // A Cornell box's ceiling with its light inset, and two walls
        // meeting at an edge: rays at the light's edges meet the light and
        // the ceiling at one distance, and rays into the edge both walls.
        let v = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
        let ceiling = Primitive::quad([v(0., 1., 0.), v(0., 1., 1.), v(1., 1., 1.), v(1., 1., 0.)]);
        let light = Primitive::quad([v(0.25, 1., 0.25), v(0.25, 1., 0.75), v(0.75, 1., 0.75), v(0.75, 1., 0.25)]);
        let wall = Primitive::quad([v(1., 0., 0.), v(1., 1., 0.), v(1., 1., 1.), v(1., 0., 1.)]);
        let filler: Vec<Primitive> = (0..40)
            .map(|k| {
                let y = 0.1 + k as f32 * 0.01;
                Primitive::triangle(v(0.1, y, 0.1), v(0.2, y, 0.1), v(0.1, y, 0.2))
            })
            .collect();
        let (mut ties, mut rays) = (0, 0);
        for order in [[0, 1, 2], [2, 1, 0], [1, 0, 2]] {
            let mut prims: Vec<Primitive> = order.map(|k| [ceiling, light, wall][k]).to_vec();
            prims.extend(&filler);
            let first = |a: usize, b: usize| order.iter().position(|&k| k == a).min(order.iter().position(|&k| k == b));
            for bvh in [PrimitiveBvh::new(&prims), PrimitiveBvh::for_bundles(&prims)] {
                // Up through the light's edge at x = 0.25; across to the
                // walls' edge x = 1, y = 1.
                for (i, z) in (0..64).map(|i| (i, 0.3 + 0.4 * i as f32 / 64.0)) {
                    let o = v(0.6, 0.5, z);
                    for (to, pair) in [(v(0.25, 1.0, z), (0, 1)), (v(1.0, 1.0, z), (0, 2))] {
                        let hit = bvh.closest_hit(o, (to - o).normalize(), 0.0).expect("a hit");
                        rays += 1;
                        let want = first(pair.0, pair.1).unwrap() as u32;
                        let other =
                            prims.iter().enumerate().filter(|&(p, _)| p as u32 != hit.primitive).any(|(_, q)| {
                                q.intersect(o, (to - o).normalize(), 0.0, f32::INFINITY)
                                    .is_some_and(|h| h.t == hit.hit.t)
                            });
                        if other {
                            ties += 1;
                            assert_eq!(hit.primitive, want, "order {order:?}, ray {i} to {to}");
                        }
                    }
                }
            }
        }
        assert!(ties > rays / 4, "{ties} of {rays} rays met two primitives at one distance");
    }

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
