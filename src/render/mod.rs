//! Rendering: patch radiance → pixels (§3.5).
//!
//! Radiance is carried to patch vertices (area-weighted average of the
//! patches sharing each vertex) and interpolated across each patch
//! (bilinear on quads, barycentric on triangles: Gouraud shading). Visibility
//! comes from primary rays through the same primitive BVH the build uses.
//! Each pixel is the box-filtered mean of an `n×n` stratified grid of
//! samples, as a path tracer's image with a box filter is; emitters seen
//! directly show their own radiance; back faces and misses are black.

mod camera;
mod detail;
pub mod direct;
pub mod false_colour;
mod gather;
pub mod image_io;
pub mod plan;
pub mod view;

use glam::{Vec2, Vec3};
use rayon::prelude::*;

pub use camera::PinholeCamera;
pub use direct::DirectLight;
pub use gather::Gather;
pub use view::{frame_radiance, indirect_frame_radiance, indirect_radiance_seen_from, radiance_seen_from};

use crate::archive::InetView;
use crate::archive::layout::{self, PrimitiveRecord, cell_order};
use crate::geometry::accel::PrimitiveBvh;
use crate::geometry::grid::{CellOrder, NO_VERTEX, PatchGrid};
use crate::geometry::{Primitive, PrimitiveKind};
use detail::SurfaceDetail;

/// A linear-RGB floating-point image, rows top to bottom.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width × height` RGB radiance values.
    pub pixels: Vec<[f32; 3]>,
}

impl Image {
    /// The pixel at column `x`, row `y`.
    pub fn at(&self, x: u32, y: u32) -> [f32; 3] {
        self.pixels[(y * self.width + x) as usize]
    }

    /// Mean RGB over the rectangle `[x0, x1) × [y0, y1)`.
    pub fn mean(&self, x0: u32, y0: u32, x1: u32, y1: u32) -> [f32; 3] {
        let mut s = [0.0f64; 3];
        for y in y0..y1 {
            for x in x0..x1 {
                let p = self.at(x, y);
                for c in 0..3 {
                    s[c] += p[c] as f64;
                }
            }
        }
        let n = ((x1 - x0) * (y1 - y0)).max(1) as f64;
        s.map(|v| (v / n) as f32)
    }
}

/// The patch each image sample sees ([`Renderer::sample_patches`]).
#[derive(Debug, Clone, PartialEq)]
pub struct SamplePatches {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Samples per pixel.
    pub per_pixel: u32,
    /// `width × height × per_pixel` patch ids, `u32::MAX` for none.
    pub patches: Vec<u32>,
}

/// Samples per axis of an edge pixel in a single frame rendered by the
/// command line ([`RenderOptions::edge_samples_per_axis`]): the Cornell
/// box's error at edges fell as the grid grew, to 16 (`docs/GATHER.md`).
pub const DEFAULT_EDGE_SAMPLES: u32 = 16;

/// Options for [`render`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderOptions {
    /// Samples per pixel along each axis (`n×n` per pixel; clamped to 1..=256).
    pub samples_per_axis: u32,
    /// Samples per axis of pixels on an edge (their samples see a miss and
    /// a surface, or surfaces that are not one plane), traced again in an
    /// `m×m` grid (m at most 256); 0 (or not above `samples_per_axis`):
    /// off. A few samples put a corner or a silhouette at the same place
    /// in every pixel along it, so the pixels' cover of the two sides errs
    /// the same way along the whole line: the Cornell box's edges were
    /// half its direct light's error at 4×4 (`docs/GATHER.md`). Edges are
    /// found among a pixel's `n × n` samples, so with one sample per pixel
    /// none are. An edge pixel's one-bounce gather traces at least one ray
    /// per sample (m² where that exceeds its rays).
    pub edge_samples_per_axis: u32,
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self { samples_per_axis: 4, edge_samples_per_axis: 0 }
    }
}

/// Whether the samples `hits` of a pixel lie across an edge: one sees
/// nothing (or a back face) and another a front face, or two see
/// primitives turned more than 18° apart, or the second's point lies off
/// the first's plane by more than 0.35 of their distance (a step in depth:
/// a surface behind another). Neighbouring triangles of a smooth mesh, or
/// coplanar quads, are not an edge. `point(k)`: where sample k's ray met
/// its primitive.
fn on_edge(hits: &[SampleHit], normals: &[Vec3], point: impl Fn(usize) -> Vec3) -> bool {
    let Some(first) = hits.first() else { return false };
    let front = |h: &SampleHit| h.primitive != u32::MAX && h.vertices != [NO_VERTEX; 4];
    let mut first_point = None;
    for (k, h) in hits.iter().enumerate().skip(1) {
        if h.primitive == first.primitive {
            continue;
        }
        match (front(first), front(h)) {
            (true, true) => {}
            (false, false) => continue,
            _ => return true,
        }
        let (na, nb) = (normals[first.primitive as usize], normals[h.primitive as usize]);
        if na.dot(nb) < 0.95 {
            return true;
        }
        let pa = *first_point.get_or_insert_with(|| point(0));
        let pb = point(k);
        if na.dot(pb - pa).abs() > 0.35 * (pb - pa).length() + 1e-6 * h.t.max(first.t) {
            return true;
        }
    }
    false
}

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

/// Mean of the patches' radiance at each vertex, weighted by the area
/// each patch (or grouped triangle) has at it times `seen(patch)`.
fn vertex_mean(v: &InetView<'_>, patch_radiance: &[[f32; 3]], seen: impl Fn(usize) -> f64) -> Vec<[f32; 3]> {
    let mut sum = vec![[0.0f64; 4]; v.vertex_position.len()];
    let mut add = |corners: &[u32], p: usize, a: f64| {
        for &c in corners.iter().filter(|&&c| c != NO_VERTEX) {
            let s = &mut sum[c as usize];
            for k in 0..3 {
                s[k] += a * patch_radiance[p][k] as f64;
            }
            s[3] += a;
        }
    };
    // Grouped patches have no corners of their own (PCOR is all NO_VERTEX).
    for (p, corners) in v.patch_corners.iter().enumerate() {
        add(corners, p, v.patch_area[p] as f64 * seen(p));
    }
    grouped_vertex_mean(v, patch_radiance, &seen, &mut sum);
    sum.iter().map(|s| if s[3] > 0.0 { [0, 1, 2].map(|k| (s[k] / s[3]) as f32) } else { [0.0; 3] }).collect()
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
    sum: &mut [[f64; 4]],
) {
    let grouped = |q: u32| v.primitives[v.patch_primitive[q as usize] as usize].kind == layout::kind::GROUPED_TRIANGLE;
    let mut incident: Vec<(u32, u32)> = v
        .primitives
        .iter()
        .filter(|r| r.kind == layout::kind::GROUPED_TRIANGLE)
        .flat_map(|r| v.grouped_triangles[r.first_vertex as usize].map(|c| (c, r.first_patch)))
        .collect();
    incident.sort_unstable();
    incident.dedup();
    let mut near: Vec<u32> = Vec::new();
    for run in incident.chunk_by(|a, b| a.0 == b.0) {
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
        let s = &mut sum[vertex];
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

fn primitive_of(r: &PrimitiveRecord) -> (Primitive, PatchGrid) {
    let kind = if r.kind == 0 { PrimitiveKind::Quad } else { PrimitiveKind::Triangle };
    let p = r.corners.map(Vec3::from);
    // Validated: tiles only for quads.
    let order = if r.cell_order == cell_order::TILES { CellOrder::Tiles } else { CellOrder::Rows };
    (Primitive { kind, p }, PatchGrid { kind, n_u: r.grid_u, n_v: r.grid_v, order })
}

/// Renders the archive's camera view from per-patch radiance.
pub fn render(v: &InetView<'_>, patch_radiance: &[[f32; 3]], opts: &RenderOptions) -> Image {
    render_frame(v, 0, patch_radiance, opts)
}

/// Renders `frame` of a sequence archive: only the primitives present then.
pub fn render_frame(v: &InetView<'_>, frame: u32, patch_radiance: &[[f32; 3]], opts: &RenderOptions) -> Image {
    Renderer::new(v, *opts).frame(frame, patch_radiance)
}

/// What one image sample sees: interpolation weights on patch vertices.
#[derive(Clone, Copy)]
struct SampleHit {
    /// Distance to the hit (`f32::INFINITY`: nothing, or a back face).
    t: f32,
    /// Primitive hit (`u32::MAX`: none).
    primitive: u32,
    /// Global vertex ids of the cell's corners (`NO_VERTEX`: unused).
    vertices: [u32; 4],
    /// Their interpolation weights.
    weights: [f32; 4],
    /// Surface coordinates of the hit on its primitive.
    uv: [f32; 2],
}

/// Largest sample cache a [`Renderer`] keeps (1 GiB: 1920×1080 at 4×4
/// samples per pixel is 1.3 GB and is shaded without it).
const CACHE_BUDGET: u64 = 1 << 30;

impl SampleHit {
    /// Adds the interpolated vertex radiance this sample sees to `acc`
    /// (term by term, so a pixel sums in one fixed order).
    #[inline]
    fn add_radiance(&self, vrad: &[[f32; 3]], acc: &mut Vec3) {
        for k in 0..4 {
            if self.vertices[k] != NO_VERTEX {
                *acc += self.weights[k] * Vec3::from(vrad[self.vertices[k] as usize]);
            }
        }
    }
}

/// Where image sample `k` of the `count` of pixel `(x, y)` (a square grid:
/// `n × n`, or an edge pixel's finer grid), which saw `hit`, lies, when it
/// is on a front face (back faces are black and take no light).
type SamplePoint<'f> = dyn Fn(u32, u32, (u32, u32), &SampleHit) -> Option<Vec3> + Sync + 'f;

/// What a ray from a point along a unit direction meets in the frame.
type RayHit<'f> = dyn Fn(Vec3, Vec3) -> SampleHit + Sync + 'f;

/// The side of the patch at a surface point of a primitive.
type PatchSize<'f> = dyn Fn(u32, Vec2) -> f32 + Sync + 'f;

/// What the direct light of a pixel needs: the frame's emitters, its
/// shadow-ray BVH, the primitives' normals and detail, and the samples'
/// positions; and for the gather, the frame's rays.
struct PixelLight<'f> {
    light: &'f DirectLight,
    bvh: &'f PrimitiveBvh,
    normals: &'f [Vec3],
    detail: &'f SurfaceDetail<'f>,
    point: &'f SamplePoint<'f>,
    trace: &'f RayHit<'f>,
    patch_size: &'f PatchSize<'f>,
    /// Where the camera is (glossy highlights depend on it).
    eye: Vec3,
    frame: u32,
}

/// Reused per row of pixels: a pixel's lit samples by primitive, their
/// points, and the emitters in front of them.
#[derive(Default)]
struct PixelScratch {
    lit: Vec<(u32, Vec3, Vec2)>,
    /// Per primitive, the weight of the gather in its samples' indirect light.
    reach: Vec<(u32, f32)>,
    points: Vec<Vec3>,
    emitters: Vec<(u32, f32)>,
}

/// The image samples of pixel `(x, y)`, in order, into the buffer.
type PixelHits<'f> = dyn Fn(u32, u32, &mut Vec<SampleHit>) + Sync + 'f;

/// How far (in pixels, each way) the second pass of direct light looks for
/// a blocked first-pass ray: a pixel is estimated again when one of the
/// `(2r + 1)² − 1` pixels around it had one. At 1, pixels on the outskirts
/// of a penumbra whose own rays alone were blocked kept their four-ray
/// estimate: isolated dark dots (27 on the Cornell box, each 15–20% dark).
const REFINE_RADIUS: u32 = 2;

/// The box-filtered image of `w × h` pixels whose samples `hits_of`
/// gives: interpolated vertex radiance plus, when `direct` is given,
/// direct light; the direct light alone; and the pixels' summed shares of
/// samples that saw a back face (an edge pixel's finer grid counts as one
/// pixel, like the others).
///
/// Direct light takes two passes. The first gives every pixel a cheap
/// unbiased estimate (four rays, [`DirectLight::estimate`]) and notes, per
/// pixel, the emitters a shadow ray to which was blocked; the second
/// estimates again, with many rays (the light samples squared), every pixel
/// with such a pixel among the 24 around it ([`REFINE_RADIUS`]), afresh for
/// the emitters found blocked there only
/// ([`DirectLight::estimate_refined`]). Deciding from the neighbours, not
/// from the pixel's own rays, keeps the result unbiased (a pixel refined
/// because its own first rays were blocked would be refined exactly when
/// it looked dark, which brightened the outskirts of soft shadows: the
/// Cornell box measured 2.78% against 1.86% with every ray traced), and
/// penumbrae are wider than a pixel, so their neighbours find them.
fn shade_image(
    (w, h): (u32, u32),
    hits_of: &PixelHits<'_>,
    vrad: &[[f32; 3]],
    detail: &SurfaceDetail<'_>,
    direct: Option<&PixelLight<'_>>,
) -> (Image, Option<Image>, Unlit) {
    // In 2⁻¹⁶ of a pixel.
    const ONE: u64 = 1 << 16;
    let back_faces = std::sync::atomic::AtomicU64::new(0);
    let nothing = std::sync::atomic::AtomicU64::new(0);
    let mut pixels = vec![[0.0f32; 3]; (w * h) as usize];
    let mut direct_pixels = vec![[0.0f32; 3]; (w * h) as usize];
    // Glossy highlights: taken once, in the first pass.
    let mut glossy_pixels = vec![[0.0f32; 3]; (w * h) as usize];
    // Per pixel, the emitters its first rays found blocked.
    let mut blocked = vec![0u64; (w * h) as usize];
    let rows = direct_pixels
        .par_chunks_mut(w as usize)
        .zip(blocked.par_chunks_mut(w as usize))
        .zip(glossy_pixels.par_chunks_mut(w as usize));
    pixels.par_chunks_mut(w as usize).zip(rows).enumerate().for_each(|(y, (row, ((drow, brow), grow)))| {
        let (mut scratch, mut hits) = (PixelScratch::default(), Vec::new());
        for (x, px) in row.iter_mut().enumerate() {
            hits_of(x as u32, y as u32, &mut hits);
            let mut acc = Vec3::ZERO;
            let (mut back, mut missed) = (0, 0);
            if let Some(pl) = direct {
                pixel_reach(&hits, pl, (x as u32, y as u32), &mut scratch);
            }
            for (k, hit) in hits.iter().enumerate() {
                let reach = scratch.reach.iter().find(|r| r.0 == hit.primitive).map_or(0.0, |r| r.1);
                if reach > 0.0
                    && let Some(pl) = direct
                {
                    let mut l = Vec3::ZERO;
                    hit.add_radiance(vrad, &mut l);
                    if detail.any() {
                        l *= detail.albedo_scale(hit.primitive, Vec2::from(hit.uv));
                    }
                    let (at, of) = ((x as u32, y as u32), (k as u32, hits.len() as u32));
                    acc += gathered(pl, at, of, hit, reach, l, &mut scratch.emitters).unwrap_or(l);
                } else if detail.any() && hit.primitive != u32::MAX {
                    // A texture multiplies what the sample's surface reflects.
                    let mut l = Vec3::ZERO;
                    hit.add_radiance(vrad, &mut l);
                    acc += l * detail.albedo_scale(hit.primitive, Vec2::from(hit.uv));
                } else {
                    hit.add_radiance(vrad, &mut acc);
                }
                back += usize::from(hit.primitive != u32::MAX && hit.vertices == [NO_VERTEX; 4]);
                missed += usize::from(hit.primitive == u32::MAX);
            }
            for (count, total) in [(back, &back_faces), (missed, &nothing)] {
                if count > 0 {
                    total.fetch_add(count as u64 * ONE / hits.len() as u64, std::sync::atomic::Ordering::Relaxed);
                }
            }
            let inv = 1.0 / hits.len().max(1) as f32;
            *px = (acc * inv).to_array();
            if let Some(pl) = direct {
                let (light, highlights, any_blocked) =
                    pixel_direct(&hits, pl, (x as u32, y as u32), &mut scratch, None);
                drow[x] = (light * inv).to_array();
                grow[x] = (highlights * inv).to_array();
                brow[x] = any_blocked;
            }
        }
    });
    let pixels_of = |n: std::sync::atomic::AtomicU64| n.into_inner() as f64 / ONE as f64;
    let unlit = Unlit { back_faces: pixels_of(back_faces), nothing: pixels_of(nothing) };
    let Some(pl) = direct else {
        return (Image { width: w, height: h, pixels }, None, unlit);
    };
    // The second pass, into the direct light: each pixel reads the first
    // pass's marks of its neighbours only.
    let near_blocked = |x: u32, y: u32| {
        let r = REFINE_RADIUS;
        let (x0, x1) = (x.saturating_sub(r), (x + r).min(w - 1));
        let (y0, y1) = (y.saturating_sub(r), (y + r).min(h - 1));
        let around = (y0..=y1).flat_map(|j| (x0..=x1).map(move |i| (i, j))).filter(|&p| p != (x, y));
        around.fold(0, |mask, (i, j)| mask | blocked[(j * w + i) as usize])
    };
    direct_pixels.par_chunks_mut(w as usize).enumerate().for_each(|(y, drow)| {
        let (mut scratch, mut hits) = (PixelScratch::default(), Vec::new());
        for (x, d) in drow.iter_mut().enumerate() {
            let near = near_blocked(x as u32, y as u32);
            if near != 0 {
                hits_of(x as u32, y as u32, &mut hits);
                let (light, _, _) = pixel_direct(&hits, pl, (x as u32, y as u32), &mut scratch, Some(near));
                *d = (light / hits.len().max(1) as f32).to_array();
            }
        }
    });
    for (d, g) in direct_pixels.iter_mut().zip(&glossy_pixels) {
        *d = [0, 1, 2].map(|c| d[c] + g[c]);
    }
    for (p, d) in pixels.iter_mut().zip(&direct_pixels) {
        *p = [0, 1, 2].map(|c| p[c] + d[c]);
    }
    (Image { width: w, height: h, pixels }, Some(Image { width: w, height: h, pixels: direct_pixels }), unlit)
}

/// How much of each sample's indirect light of pixel `(x, y)` comes from
/// the gather ([`Gather::reach_weight`]), by primitive, into
/// `scratch.reach`: probed once per primitive the pixel's samples see, from
/// their mean point.
fn pixel_reach(hits: &[SampleHit], pl: &PixelLight<'_>, (x, y): (u32, u32), scratch: &mut PixelScratch) {
    scratch.reach.clear();
    let Some(gather) = pl.light.gather() else { return };
    scratch.lit.clear();
    for (k, hit) in hits.iter().enumerate() {
        if hit.vertices != [NO_VERTEX; 4]
            && pl.light.gather_for(hit.primitive).is_some()
            && let Some(p) = (pl.point)(x, y, (k as u32, hits.len() as u32), hit)
        {
            scratch.lit.push((hit.primitive, p, Vec2::from(hit.uv)));
        }
    }
    scratch.lit.sort_by_key(|&(prim, _, _)| prim);
    for run in scratch.lit.chunk_by(|a, b| a.0 == b.0) {
        let prim = run[0].0;
        let mean = run.iter().map(|r| r.1).sum::<Vec3>() / run.len() as f32;
        let size = (pl.patch_size)(prim, run[0].2);
        let w = gather.reach_weight(mean, pl.normals[prim as usize], size, pl.light.epsilon(), pl.trace);
        scratch.reach.push((prim, w));
    }
}

/// The indirect light of sample `k` of `count` of pixel `(x, y)`, which
/// saw `hit`, when the frame gathers and its primitive takes the gather
/// with weight `reach` > 0: the gathered light, blended with the
/// interpolated light `interpolated` by that weight.
#[allow(clippy::too_many_arguments)]
fn gathered(
    pl: &PixelLight<'_>,
    (x, y): (u32, u32),
    (k, count): (u32, u32),
    hit: &SampleHit,
    reach: f32,
    interpolated: Vec3,
    emitters: &mut Vec<(u32, f32)>,
) -> Option<Vec3> {
    let (gather, kd) = pl.light.gather_for(hit.primitive)?;
    let point = (pl.point)(x, y, (k, count), hit)?;
    let face = pl.normals[hit.primitive as usize];
    let uv = Vec2::from(hit.uv);
    let (n, scale) = if pl.detail.any() {
        (pl.detail.normal(hit.primitive, uv, face), pl.detail.albedo_scale(hit.primitive, uv))
    } else {
        (face, Vec3::ONE)
    };
    let key = direct::pixel_key(pl.frame, x, y) ^ 0x2545_f491_4f6c_dd1d;
    let exact = gather::ExactDirect { light: pl.light, bvh: pl.bvh, normals: pl.normals, emitters };
    let incoming = gather.incoming(point, (n, face), key, (k, count), pl.trace, pl.detail, exact);
    Some(kd * scale * incoming * reach + interpolated * (1.0 - reach))
}

/// The summed diffuse direct light of a pixel's samples `hits` (its first
/// estimate, or, given the emitters its neighbours' first rays found
/// blocked, the refined one), computed once per primitive the samples
/// see and weighted by how many see it; the summed glossy highlights (first
/// estimate only: they are not refined); and the emitters a first-estimate
/// shadow ray to which was blocked.
fn pixel_direct(
    hits: &[SampleHit],
    pl: &PixelLight<'_>,
    (x, y): (u32, u32),
    scratch: &mut PixelScratch,
    refined: Option<u64>,
) -> (Vec3, Vec3, u64) {
    scratch.lit.clear();
    for (k, hit) in hits.iter().enumerate() {
        if hit.primitive != u32::MAX
            && let Some(p) = (pl.point)(x, y, (k as u32, hits.len() as u32), hit)
        {
            scratch.lit.push((hit.primitive, p, Vec2::from(hit.uv)));
        }
    }
    // Stable: each primitive's samples stay in sample order.
    scratch.lit.sort_by_key(|&(prim, _, _)| prim);
    let pixel = direct::pixel_key(pl.frame, x, y);
    let (mut light, mut highlights, mut blocked) = (Vec3::ZERO, Vec3::ZERO, 0);
    for run in scratch.lit.chunk_by(|a, b| a.0 == b.0) {
        let prim = run[0].0;
        scratch.points.clear();
        scratch.points.extend(run.iter().map(|r| r.1));
        let key = pixel ^ (prim as u64 + 1).wrapping_mul(0xa076_1d64_78bd_642f);
        let (face, points) = (pl.normals[prim as usize], &scratch.points);
        // Mesh detail: the samples' mean shading normal and texture scale
        // (to first order in the pixel's footprint, as the points' mean).
        let (n, scale) = if pl.detail.any() {
            let normal: Vec3 = run.iter().map(|r| pl.detail.normal(prim, r.2, face)).sum();
            let scale: Vec3 = run.iter().map(|r| pl.detail.albedo_scale(prim, r.2)).sum();
            (normal.try_normalize().unwrap_or(face), scale / run.len() as f32)
        } else {
            (face, Vec3::ONE)
        };
        let l = if let Some(near) = refined {
            let rays = (pl.light.refined_rays(), near);
            pl.light.estimate_refined(points, (n, face), prim, pl.bvh, key, rays, &mut scratch.emitters)
        } else {
            let rays = direct::FIRST_RAYS;
            let (l, b) = pl.light.estimate(points, (n, face), prim, pl.bvh, key, rays, &mut scratch.emitters);
            blocked |= b;
            l
        };
        light += l * scale * run.len() as f32;
        if refined.is_none() && pl.light.is_glossy(prim) {
            highlights += pl.light.glossy_estimate(points, face, pl.eye, prim, pl.bvh, key, &mut scratch.emitters);
        }
    }
    (light, highlights, blocked)
}

/// A frame's camera and the BVH of the primitives present in it (`kept`:
/// the archive's primitive of each of the BVH's), `n × n` samples per pixel.
struct FrameRays {
    record: crate::archive::layout::CameraRecord,
    camera: PinholeCamera,
    kept: Vec<u32>,
    bvh: PrimitiveBvh,
    n: u32,
}

const NO_HIT: SampleHit =
    SampleHit { t: f32::INFINITY, primitive: u32::MAX, vertices: [NO_VERTEX; 4], weights: [0.0; 4], uv: [0.0; 2] };

/// Bytes a [`Renderer`]'s sample cache takes for `pixels` pixels of
/// `per_pixel` samples: the samples and a flag per pixel.
pub(crate) fn sample_cache_bytes(pixels: u64, per_pixel: u64) -> u64 {
    pixels * (per_pixel * std::mem::size_of::<SampleHit>() as u64 + 1)
}

/// Renders the frames of one archive, keeping what every image sample saw
/// (48 bytes per sample: 59 MB at 320×240 with 16 samples per pixel; up to
/// 1 GiB, larger images are shaded without the cache) so that
/// later frames with the same camera re-trace only the samples that moving
/// geometry may change: those that saw a temporal instance, and those whose
/// ray meets a temporal instance present in the frame nearer than what they
/// saw. Pixels with neither kind of sample are not read (a flag per pixel).
/// Images are bit-identical to tracing every sample (tested).
pub struct Renderer<'a> {
    v: InetView<'a>,
    opts: RenderOptions,
    all_prims: Vec<Primitive>,
    grids: Vec<PatchGrid>,
    normals: Vec<Vec3>,
    /// Textures and shading normals of imported meshes.
    detail: SurfaceDetail<'a>,
    /// Primitives of temporal instances (present in only some frames).
    temporal: Vec<bool>,
    /// The last frame's camera, samples, and per pixel whether one of its
    /// samples sees a temporal primitive (a pixel with none, outside the
    /// moving primitives' rectangles, keeps its samples unread).
    cache: Option<(crate::archive::layout::CameraRecord, Vec<SampleHit>, Vec<bool>)>,
    cache_budget: u64,
    /// The camera given at render time, replacing the archive's.
    camera: Option<crate::archive::layout::CameraRecord>,
    /// Samples of the `n × n` grids traced against the whole scene in the
    /// last frame (edge pixels' finer grids are traced besides, every
    /// frame, and not counted).
    pub retraced: usize,
    /// Samples of the last frame that saw a back face (shown black:
    /// surfaces are one-sided), in units of the `n × n` grid: an edge
    /// pixel's finer samples count by their share of the pixel.
    pub back_faces: usize,
    /// Samples of the last frame that saw no surface (the background,
    /// black), in the same units.
    pub nothing_seen: usize,
}

/// Pixels (and shares of pixels) of an image whose samples saw a back
/// face, or nothing: what a black image is made of when the camera is
/// misplaced.
#[derive(Clone, Copy, Debug, Default)]
struct Unlit {
    back_faces: f64,
    nothing: f64,
}

impl<'a> Renderer<'a> {
    /// A renderer for `v` with `opts`.
    pub fn new(v: &InetView<'a>, opts: RenderOptions) -> Self {
        let (all_prims, grids): (Vec<Primitive>, Vec<PatchGrid>) = v.primitives.iter().map(primitive_of).unzip();
        let normals = all_prims.iter().map(|p| p.normal()).collect();
        let temporal = v.temporal_primitives();
        let detail = SurfaceDetail::new(v, &all_prims);
        Self {
            v: *v,
            opts,
            all_prims,
            grids,
            normals,
            detail,
            temporal,
            cache: None,
            cache_budget: CACHE_BUDGET,
            camera: None,
            retraced: 0,
            back_faces: 0,
            nothing_seen: 0,
        }
    }

    /// Sets the largest sample cache kept, in bytes (default 1 GiB); 0 traces
    /// every sample of every frame.
    pub fn with_cache_budget(mut self, bytes: u64) -> Self {
        self.cache_budget = bytes;
        self
    }

    /// Renders the next frames from `camera` instead of the archive's
    /// (`None`: the archive's again). The I-net does not depend on the
    /// view: only the pixels change. Samples are kept and reused while the
    /// camera holds still. Callers check the camera can make rays
    /// ([`crate::limits::camera_is_usable`], a field of view in (0, 180)
    /// degrees, a size of at least one pixel).
    pub fn set_camera(&mut self, camera: Option<crate::archive::layout::CameraRecord>) {
        self.camera = camera;
    }

    /// The camera `frame` is rendered from: the one set with
    /// [`Self::set_camera`], else the archive's for that frame.
    pub fn camera(&self, frame: u32) -> crate::archive::layout::CameraRecord {
        self.camera.unwrap_or_else(|| self.v.camera_at(frame))
    }

    /// What tracing `frame`'s image samples needs.
    fn frame_rays(&self, frame: u32) -> FrameRays {
        let record = self.camera(frame);
        let present = self.v.presence(frame).primitives;
        let kept: Vec<u32> = (0..self.all_prims.len() as u32).filter(|&i| present[i as usize]).collect();
        let prims: Vec<Primitive> = kept.iter().map(|&i| self.all_prims[i as usize]).collect();
        FrameRays {
            record,
            camera: PinholeCamera::from_record(&record),
            bvh: PrimitiveBvh::new(&prims),
            kept,
            // At most 256 samples per axis (the CLI allows 64): n² fits u32.
            n: self.opts.samples_per_axis.clamp(1, 256),
        }
    }

    /// The patch every image sample of `frame` sees (`u32::MAX`: nothing,
    /// or a back face), `n × n` samples per pixel in row order of pixels:
    /// what a false-colour picture of per-patch values colours
    /// ([`false_colour`]). Traced afresh; the sample cache is left alone.
    pub fn sample_patches(&self, frame: u32) -> SamplePatches {
        let FrameRays { camera, kept, bvh, n, .. } = self.frame_rays(frame);
        let v = &self.v;
        let (w, h) = (camera.width, camera.height);
        let per_pixel = (n * n) as usize;
        let mut patches = vec![u32::MAX; (w * h) as usize * per_pixel];
        patches.par_chunks_mut(w as usize * per_pixel).enumerate().for_each(|(y, row)| {
            for (i, out) in row.iter_mut().enumerate() {
                let (x, k) = ((i / per_pixel) as u32, (i % per_pixel) as u32);
                let s = Vec2::new(((k % n) as f32 + 0.5) / n as f32, ((k / n) as f32 + 0.5) / n as f32);
                let (o, d) = camera.ray(x as f32 + s.x, y as f32 + s.y);
                let Some(hit) = bvh.closest_hit(o, d, 0.0) else { continue };
                let pi = kept[hit.primitive as usize] as usize;
                if self.normals[pi].dot(d) >= 0.0 {
                    continue;
                }
                let record = &v.primitives[pi];
                *out = match record.kind == layout::kind::GROUPED_TRIANGLE {
                    true => record.first_patch,
                    false => record.first_patch + self.grids[pi].locate(hit.hit.uv).cell,
                };
            }
        });
        SamplePatches { width: w, height: h, per_pixel: per_pixel as u32, patches }
    }

    /// Records what of the last frame was unlit, in samples.
    fn count_unlit(&mut self, unlit: Unlit, per_pixel: usize) {
        self.back_faces = (unlit.back_faces * per_pixel as f64).round() as usize;
        self.nothing_seen = (unlit.nothing * per_pixel as f64).round() as usize;
    }

    /// Renders `frame` from per-patch radiance.
    pub fn frame(&mut self, frame: u32, patch_radiance: &[[f32; 3]]) -> Image {
        self.shade(frame, patch_radiance, None).0
    }

    /// Renders `frame` with direct light computed per pixel
    /// (`direct.rs`) added to `indirect`, the per-patch radiance without
    /// its direct part (see [`indirect_frame_radiance`]). Returns the
    /// image and its direct light alone (the indirect light is the
    /// difference).
    pub fn frame_direct(&mut self, frame: u32, indirect: &[[f32; 3]], direct: &DirectLight) -> (Image, Image) {
        let (total, direct) = self.shade(frame, indirect, Some(direct));
        (total, direct.expect("asked for"))
    }

    /// The image of `frame` (and its direct part when `direct` is given).
    fn shade(
        &mut self,
        frame: u32,
        patch_radiance: &[[f32; 3]],
        direct: Option<&DirectLight>,
    ) -> (Image, Option<Image>) {
        let FrameRays { record, camera, kept, bvh, n } = self.frame_rays(frame);
        let v = &self.v;
        let (w, h) = (camera.width, camera.height);
        let per_pixel = (n * n) as usize;
        // Edge pixels' finer grid (0: none).
        let m = match self.opts.edge_samples_per_axis.min(256) {
            m if m > n => m,
            _ => 0,
        };
        // Sample (sx, sy) of the g×g grid in pixel (x, y).
        let grid_ray = |x: u32, y: u32, (sx, sy): (u32, u32), g: u32| {
            let s = Vec2::new((sx as f32 + 0.5) / g as f32, (sy as f32 + 0.5) / g as f32);
            camera.ray(x as f32 + s.x, y as f32 + s.y)
        };
        // Sample (sx, sy) of the n×n grid in pixel (x, y).
        let sample_ray = |x: u32, y: u32, sx: u32, sy: u32| grid_ray(x, y, (sx, sy), n);
        let hit_at = |o: Vec3, d: Vec3| -> SampleHit {
            let Some(hit) = bvh.closest_hit(o, d, 0.0) else {
                return NO_HIT;
            };
            let pi = kept[hit.primitive as usize] as usize;
            if self.normals[pi].dot(d) >= 0.0 {
                // A back face: surfaces are one-sided, it shows black but hides what is behind.
                return SampleHit { t: hit.hit.t, primitive: pi as u32, ..NO_HIT };
            }
            let loc = self.grids[pi].locate(hit.hit.uv);
            let record = &v.primitives[pi];
            // A grouped triangle's one cell has local corners 0, 1, 2: its TVTX row.
            let vertex = |c: u32| match record.kind == layout::kind::GROUPED_TRIANGLE {
                true => v.grouped_triangles[record.first_vertex as usize][c as usize],
                false => record.first_vertex + c,
            };
            let mut vertices = [NO_VERTEX; 4];
            let mut weights = [0.0; 4];
            for k in 0..4 {
                if loc.corners[k] != NO_VERTEX && loc.weights[k] != 0.0 {
                    vertices[k] = vertex(loc.corners[k]);
                    weights[k] = loc.weights[k];
                }
            }
            SampleHit { t: hit.hit.t, primitive: pi as u32, vertices, weights, uv: hit.hit.uv.to_array() }
        };
        let trace = |x: u32, y: u32, sx: u32, sy: u32| -> SampleHit {
            let (o, d) = sample_ray(x, y, sx, sy);
            hit_at(o, d)
        };
        // The side of a pixel's grid of `count` samples.
        let side = |count: u32| if count == n * n || m == 0 { n } else { m };
        // Where sample k of the `count` of pixel (x, y), which saw `hit`, lies.
        let sample_point = |x: u32, y: u32, (k, count): (u32, u32), hit: &SampleHit| -> Option<Vec3> {
            let g = side(count);
            let (o, d) = grid_ray(x, y, (k % g, k / g), g);
            (self.normals[hit.primitive as usize].dot(d) < 0.0).then(|| o + d * hit.t)
        };
        // Edge pixels' samples replaced by the finer grid's.
        let refine_edges = |x: u32, y: u32, buf: &mut Vec<SampleHit>| {
            if m == 0 {
                return;
            }
            let point = |k: usize| {
                let (o, d) = grid_ray(x, y, (k as u32 % n, k as u32 / n), n);
                o + d * buf[k].t
            };
            if on_edge(buf, &self.normals, point) {
                buf.clear();
                buf.extend((0..m * m).map(|k| {
                    let (o, d) = grid_ray(x, y, (k % m, k / m), m);
                    hit_at(o, d)
                }));
            }
        };
        let grids = &self.grids;
        // The side of the patch at surface point uv of a primitive (a
        // grouped triangle's group: its area's square root).
        let patch_size = |prim: u32, uv: Vec2| {
            let record = &v.primitives[prim as usize];
            let cell = match record.kind == layout::kind::GROUPED_TRIANGLE {
                true => 0,
                false => grids[prim as usize].locate(uv).cell,
            };
            v.patch_area.get((record.first_patch + cell) as usize).map_or(0.0, |a| a.sqrt())
        };
        let pixel_light = direct.map(|light| PixelLight {
            light,
            bvh: &bvh,
            normals: &self.normals,
            detail: &self.detail,
            point: &sample_point as &SamplePoint<'_>,
            trace: &hit_at as &RayHit<'_>,
            patch_size: &patch_size,
            eye: Vec3::from(record.position),
            frame,
        });
        // Images whose samples would not fit the cache budget are shaded
        // directly, sample by sample, keeping nothing.
        let sample_count = (w as u64) * (h as u64) * per_pixel as u64;
        if sample_cache_bytes((w as u64) * (h as u64), per_pixel as u64) > self.cache_budget {
            self.cache = None;
            self.retraced = sample_count as usize;
            let vrad = if direct.is_some() {
                vertex_radiance_seen(v, patch_radiance)
            } else {
                vertex_radiance(v, patch_radiance)
            };
            let hits_of = |x: u32, y: u32, buf: &mut Vec<SampleHit>| {
                buf.clear();
                buf.extend((0..per_pixel as u32).map(|k| trace(x, y, k % n, k / n)));
                refine_edges(x, y, buf);
            };
            let (image, direct, unlit) = shade_image((w, h), &hits_of, &vrad, &self.detail, pixel_light.as_ref());
            self.count_unlit(unlit, per_pixel);
            return (image, direct);
        }
        // Reuse what the samples saw last frame when the camera is the same.
        let mut samples = match self.cache.take() {
            Some((cam, samples, flags)) if cam == record && samples.len() == (w * h) as usize * per_pixel => {
                Some((samples, flags))
            }
            _ => None,
        };
        let retraced = std::sync::atomic::AtomicUsize::new(0);
        let sees_temporal = |s: &SampleHit| s.primitive != u32::MAX && self.temporal[s.primitive as usize];
        let on_temporal = |pixel: &[SampleHit]| pixel.iter().any(sees_temporal);
        match &mut samples {
            Some((cached, flags)) => {
                // Temporal primitives present now, in a small BVH of their own.
                let moving: Vec<u32> = kept.iter().copied().filter(|&i| self.temporal[i as usize]).collect();
                let moving_prims: Vec<Primitive> = moving.iter().map(|&i| self.all_prims[i as usize]).collect();
                let moving_bvh = (!moving_prims.is_empty()).then(|| PrimitiveBvh::new(&moving_prims));
                // Pixels the moving primitives may cover: each one's projected
                // bounding rectangle (the whole image if it reaches behind
                // the camera), widened by a pixel. (One rectangle around all
                // of them covered 2–3× the pixels in the fan room: the fan
                // and the lamp are far apart on screen.)
                let mut covered = vec![false; (w * h) as usize];
                for p in &moving_prims {
                    let mut rect = (f32::MAX, f32::MAX, f32::MIN, f32::MIN);
                    for v in &p.p[..p.corner_count()] {
                        match camera.project(*v) {
                            Some((x, y)) => rect = (rect.0.min(x), rect.1.min(y), rect.2.max(x), rect.3.max(y)),
                            None => rect = (f32::MIN, f32::MIN, f32::MAX, f32::MAX),
                        }
                    }
                    // Pixel x covers [x, x + 1): it may meet the rectangle
                    // widened by a pixel when x + 1 ≥ min − 1 and x ≤ max + 1.
                    let span = |lo: f32, hi: f32, n: u32| {
                        let a = (lo - 2.0).ceil().clamp(0.0, n as f32) as usize;
                        let b = ((hi + 1.0).floor() + 1.0).clamp(0.0, n as f32) as usize;
                        a..b.max(a)
                    };
                    let (xs, ys) = (span(rect.0, rect.2, w), span(rect.1, rect.3, h));
                    let whole = xs.len() == w as usize && ys.len() == h as usize;
                    for y in ys {
                        covered[y * w as usize..][xs.clone()].fill(true);
                    }
                    if whole {
                        break;
                    }
                }
                let inside = |x: u32, y: u32| covered[(y * w + x) as usize];
                let rows = cached.par_chunks_mut(w as usize * per_pixel).zip(flags.par_chunks_mut(w as usize));
                rows.enumerate().for_each(|(y, (row, row_flags))| {
                    for (x, (pixel, flag)) in row.chunks_mut(per_pixel).zip(row_flags).enumerate() {
                        let (x, y) = (x as u32, y as u32);
                        // Only a sample of a temporal primitive, or one a
                        // moving primitive may now hide, can be stale.
                        let near = inside(x, y);
                        if !*flag && !near {
                            continue;
                        }
                        for (k, sample) in pixel.iter_mut().enumerate() {
                            let (sx, sy) = ((k as u32) % n, (k as u32) / n);
                            let stale = sees_temporal(sample)
                                || moving_bvh.as_ref().filter(|_| near).is_some_and(|b| {
                                    let (o, d) = sample_ray(x, y, sx, sy);
                                    b.closest_hit(o, d, 0.0).is_some_and(|hit| hit.hit.t <= sample.t)
                                });
                            if stale {
                                *sample = trace(x, y, sx, sy);
                                retraced.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                            }
                        }
                        *flag = on_temporal(pixel);
                    }
                });
            }
            None => {
                let mut fresh = vec![NO_HIT; (w * h) as usize * per_pixel];
                fresh.par_chunks_mut(w as usize * per_pixel).enumerate().for_each(|(y, row)| {
                    for (i, sample) in row.iter_mut().enumerate() {
                        let (x, k) = ((i / per_pixel) as u32, i % per_pixel);
                        *sample = trace(x, y as u32, (k as u32) % n, (k as u32) / n);
                    }
                });
                retraced.store(fresh.len(), std::sync::atomic::Ordering::Relaxed);
                let flags = fresh.par_chunks(per_pixel).map(on_temporal).collect();
                samples = Some((fresh, flags));
            }
        }
        let (samples, flags) = samples.expect("filled above");
        self.retraced = retraced.into_inner();
        let vrad =
            if direct.is_some() { vertex_radiance_seen(v, patch_radiance) } else { vertex_radiance(v, patch_radiance) };
        let hits_of = |x: u32, y: u32, buf: &mut Vec<SampleHit>| {
            let at = (y as usize * w as usize + x as usize) * per_pixel;
            buf.clear();
            buf.extend_from_slice(&samples[at..at + per_pixel]);
            refine_edges(x, y, buf);
        };
        let (image, direct_image, unlit) = shade_image((w, h), &hits_of, &vrad, &self.detail, pixel_light.as_ref());
        self.count_unlit(unlit, per_pixel);
        let images = (image, direct_image);
        self.cache = Some((record, samples, flags));
        images
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A front-face sample of primitive `p` at distance `t`.
    fn seen(p: u32, t: f32) -> SampleHit {
        SampleHit { t, primitive: p, vertices: [0, 1, 2, 3], weights: [0.25; 4], ..NO_HIT }
    }

    #[test]
    fn edges_are_corners_silhouettes_and_steps_not_seams_in_a_plane() {
        let up = Vec3::Y;
        let tilted = |deg: f32| Vec3::new(deg.to_radians().sin(), deg.to_radians().cos(), 0.0);
        // Primitives: 0 and 1 the same floor plane, 2 a wall at 90°, 3 a
        // floor 0.3 below, 4 a facet 10° off the floor, 5 one 25° off.
        let normals = [up, up, Vec3::X, up, tilted(10.0), tilted(25.0)];
        // Sample 0 at the origin, the other a pixel's width (1 cm) away at
        // a distance of 2 m, on the plane each primitive is said to be in.
        let points = |second: Vec3| move |k: usize| if k == 0 { Vec3::ZERO } else { second };
        let pair = |p: u32| [seen(0, 2.0), seen(p, 2.0)];
        let across = Vec3::new(0.01, 0.0, 0.0);
        assert!(!on_edge(&pair(0), &normals, points(across)), "one primitive");
        assert!(!on_edge(&pair(1), &normals, points(across)), "a seam between coplanar quads");
        assert!(on_edge(&pair(2), &normals, points(across)), "a corner");
        assert!(on_edge(&pair(3), &normals, points(Vec3::new(0.01, -0.3, 0.0))), "a step down to a parallel floor");
        let facet = Vec3::new(0.01, 0.01 * 10f32.to_radians().tan(), 0.0);
        assert!(!on_edge(&pair(4), &normals, points(facet)), "neighbouring facets of a smooth mesh");
        assert!(on_edge(&pair(5), &normals, points(facet)), "a crease");
        // Misses and back faces against a front face are edges; among
        // themselves they are not.
        let back = SampleHit { t: 2.0, primitive: 2, ..NO_HIT };
        assert!(on_edge(&[seen(0, 2.0), NO_HIT], &normals, points(across)), "a silhouette against nothing");
        assert!(on_edge(&[NO_HIT, seen(0, 2.0)], &normals, points(across)));
        assert!(on_edge(&[seen(0, 2.0), back], &normals, points(across)), "a back face");
        assert!(!on_edge(&[NO_HIT, back, NO_HIT], &normals, points(across)));
        // Every sample is compared with the first.
        let hits = [seen(0, 2.0), seen(1, 2.0), seen(0, 2.0), seen(2, 2.0)];
        assert!(on_edge(&hits, &normals, |k| if k == 0 { Vec3::ZERO } else { across }));
    }
}
