//! Shading pixels from their samples: each pixel the box-filtered mean
//! of what its samples see (interpolated vertex radiance, times a
//! texture's albedo scale), with, when the frame has a [`DirectLight`],
//! the one-bounce gather blended in near other geometry and the direct
//! light of the emitters in two passes.

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use super::Image;
use super::detail::SurfaceDetail;
use super::direct::gather::ExactDirect;
use super::direct::{self, DirectLight};
use super::primary::{PatchSize, RayHit, SampleHit, SamplePoint};
use super::sampling::pixel_key;
use crate::geometry::accel::PrimitiveBvh;
use crate::geometry::grid::NO_VERTEX;

/// What the direct light of a pixel needs: the frame's emitters, its
/// shadow-ray BVH, the primitives' normals and detail, and the samples'
/// positions; and for the gather, the frame's rays.
pub(super) struct PixelLight<'f> {
    pub(super) light: &'f DirectLight,
    pub(super) bvh: &'f PrimitiveBvh,
    pub(super) normals: &'f [Vec3],
    pub(super) detail: &'f SurfaceDetail<'f>,
    pub(super) point: &'f SamplePoint<'f>,
    pub(super) trace: &'f RayHit<'f>,
    pub(super) patch_size: &'f PatchSize<'f>,
    /// Where the camera is (glossy highlights depend on it).
    pub(super) eye: Vec3,
    pub(super) frame: u32,
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
pub(super) type PixelHits<'f> = dyn Fn(u32, u32, &mut Vec<SampleHit>) + Sync + 'f;

/// How far (in pixels, each way) the second pass of direct light looks for
/// a blocked first-pass ray: a pixel is estimated again when one of the
/// `(2r + 1)² − 1` pixels around it had one. At 1, pixels on the outskirts
/// of a penumbra whose own rays alone were blocked kept their four-ray
/// estimate: isolated dark dots (27 on the Cornell box, each 15–20% dark).
const REFINE_RADIUS: u32 = 2;

/// Pixels (and shares of pixels) of an image whose samples saw a back
/// face, or nothing: what a black image is made of when the camera is
/// misplaced.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Unlit {
    pub(super) back_faces: f64,
    pub(super) nothing: f64,
}

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
pub(super) fn shade_image(
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
    refine_direct((w, h), hits_of, pl, &blocked, &mut direct_pixels);
    for (d, g) in direct_pixels.iter_mut().zip(&glossy_pixels) {
        *d = [0, 1, 2].map(|c| d[c] + g[c]);
    }
    for (p, d) in pixels.iter_mut().zip(&direct_pixels) {
        *p = [0, 1, 2].map(|c| p[c] + d[c]);
    }
    (Image { width: w, height: h, pixels }, Some(Image { width: w, height: h, pixels: direct_pixels }), unlit)
}

/// The second pass of direct light ([`shade_image`]), into
/// `direct_pixels`: every pixel with a pixel within [`REFINE_RADIUS`]
/// whose first rays were blocked (`blocked`, per pixel the emitters they
/// found so) is estimated again for those emitters. Each pixel reads the
/// first pass's marks of its neighbours only.
fn refine_direct(
    (w, h): (u32, u32),
    hits_of: &PixelHits<'_>,
    pl: &PixelLight<'_>,
    blocked: &[u64],
    direct_pixels: &mut [[f32; 3]],
) {
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
}

/// How much of each sample's indirect light of pixel `(x, y)` comes from
/// the gather ([`super::Gather::reach_weight`]), by primitive, into
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
    // What the camera's rays meet is found in the same BVH. The search
    // looks a little past `t_max` (10⁻⁵ of it): the traversal skips a box
    // whose entry, rounded, is not below its bound, and a hit just below
    // `t_max` would be lost where the box's entry rounds up to it; a hit
    // past `t_max` changes no probe's minimum.
    let nearest = |o: Vec3, w: Vec3, t_max: f32| {
        pl.bvh.closest_hit_within(o, w, 0.0, t_max * (1.0 + 1e-5)).map_or(t_max, |h| h.hit.t)
    };
    for run in scratch.lit.chunk_by(|a, b| a.0 == b.0) {
        let prim = run[0].0;
        let mean = run.iter().map(|r| r.1).sum::<Vec3>() / run.len() as f32;
        let size = (pl.patch_size)(prim, run[0].2);
        let w = gather.reach_weight(mean, pl.normals[prim as usize], size, pl.light.epsilon(), &nearest);
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
    let key = pixel_key(pl.frame, x, y) ^ 0x2545_f491_4f6c_dd1d;
    let exact = ExactDirect { light: pl.light, bvh: pl.bvh, normals: pl.normals, emitters };
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
    let pixel = pixel_key(pl.frame, x, y);
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
