//! A mesh primitive's triangles in world space.
//!
//! Exporters split every quad into two triangles; two consecutive
//! triangles `(a, b, c)`, `(c, d, a)` that share the diagonal and make a
//! planar convex quad become that quad again, so a box exported by any tool
//! is cut into the same patch grid as the box written in TOML (a quad is one
//! primitive with a regular grid of patches; two triangles are two).

use std::collections::HashMap;
use std::path::Path;

use glam::{Mat4, Vec2, Vec3};
use gltf::mesh::Mode;

use crate::geometry::{Primitive, PrimitiveKind};
use crate::scene::SceneError;
use crate::scene::check::check_primitive;
use crate::scene::error::error;
use crate::scene::import::{Notes, merge_quads_indexed};

/// One source triangle's shading frame and texture coordinates.
#[derive(Clone, Copy)]
pub(super) struct Corner {
    /// World-space area (m²).
    pub(super) area: f32,
    /// Unit world-space tangent (+u) and bitangent, when the mesh has
    /// `TANGENT`s or texture coordinates; zero otherwise.
    pub(super) tangent: Vec3,
    pub(super) bitangent: Vec3,
}

/// The triangles of one mesh primitive placed by one node.
pub(super) struct Triangles {
    /// Quads (merged pairs) and triangles, front faces as the file winds them.
    pub(super) primitives: Vec<Primitive>,
    /// Per source triangle: area and tangent frame.
    pub(super) corners: Vec<Corner>,
    /// Per source triangle, texture coordinates of sets 0 and 1 (when present).
    pub(super) uvs: [Option<Vec<[Vec2; 3]>>; 2],
    /// Per primitive, its corners' vertex indices (a triangle repeats corner 2).
    pub(super) vertices: Vec<[u32; 4]>,
    /// Per vertex, texture coordinates of sets 0 and 1 (when present).
    pub(super) vertex_uv: [Option<Vec<Vec2>>; 2],
    /// Per vertex, its unit world-space normal (`NORMAL`, when present).
    pub(super) vertex_normal: Option<Vec<Vec3>>,
    /// Every edge is shared by exactly two triangles: no back face can be seen.
    pub(super) closed: bool,
    /// Zero-area or non-finite triangles left out.
    pub(super) degenerate: usize,
}

/// `p` with its front and back swapped.
pub(super) fn flipped(p: &Primitive) -> Primitive {
    match p.kind {
        PrimitiveKind::Quad => Primitive::quad([p.p[3], p.p[2], p.p[1], p.p[0]]),
        PrimitiveKind::Triangle => Primitive::triangle(p.p[0], p.p[2], p.p[1]),
    }
}

/// Reads `prim` placed by `world`; degenerate triangles are left out and
/// counted.
pub(super) fn read(
    path: &Path,
    at: &str,
    prim: &gltf::Primitive<'_>,
    buffers: &[gltf::buffer::Data],
    world: Mat4,
    notes: &mut Notes,
) -> Result<Triangles, SceneError> {
    let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
    let empty = || Triangles {
        primitives: Vec::new(),
        corners: Vec::new(),
        uvs: [None, None],
        vertices: Vec::new(),
        vertex_uv: [None, None],
        vertex_normal: None,
        closed: true,
        degenerate: 0,
    };
    match prim.mode() {
        Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan => {}
        other => {
            notes.add(format!("{other:?} primitives (points or lines) are not surfaces and were left out"));
            return Ok(empty());
        }
    }
    check_attributes(path, prim)?;
    let positions: Vec<Vec3> = reader
        .read_positions()
        .ok_or_else(|| error(path, format!("{at}/attributes/POSITION"), "the primitive has no readable positions"))?
        .map(|p| world.transform_point3(Vec3::from(p)))
        .collect();
    let indices: Vec<u32> = match reader.read_indices() {
        Some(i) => i.into_u32().collect(),
        None => (0..positions.len() as u32).collect(),
    };
    if let Some(bad) = indices.iter().find(|&&i| i as usize >= positions.len()) {
        return Err(error(
            path,
            format!("{at}/indices"),
            format!("index {bad} is out of range ({} vertices)", positions.len()),
        ));
    }
    let tri = triangle_indices(prim.mode(), &indices);
    let mirrored = world.determinant() < 0.0;
    let uv_sets: [Option<Vec<Vec2>>; 2] =
        [0, 1].map(|set| reader.read_tex_coords(set).map(|t| t.into_f32().map(Vec2::from).collect()));
    for (set, uv) in uv_sets.iter().enumerate() {
        if uv.as_ref().is_some_and(|u| u.len() != positions.len()) {
            return Err(error(path, format!("{at}/attributes/TEXCOORD_{set}"), "not one coordinate per vertex"));
        }
    }
    // Normals transform by the inverse transpose (which also keeps them
    // on the front of a mirrored, re-wound triangle).
    let normal_matrix = glam::Mat3::from_mat4(world).inverse().transpose();
    let vertex_normal: Option<Vec<Vec3>> =
        reader.read_normals().map(|n| n.map(|n| (normal_matrix * Vec3::from(n)).normalize_or_zero()).collect());
    if vertex_normal.as_ref().is_some_and(|n| n.len() != positions.len()) {
        return Err(error(path, format!("{at}/attributes/NORMAL"), "not one normal per vertex"));
    }
    let tangents: Option<Vec<[f32; 4]>> = reader.read_tangents().map(|t| t.collect());
    if tangents.as_ref().is_some_and(|t| t.len() != positions.len()) {
        return Err(error(path, format!("{at}/attributes/TANGENT"), "not one tangent per vertex"));
    }

    let (kept, degenerate) = kept_triangles(&positions, tri, mirrored);
    let corners = corners_of(&positions, &kept, tangents.as_deref(), uv_sets[0].as_deref(), world);
    let uvs = uv_sets.clone().map(|u| u.map(|uv| kept.iter().map(|t| t.map(|i| uv[i as usize])).collect()));
    let closed = prim.material().double_sided() && is_closed(&positions, &kept);
    let (primitives, vertices) = merge_quads_indexed(&positions, &kept);
    Ok(Triangles { primitives, corners, uvs, vertices, vertex_uv: uv_sets, vertex_normal, closed, degenerate })
}

/// Checks the component types and shapes of `prim`'s accessors before any
/// is read.
fn check_attributes(path: &Path, prim: &gltf::Primitive<'_>) -> Result<(), SceneError> {
    use gltf::Semantic;
    use gltf::accessor::{DataType::*, Dimensions};
    let check = super::load::check_accessor;
    if let Some(a) = prim.get(&Semantic::Positions) {
        check(path, &a, &[F32], Dimensions::Vec3, "POSITION")?;
    }
    if let Some(a) = prim.indices() {
        check(path, &a, &[U8, U16, U32], Dimensions::Scalar, "indices")?;
    }
    for set in 0..2 {
        if let Some(a) = prim.get(&Semantic::TexCoords(set)) {
            check(path, &a, &[F32, U8, U16], Dimensions::Vec2, "TEXCOORD")?;
        }
    }
    if let Some(a) = prim.get(&Semantic::Tangents) {
        check(path, &a, &[F32], Dimensions::Vec4, "TANGENT")?;
    }
    if let Some(a) = prim.get(&Semantic::Normals) {
        check(path, &a, &[F32], Dimensions::Vec3, "NORMAL")?;
    }
    Ok(())
}

/// The triangles of `indices` in `mode` (a list, strip or fan), as the
/// file winds them.
fn triangle_indices(mode: Mode, indices: &[u32]) -> Vec<[u32; 3]> {
    match mode {
        Mode::TriangleStrip => (0..indices.len().saturating_sub(2))
            .map(|i| {
                let o = i % 2;
                [indices[i], indices[i + 1 + o], indices[i + 2 - o]]
            })
            .collect(),
        Mode::TriangleFan => {
            (1..indices.len().saturating_sub(1)).map(|i| [indices[i], indices[i + 1], indices[0]]).collect()
        }
        _ => indices.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
    }
}

/// The triangles of `tri` that pass [`check_primitive`] (re-wound when
/// `mirrored`, so that they face front), and how many did not.
fn kept_triangles(positions: &[Vec3], tri: Vec<[u32; 3]>, mirrored: bool) -> (Vec<[u32; 3]>, usize) {
    let mut kept: Vec<[u32; 3]> = Vec::with_capacity(tri.len());
    let mut degenerate = 0usize;
    for t in tri {
        let t = if mirrored { [t[0], t[2], t[1]] } else { t };
        let p = Primitive::triangle(positions[t[0] as usize], positions[t[1] as usize], positions[t[2] as usize]);
        if check_primitive(&p).is_ok() {
            kept.push(t);
        } else {
            degenerate += 1;
        }
    }
    (kept, degenerate)
}

/// Per triangle of `kept`, its area and tangent frame: from `TANGENT`s
/// (placed by `world`), else from the +u direction of texture set 0,
/// else none.
fn corners_of(
    positions: &[Vec3],
    kept: &[[u32; 3]],
    tangents: Option<&[[f32; 4]]>,
    uv0: Option<&[Vec2]>,
    world: Mat4,
) -> Vec<Corner> {
    let mirrored = world.determinant() < 0.0;
    kept.iter()
        .map(|t| {
            let p = t.map(|i| positions[i as usize]);
            let normal = (p[1] - p[0]).cross(p[2] - p[0]);
            let area = normal.length() / 2.0;
            let n = normal.normalize_or_zero();
            let (tangent, sign) = if let Some(tg) = tangents {
                let s: Vec3 = t.iter().map(|&i| Vec3::from_slice(&tg[i as usize][..3])).sum();
                let w = tg[t[0] as usize][3];
                (world.transform_vector3(s), if w < 0.0 { -1.0 } else { 1.0 })
            } else if let Some(uv) = uv0 {
                let q = t.map(|i| uv[i as usize]);
                let (d1, d2) = (q[1] - q[0], q[2] - q[0]);
                let det = d1.x * d2.y - d2.x * d1.y;
                let tg = ((p[1] - p[0]) * d2.y - (p[2] - p[0]) * d1.y) * det.signum();
                (tg, if mirrored { -1.0 } else { 1.0 })
            } else {
                (Vec3::ZERO, 1.0)
            };
            let tangent = (tangent - n * tangent.dot(n)).normalize_or_zero();
            let bitangent = if tangent == Vec3::ZERO { Vec3::ZERO } else { n.cross(tangent) * sign };
            Corner { area, tangent, bitangent }
        })
        .collect()
}

/// Whether every edge of `tri` is shared by exactly two triangles, vertices
/// welded by position (exporters split vertices where normals or texture
/// coordinates differ).
fn is_closed(pos: &[Vec3], tri: &[[u32; 3]]) -> bool {
    let mut ids: HashMap<[u32; 3], u32> = HashMap::new();
    let mut id = |i: u32| {
        let n = ids.len() as u32;
        *ids.entry(pos[i as usize].to_array().map(f32::to_bits)).or_insert(n)
    };
    let welded: Vec<[u32; 3]> = tri.iter().map(|t| t.map(&mut id)).collect();
    let mut edges: HashMap<(u32, u32), u32> = HashMap::with_capacity(tri.len() * 3);
    for t in &welded {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *edges.entry((a.min(b), a.max(b))).or_insert(0) += 1;
        }
    }
    !tri.is_empty() && edges.values().all(|&n| n == 2)
}

/// The corners of `p` flipped by [`flipped`], in its order.
pub(super) fn flipped_corners<T: Copy>(kind: PrimitiveKind, c: [T; 4]) -> [T; 4] {
    match kind {
        PrimitiveKind::Quad => [c[3], c[2], c[1], c[0]],
        PrimitiveKind::Triangle => [c[0], c[2], c[1], c[1]],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closed_means_every_edge_twice() {
        let pos = [Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z, Vec3::Z];
        let tetra = [[0, 1, 2], [0, 3, 1], [1, 3, 2], [2, 3, 0]];
        assert!(is_closed(&pos, &tetra));
        assert!(!is_closed(&pos, &tetra[..3]));
        // Vertex 4 repeats vertex 3's position: welded, still closed.
        assert!(is_closed(&pos, &[[0, 1, 2], [0, 4, 1], [1, 3, 2], [2, 3, 0]]));
    }
}
