//! The patches as the page draws them: one triangle list, each vertex
//! with its position and its patch, so that the page colours every patch
//! flat with the radiance it is sent (a texture of one texel a patch).

use illumnet::archive::InetView;
use illumnet::archive::layout::kind;
use illumnet::geometry::grid::NO_VERTEX;

/// The mesh's bytes (little-endian): `u32` vertices `V`, then `V × 3`
/// `f32` positions, then `V` `u32` patch ids. A quad cell is two
/// triangles, a triangular cell or a grouped triangle one.
pub fn mesh_bytes(v: &InetView<'_>) -> Vec<u8> {
    let mut positions: Vec<[f32; 3]> = Vec::new();
    let mut patches: Vec<u32> = Vec::new();
    let mut add = |corners: [u32; 3], patch: u32| {
        for c in corners {
            positions.push(v.vertex_position[c as usize]);
            patches.push(patch);
        }
    };
    for (p, c) in v.patch_corners.iter().enumerate() {
        if c[0] == NO_VERTEX {
            continue; // a grouped patch: its triangles below
        }
        add([c[0], c[1], c[2]], p as u32);
        if c[3] != NO_VERTEX {
            add([c[0], c[2], c[3]], p as u32);
        }
    }
    for r in v.primitives.iter().filter(|r| r.kind == kind::GROUPED_TRIANGLE) {
        add(v.grouped_triangles[r.first_vertex as usize], r.first_patch);
    }
    let mut out = Vec::with_capacity(4 + positions.len() * 16);
    out.extend_from_slice(&(positions.len() as u32).to_le_bytes());
    out.extend_from_slice(bytemuck::cast_slice(&positions));
    for p in &patches {
        out.extend_from_slice(&p.to_le_bytes());
    }
    out
}

/// Per patch, whether it is in `frame` (temporal instances come and go).
pub fn present(v: &InetView<'_>, frame: u32) -> Vec<bool> {
    let spans = v.primitive_spans();
    v.patch_primitive.iter().map(|&p| spans[p as usize].contains(frame)).collect()
}
