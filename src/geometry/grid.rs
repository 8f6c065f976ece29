//! Patch grids: how a primitive's surface coordinates name patches and
//! patch vertices.
//!
//! A quad is cut into `n_u × n_v` bilinear cells; cell `(i, j)` is local patch
//! `j·n_u + i` and its corners are grid vertices `(i, j) (i+1, j) (i+1, j+1)
//! (i, j+1)`, vertex `(i, j)` having local index `j·(n_u+1) + i`.
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

/// The patch grid of one primitive.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PatchGrid {
    /// Quad (bilinear cells) or triangle (sub-triangles).
    pub kind: PrimitiveKind,
    /// Cells along `u` (for triangles, the subdivision `k`).
    pub n_u: u32,
    /// Cells along `v` (for triangles, equal to `n_u`).
    pub n_v: u32,
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
                let (i, j) = (cell % self.n_u, cell / self.n_u);
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

    /// The cell containing surface point `uv` and the corner weights that
    /// interpolate vertex values there (bilinear for quads, barycentric for
    /// triangles).
    #[inline]
    pub fn locate(&self, uv: Vec2) -> CellLocation {
        match self.kind {
            PrimitiveKind::Quad => {
                let a = (uv.x.clamp(0.0, 1.0)) * self.n_u as f32;
                let b = (uv.y.clamp(0.0, 1.0)) * self.n_v as f32;
                let i = (a as u32).min(self.n_u - 1);
                let j = (b as u32).min(self.n_v - 1);
                let (s, t) = (a - i as f32, b - j as f32);
                let cell = j * self.n_u + i;
                CellLocation {
                    cell,
                    corners: self.cell_corners(cell),
                    weights: [(1.0 - s) * (1.0 - t), s * (1.0 - t), s * t, (1.0 - s) * t],
                }
            }
            PrimitiveKind::Triangle => {
                let k = self.n_u;
                let a = uv.x.max(0.0) * k as f32;
                let b = uv.y.max(0.0) * k as f32;
                let j = (b as u32).min(k - 1);
                let i = (a as u32).min(k - 1 - j);
                let (mut fa, mut fb) = (a - i as f32, b - j as f32);
                // Points past the hypotenuse after rounding belong to the last
                // upright cell of the row: pull them back onto its edge.
                let upright = fa + fb <= 1.0 || i + j + 1 >= k;
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
                let (i, j) = (cell % self.n_u, cell / self.n_u);
                if j > 0 {
                    out.push(cell - self.n_u);
                }
                if i > 0 {
                    out.push(cell - 1);
                }
                if i + 1 < self.n_u {
                    out.push(cell + 1);
                }
                if j + 1 < self.n_v {
                    out.push(cell + self.n_u);
                }
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
            let g = PatchGrid { kind: PrimitiveKind::Triangle, n_u: k, n_v: k };
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
    fn quad_grid_cells_and_neighbours() {
        let g = PatchGrid { kind: PrimitiveKind::Quad, n_u: 3, n_v: 2 };
        assert_eq!(g.cell_count(), 6);
        assert_eq!(g.vertex_count(), 12);
        let loc = g.locate(Vec2::new(0.5, 0.75));
        assert_eq!(loc.cell, 4);
        let mut n = Vec::new();
        g.cell_neighbours(4, &mut n);
        assert_eq!(n, vec![1, 3, 5]);
        let tg = PatchGrid { kind: PrimitiveKind::Triangle, n_u: 2, n_v: 2 };
        tg.cell_neighbours(1, &mut n);
        assert_eq!(n.len(), 3, "the inverted middle cell touches all three");
    }
}
