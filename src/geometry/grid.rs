//! Patch grids: how a primitive's surface coordinates name patches and
//! patch vertices.
//!
//! A quad is cut into `n_u × n_v` bilinear cells whose corners are grid
//! vertices `(i, j) (i+1, j) (i+1, j+1) (i, j+1)`, vertex `(i, j)` having
//! local index `j·(n_u+1) + i`. Cells are numbered row by row (`j·n_u + i`,
//! [`CellOrder::Rows`], archives before version 7) or in square tiles
//! ([`CellOrder::Tiles`], the default since version 7): tiles of T×T cells
//! row by row, the cells of a tile row by row, tiles cut short at the far
//! edges. Tiles keep cells that are near in space near in number in both
//! directions, so the distribution's gathers, whose neighbouring receivers
//! read neighbouring senders along a direction, stay in the cache (issue 11;
//! docs/notebook/2026-12-02-format-7.md).
//!
//! A triangle is cut into `k²` similar sub-triangles (`k = n_u = n_v`). Grid
//! vertex `(i, j)` (`i + j ≤ k`, at barycentrics `(i/k, j/k)`) has local index
//! `j(k+1) − j(j−1)/2 + i`. Row `j` holds `2(k−j)−1` cells starting at local
//! patch `j(2k−j)`: the upright cell `(i, j)` → `(i,j) (i+1,j) (i,j+1)` is at
//! `2i`, the inverted cell `(i+1,j+1) (i,j+1) (i+1,j)` at `2i+1`.
//!
//! Vertices are shared by the cells of one primitive, which is what lets the
//! renderer interpolate radiance smoothly (§3.5).

use glam::Vec2;

use super::PrimitiveKind;

/// Marks an unused corner (the fourth corner of a triangular cell).
pub const NO_VERTEX: u32 = u32::MAX;

/// How a quad's cells are numbered (triangles' cells always go row by row).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CellOrder {
    /// Row by row: cell `(i, j)` is `j·n_u + i` (archives before version 7).
    Rows,
    /// Square tiles of `TILE`×`TILE` cells, row by row, and the cells of a
    /// tile row by row (since version 7).
    Tiles,
}

/// The tile edge of [`CellOrder::Tiles`], in cells: 8×8 patches hold
/// 1 KiB of the distribution's 16-byte state, a few dozen cache lines.
pub const TILE: u32 = 8;

/// The patch grid of one primitive.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PatchGrid {
    /// Quad (bilinear cells) or triangle (sub-triangles).
    pub kind: PrimitiveKind,
    /// Cells along `u` (for triangles, the subdivision `k`).
    pub n_u: u32,
    /// Cells along `v` (for triangles, equal to `n_u`).
    pub n_v: u32,
    /// How a quad's cells are numbered.
    pub order: CellOrder,
}

/// Where a surface point falls: its cell and interpolation weights.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CellLocation {
    /// Local patch index within the primitive.
    pub cell: u32,
    /// Local vertex indices of the cell's corners ([`NO_VERTEX`] if unused).
    pub corners: [u32; 4],
    /// Interpolation weight of each corner (sum 1; 0 for unused corners).
    pub weights: [f32; 4],
}

impl PatchGrid {
    /// Number of cells (patches).
    pub fn cell_count(&self) -> u32 {
        match self.kind {
            PrimitiveKind::Quad => self.n_u * self.n_v,
            PrimitiveKind::Triangle => self.n_u * self.n_u,
        }
    }

    /// Number of grid vertices.
    pub fn vertex_count(&self) -> u32 {
        match self.kind {
            PrimitiveKind::Quad => (self.n_u + 1) * (self.n_v + 1),
            PrimitiveKind::Triangle => (self.n_u + 1) * (self.n_u + 2) / 2,
        }
    }

    /// The local index of quad cell `(i, j)`.
    #[inline]
    pub fn quad_cell(&self, i: u32, j: u32) -> u32 {
        match self.order {
            CellOrder::Rows => j * self.n_u + i,
            CellOrder::Tiles => {
                let (ti, tj) = (i / TILE, j / TILE);
                // Tile rows above are full: TILE rows of n_u cells each.
                let h = TILE.min(self.n_v - tj * TILE);
                let w = TILE.min(self.n_u - ti * TILE);
                tj * TILE * self.n_u + ti * TILE * h + (j - tj * TILE) * w + (i - ti * TILE)
            }
        }
    }

    /// The `(i, j)` of local quad cell `cell` (inverse of [`Self::quad_cell`]).
    #[inline]
    pub fn quad_ij(&self, cell: u32) -> (u32, u32) {
        match self.order {
            CellOrder::Rows => (cell % self.n_u, cell / self.n_u),
            CellOrder::Tiles => {
                let tj = cell / (TILE * self.n_u);
                let r = cell - tj * TILE * self.n_u;
                let h = TILE.min(self.n_v - tj * TILE);
                let ti = r / (TILE * h);
                let r = r - ti * TILE * h;
                let w = TILE.min(self.n_u - ti * TILE);
                (ti * TILE + r % w, tj * TILE + r / w)
            }
        }
    }

    fn tri_vertex(&self, i: u32, j: u32) -> u32 {
        let k = self.n_u;
        j * (k + 1) - j * j.saturating_sub(1) / 2 + i
    }

    /// Surface coordinates of local vertex `index`.
    pub fn vertex_uv(&self, index: u32) -> Vec2 {
        match self.kind {
            PrimitiveKind::Quad => {
                let (i, j) = (index % (self.n_u + 1), index / (self.n_u + 1));
                Vec2::new(i as f32 / self.n_u as f32, j as f32 / self.n_v as f32)
            }
            PrimitiveKind::Triangle => {
                let k = self.n_u;
                let mut j = 0;
                while j < k && self.tri_vertex(0, j + 1) <= index {
                    j += 1;
                }
                let i = index - self.tri_vertex(0, j);
                Vec2::new(i as f32 / k as f32, j as f32 / k as f32)
            }
        }
    }

    /// Local vertex indices of the corners of local cell `cell`, counter-
    /// clockwise in `(u, v)`; the fourth is [`NO_VERTEX`] for triangles.
    pub fn cell_corners(&self, cell: u32) -> [u32; 4] {
        match self.kind {
            PrimitiveKind::Quad => {
                let (i, j) = self.quad_ij(cell);
                let w = self.n_u + 1;
                [j * w + i, j * w + i + 1, (j + 1) * w + i + 1, (j + 1) * w + i]
            }
            PrimitiveKind::Triangle => {
                let k = self.n_u;
                let mut j = 0;
                while j + 1 < k && (j + 1) * (2 * k - (j + 1)) <= cell {
                    j += 1;
                }
                let r = cell - j * (2 * k - j);
                let i = r / 2;
                if r.is_multiple_of(2) {
                    [self.tri_vertex(i, j), self.tri_vertex(i + 1, j), self.tri_vertex(i, j + 1), NO_VERTEX]
                } else {
                    [self.tri_vertex(i + 1, j + 1), self.tri_vertex(i, j + 1), self.tri_vertex(i + 1, j), NO_VERTEX]
                }
            }
        }
    }

    /// Quad cell `(i, j)` holding surface point `uv`, and `uv`'s place in
    /// it `(s, t)` (the one arithmetic [`Self::locate`] and
    /// [`Self::cell_at`] share).
    #[inline]
    fn quad_at(&self, uv: Vec2) -> (u32, u32, f32, f32) {
        let a = (uv.x.clamp(0.0, 1.0)) * self.n_u as f32;
        let b = (uv.y.clamp(0.0, 1.0)) * self.n_v as f32;
        let i = (a as u32).min(self.n_u - 1);
        let j = (b as u32).min(self.n_v - 1);
        (i, j, a - i as f32, b - j as f32)
    }

    /// Triangle row `j` and column `i` holding surface point `uv`, `uv`'s
    /// place `(fa, fb)` in the cell's square, and whether it is in the
    /// upright cell (points past the hypotenuse after rounding belong to
    /// the last upright cell of the row).
    #[inline]
    fn triangle_at(&self, uv: Vec2) -> (u32, u32, f32, f32, bool) {
        let k = self.n_u;
        let a = uv.x.max(0.0) * k as f32;
        let b = uv.y.max(0.0) * k as f32;
        let j = (b as u32).min(k - 1);
        let i = (a as u32).min(k - 1 - j);
        let (fa, fb) = (a - i as f32, b - j as f32);
        (i, j, fa, fb, fa + fb <= 1.0 || i + j + 1 >= k)
    }

    /// The cell containing surface point `uv`: [`Self::locate`]'s cell,
    /// without the corners and weights (a build's walk asks for the cell
    /// of every hit; the corners cost more than the cell).
    #[inline]
    pub fn cell_at(&self, uv: Vec2) -> u32 {
        match self.kind {
            PrimitiveKind::Quad => {
                let (i, j, _, _) = self.quad_at(uv);
                self.quad_cell(i, j)
            }
            PrimitiveKind::Triangle => {
                let (i, j, _, _, upright) = self.triangle_at(uv);
                let k = self.n_u;
                j * (2 * k - j) + 2 * i + if upright { 0 } else { 1 }
            }
        }
    }

    /// The cell containing surface point `uv` and the corner weights that
    /// interpolate vertex values there (bilinear for quads, barycentric for
    /// triangles).
    #[inline]
    pub fn locate(&self, uv: Vec2) -> CellLocation {
        match self.kind {
            PrimitiveKind::Quad => {
                let (i, j, s, t) = self.quad_at(uv);
                let cell = self.quad_cell(i, j);
                CellLocation {
                    cell,
                    corners: self.cell_corners(cell),
                    weights: [(1.0 - s) * (1.0 - t), s * (1.0 - t), s * t, (1.0 - s) * t],
                }
            }
            PrimitiveKind::Triangle => {
                let k = self.n_u;
                let (i, j, mut fa, mut fb, upright) = self.triangle_at(uv);
                if upright {
                    if fa + fb > 1.0 {
                        let s = 1.0 / (fa + fb);
                        fa *= s;
                        fb *= s;
                    }
                    CellLocation {
                        cell: j * (2 * k - j) + 2 * i,
                        corners: [
                            self.tri_vertex(i, j),
                            self.tri_vertex(i + 1, j),
                            self.tri_vertex(i, j + 1),
                            NO_VERTEX,
                        ],
                        weights: [(1.0 - fa - fb).max(0.0), fa, fb, 0.0],
                    }
                } else {
                    let (ga, gb) = (1.0 - fa, 1.0 - fb);
                    CellLocation {
                        cell: j * (2 * k - j) + 2 * i + 1,
                        corners: [
                            self.tri_vertex(i + 1, j + 1),
                            self.tri_vertex(i, j + 1),
                            self.tri_vertex(i + 1, j),
                            NO_VERTEX,
                        ],
                        weights: [1.0 - ga - gb, ga, gb, 0.0],
                    }
                }
            }
        }
    }

    /// Local cells sharing an edge with local cell `cell`, in ascending order.
    pub fn cell_neighbours(&self, cell: u32, out: &mut Vec<u32>) {
        out.clear();
        match self.kind {
            PrimitiveKind::Quad => {
                let (i, j) = self.quad_ij(cell);
                if j > 0 {
                    out.push(self.quad_cell(i, j - 1));
                }
                if i > 0 {
                    out.push(self.quad_cell(i - 1, j));
                }
                if i + 1 < self.n_u {
                    out.push(self.quad_cell(i + 1, j));
                }
                if j + 1 < self.n_v {
                    out.push(self.quad_cell(i, j + 1));
                }
                out.sort_unstable();
            }
            PrimitiveKind::Triangle => {
                // Cells sharing two corners share an edge.
                let mine = self.cell_corners(cell);
                for other in 0..self.cell_count() {
                    if other == cell {
                        continue;
                    }
                    let theirs = self.cell_corners(other);
                    let shared = mine[..3].iter().filter(|v| theirs[..3].contains(v)).count();
                    if shared == 2 {
                        out.push(other);
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn triangle_grid_locates_every_cell_centre_in_that_cell() {
        for k in 1..6 {
            let g = PatchGrid { kind: PrimitiveKind::Triangle, n_u: k, n_v: k, order: CellOrder::Rows };
            assert_eq!(g.vertex_count(), (k + 1) * (k + 2) / 2);
            for cell in 0..g.cell_count() {
                let c = g.cell_corners(cell);
                let centre = (g.vertex_uv(c[0]) + g.vertex_uv(c[1]) + g.vertex_uv(c[2])) / 3.0;
                let loc = g.locate(centre);
                assert_eq!(loc.cell, cell, "k={k}");
                assert_eq!(loc.corners, c);
                let w: f32 = loc.weights.iter().sum();
                assert!((w - 1.0).abs() < 1e-5);
                // Weights reproduce the point.
                let p = (0..3).map(|n| g.vertex_uv(c[n]) * loc.weights[n]).sum::<Vec2>();
                assert!((p - centre).length() < 1e-5);
            }
        }
    }

    #[test]
    fn cell_at_is_the_cell_locate_finds_everywhere() {
        // Points on and around every cell edge (k/n and one ulp either
        // side), past the primitive's edges, and beyond a triangle's
        // hypotenuse.
        let mut values: Vec<f32> = vec![-0.25, -0.0, 0.0, 1.0, 1.25, 0.5, 0.999_999_9, 1e-8];
        for n in 1..=23u32 {
            for k in 0..=n {
                let x = k as f32 / n as f32;
                values.extend([
                    x,
                    f32::from_bits(x.to_bits().saturating_add(1)),
                    f32::from_bits(x.to_bits().max(1) - 1),
                ]);
            }
        }
        for kind in [PrimitiveKind::Quad, PrimitiveKind::Triangle] {
            for order in [CellOrder::Rows, CellOrder::Tiles] {
                for (n_u, n_v) in [(1, 1), (3, 2), (7, 7), (20, 9), (23, 23)] {
                    let n_v = if kind == PrimitiveKind::Triangle { n_u } else { n_v };
                    let g = PatchGrid { kind, n_u, n_v, order };
                    for &u in &values {
                        for &v in &values {
                            let uv = Vec2::new(u, v);
                            assert_eq!(g.cell_at(uv), g.locate(uv).cell, "{kind:?} {order:?} {n_u}×{n_v} at {uv:?}");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn quad_grid_cells_and_neighbours() {
        let g = PatchGrid { kind: PrimitiveKind::Quad, n_u: 3, n_v: 2, order: CellOrder::Rows };
        assert_eq!(g.cell_count(), 6);
        assert_eq!(g.vertex_count(), 12);
        let loc = g.locate(Vec2::new(0.5, 0.75));
        assert_eq!(loc.cell, 4);
        let mut n = Vec::new();
        g.cell_neighbours(4, &mut n);
        assert_eq!(n, vec![1, 3, 5]);
        let tg = PatchGrid { kind: PrimitiveKind::Triangle, n_u: 2, n_v: 2, order: CellOrder::Rows };
        tg.cell_neighbours(1, &mut n);
        assert_eq!(n.len(), 3, "the inverted middle cell touches all three");
    }

    #[test]
    fn tiled_quad_cells_are_a_bijection_with_the_same_neighbours() {
        // Grids around and across the tile size, with cut tiles at both edges.
        for (nu, nv) in [(1, 1), (3, 2), (8, 8), (9, 17), (16, 5), (23, 31)] {
            let rows = PatchGrid { kind: PrimitiveKind::Quad, n_u: nu, n_v: nv, order: CellOrder::Rows };
            let tiles = PatchGrid { order: CellOrder::Tiles, ..rows };
            let mut seen = vec![false; (nu * nv) as usize];
            let (mut a, mut b) = (Vec::new(), Vec::new());
            for j in 0..nv {
                for i in 0..nu {
                    let c = tiles.quad_cell(i, j);
                    assert!(c < nu * nv && !seen[c as usize], "{nu}×{nv}: ({i}, {j}) -> {c}");
                    seen[c as usize] = true;
                    assert_eq!(tiles.quad_ij(c), (i, j));
                    assert_eq!(tiles.cell_corners(c), rows.cell_corners(rows.quad_cell(i, j)), "same corners");
                    let centre = Vec2::new((i as f32 + 0.5) / nu as f32, (j as f32 + 0.5) / nv as f32);
                    assert_eq!(tiles.locate(centre).cell, c);
                    // The same neighbours, as (i, j).
                    tiles.cell_neighbours(c, &mut a);
                    rows.cell_neighbours(rows.quad_cell(i, j), &mut b);
                    let mut a: Vec<_> = a.iter().map(|&x| tiles.quad_ij(x)).collect();
                    let mut b: Vec<_> = b.iter().map(|&x| rows.quad_ij(x)).collect();
                    a.sort_unstable();
                    b.sort_unstable();
                    assert_eq!(a, b);
                }
            }
            // Cells of one tile are consecutive.
            if nu >= TILE && nv >= TILE {
                let first: Vec<u32> = (0..TILE)
                    .flat_map(|j| (0..TILE).map(move |i| (i, j)))
                    .map(|(i, j)| tiles.quad_cell(i, j))
                    .collect();
                assert_eq!(first, (0..TILE * TILE).collect::<Vec<_>>());
            }
        }
    }
}
