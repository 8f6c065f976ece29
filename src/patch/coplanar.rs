//! Adjacency across the edges between coplanar primitives of one group
//! (one surface, or one temporal instance): which pairs of primitives may
//! touch, found through a tree of their bounding boxes, and which of
//! their boundary cells share an edge over a positive length.

use glam::Vec3;
use rayon::prelude::*;

use super::{Patches, PrimitivePatches};
use crate::geometry::grid::NO_VERTEX;
use crate::geometry::{Primitive, PrimitiveKind};

/// Most boxes a leaf of [`BoxTree`] holds.
const LEAF: usize = 8;

/// A bounding-volume tree over axis-aligned boxes, split at the median of
/// the boxes' centres along their widest spread: a box's query meets the
/// boxes near it in about log n steps and as many more as it overlaps,
/// whatever the boxes' shapes (a row of long thin strips, a grid of tiles).
struct BoxTree {
    /// Nodes, the root first.
    nodes: Vec<Node>,
    /// The boxes' indices, each leaf's a contiguous range.
    items: Vec<u32>,
}

/// One node of a [`BoxTree`]: the bounds of its boxes and, for an inner
/// node, where its two children are.
struct Node {
    lo: Vec3,
    hi: Vec3,
    /// The node's boxes: `items[start..end]`.
    start: u32,
    end: u32,
    /// Index of the first child, the second following it; 0 for a leaf.
    first: u32,
}

impl BoxTree {
    /// The tree over `boxes` (lo, hi).
    fn new(boxes: &[(Vec3, Vec3)]) -> Self {
        let mut tree =
            Self { nodes: Vec::with_capacity(2 * boxes.len() / LEAF + 1), items: (0..boxes.len() as u32).collect() };
        // (node, start, end) still to split; the tree is built depth first.
        let mut todo = vec![(tree.push(boxes, 0, boxes.len()), 0, boxes.len())];
        while let Some((node, start, end)) = todo.pop() {
            if end - start <= LEAF {
                continue;
            }
            let (mut clo, mut chi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
            for &i in &tree.items[start..end] {
                let c = (boxes[i as usize].0 + boxes[i as usize].1) * 0.5;
                (clo, chi) = (clo.min(c), chi.max(c));
            }
            let axis = (chi - clo).max_position();
            let mid = start + (end - start) / 2;
            let centre = |i: &u32| boxes[*i as usize].0[axis] + boxes[*i as usize].1[axis];
            tree.items[start..end]
                .select_nth_unstable_by(mid - start, |a, b| centre(a).total_cmp(&centre(b)).then(a.cmp(b)));
            let first = tree.push(boxes, start, mid);
            let second = tree.push(boxes, mid, end);
            tree.nodes[node].first = first as u32;
            todo.push((second, mid, end));
            todo.push((first, start, mid));
        }
        tree
    }

    /// Adds a node over `items[start..end]`, returning its index.
    fn push(&mut self, boxes: &[(Vec3, Vec3)], start: usize, end: usize) -> usize {
        let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
        for &i in &self.items[start..end] {
            (lo, hi) = (lo.min(boxes[i as usize].0), hi.max(boxes[i as usize].1));
        }
        self.nodes.push(Node { lo, hi, start: start as u32, end: end as u32, first: 0 });
        self.nodes.len() - 1
    }

    /// Calls `found` with every box of `boxes` (the tree's) that comes
    /// within `slack` of `(lo, hi)` along every axis.
    fn overlapping(&self, boxes: &[(Vec3, Vec3)], (lo, hi): (Vec3, Vec3), slack: f32, mut found: impl FnMut(usize)) {
        // Compared as `touching` compares, a box's far side raised by the
        // slack, so that no pair it would keep is left out.
        let meets = |(l, h): (Vec3, Vec3)| l.cmple(hi + slack).all() && lo.cmple(h + slack).all();
        let mut stack = vec![0usize];
        while let Some(n) = stack.pop() {
            let node = &self.nodes[n];
            if !meets((node.lo, node.hi)) {
                continue;
            }
            if node.first == 0 {
                for &i in &self.items[node.start as usize..node.end as usize] {
                    if meets(boxes[i as usize]) {
                        found(i as usize);
                    }
                }
            } else {
                stack.push(node.first as usize + 1);
                stack.push(node.first as usize);
            }
        }
    }
}

/// Pairs of patches of different, coplanar primitives of one group whose
/// boundary edges overlap over a positive length, and how many pairs of
/// primitives were compared to find them.
///
/// Candidates are the pairs whose bounding boxes come within the test's
/// slack of each other, found per group through a [`BoxTree`]: a surface
/// of 10⁵ coplanar quads costs about as many comparisons as it has
/// touching neighbours, where comparing every pair cost n²/2, and so did
/// the sweep along one axis this replaced when the primitives overlapped
/// along it (a row of strips as long as the row, issue 42 §4).
pub(super) fn neighbours(prims: &[Primitive], group_of: &[u32], patches: &Patches) -> (Vec<(u32, u32)>, u64) {
    // Grouped triangles meet their neighbours through their mesh's edges.
    let mut cand: Vec<u32> = (0..prims.len() as u32).filter(|&i| !patches.primitives[i as usize].grouped()).collect();
    let size = |b: &(Vec3, Vec3)| (b.1 - b.0).length();
    // The largest slack any pair's test below allows, for the candidates.
    let slack = 1e-5 * cand.iter().map(|&i| size(&prims[i as usize].bounds())).fold(0.0f32, f32::max);
    cand.sort_by_key(|&i| group_of[i as usize]);
    let (mut pairs, mut compared) = (Vec::new(), 0u64);
    for run in cand.chunk_by(|&a, &b| group_of[a as usize] == group_of[b as usize]) {
        let bounds: Vec<(Vec3, Vec3)> = run.iter().map(|&i| prims[i as usize].bounds()).collect();
        let tree = BoxTree::new(&bounds);
        // In parallel over pieces of the group, each piece's pairs in
        // primitive order and the pieces in theirs: the same list as one
        // thread's.
        let pieces: Vec<(Vec<(u32, u32)>, u64)> = (0..run.len())
            .collect::<Vec<usize>>()
            .par_chunks(1024)
            .map(|piece| {
                let (mut found, mut n) = (Vec::new(), 0u64);
                let (mut ei, mut ej, mut sorted) = (Vec::new(), Vec::new(), Vec::new());
                for &a in piece {
                    let i = run[a];
                    // i's boundary edges, made once for all its pairs.
                    let mut made = false;
                    tree.overlapping(&bounds, bounds[a], slack, |b| {
                        // Each pair once, the lower primitive first
                        // (`touching` is not symmetric in floating point).
                        let j = run[b];
                        if j > i {
                            n += 1;
                            let edges = Edges { i: &mut ei, j: &mut ej, sorted: &mut sorted, i_made: &mut made };
                            touching(prims, (bounds[a], bounds[b]), patches, i as usize, j as usize, edges, &mut found);
                        }
                    });
                }
                (found, n)
            })
            .collect();
        for (found, n) in pieces {
            pairs.extend(found);
            compared += n;
        }
    }
    (pairs, compared)
}

/// Buffers `touching` reuses across the pairs of a group: the boundary
/// edges of the pair's two primitives (the first's made once for all its
/// pairs), and the second's sorted along the pair's widest axis.
struct Edges<'a> {
    i: &'a mut Vec<(u32, Vec3, Vec3)>,
    j: &'a mut Vec<(u32, Vec3, Vec3)>,
    sorted: &'a mut Vec<(f32, f32, usize)>,
    i_made: &'a mut bool,
}

/// Boundary edges of a primitive's cells, `(patch, start, end)`, into `out`.
fn boundary_edges(prim: &Primitive, pp: &PrimitivePatches, out: &mut Vec<(u32, Vec3, Vec3)>) {
    let g = pp.grid;
    out.clear();
    let at = |local_vertex: u32| prim.point(g.vertex_uv(local_vertex));
    for cell in 0..g.cell_count() {
        let c = g.cell_corners(cell);
        let n = if c[3] == NO_VERTEX { 3 } else { 4 };
        for k in 0..n {
            let (v0, v1) = (c[k], c[(k + 1) % n]);
            let (a, b) = (g.vertex_uv(v0), g.vertex_uv(v1));
            // An edge lies on the primitive's boundary when both ends do, on one side.
            let on_u0 = a.x == 0.0 && b.x == 0.0;
            let on_v0 = a.y == 0.0 && b.y == 0.0;
            let on_far = match prim.kind {
                PrimitiveKind::Quad => (a.x == 1.0 && b.x == 1.0) || (a.y == 1.0 && b.y == 1.0),
                PrimitiveKind::Triangle => (a.x + a.y - 1.0).abs() < 1e-6 && (b.x + b.y - 1.0).abs() < 1e-6,
            };
            if on_u0 || on_v0 || on_far {
                out.push((pp.first_patch + cell, at(v0), at(v1)));
            }
        }
    }
}

/// Adds to `pairs` the patches of primitives `i` and `j` (of one group)
/// whose boundary edges overlap, when the two are coplanar and touch.
fn touching(
    prims: &[Primitive],
    (bound_i, bound_j): ((Vec3, Vec3), (Vec3, Vec3)),
    patches: &Patches,
    i: usize,
    j: usize,
    edges: Edges<'_>,
    pairs: &mut Vec<(u32, u32)>,
) {
    let size = |b: &(Vec3, Vec3)| (b.1 - b.0).length();
    let (pi, pj) = (&prims[i], &prims[j]);
    let (ni, nj) = (pi.normal(), pj.normal());
    let ((lo_i, hi_i), (lo_j, hi_j)) = (bound_i, bound_j);
    let eps = 1e-5 * size(&bound_i).max(size(&bound_j));
    if lo_i.cmpgt(hi_j + eps).any() || lo_j.cmpgt(hi_i + eps).any() {
        return; // too far apart to touch
    }
    if ni.dot(nj) < 0.9999 || (pj.p[0] - pi.p[0]).dot(ni).abs() > eps {
        return; // not coplanar
    }
    if !std::mem::replace(edges.i_made, true) {
        boundary_edges(pi, &patches.primitives[i], edges.i);
    }
    boundary_edges(pj, &patches.primitives[j], edges.j);
    let (ei, ej) = (&*edges.i, &*edges.j);
    // Edges that overlap over more than `eps` come within `eps` of each
    // other (the test's rounding, relative to the primitives' size, is
    // far below it): only those whose extents along the pair's widest
    // axis come within `margin` are tested, found by a search among j's
    // edges sorted along it, so two strips of n cells cost about n
    // tests, not n². Extents are taken from a point of the pair, where
    // they are exact to well below the margin wherever the pair lies.
    let (o, margin) = (pi.p[0], 4.0 * eps);
    let k = (hi_i.max(hi_j) - lo_i.min(lo_j)).max_position();
    let extent = |p0: Vec3, p1: Vec3| {
        let (s, t) = (p0[k] - o[k], p1[k] - o[k]);
        (s.min(t), s.max(t))
    };
    let sorted = edges.sorted;
    sorted.clear();
    sorted.extend(ej.iter().enumerate().map(|(x, &(_, b0, b1))| (extent(b0, b1).0, extent(b0, b1).1, x)));
    sorted.sort_unstable_by(|x, y| x.0.total_cmp(&y.0).then(x.2.cmp(&y.2)));
    let longest = sorted.iter().map(|e| e.1 - e.0).fold(0.0f32, f32::max);
    for &(a, a0, a1) in ei {
        let len = (a1 - a0).length();
        let dir = (a1 - a0) / len;
        let (a_lo, a_hi) = extent(a0, a1);
        let first = sorted.partition_point(|e| e.0 < a_lo - margin - longest);
        for &(_, _, x) in sorted[first..].iter().take_while(|e| e.0 <= a_hi + margin) {
            let (b, b0, b1) = ej[x];
            // Collinear: both ends of b on a's line.
            let off = |p: Vec3| (p - a0) - dir * (p - a0).dot(dir);
            if off(b0).length() > eps || off(b1).length() > eps {
                continue;
            }
            let (s0, s1) = ((b0 - a0).dot(dir), (b1 - a0).dot(dir));
            let overlap = s0.max(s1).min(len) - s0.min(s1).max(0.0);
            if overlap > eps {
                pairs.push((a, b));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::patch::DEFAULT_CELL_ORDER;

    #[test]
    fn the_sweep_finds_the_coplanar_neighbours_every_pair_finds() {
        // Quads tiling two planes (one crossing the other) in three groups,
        // one of them a wall seen edge-on from its sweep axis (x = 3),
        // shuffled, with gaps: the sweep must find exactly the pairs that
        // testing every pair of primitives finds.
        let mut prims = Vec::new();
        let mut group = Vec::new();
        for i in 0..12u32 {
            for k in 0..9u32 {
                if (i * 7 + k * 3) % 5 == 0 {
                    continue; // a gap
                }
                let (x, z) = (i as f32 * 0.5, k as f32 * 0.4);
                let p0 = Vec3::new(x, 0.0, z);
                prims.push(Primitive::quad([
                    p0,
                    p0 + Vec3::Z * 0.4,
                    p0 + Vec3::new(0.5, 0.0, 0.4),
                    p0 + Vec3::X * 0.5,
                ]));
                group.push((i + k) % 2);
                let q0 = Vec3::new(x, k as f32 * 0.4, 1.0);
                prims.push(Primitive::quad([
                    q0,
                    q0 + Vec3::X * 0.5,
                    q0 + Vec3::new(0.5, 0.4, 0.0),
                    q0 + Vec3::Y * 0.4,
                ]));
                group.push(2);
            }
        }
        let order: Vec<usize> = (0..prims.len()).map(|i| (i * 37) % prims.len()).collect();
        let (prims, group): (Vec<Primitive>, Vec<u32>) = order.iter().map(|&i| (prims[i], group[i])).unzip();
        let patches = Patches::new(&prims, &group, 0.2, DEFAULT_CELL_ORDER).unwrap();
        let bounds: Vec<_> = prims.iter().map(Primitive::bounds).collect();
        let mut every = Vec::new();
        for i in 0..prims.len() {
            for j in i + 1..prims.len() {
                if group[i] == group[j] {
                    let (mut ei, mut ej, mut sorted, mut made) = (Vec::new(), Vec::new(), Vec::new(), false);
                    let edges = Edges { i: &mut ei, j: &mut ej, sorted: &mut sorted, i_made: &mut made };
                    touching(&prims, (bounds[i], bounds[j]), &patches, i, j, edges, &mut every);
                }
            }
        }
        let mut swept = neighbours(&prims, &group, &patches).0;
        swept.sort_unstable();
        every.sort_unstable();
        assert!(every.len() > 100, "{} pairs", every.len());
        assert_eq!(swept, every);
    }

    fn edges_of(prim: &Primitive, pp: &PrimitivePatches) -> Vec<(u32, Vec3, Vec3)> {
        let mut out = Vec::new();
        boundary_edges(prim, pp, &mut out);
        out
    }

    /// Every pair of primitives of one group compared, every pair of
    /// their boundary edges tested: the quadratic reference the tree's
    /// candidates and the edges' search must give the same pairs as.
    fn every_pair(prims: &[Primitive], group: &[u32], patches: &Patches) -> Vec<(u32, u32)> {
        let bounds: Vec<_> = prims.iter().map(Primitive::bounds).collect();
        let mut every = Vec::new();
        for i in 0..prims.len() {
            for j in i + 1..prims.len() {
                let grouped = patches.primitives[i].grouped() || patches.primitives[j].grouped();
                let (pi, pj) = (&prims[i], &prims[j]);
                let size = |b: &(Vec3, Vec3)| (b.1 - b.0).length();
                let eps = 1e-5 * size(&bounds[i]).max(size(&bounds[j]));
                let coplanar =
                    pi.normal().dot(pj.normal()) >= 0.9999 && (pj.p[0] - pi.p[0]).dot(pi.normal()).abs() <= eps;
                if group[i] != group[j] || grouped || !coplanar {
                    continue;
                }
                for &(a, a0, a1) in &edges_of(pi, &patches.primitives[i]) {
                    let len = (a1 - a0).length();
                    let dir = (a1 - a0) / len;
                    for &(b, b0, b1) in &edges_of(pj, &patches.primitives[j]) {
                        let off = |p: Vec3| (p - a0) - dir * (p - a0).dot(dir);
                        let (s0, s1) = ((b0 - a0).dot(dir), (b1 - a0).dot(dir));
                        let overlap = s0.max(s1).min(len) - s0.min(s1).max(0.0);
                        if off(b0).length() <= eps && off(b1).length() <= eps && overlap > eps {
                            every.push((a, b));
                        }
                    }
                }
            }
        }
        every.sort_unstable();
        every
    }

    proptest::proptest! {
        #![proptest_config(proptest::test_runner::Config::with_cases(64))]

        /// On random layouts of rectangles and triangles on a lattice (so
        /// that many share edges, whole or in part), long strips among
        /// them, on two crossing planes, in up to three groups, turned and
        /// moved anywhere: the tree finds exactly the pairs that comparing
        /// every pair finds (issue 42 §4).
        #[test]
        fn the_tree_finds_the_pairs_every_pair_finds(
            cells in proptest::collection::vec((0u32..8, 0u32..8, 1u32..4, 1u32..9, 0u32..3, 0u32..2, 0u32..4), 1..40),
            size in proptest::sample::select(vec![0.4f32, 1.0, 3.0]),
            angle in 0.0f32..std::f32::consts::TAU,
            tilt in 0.0f32..std::f32::consts::PI,
            offset in proptest::array::uniform3(-50.0f32..50.0),
            scale in proptest::sample::select(vec![1e-3f32, 0.25, 40.0]),
        ) {
            let rot = glam::Quat::from_rotation_z(angle) * glam::Quat::from_rotation_x(tilt);
            let at = |x: u32, z: u32, wall: u32| {
                let p = match wall {
                    0 => Vec3::new(x as f32, 0.0, z as f32),
                    _ => Vec3::new(x as f32, z as f32, 4.0),
                };
                rot * (p * scale) + Vec3::from(offset)
            };
            let (mut prims, mut group) = (Vec::new(), Vec::new());
            for &(x, z, w, h, g, wall, kind) in &cells {
                let c = [at(x, z, wall), at(x, z + h, wall), at(x + w, z + h, wall), at(x + w, z, wall)];
                let p = match kind {
                    0 => Primitive::triangle(c[0], c[1], c[2]),
                    1 => Primitive::triangle(c[0], c[2], c[3]),
                    _ => Primitive::quad(c),
                };
                prims.push(p);
                group.push(g);
            }
            let patches = Patches::new(&prims, &group, size * scale, DEFAULT_CELL_ORDER).unwrap();
            let mut found = neighbours(&prims, &group, &patches).0;
            found.sort_unstable();
            proptest::prop_assert_eq!(found, every_pair(&prims, &group, &patches));
        }
    }

    #[test]
    fn a_row_of_long_strips_compares_about_as_many_pairs_as_it_has_neighbours() {
        // 2 000 strips side by side, each as long as the row is wide (the
        // layout where the sweep along one axis compared every pair, n²/2),
        // and a grid of 40 × 50 tiles: the tree compares a few pairs per
        // primitive, and finds every strip's and tile's neighbours.
        let n = 2000;
        let mut prims = Vec::new();
        for i in 0..n {
            let x = i as f32 * 0.01;
            prims.push(Primitive::quad([
                Vec3::new(x, 0.0, 0.0),
                Vec3::new(x, 0.0, 20.2),
                Vec3::new(x + 0.01, 0.0, 20.2),
                Vec3::new(x + 0.01, 0.0, 0.0),
            ]));
        }
        for i in 0..40 {
            for k in 0..50 {
                let p = Vec3::new(i as f32 * 0.5, 1.0, k as f32 * 0.4);
                prims.push(Primitive::quad([p, p + Vec3::Z * 0.4, p + Vec3::new(0.5, 0.0, 0.4), p + Vec3::X * 0.5]));
            }
        }
        let group: Vec<u32> = (0..prims.len()).map(|i| u32::from(i >= n)).collect();
        let patches = Patches::new(&prims, &group, 30.0, DEFAULT_CELL_ORDER).unwrap();
        let (pairs, compared) = neighbours(&prims, &group, &patches);
        let tiles = 39 * 50 + 40 * 49;
        assert_eq!(pairs.len(), (n - 1) + tiles, "every strip's and tile's neighbours");
        assert!(compared < 8 * prims.len() as u64, "{compared} pairs compared for {} primitives", prims.len());
    }
}
