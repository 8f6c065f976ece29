//! Primary rays: what each image sample sees (the primitive it meets, how
//! far, and its interpolation weights on patch vertices), where it lies,
//! and which pixels lie across an edge and are traced again in a finer
//! grid.

use glam::{Vec2, Vec3};

use super::camera::PinholeCamera;
use crate::archive::InetView;
use crate::archive::layout;
use crate::geometry::accel::PrimitiveBvh;
use crate::geometry::grid::{NO_VERTEX, PatchGrid};

/// What one image sample sees: interpolation weights on patch vertices.
#[derive(Clone, Copy)]
pub(super) struct SampleHit {
    /// Distance to the hit (`f32::INFINITY`: nothing, or a back face).
    pub(super) t: f32,
    /// Primitive hit (`u32::MAX`: none).
    pub(super) primitive: u32,
    /// Global vertex ids of the cell's corners (`NO_VERTEX`: unused).
    pub(super) vertices: [u32; 4],
    /// Their interpolation weights.
    pub(super) weights: [f32; 4],
    /// Surface coordinates of the hit on its primitive.
    pub(super) uv: [f32; 2],
}

impl SampleHit {
    /// Adds the interpolated vertex radiance this sample sees to `acc`
    /// (term by term, so a pixel sums in one fixed order).
    #[inline]
    pub(super) fn add_radiance(&self, vrad: &[[f32; 3]], acc: &mut Vec3) {
        for k in 0..4 {
            if self.vertices[k] != NO_VERTEX {
                *acc += self.weights[k] * Vec3::from(vrad[self.vertices[k] as usize]);
            }
        }
    }
}

/// What a sample that sees nothing holds.
pub(super) const NO_HIT: SampleHit =
    SampleHit { t: f32::INFINITY, primitive: u32::MAX, vertices: [NO_VERTEX; 4], weights: [0.0; 4], uv: [0.0; 2] };

/// Where image sample `k` of the `count` of pixel `(x, y)` (a square grid:
/// `n × n`, or an edge pixel's finer grid), which saw `hit`, lies, when it
/// is on a front face (back faces are black and take no light).
pub(super) type SamplePoint<'f> = dyn Fn(u32, u32, (u32, u32), &SampleHit) -> Option<Vec3> + Sync + 'f;

/// What a ray from a point along a unit direction meets in the frame.
pub(super) type RayHit<'f> = dyn Fn(Vec3, Vec3) -> SampleHit + Sync + 'f;

/// The side of the patch at a surface point of a primitive.
pub(super) type PatchSize<'f> = dyn Fn(u32, Vec2) -> f32 + Sync + 'f;

/// Whether the samples `hits` of a pixel lie across an edge: one sees
/// nothing (or a back face) and another a front face, or two see
/// primitives turned more than 18° apart, or the second's point lies off
/// the first's plane by more than 0.35 of their distance (a step in depth:
/// a surface behind another). Neighbouring triangles of a smooth mesh, or
/// coplanar quads, are not an edge. `point(k)`: where sample k's ray met
/// its primitive.
pub(super) fn on_edge(hits: &[SampleHit], normals: &[Vec3], point: impl Fn(usize) -> Vec3) -> bool {
    let Some(first) = hits.first() else { return false };
    let front = |h: &SampleHit| h.primitive != u32::MAX && h.vertices != [NO_VERTEX; 4];
    let mut first_point = None;
    for (k, h) in hits.iter().enumerate().skip(1) {
        if h.primitive == first.primitive {
            continue;
        }
        match (front(first), front(h)) {
            (true, true) => {}
            (false, false) => continue,
            _ => return true,
        }
        let (na, nb) = (normals[first.primitive as usize], normals[h.primitive as usize]);
        if na.dot(nb) < 0.95 {
            return true;
        }
        let pa = *first_point.get_or_insert_with(|| point(0));
        let pb = point(k);
        if na.dot(pb - pa).abs() > 0.35 * (pb - pa).length() + 1e-6 * h.t.max(first.t) {
            return true;
        }
    }
    false
}

/// What tracing a frame's image samples needs: the frame's camera and the
/// BVH of the primitives present in it (`kept`: the archive's primitive of
/// each of the BVH's), the primitives' face normals and patch grids, `n × n`
/// samples per pixel and edge pixels' finer `m × m` grid (0: none).
pub(super) struct FrameTracer<'t> {
    pub(super) v: &'t InetView<'t>,
    pub(super) camera: &'t PinholeCamera,
    pub(super) kept: &'t [u32],
    pub(super) bvh: &'t PrimitiveBvh,
    pub(super) normals: &'t [Vec3],
    pub(super) grids: &'t [PatchGrid],
    pub(super) n: u32,
    pub(super) m: u32,
}

impl FrameTracer<'_> {
    /// The ray of sample `(sx, sy)` of the `g × g` grid in pixel `(x, y)`.
    pub(super) fn grid_ray(&self, x: u32, y: u32, (sx, sy): (u32, u32), g: u32) -> (Vec3, Vec3) {
        let s = Vec2::new((sx as f32 + 0.5) / g as f32, (sy as f32 + 0.5) / g as f32);
        self.camera.ray(x as f32 + s.x, y as f32 + s.y)
    }

    /// The ray of sample `(sx, sy)` of the `n × n` grid in pixel `(x, y)`.
    pub(super) fn sample_ray(&self, x: u32, y: u32, sx: u32, sy: u32) -> (Vec3, Vec3) {
        self.grid_ray(x, y, (sx, sy), self.n)
    }

    /// What a ray from `o` along the unit direction `d` meets in the frame.
    pub(super) fn hit_at(&self, o: Vec3, d: Vec3) -> SampleHit {
        let v = self.v;
        let Some(hit) = self.bvh.closest_hit(o, d, 0.0) else {
            return NO_HIT;
        };
        let pi = self.kept[hit.primitive as usize] as usize;
        if self.normals[pi].dot(d) >= 0.0 {
            // A back face: surfaces are one-sided, it shows black but hides what is behind.
            return SampleHit { t: hit.hit.t, primitive: pi as u32, ..NO_HIT };
        }
        let loc = self.grids[pi].locate(hit.hit.uv);
        let record = &v.primitives[pi];
        // A grouped triangle's one cell has local corners 0, 1, 2: its TVTX row.
        let vertex = |c: u32| match record.kind == layout::kind::GROUPED_TRIANGLE {
            true => v.grouped_triangles[record.first_vertex as usize][c as usize],
            false => record.first_vertex + c,
        };
        let mut vertices = [NO_VERTEX; 4];
        let mut weights = [0.0; 4];
        for k in 0..4 {
            if loc.corners[k] != NO_VERTEX && loc.weights[k] != 0.0 {
                vertices[k] = vertex(loc.corners[k]);
                weights[k] = loc.weights[k];
            }
        }
        SampleHit { t: hit.hit.t, primitive: pi as u32, vertices, weights, uv: hit.hit.uv.to_array() }
    }

    /// What sample `(sx, sy)` of the `n × n` grid in pixel `(x, y)` sees.
    pub(super) fn trace(&self, x: u32, y: u32, sx: u32, sy: u32) -> SampleHit {
        let (o, d) = self.sample_ray(x, y, sx, sy);
        self.hit_at(o, d)
    }

    /// The side of a pixel's grid of `count` samples.
    fn side(&self, count: u32) -> u32 {
        if count == self.n * self.n || self.m == 0 { self.n } else { self.m }
    }

    /// Where sample `k` of the `count` of pixel `(x, y)`, which saw `hit`,
    /// lies, when it is on a front face ([`SamplePoint`]).
    pub(super) fn sample_point(&self, x: u32, y: u32, (k, count): (u32, u32), hit: &SampleHit) -> Option<Vec3> {
        let g = self.side(count);
        let (o, d) = self.grid_ray(x, y, (k % g, k / g), g);
        (self.normals[hit.primitive as usize].dot(d) < 0.0).then(|| o + d * hit.t)
    }

    /// Replaces the samples `buf` of pixel `(x, y)` by the finer grid's
    /// when they lie across an edge ([`on_edge`]).
    pub(super) fn refine_edges(&self, x: u32, y: u32, buf: &mut Vec<SampleHit>) {
        let (n, m) = (self.n, self.m);
        if m == 0 {
            return;
        }
        let point = |k: usize| {
            let (o, d) = self.grid_ray(x, y, (k as u32 % n, k as u32 / n), n);
            o + d * buf[k].t
        };
        if on_edge(buf, self.normals, point) {
            buf.clear();
            buf.extend((0..m * m).map(|k| {
                let (o, d) = self.grid_ray(x, y, (k % m, k / m), m);
                self.hit_at(o, d)
            }));
        }
    }

    /// The side of the patch at surface point `uv` of primitive `prim` (a
    /// grouped triangle's group: its area's square root).
    pub(super) fn patch_size(&self, prim: u32, uv: Vec2) -> f32 {
        let v = self.v;
        let record = &v.primitives[prim as usize];
        let cell = match record.kind == layout::kind::GROUPED_TRIANGLE {
            true => 0,
            false => self.grids[prim as usize].locate(uv).cell,
        };
        v.patch_area.get((record.first_patch + cell) as usize).map_or(0.0, |a| a.sqrt())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A front-face sample of primitive `p` at distance `t`.
    fn seen(p: u32, t: f32) -> SampleHit {
        SampleHit { t, primitive: p, vertices: [0, 1, 2, 3], weights: [0.25; 4], ..NO_HIT }
    }

    #[test]
    fn edges_are_corners_silhouettes_and_steps_not_seams_in_a_plane() {
        let up = Vec3::Y;
        let tilted = |deg: f32| Vec3::new(deg.to_radians().sin(), deg.to_radians().cos(), 0.0);
        // Primitives: 0 and 1 the same floor plane, 2 a wall at 90°, 3 a
        // floor 0.3 below, 4 a facet 10° off the floor, 5 one 25° off.
        let normals = [up, up, Vec3::X, up, tilted(10.0), tilted(25.0)];
        // Sample 0 at the origin, the other a pixel's width (1 cm) away at
        // a distance of 2 m, on the plane each primitive is said to be in.
        let points = |second: Vec3| move |k: usize| if k == 0 { Vec3::ZERO } else { second };
        let pair = |p: u32| [seen(0, 2.0), seen(p, 2.0)];
        let across = Vec3::new(0.01, 0.0, 0.0);
        assert!(!on_edge(&pair(0), &normals, points(across)), "one primitive");
        assert!(!on_edge(&pair(1), &normals, points(across)), "a seam between coplanar quads");
        assert!(on_edge(&pair(2), &normals, points(across)), "a corner");
        assert!(on_edge(&pair(3), &normals, points(Vec3::new(0.01, -0.3, 0.0))), "a step down to a parallel floor");
        let facet = Vec3::new(0.01, 0.01 * 10f32.to_radians().tan(), 0.0);
        assert!(!on_edge(&pair(4), &normals, points(facet)), "neighbouring facets of a smooth mesh");
        assert!(on_edge(&pair(5), &normals, points(facet)), "a crease");
        // Misses and back faces against a front face are edges; among
        // themselves they are not.
        let back = SampleHit { t: 2.0, primitive: 2, ..NO_HIT };
        assert!(on_edge(&[seen(0, 2.0), NO_HIT], &normals, points(across)), "a silhouette against nothing");
        assert!(on_edge(&[NO_HIT, seen(0, 2.0)], &normals, points(across)));
        assert!(on_edge(&[seen(0, 2.0), back], &normals, points(across)), "a back face");
        assert!(!on_edge(&[NO_HIT, back, NO_HIT], &normals, points(across)));
        // Every sample is compared with the first.
        let hits = [seen(0, 2.0), seen(1, 2.0), seen(0, 2.0), seen(2, 2.0)];
        assert!(on_edge(&hits, &normals, |k| if k == 0 { Vec3::ZERO } else { across }));
    }
}
