//! Patches: every primitive cut into cells of about the target size.
//!
//! Patches are plain columns indexed by a global patch id (struct of arrays).
//! Each primitive's patches are contiguous, numbered by its
//! [`PatchGrid`](crate::geometry::grid::PatchGrid); its grid vertices are
//! contiguous too and shared by neighbouring patches, so radiance can be
//! interpolated smoothly (§3.5). Adjacency (patches sharing an edge within a
//! primitive) is a CSR table, for the buckets of §3.4.
//!
//! Adjacency does not yet cross primitive edges (e.g. between two coplanar
//! quads of one wall): the bucket work extends it.

use crate::geometry::grid::{NO_VERTEX, PatchGrid};
use crate::geometry::{Primitive, PrimitiveKind};

/// Most patches a build may make (ids are `u32`; the rest is headroom).
pub const MAX_PATCHES: u64 = 1 << 30;

/// Where one primitive's patches and vertices start.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PrimitivePatches {
    /// The primitive's grid.
    pub grid: PatchGrid,
    /// Global id of its first patch.
    pub first_patch: u32,
    /// Global id of its first grid vertex.
    pub first_vertex: u32,
}

/// All patches of a scene, as columns.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Patches {
    /// One entry per primitive, in primitive order.
    pub primitives: Vec<PrimitivePatches>,
    /// Patch centre (m).
    pub centre: Vec<[f32; 3]>,
    /// Unit front normal.
    pub normal: Vec<[f32; 3]>,
    /// Area (m²).
    pub area: Vec<f32>,
    /// Index of the primitive the patch belongs to.
    pub primitive: Vec<u32>,
    /// Global vertex ids of the corners, counter-clockwise; `u32::MAX` marks
    /// the unused fourth corner of a triangular patch.
    pub corners: Vec<[u32; 4]>,
    /// Vertex positions (m).
    pub vertex_position: Vec<[f32; 3]>,
    /// CSR offsets into [`Self::adjacency`], one per patch plus one.
    pub adjacency_offsets: Vec<u32>,
    /// Edge-adjacent patches of each patch, ascending.
    pub adjacency: Vec<u32>,
}

/// Cells along an edge of length `len` for a target size.
fn cells(len: f32, size: f32) -> u32 {
    ((len / size).round() as u32).max(1)
}

/// The grid a primitive gets for a target patch size (m).
pub fn grid_for(p: &Primitive, size: f32) -> PatchGrid {
    match p.kind {
        PrimitiveKind::Quad => {
            let lu = (p.p[1] - p.p[0]).length().max((p.p[2] - p.p[3]).length());
            let lv = (p.p[3] - p.p[0]).length().max((p.p[2] - p.p[1]).length());
            PatchGrid {
                kind: p.kind,
                n_u: cells(lu, size),
                n_v: cells(lv, size),
            }
        }
        PrimitiveKind::Triangle => {
            let l = (p.p[1] - p.p[0])
                .length()
                .max((p.p[2] - p.p[0]).length())
                .max((p.p[2] - p.p[1]).length());
            let k = cells(l, size);
            PatchGrid {
                kind: p.kind,
                n_u: k,
                n_v: k,
            }
        }
    }
}

impl Patches {
    /// Cuts `primitives` into patches of about `size` metres.
    pub fn new(primitives: &[Primitive], size: f32) -> Result<Self, String> {
        let grids: Vec<PatchGrid> = primitives.iter().map(|p| grid_for(p, size)).collect();
        let total: u64 = grids.iter().map(|g| g.cell_count() as u64).sum();
        if total > MAX_PATCHES {
            return Err(format!(
                "patch size {size} m gives {total} patches, more than the {MAX_PATCHES} supported"
            ));
        }
        let mut out = Patches::default();
        let mut nb = Vec::new();
        for (pi, (prim, grid)) in primitives.iter().zip(&grids).enumerate() {
            let first_patch = out.area.len() as u32;
            let first_vertex = out.vertex_position.len() as u32;
            out.primitives.push(PrimitivePatches {
                grid: *grid,
                first_patch,
                first_vertex,
            });
            for v in 0..grid.vertex_count() {
                out.vertex_position
                    .push(prim.point(grid.vertex_uv(v)).to_array());
            }
            let normal = prim.normal().to_array();
            for cell in 0..grid.cell_count() {
                let local = grid.cell_corners(cell);
                let uv: Vec<_> = local
                    .iter()
                    .filter(|&&c| c != NO_VERTEX)
                    .map(|&c| grid.vertex_uv(c))
                    .collect();
                let pts: Vec<_> = uv.iter().map(|&t| prim.point(t)).collect();
                let (area, centre) = if pts.len() == 4 {
                    // Cells of a planar quad are planar quads with straight edges.
                    let a = 0.5 * (pts[2] - pts[0]).cross(pts[3] - pts[1]).length();
                    (a, prim.point((uv[0] + uv[2]) * 0.5))
                } else {
                    let a = 0.5 * (pts[1] - pts[0]).cross(pts[2] - pts[0]).length();
                    (a, (pts[0] + pts[1] + pts[2]) / 3.0)
                };
                out.centre.push(centre.to_array());
                out.normal.push(normal);
                out.area.push(area);
                out.primitive.push(pi as u32);
                out.corners.push(local.map(|c| {
                    if c == NO_VERTEX {
                        NO_VERTEX
                    } else {
                        first_vertex + c
                    }
                }));
            }
        }
        // Adjacency, CSR.
        out.adjacency_offsets.push(0);
        for pp in &out.primitives {
            for cell in 0..pp.grid.cell_count() {
                pp.grid.cell_neighbours(cell, &mut nb);
                out.adjacency.extend(nb.iter().map(|&c| pp.first_patch + c));
                out.adjacency_offsets.push(out.adjacency.len() as u32);
            }
        }
        Ok(out)
    }

    /// Number of patches.
    pub fn len(&self) -> usize {
        self.area.len()
    }

    /// True when there are no patches.
    pub fn is_empty(&self) -> bool {
        self.area.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn patch_areas_sum_to_surface_areas() {
        let scene = crate::scene::Scene::cornell_box();
        let prims: Vec<Primitive> = scene.primitives().map(|(_, p)| *p).collect();
        let patches = Patches::new(&prims, 0.02).unwrap();
        for (i, (prim, pp)) in prims.iter().zip(&patches.primitives).enumerate() {
            let n = pp.grid.cell_count() as usize;
            let s: f64 = patches.area[pp.first_patch as usize..][..n]
                .iter()
                .map(|&a| a as f64)
                .sum();
            assert!(
                (s - prim.area() as f64).abs() < 1e-6 * prim.area() as f64 + 1e-9,
                "primitive {i}: {s} vs {}",
                prim.area()
            );
        }
        let tri = Primitive::triangle(
            Vec3::ZERO,
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 0.0, -1.0),
        );
        let p = Patches::new(&[tri], 0.1).unwrap();
        assert_eq!(p.len(), 14 * 14, "k = round(hypotenuse / size)");
        let s: f32 = p.area.iter().sum();
        assert!((s - 0.5).abs() < 1e-5);
        // Every interior quad patch has four neighbours, CSR is consistent.
        assert_eq!(
            *patches.adjacency_offsets.last().unwrap() as usize,
            patches.adjacency.len()
        );
    }
}
