//! The order patches are numbered in. The distribution's gather reads the
//! state of every link end's other patch; a patch's links mostly stay in
//! its room, so numbering the patches of primitives near each other
//! together keeps a receiver's senders within a few cache-sized stretches
//! of state (`docs/notebook/2026-12-05-format-11-spatial-order.md`). Primitives
//! come in scene order, a surface's primitives together (every wall of a
//! building, then every floor): a spatial order takes their patch blocks
//! along a Morton curve over the primitives' centres instead.

use glam::Vec3;

use super::Patches;
use crate::geometry::Primitive;

/// How a build numbers its patches (§5.5 of the format).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PatchOrder {
    /// Primitive by primitive, in primitive order (every archive before
    /// version 11; `--patch-order primitives`).
    Primitives,
    /// Primitives' patch blocks along a Morton curve over their centres
    /// (the default; builds apply it to still scenes, not sequences).
    Spatial,
}

/// Spreads the low 21 bits of `x` to every third bit.
fn spread3(x: u64) -> u64 {
    let mut x = x & 0x1f_ffff;
    x = (x | (x << 32)) & 0x1f_0000_0000_ffff;
    x = (x | (x << 16)) & 0x1f_0000_ff00_00ff;
    x = (x | (x << 8)) & 0x100f_00f0_0f00_f00f;
    x = (x | (x << 4)) & 0x10c3_0c30_c30c_30c3;
    (x | (x << 2)) & 0x1249_2492_4924_9249
}

/// Each point's place on a Morton curve over the cube (21 bits an axis)
/// that bounds the points.
pub fn morton_keys(points: &[Vec3]) -> Vec<u64> {
    let (lo, hi) =
        points.iter().fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(l, h), &c| (l.min(c), h.max(c)));
    let top = ((1u64 << 21) - 1) as f32;
    let scale = top / (hi - lo).max_element().max(f32::MIN_POSITIVE);
    points
        .iter()
        .map(|&c| {
            let q = ((c - lo) * scale).to_array().map(|x| x.clamp(0.0, top) as u64);
            spread3(q[0]) | (spread3(q[1]) << 1) | (spread3(q[2]) << 2)
        })
        .collect()
}

/// The primitives that own patches (grids, and the first triangle of each
/// group), along a Morton curve over their centres, ties by index.
pub fn spatial_order(primitives: &[Primitive], patches: &Patches) -> Vec<u32> {
    let owners: Vec<u32> =
        (0..primitives.len() as u32).filter(|&i| patches.primitives[i as usize].owned_patches() > 0).collect();
    let centres: Vec<Vec3> = owners
        .iter()
        .map(|&i| {
            let p = &primitives[i as usize];
            p.p[..p.corner_count()].iter().sum::<Vec3>() / p.corner_count() as f32
        })
        .collect();
    let keys = morton_keys(&centres);
    let mut order: Vec<u32> = (0..owners.len() as u32).collect();
    order.sort_unstable_by_key(|&k| (keys[k as usize], owners[k as usize]));
    order.iter().map(|&k| owners[k as usize]).collect()
}

impl Patches {
    /// Renumbers the patches so that the primitives' patch blocks follow
    /// `order` (every primitive that owns patches, once; a group's joining
    /// triangles keep its patch): a primitive's patches stay contiguous and
    /// in its grid's cell order; columns and adjacency are permuted to
    /// match, each patch's neighbours ascending again.
    pub fn renumber(&mut self, order: &[u32]) {
        let n = self.len();
        let mut new_of = vec![u32::MAX; n];
        let mut next = 0u32;
        for &pi in order {
            let pp = self.primitives[pi as usize];
            for k in 0..pp.owned_patches() {
                new_of[(pp.first_patch + k) as usize] = next + k;
            }
            next += pp.owned_patches();
        }
        assert!(next as usize == n && new_of.iter().all(|&q| q != u32::MAX), "the order covers every patch once");
        let mut old_of = vec![0u32; n];
        for (old, &new) in new_of.iter().enumerate() {
            old_of[new as usize] = old as u32;
        }
        for pp in &mut self.primitives {
            if (pp.first_patch as usize) < n {
                pp.first_patch = new_of[pp.first_patch as usize];
            }
        }
        fn permute<T: Copy>(column: &mut Vec<T>, old_of: &[u32]) {
            *column = old_of.iter().map(|&o| column[o as usize]).collect();
        }
        permute(&mut self.centre, &old_of);
        permute(&mut self.normal, &old_of);
        permute(&mut self.area, &old_of);
        permute(&mut self.primitive, &old_of);
        permute(&mut self.corners, &old_of);
        let (offsets, adjacency) = (std::mem::take(&mut self.adjacency_offsets), std::mem::take(&mut self.adjacency));
        self.adjacency_offsets.reserve_exact(n + 1);
        self.adjacency.reserve_exact(adjacency.len());
        self.adjacency_offsets.push(0);
        for &old in &old_of {
            let start = self.adjacency.len();
            let range = offsets[old as usize] as usize..offsets[old as usize + 1] as usize;
            self.adjacency.extend(adjacency[range].iter().map(|&q| new_of[q as usize]));
            self.adjacency[start..].sort_unstable();
            self.adjacency_offsets.push(self.adjacency.len() as u32);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::patch::DEFAULT_CELL_ORDER;
    use crate::patch::mesh::{UNGROUPED, group_triangles};

    #[test]
    fn renumbering_moves_whole_blocks_and_keeps_every_column_and_neighbour() {
        // The Cornell box's quads, then a 40 × 40 sheet of 1 cm squares as
        // triangles grouped into patches (openers and joiners).
        let scene = crate::scene::Scene::cornell_box();
        let mut prims: Vec<Primitive> = scene.primitives().map(|(_, p)| *p).collect();
        let mut instance: Vec<u32> = scene.primitives().map(|(s, _)| s).collect();
        let quads = prims.len();
        let at = |i: u32, j: u32| Vec3::new(1.0 + i as f32 * 0.01, 0.3, 1.0 + j as f32 * 0.01);
        let mut tris = Vec::new();
        for j in 0..40 {
            for i in 0..40 {
                tris.push(Primitive::triangle(at(i, j), at(i, j + 1), at(i + 1, j + 1)));
                tris.push(Primitive::triangle(at(i, j), at(i + 1, j + 1), at(i + 1, j)));
            }
        }
        let g = group_triangles(&tris, 0.1);
        prims.extend(g.order.iter().map(|&i| tris[i as usize]));
        instance.extend(std::iter::repeat_n(99, tris.len()));
        let mut groups = vec![UNGROUPED; quads];
        groups.extend_from_slice(&g.group);
        let before = Patches::with_groups(&prims, &instance, &groups, 0.1, DEFAULT_CELL_ORDER).unwrap();
        let order = spatial_order(&prims, &before);
        assert_eq!(order, spatial_order(&prims, &before), "the same input gives the same order");
        let mut owners: Vec<u32> = order.clone();
        owners.sort_unstable();
        assert!(owners.windows(2).all(|w| w[0] < w[1]), "each owner once");
        assert_eq!(owners.len(), before.primitives.iter().filter(|p| p.owned_patches() > 0).count());
        let mut after = before.clone();
        after.renumber(&order);

        // The blocks tile the patches in the order's sequence.
        let mut next = 0;
        for &pi in &order {
            let pp = after.primitives[pi as usize];
            assert_eq!(pp.first_patch, next, "primitive {pi}");
            next += pp.owned_patches();
        }
        assert_eq!(next as usize, before.len());
        let moved = (0..prims.len()).filter(|&i| after.primitives[i] != before.primitives[i]).count();
        assert!(moved > prims.len() / 2, "the curve moves most blocks ({moved} of {})", prims.len());
        assert!(before.primitives.iter().any(|p| p.role == crate::patch::PatchRole::Joins));

        // Every patch keeps its columns and neighbours under its new id.
        let mut new_of = vec![u32::MAX; before.len()];
        for (b, a) in before.primitives.iter().zip(&after.primitives) {
            assert_eq!((b.grid, b.first_vertex, b.role), (a.grid, a.first_vertex, a.role));
            for k in 0..b.owned_patches().max(1) {
                let (old, new) = ((b.first_patch + k) as usize, (a.first_patch + k) as usize);
                assert!(new_of[old] == u32::MAX || new_of[old] == new as u32, "a joiner keeps its opener's patch");
                new_of[old] = new as u32;
            }
        }
        for old in 0..before.len() {
            let new = new_of[old] as usize;
            assert_eq!(
                (before.centre[old], before.normal[old], before.area[old], before.primitive[old], before.corners[old]),
                (after.centre[new], after.normal[new], after.area[new], after.primitive[new], after.corners[new])
            );
            let nb = |p: &Patches, q: usize| {
                p.adjacency[p.adjacency_offsets[q] as usize..]
                    [..(p.adjacency_offsets[q + 1] - p.adjacency_offsets[q]) as usize]
                    .to_vec()
            };
            let mut want: Vec<u32> = nb(&before, old).iter().map(|&q| new_of[q as usize]).collect();
            want.sort_unstable();
            assert_eq!(nb(&after, new), want, "patch {old} → {new}");
        }
        assert_eq!((before.vertex_position, before.mesh_triangles), (after.vertex_position, after.mesh_triangles));
    }
}
