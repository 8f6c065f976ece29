//! Patches made of several small triangles of a mesh.
//!
//! A scanned or modelled mesh has triangles far smaller than the patches a
//! build wants: as its own patch, each would catch a ray or two per
//! direction, and its light would be noise (the Stanford bunny rendered
//! speckled). Neighbouring triangles that face about the same way are
//! grouped instead into patches of about the target size, whose light is
//! interpolated smoothly across the mesh through its shared vertices.
//!
//! Grouping is region growing over the triangles' shared edges, seeded in
//! the order of a space-filling curve over their centres (so patches near
//! in space are near in number, as the gathers want) and kept within a
//! radius, an area and a cone of normals. It depends on nothing but the
//! geometry and the patch size, so builds stay byte-identical.

use std::collections::HashMap;

use glam::{DVec3, Vec3};

use super::grid_for;
use crate::geometry::grid::CellOrder;
use crate::geometry::{Primitive, PrimitiveKind};

/// Largest angle between a grouped triangle's normal and its group's first
/// triangle's (30°): "nearly coplanar". A group's triangles differ by at
/// most twice this; wider cones would average light across folds.
pub const GROUP_COS: f32 = 0.866_025_4;

/// Groups whose normals differ by more than this (45°) are not neighbours
/// for the spreading of §3.4, which must not cross a crease.
pub const ADJACENT_COS: f32 = std::f32::consts::FRAC_1_SQRT_2;

/// How far a grouped triangle's corners may lie from the centre of its
/// group's first triangle, in patch sizes. Groups then cover about a
/// triangle cut at the patch size (0.37 of its square on the bunny);
/// wider groups measured worse against the path-traced bunny (0.7: 2.3%,
/// 1.0: 2.4% around it, against 2.2% at 0.5), narrower ones no better.
pub const GROUP_RADIUS: f32 = 0.5;

/// Marks a primitive that keeps its own patch grid.
pub const UNGROUPED: u32 = u32::MAX;

/// How one instance's primitives are ordered and grouped.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TriangleGroups {
    /// The primitives in their new order: indices into the input, first
    /// those that keep their own grids (in input order), then the grouped
    /// triangles group by group.
    pub order: Vec<u32>,
    /// Per primitive in the new order: its group, counted from 0 in
    /// order, or [`UNGROUPED`].
    pub group: Vec<u32>,
}

impl TriangleGroups {
    /// Number of groups.
    pub fn count(&self) -> u32 {
        self.group.iter().filter(|&&g| g != UNGROUPED).max().map_or(0, |&g| g + 1)
    }
}

/// The bits of a position, with −0 taken as +0, for welding corners that
/// are the same point.
pub(crate) fn position_key(p: Vec3) -> [u32; 3] {
    (p + Vec3::ZERO).to_array().map(f32::to_bits)
}

/// Groups the triangles of `prims` (one instance of a surface that does
/// not move) whose grid at patch size `size` would be a single cell:
/// triangles sharing an edge (corners at exactly the same points) join a
/// group while all their corners lie within [`GROUP_RADIUS`]` · size` of
/// the group's first triangle's centre, their normals within 30° of its
/// normal, and the group's area stays at most `size²`; then each group
/// under a quarter of that area joins a neighbouring group if one faces
/// within 45° of all its triangles. Every grouped triangle is in exactly
/// one group; a triangle with no neighbour to join makes a group of one.
pub fn group_triangles(prims: &[Primitive], size: f32) -> TriangleGroups {
    let small: Vec<u32> = (0..prims.len() as u32)
        .filter(|&i| {
            let p = &prims[i as usize];
            p.kind == PrimitiveKind::Triangle && grid_for(p, size, CellOrder::Rows).n_u == 1
        })
        .collect();
    let mut order: Vec<u32> = (0..prims.len() as u32).filter(|i| small.binary_search(i).is_err()).collect();
    let mut group = vec![UNGROUPED; order.len()];
    if small.is_empty() {
        return TriangleGroups { order, group };
    }
    let neighbours = EdgeNeighbours::of(prims, &small);
    let mut groups = Growth::grow(prims, &small, &neighbours, size);
    groups.merge_fragments(&neighbours);
    for (g, m) in groups.members.iter().filter(|m| !m.is_empty()).enumerate() {
        order.extend(m.iter().map(|&t| small[t as usize]));
        group.extend(std::iter::repeat_n(g as u32, m.len()));
    }
    TriangleGroups { order, group }
}

/// The small triangles' neighbours across shared edges (corners at
/// exactly the same points), as compressed rows: triangle `t`'s are
/// `pairs[start[t]..start[t + 1]]`, each `(t, neighbour)`, ascending.
struct EdgeNeighbours {
    pairs: Vec<(u32, u32)>,
    start: Vec<usize>,
}

impl EdgeNeighbours {
    /// The neighbours of `small` (indices into `prims`), numbered as
    /// positions in `small`.
    fn of(prims: &[Primitive], small: &[u32]) -> Self {
        // Corners welded by position; edges as sorted pairs of welded corners.
        let mut weld: HashMap<[u32; 3], u32> = HashMap::new();
        let corner = |p: Vec3, weld: &mut HashMap<[u32; 3], u32>| {
            let n = weld.len() as u32;
            *weld.entry(position_key(p)).or_insert(n)
        };
        let mut edges: Vec<(u64, u32)> = Vec::with_capacity(small.len() * 3);
        for (t, &i) in small.iter().enumerate() {
            let p = &prims[i as usize].p;
            let c = [corner(p[0], &mut weld), corner(p[1], &mut weld), corner(p[2], &mut weld)];
            for k in 0..3 {
                let (a, b) = (c[k].min(c[(k + 1) % 3]), c[k].max(c[(k + 1) % 3]));
                edges.push((((a as u64) << 32) | b as u64, t as u32));
            }
        }
        edges.sort_unstable();
        // Neighbours across shared edges, as compressed rows.
        let mut pairs: Vec<(u32, u32)> = Vec::new();
        for run in edges.chunk_by(|a, b| a.0 == b.0) {
            for (x, &(_, a)) in run.iter().enumerate() {
                for &(_, b) in &run[x + 1..] {
                    if a != b {
                        pairs.push((a, b));
                        pairs.push((b, a));
                    }
                }
            }
        }
        pairs.sort_unstable();
        pairs.dedup();
        let mut start = vec![0usize; small.len() + 1];
        for &(a, _) in &pairs {
            start[a as usize + 1] += 1;
        }
        for t in 0..small.len() {
            start[t + 1] += start[t];
        }
        Self { pairs, start }
    }

    /// Triangle `t`'s neighbours, as `(t, neighbour)` pairs.
    fn of_triangle(&self, t: u32) -> &[(u32, u32)] {
        &self.pairs[self.start[t as usize]..self.start[t as usize + 1]]
    }
}

/// Groups of the small triangles as they grow and merge: per triangle
/// (a position in `small`) its group, per group its triangles, its first
/// triangle's normal and its area.
struct Growth {
    label: Vec<u32>,
    members: Vec<Vec<u32>>,
    seed_normal: Vec<Vec3>,
    group_area: Vec<f64>,
    /// Per triangle, its unit normal.
    normal: Vec<Vec3>,
    /// The most area a group may have (`size²`).
    most_area: f64,
}

impl Growth {
    /// Groups grown from seeds along a Morton curve over the triangles'
    /// centres: a neighbour joins while its corners lie within
    /// [`GROUP_RADIUS`]` · size` of the seed's centre, its normal within
    /// 30° of the seed's, and the group's area stays at most `size²`.
    fn grow(prims: &[Primitive], small: &[u32], neighbours: &EdgeNeighbours, size: f32) -> Self {
        // Seeds along a Morton curve over the triangles' centres.
        let centre: Vec<Vec3> = small.iter().map(|&i| prims[i as usize].p[..3].iter().sum::<Vec3>() / 3.0).collect();
        let morton = super::order::morton_keys(&centre);
        let mut seeds: Vec<u32> = (0..small.len() as u32).collect();
        seeds.sort_by_key(|&t| (morton[t as usize], t));
        let normal: Vec<Vec3> = small.iter().map(|&i| prims[i as usize].normal()).collect();
        let area: Vec<f64> = small.iter().map(|&i| prims[i as usize].area() as f64).collect();
        let (radius, most_area) = (GROUP_RADIUS * size, (size as f64) * (size as f64));
        // Grow groups from the seeds.
        let mut label = vec![u32::MAX; small.len()];
        let mut members: Vec<Vec<u32>> = Vec::new();
        let mut seed_normal: Vec<Vec3> = Vec::new();
        let mut group_area: Vec<f64> = Vec::new();
        let mut queue = std::collections::VecDeque::new();
        for &seed in &seeds {
            if label[seed as usize] != u32::MAX {
                continue;
            }
            let g = members.len() as u32;
            let (c0, n0) = (centre[seed as usize], normal[seed as usize]);
            label[seed as usize] = g;
            let mut taken = vec![seed];
            let mut sum = area[seed as usize];
            queue.clear();
            queue.push_back(seed);
            while let Some(t) = queue.pop_front() {
                for &(_, u) in neighbours.of_triangle(t) {
                    let u = u as usize;
                    let fits = label[u] == u32::MAX
                        && normal[u].dot(n0) >= GROUP_COS
                        && sum + area[u] <= most_area
                        && prims[small[u] as usize].p[..3].iter().all(|&p| (p - c0).length() <= radius);
                    if fits {
                        label[u] = g;
                        sum += area[u];
                        taken.push(u as u32);
                        queue.push_back(u as u32);
                    }
                }
            }
            members.push(taken);
            seed_normal.push(n0);
            group_area.push(sum);
        }
        Self { label, members, seed_normal, group_area, normal, most_area }
    }

    /// Growing leaves fragments between groups, too small to catch enough
    /// rays: each group under a quarter of the target joins the smallest
    /// neighbouring group whose first normal is within 45° of all of its
    /// triangles' (in group order, so the result is deterministic).
    fn merge_fragments(&mut self, neighbours: &EdgeNeighbours) {
        let Self { label, members, seed_normal, group_area, normal, most_area } = self;
        for g in 0..members.len() {
            if members[g].is_empty() || group_area[g] >= 0.25 * *most_area {
                continue;
            }
            let mut best: Option<u32> = None;
            for &t in &members[g] {
                for &(_, u) in neighbours.of_triangle(t) {
                    let h = label[u as usize];
                    let fits = h != g as u32
                        && members[g].iter().all(|&x| normal[x as usize].dot(seed_normal[h as usize]) >= ADJACENT_COS);
                    if fits && best.is_none_or(|b| (group_area[h as usize], h) < (group_area[b as usize], b)) {
                        best = Some(h);
                    }
                }
            }
            if let Some(h) = best {
                let moved = std::mem::take(&mut members[g]);
                for &t in &moved {
                    label[t as usize] = h;
                }
                group_area[h as usize] += group_area[g];
                members[h as usize].extend(moved);
            }
        }
    }
}

/// Area-weighted centre, unit normal and area of a group of triangles
/// (the normal of the first when the others cancel it).
pub(crate) fn group_shape(tris: impl Iterator<Item = Primitive>) -> (Vec3, Vec3, f32) {
    let (mut c, mut n, mut a, mut first) = (DVec3::ZERO, DVec3::ZERO, 0.0f64, None);
    for t in tris {
        let (ta, tn) = (t.area() as f64, t.normal().as_dvec3());
        c += ta * (t.p[..3].iter().map(|p| p.as_dvec3()).sum::<DVec3>() / 3.0);
        n += ta * tn;
        a += ta;
        first.get_or_insert(tn);
    }
    let n = if n.length() > 1e-6 * a { n.normalize() } else { first.unwrap_or(DVec3::Y) };
    ((c / a.max(f64::MIN_POSITIVE)).as_vec3(), n.as_vec3(), a as f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `n × n` grid of unit-spaced squares, each split into two
    /// triangles, bent along x = `fold` by `angle` degrees.
    fn sheet(n: u32, cell: f32, fold: u32, angle: f32) -> Vec<Primitive> {
        let (s, c) = angle.to_radians().sin_cos();
        let at = |i: u32, j: u32| {
            let (x, z) = (i as f32 * cell, j as f32 * cell);
            let f = fold as f32 * cell;
            if i <= fold { Vec3::new(x, 0.0, z) } else { Vec3::new(f + (x - f) * c, (x - f) * s, z) }
        };
        let mut out = Vec::new();
        for j in 0..n {
            for i in 0..n {
                let (a, b, d, e) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
                out.push(Primitive::triangle(a, e, d));
                out.push(Primitive::triangle(a, d, b));
            }
        }
        out
    }

    #[test]
    fn small_triangles_make_patches_of_about_the_target_size() {
        // 40 × 40 squares of 1 cm (3 200 triangles), patches of 5 cm.
        let prims = sheet(40, 0.01, 40, 0.0);
        let g = group_triangles(&prims, 0.05);
        let mut seen = g.order.clone();
        seen.sort_unstable();
        assert_eq!(seen, (0..prims.len() as u32).collect::<Vec<_>>(), "a permutation");
        assert!(g.group.iter().all(|&x| x != UNGROUPED));
        let n = g.count() as usize;
        let mut areas = vec![0.0f32; n];
        for (&i, &k) in g.order.iter().zip(&g.group) {
            areas[k as usize] += prims[i as usize].area();
        }
        assert!(areas.iter().all(|&a| a <= 0.05 * 0.05 + 1e-6));
        // The mean patch is about the target's area (a quad cut at 5 cm:
        // 25 cm²); the sheet is 16 of them.
        let mean = areas.iter().sum::<f32>() / n as f32;
        assert!((8e-4..=25e-4).contains(&mean), "{n} groups of mean area {mean}");
        // Groups are contiguous in the order and numbered in order.
        assert!(g.group.windows(2).all(|w| w[1] == w[0] || w[1] == w[0] + 1));
        // The same input gives the same groups.
        assert_eq!(g, group_triangles(&prims, 0.05));
    }

    #[test]
    fn groups_do_not_cross_a_fold_and_large_triangles_keep_their_grids() {
        let mut prims = sheet(20, 0.01, 10, 60.0);
        let big = Primitive::triangle(Vec3::new(0.0, 1.0, 0.0), Vec3::new(0.0, 1.0, 1.0), Vec3::new(1.0, 1.0, 0.0));
        prims.insert(7, big);
        let g = group_triangles(&prims, 0.05);
        assert_eq!((g.order[0], g.group[0]), (7, UNGROUPED), "the large triangle keeps its grid, first");
        // Every group lies on one side of the fold (x = 0.1).
        let side = |i: u32| prims[i as usize].p.iter().take(3).any(|p| p.y > 1e-6);
        let n = g.count();
        for k in 0..n {
            let members: Vec<u32> = g.order.iter().zip(&g.group).filter(|(_, x)| **x == k).map(|(&i, _)| i).collect();
            assert!(members.iter().all(|&i| side(i) == side(members[0])), "group {k} crosses the fold");
        }
    }

    #[test]
    fn a_group_has_the_area_weighted_shape_of_its_triangles() {
        let a = Primitive::triangle(Vec3::ZERO, Vec3::Z, Vec3::X);
        let b = Primitive::triangle(Vec3::X, Vec3::Z, Vec3::new(1.0, 0.0, 1.0));
        let (c, n, area) = group_shape([a, b].into_iter());
        assert!(
            (area - 1.0).abs() < 1e-6
                && (n - Vec3::Y).length() < 1e-6
                && (c - Vec3::new(0.5, 0.0, 0.5)).length() < 1e-6
        );
    }
}
