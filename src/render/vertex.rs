//! Radiance at patch vertices: the per-patch radiance carried to the
//! vertices (an area-weighted mean of the patches around each), from which
//! image samples interpolate it (Gouraud shading).

use glam::Vec3;

use crate::archive::InetView;
use crate::archive::layout;
use crate::geometry::grid::NO_VERTEX;

/// Radiance at every patch vertex: area-weighted mean of adjacent patches
/// (for a grouped patch, of its triangles around the vertex).
pub fn vertex_radiance(v: &InetView<'_>, patch_radiance: &[[f32; 3]]) -> Vec<[f32; 3]> {
    vertex_mean(v, patch_radiance, |_| 1.0)
}

/// Radiance at every patch vertex, weighted by the area of each adjacent
/// patch that the build's rays saw (`A_p·H_p/E[H_p]`): a patch hidden
/// under a box (no ray reached it) does not darken the lit patches it
/// shares vertices with, which the plain area weights do along every
/// contact edge.
pub fn vertex_radiance_seen(v: &InetView<'_>, patch_radiance: &[[f32; 3]]) -> Vec<[f32; 3]> {
    vertex_mean(v, patch_radiance, |p| {
        let expected = v.patch_expected_hits[p] as f64;
        if expected > 0.0 { (v.patch_hits[p] as f64 / expected).min(1.0) } else { 1.0 }
    })
}

/// Vertices whose sums are held at once (32 bytes each: 4 MiB), so that
/// a mesh of millions of vertices does not hold a sum for every one of
/// them beside the radiance it makes: each block of vertices is one pass
/// over the patches, the sums of a vertex added in the same order
/// whatever the block.
const SUMS_HELD: usize = 1 << 17;

/// Mean of the patches' radiance at each vertex, weighted by the area
/// each patch (or grouped triangle) has at it times `seen(patch)`.
fn vertex_mean(v: &InetView<'_>, patch_radiance: &[[f32; 3]], seen: impl Fn(usize) -> f64) -> Vec<[f32; 3]> {
    let vertices = v.vertex_position.len();
    let mut out = vec![[0.0f32; 3]; vertices];
    let incident = grouped_incidence(v);
    let mut sum = vec![[0.0f64; 4]; vertices.min(SUMS_HELD)];
    for first in (0..vertices).step_by(SUMS_HELD) {
        let held = first..(first + SUMS_HELD).min(vertices);
        let sum = &mut sum[..held.len()];
        sum.fill([0.0; 4]);
        // Grouped patches have no corners of their own (PCOR is all NO_VERTEX).
        for (p, corners) in v.patch_corners.iter().enumerate() {
            let a = v.patch_area[p] as f64 * seen(p);
            for &c in corners.iter().filter(|&&c| c != NO_VERTEX && held.contains(&(c as usize))) {
                let s = &mut sum[c as usize - first];
                for k in 0..3 {
                    s[k] += a * patch_radiance[p][k] as f64;
                }
                s[3] += a;
            }
        }
        grouped_vertex_mean(v, patch_radiance, &seen, &incident, held.clone(), sum);
        for (o, s) in out[held].iter_mut().zip(sum.iter()) {
            *o = if s[3] > 0.0 { [0, 1, 2].map(|k| (s[k] / s[3]) as f32) } else { [0.0; 3] };
        }
    }
    out
}

/// Each grouped triangle's corners with its group, sorted by vertex.
fn grouped_incidence(v: &InetView<'_>) -> Vec<(u32, u32)> {
    let mut incident: Vec<(u32, u32)> = v
        .primitives
        .iter()
        .filter(|r| r.kind == layout::kind::GROUPED_TRIANGLE)
        .flat_map(|r| v.grouped_triangles[r.first_vertex as usize].map(|c| (c, r.first_patch)))
        .collect();
    incident.sort_unstable();
    incident.dedup();
    incident
}

/// The vertices of grouped triangles (§5.8 of the format): a smooth field
/// over the mesh, not one flat value per group. Each vertex takes the
/// groups its triangles belong to and their neighbours (`ADJI`: groups
/// sharing an edge without a fold), weighted by `A_g·seen(g)/(d² + A_g/4)`,
/// `d` the distance to the group's centre: close to a group's own light
/// at its centre, blending into its neighbours' towards its edges.
fn grouped_vertex_mean(
    v: &InetView<'_>,
    patch_radiance: &[[f32; 3]],
    seen: &dyn Fn(usize) -> f64,
    incident: &[(u32, u32)],
    held: std::ops::Range<usize>,
    sum: &mut [[f64; 4]],
) {
    let grouped = |q: u32| v.primitives[v.patch_primitive[q as usize] as usize].kind == layout::kind::GROUPED_TRIANGLE;
    let from = incident.partition_point(|x| (x.0 as usize) < held.start);
    let to = incident.partition_point(|x| (x.0 as usize) < held.end);
    let mut near: Vec<u32> = Vec::new();
    for run in incident[from..to].chunk_by(|a, b| a.0 == b.0) {
        let vertex = run[0].0 as usize;
        near.clear();
        for &(_, g) in run {
            near.push(g);
            let (a, b) = (v.adjacency_offsets[g as usize] as usize, v.adjacency_offsets[g as usize + 1] as usize);
            near.extend(v.adjacency[a..b].iter().copied().filter(|&q| grouped(q)));
        }
        near.sort_unstable();
        near.dedup();
        let x = Vec3::from(v.vertex_position[vertex]).as_dvec3();
        let s = &mut sum[vertex - held.start];
        for &g in &near {
            let g = g as usize;
            let area = v.patch_area[g] as f64;
            let d2 = (Vec3::from(v.patch_centre[g]).as_dvec3() - x).length_squared();
            let w = area * seen(g) / (d2 + 0.25 * area);
            for k in 0..3 {
                s[k] += w * patch_radiance[g][k] as f64;
            }
            s[3] += w;
        }
    }
}
