//! Patches: every primitive cut into cells of about the target size.
//!
//! Patches are plain columns indexed by a global patch id (struct of arrays).
//! Each primitive's patches are contiguous, numbered by the cells of its
//! [`PatchGrid`]; its grid vertices are contiguous too and shared by
//! neighbouring patches, so radiance can be interpolated smoothly (§3.5).
//! Adjacency (patches sharing an edge) is a CSR table, for the buckets of §3.4.
//!
//! Adjacency also crosses the edges between coplanar primitives of one
//! surface (the four quads of the Cornell ceiling), where a cell's boundary
//! edge overlaps another's over a positive length; it never crosses a crease,
//! where spreading light would be wrong.

mod coplanar;
pub mod mesh;
pub mod order;

use crate::geometry::grid::{CellOrder, NO_VERTEX, PatchGrid};
use glam::Vec3;
use mesh::UNGROUPED;

use crate::geometry::{Primitive, PrimitiveKind};

/// Most patches a build may make (ids are `u32`; the rest is headroom).
pub const MAX_PATCHES: u64 = 1 << 30;
/// Most cells along one edge of a primitive (the archive's limit, §5.5).
pub const MAX_GRID: u32 = 1 << 16;

/// How builds number a quad's patches unless told otherwise: in tiles,
/// whose locality the distribution's gathers use (docs/notebook/2026-12-02-format-7.md).
pub const DEFAULT_CELL_ORDER: CellOrder = CellOrder::Tiles;

/// Where one primitive's patches and vertices start.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PrimitivePatches {
    /// The primitive's grid.
    pub grid: PatchGrid,
    /// Global id of its first patch.
    pub first_patch: u32,
    /// Global id of its first grid vertex; for a grouped triangle, its
    /// row in [`Patches::mesh_triangles`].
    pub first_vertex: u32,
    /// Whether it keeps its own grid or is a triangle of a group.
    pub role: PatchRole,
}

/// How a primitive's patches are made.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PatchRole {
    /// Its own grid of cells, each a patch.
    Grid,
    /// A small triangle that starts a patch of several (`mesh`): its one
    /// cell is the patch `first_patch`.
    Opens,
    /// A small triangle of the patch the previous primitive belongs to.
    Joins,
}

impl PrimitivePatches {
    /// Whether it is a triangle of a group (the archive's kind 2).
    pub fn grouped(&self) -> bool {
        self.role != PatchRole::Grid
    }

    /// Patches it adds: its cells, one for a group's first triangle, none
    /// for the others.
    pub fn owned_patches(&self) -> u32 {
        match self.role {
            PatchRole::Grid => self.grid.cell_count(),
            PatchRole::Opens => 1,
            PatchRole::Joins => 0,
        }
    }
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
    /// Vertex positions (m): the grids' vertices, then the corners of the
    /// grouped triangles (shared by the triangles of one mesh).
    pub vertex_position: Vec<[f32; 3]>,
    /// Per grouped triangle, in primitive order: its corners' vertex ids.
    pub mesh_triangles: Vec<[u32; 3]>,
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
pub fn grid_for(p: &Primitive, size: f32, order: CellOrder) -> PatchGrid {
    match p.kind {
        PrimitiveKind::Quad => {
            let lu = (p.p[1] - p.p[0]).length().max((p.p[2] - p.p[3]).length());
            let lv = (p.p[3] - p.p[0]).length().max((p.p[2] - p.p[1]).length());
            PatchGrid { kind: p.kind, n_u: cells(lu, size), n_v: cells(lv, size), order }
        }
        PrimitiveKind::Triangle => {
            let l = (p.p[1] - p.p[0]).length().max((p.p[2] - p.p[0]).length()).max((p.p[2] - p.p[1]).length());
            let k = cells(l, size);
            PatchGrid { kind: p.kind, n_u: k, n_v: k, order: CellOrder::Rows }
        }
    }
}

/// Each primitive's grid at patch size `size` (quads' cells numbered in
/// `order`; a grouped triangle, per `triangle_group`, is a single cell),
/// refused when a primitive would have more than [`MAX_GRID`] cells along
/// an edge or the patches would be more than [`MAX_PATCHES`].
fn checked_grids(
    primitives: &[Primitive],
    triangle_group: &[u32],
    size: f32,
    order: CellOrder,
) -> Result<Vec<PatchGrid>, String> {
    let grouped = |i: usize| triangle_group[i] != UNGROUPED;
    let grids: Vec<PatchGrid> = primitives
        .iter()
        .enumerate()
        .map(|(i, p)| match grouped(i) {
            true => PatchGrid { kind: p.kind, n_u: 1, n_v: 1, order: CellOrder::Rows },
            false => grid_for(p, size, order),
        })
        .collect();
    // Per-axis cell counts saturate at u32::MAX; bound them before any u32 product.
    if let Some(g) = grids.iter().find(|g| g.n_u > MAX_GRID || g.n_v > MAX_GRID) {
        return Err(format!(
            "patch size {size} m cuts a primitive into {}×{} cells, more than {MAX_GRID} along an edge",
            g.n_u, g.n_v
        ));
    }
    // In u64: 2¹⁶ × 2¹⁶ cells overflow a u32.
    let total: u64 = grids.iter().enumerate().filter(|(i, _)| !grouped(*i)).map(|(_, g)| cells_u64(g)).sum();
    if total > MAX_PATCHES {
        return Err(format!("patch size {size} m gives {total} patches, more than the {MAX_PATCHES} supported"));
    }
    Ok(grids)
}

/// A grid's cells, in u64 (its `cell_count` is a u32 product).
fn cells_u64(g: &PatchGrid) -> u64 {
    match g.kind {
        PrimitiveKind::Quad => g.n_u as u64 * g.n_v as u64,
        PrimitiveKind::Triangle => g.n_u as u64 * g.n_u as u64,
    }
}

/// What cutting a scene's primitives makes, counted from their grids
/// before any patch is made: a build refuses a cut its memory budget
/// cannot hold before cutting it (issue 42 §4), where the cut itself had
/// grown until the allocator aborted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CutSize {
    /// Patches: every grid's cells and one per group of small triangles.
    pub patches: u64,
    /// Vertices: every grid's, and at most three per grouped triangle.
    pub vertices: u64,
}

/// The patches and vertices [`Patches::with_groups`] would make of the
/// same arguments (vertices at most), or its refusal of the grids; in
/// time and memory linear in the primitives, whatever the patch size.
pub fn cut_size(
    primitives: &[Primitive],
    group_of: &[u32],
    triangle_group: &[u32],
    size: f32,
    order: CellOrder,
) -> Result<CutSize, String> {
    let grids = checked_grids(primitives, triangle_group, size, order)?;
    let mut cut = CutSize { patches: 0, vertices: 0 };
    for (pi, g) in grids.iter().enumerate() {
        if triangle_group[pi] == UNGROUPED {
            let n = g.n_u as u64 + 1;
            cut.patches += cells_u64(g);
            cut.vertices += match g.kind {
                PrimitiveKind::Quad => n * (g.n_v as u64 + 1),
                PrimitiveKind::Triangle => n * (n + 1) / 2,
            };
        } else {
            // As push_grouped_triangle: a patch for each triangle that opens a group.
            let joins = pi > 0 && triangle_group[pi - 1] == triangle_group[pi] && group_of[pi - 1] == group_of[pi];
            cut.patches += u64::from(!joins);
            cut.vertices += 3;
        }
    }
    Ok(cut)
}

impl Patches {
    /// Cuts `primitives` into patches of about `size` metres. Adjacency
    /// crosses the edges between coplanar primitives with the same
    /// `group_of` value (the same surface, or the same temporal instance).
    /// Quads' cells are numbered in `order`.
    pub fn new(primitives: &[Primitive], group_of: &[u32], size: f32, order: CellOrder) -> Result<Self, String> {
        Self::with_groups(primitives, group_of, &vec![UNGROUPED; primitives.len()], size, order)
    }

    /// As [`Self::new`], with small triangles grouped into patches:
    /// `triangle_group[i]` is primitive i's group ([`mesh::group_triangles`],
    /// numbered apart per instance) or [`UNGROUPED`]. A group's triangles
    /// are consecutive primitives of one `group_of`; each group is one
    /// patch, and its triangles' corners are vertices shared across the
    /// mesh, welded by position within a `group_of`.
    pub fn with_groups(
        primitives: &[Primitive],
        group_of: &[u32],
        triangle_group: &[u32],
        size: f32,
        order: CellOrder,
    ) -> Result<Self, String> {
        let grids = checked_grids(primitives, triangle_group, size, order)?;
        let mut out = Patches::default();
        for (pi, (prim, grid)) in primitives.iter().zip(&grids).enumerate() {
            if triangle_group[pi] != UNGROUPED {
                out.push_grouped_triangle(pi, *grid, group_of, triangle_group);
            } else {
                out.push_grid(pi, prim, *grid);
            }
        }
        out.shape_groups(primitives);
        out.weld_mesh_corners(primitives, group_of);
        out.link_adjacency(primitives, group_of);
        Ok(out)
    }

    /// Adds grouped triangle `pi` (of grid `grid`, a single cell): a new
    /// patch when it opens its group, none when it joins the previous
    /// primitive's (the same `triangle_group` and `group_of`). The patch's
    /// shape ([`Self::shape_groups`]) and the triangle's corners
    /// ([`Self::weld_mesh_corners`]) are filled in once every triangle is
    /// added.
    fn push_grouped_triangle(&mut self, pi: usize, grid: PatchGrid, group_of: &[u32], triangle_group: &[u32]) {
        let joins = pi > 0 && triangle_group[pi - 1] == triangle_group[pi] && group_of[pi - 1] == group_of[pi];
        let role = if joins { PatchRole::Joins } else { PatchRole::Opens };
        if role == PatchRole::Opens {
            // Shape filled in below, from all the group's triangles.
            self.centre.push([0.0; 3]);
            self.normal.push([0.0; 3]);
            self.area.push(0.0);
            self.primitive.push(pi as u32);
            self.corners.push([NO_VERTEX; 4]);
        }
        self.primitives.push(PrimitivePatches {
            grid,
            first_patch: self.area.len() as u32 - 1,
            first_vertex: self.mesh_triangles.len() as u32,
            role,
        });
        // Corners welded below, once the groups' normals are known.
        self.mesh_triangles.push([NO_VERTEX; 3]);
    }

    /// Adds primitive `pi`'s own grid of patches: its vertices, and a patch
    /// per cell with its centre, normal, area and corners.
    fn push_grid(&mut self, pi: usize, prim: &Primitive, grid: PatchGrid) {
        let first_patch = self.area.len() as u32;
        let first_vertex = self.vertex_position.len() as u32;
        self.primitives.push(PrimitivePatches { grid, first_patch, first_vertex, role: PatchRole::Grid });
        for v in 0..grid.vertex_count() {
            self.vertex_position.push(prim.point(grid.vertex_uv(v)).to_array());
        }
        let normal = prim.normal().to_array();
        for cell in 0..grid.cell_count() {
            let local = grid.cell_corners(cell);
            let uv: Vec<_> = local.iter().filter(|&&c| c != NO_VERTEX).map(|&c| grid.vertex_uv(c)).collect();
            let pts: Vec<_> = uv.iter().map(|&t| prim.point(t)).collect();
            let (area, centre) = if pts.len() == 4 {
                // Cells of a planar quad are planar quads with straight edges.
                let a = 0.5 * (pts[2] - pts[0]).cross(pts[3] - pts[1]).length();
                (a, prim.point((uv[0] + uv[2]) * 0.5))
            } else {
                let a = 0.5 * (pts[1] - pts[0]).cross(pts[2] - pts[0]).length();
                (a, (pts[0] + pts[1] + pts[2]) / 3.0)
            };
            self.centre.push(centre.to_array());
            self.normal.push(normal);
            self.area.push(area);
            self.primitive.push(pi as u32);
            self.corners.push(local.map(|c| if c == NO_VERTEX { NO_VERTEX } else { first_vertex + c }));
        }
    }

    /// Fills in each group's patch: the area-weighted centre, normal and
    /// area of its triangles ([`mesh::group_shape`]).
    fn shape_groups(&mut self, primitives: &[Primitive]) {
        let mut pi = 0;
        while pi < primitives.len() {
            let pp = self.primitives[pi];
            let end = pi + 1 + self.primitives[pi + 1..].iter().take_while(|q| q.role == PatchRole::Joins).count();
            if pp.role == PatchRole::Opens {
                let (c, n, a) = mesh::group_shape(primitives[pi..end].iter().copied());
                let p = pp.first_patch as usize;
                (self.centre[p], self.normal[p], self.area[p]) = (c.to_array(), n.to_array(), a);
            }
            pi = end;
        }
    }

    /// Grouped triangles' corners: one vertex per point of a mesh and
    /// side of a crease, numbered after the grids' vertices. Triangles
    /// share a corner's vertex when their groups' normals are within
    /// 45° of the group that made it, so light is interpolated across
    /// the mesh but never round a fold (the two faces of an ear).
    fn weld_mesh_corners(&mut self, primitives: &[Primitive], group_of: &[u32]) {
        // Grouped triangles' corners, welded per `group_of`, numbered after the grids' vertices.
        let mut point_vertex: std::collections::HashMap<[u32; 3], u32> = Default::default();
        let mut mesh_position: Vec<[f32; 3]> = Vec::new();
        // Per point, its first vertex; per vertex, the normal of the group
        // that made it and the next vertex at the same point (a chain, one
        // link per side of a crease). Points are welded within an
        // instance, whose grouped triangles are consecutive, so the map
        // holds one mesh at a time.
        let grid_vertices = self.vertex_position.len() as u32;
        let mut side_normal: Vec<Vec3> = Vec::new();
        let mut side_next: Vec<u32> = Vec::new();
        let mut instance = u32::MAX;
        for (pi, pp) in self.primitives.iter().enumerate().filter(|(_, pp)| pp.grouped()) {
            if group_of[pi] != instance {
                instance = group_of[pi];
                point_vertex.clear();
            }
            let n = Vec3::from(self.normal[pp.first_patch as usize]);
            self.mesh_triangles[pp.first_vertex as usize] = [0, 1, 2].map(|k| {
                let p = primitives[pi].p[k];
                let new = mesh_position.len() as u32;
                let mut at = *point_vertex.entry(mesh::position_key(p)).or_insert(new);
                while at != new {
                    if side_normal[at as usize].dot(n) >= mesh::ADJACENT_COS {
                        return grid_vertices + at;
                    }
                    if side_next[at as usize] == NO_VERTEX {
                        side_next[at as usize] = new;
                    }
                    at = side_next[at as usize];
                }
                mesh_position.push(p.to_array());
                side_normal.push(n);
                side_next.push(NO_VERTEX);
                grid_vertices + new
            });
        }
        self.vertex_position.extend_from_slice(&mesh_position);
    }

    /// Adjacency: within each grid, across coplanar primitive edges (of
    /// one `group_of`), and across the edges groups share where they do
    /// not fold; as CSR, each patch's neighbours ascending.
    fn link_adjacency(&mut self, primitives: &[Primitive], group_of: &[u32]) {
        let mut nb = Vec::new();
        let mut lists: Vec<Vec<u32>> = Vec::with_capacity(self.len());
        for pp in self.primitives.iter().filter(|pp| !pp.grouped()) {
            for cell in 0..pp.grid.cell_count() {
                pp.grid.cell_neighbours(cell, &mut nb);
                lists.resize(pp.first_patch as usize + cell as usize, Vec::new());
                lists.push(nb.iter().map(|&c| pp.first_patch + c).collect());
            }
        }
        lists.resize(self.len(), Vec::new());
        for (a, b) in coplanar::neighbours(primitives, group_of, self).0 {
            lists[a as usize].push(b);
            lists[b as usize].push(a);
        }
        for (a, b) in self.group_neighbours() {
            lists[a as usize].push(b);
            lists[b as usize].push(a);
        }
        self.adjacency_offsets.push(0);
        for l in &mut lists {
            l.sort_unstable();
            l.dedup();
            self.adjacency.extend_from_slice(l);
            self.adjacency_offsets.push(self.adjacency.len() as u32);
        }
    }

    /// Pairs of groups whose triangles share an edge and whose normals
    /// differ by less than 45° ([`mesh::ADJACENT_COS`]).
    fn group_neighbours(&self) -> Vec<(u32, u32)> {
        let mut pairs = Vec::new();
        let mut edges: Vec<(u64, u32)> = Vec::new();
        // A mesh's grouped triangles are consecutive: one run at a time.
        for run in self.primitives.chunk_by(|a, b| a.grouped() == b.grouped()).filter(|r| r[0].grouped()) {
            edges.clear();
            for pp in run {
                let c = self.mesh_triangles[pp.first_vertex as usize];
                for k in 0..3 {
                    let (a, b) = (c[k].min(c[(k + 1) % 3]), c[k].max(c[(k + 1) % 3]));
                    edges.push((((a as u64) << 32) | b as u64, pp.first_patch));
                }
            }
            edges.sort_unstable();
            edges.dedup();
            for shared in edges.chunk_by(|a, b| a.0 == b.0) {
                for (x, &(_, a)) in shared.iter().enumerate() {
                    for &(_, b) in &shared[x + 1..] {
                        let (na, nb) = (Vec3::from(self.normal[a as usize]), Vec3::from(self.normal[b as usize]));
                        if na.dot(nb) >= mesh::ADJACENT_COS {
                            pairs.push((a, b));
                        }
                    }
                }
            }
        }
        pairs
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
        let surfaces: Vec<u32> = scene.primitives().map(|(s, _)| s).collect();
        let patches = Patches::new(&prims, &surfaces, 0.02, DEFAULT_CELL_ORDER).unwrap();
        for (i, (prim, pp)) in prims.iter().zip(&patches.primitives).enumerate() {
            let n = pp.grid.cell_count() as usize;
            let s: f64 = patches.area[pp.first_patch as usize..][..n].iter().map(|&a| a as f64).sum();
            assert!(
                (s - prim.area() as f64).abs() < 1e-6 * prim.area() as f64 + 1e-9,
                "primitive {i}: {s} vs {}",
                prim.area()
            );
        }
        let tri = Primitive::triangle(Vec3::ZERO, Vec3::new(1.0, 0.0, 0.0), Vec3::new(0.0, 0.0, -1.0));
        let p = Patches::new(&[tri], &[0], 0.1, DEFAULT_CELL_ORDER).unwrap();
        assert_eq!(p.len(), 14 * 14, "k = round(hypotenuse / size)");
        let s: f32 = p.area.iter().sum();
        assert!((s - 0.5).abs() < 1e-5);
        // Every interior quad patch has four neighbours, CSR is consistent.
        assert_eq!(*patches.adjacency_offsets.last().unwrap() as usize, patches.adjacency.len());
    }
}
