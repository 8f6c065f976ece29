//! A frame's image ([`Renderer::shade`]): its samples traced, or those
//! of the last frame reused where the camera held still and re-traced
//! only where moving geometry may have changed them (the sample cache),
//! then shaded into pixels (`pixels.rs`).

use std::sync::atomic::{AtomicUsize, Ordering};

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use super::pixels::{PixelLight, shade_image};
use super::primary::{FrameTracer, NO_HIT, RayHit, SampleHit, SamplePoint};
use super::vertex::{vertex_radiance, vertex_radiance_seen};
use super::{DirectLight, FrameRays, Image, PinholeCamera, Renderer, sample_cache_bytes};
use crate::geometry::Primitive;
use crate::geometry::accel::PrimitiveBvh;

impl Renderer<'_> {
    /// The image of `frame` (and its direct part when `direct` is given).
    pub(super) fn shade(
        &mut self,
        frame: u32,
        patch_radiance: &[[f32; 3]],
        direct: Option<&DirectLight>,
    ) -> (Image, Option<Image>) {
        let FrameRays { record, camera, kept, bvh, n } = self.frame_rays(frame);
        let (w, h) = (camera.width, camera.height);
        let per_pixel = (n * n) as usize;
        // Edge pixels' finer grid (0: none).
        let m = match self.opts.edge_samples_per_axis.min(256) {
            m if m > n => m,
            _ => 0,
        };
        let tracer = FrameTracer {
            v: &self.v,
            camera: &camera,
            kept: &kept,
            bvh: &bvh,
            normals: &self.normals,
            grids: &self.grids,
            n,
            m,
        };
        let sample_point =
            |x: u32, y: u32, of: (u32, u32), hit: &SampleHit| -> Option<Vec3> { tracer.sample_point(x, y, of, hit) };
        let hit_at = |o: Vec3, d: Vec3| -> SampleHit { tracer.hit_at(o, d) };
        let patch_size = |prim: u32, uv: Vec2| tracer.patch_size(prim, uv);
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
        let vrad = if direct.is_some() {
            vertex_radiance_seen(&self.v, patch_radiance)
        } else {
            vertex_radiance(&self.v, patch_radiance)
        };
        // Images whose samples would not fit the cache budget are shaded
        // directly, sample by sample, keeping nothing.
        let sample_count = (w as u64) * (h as u64) * per_pixel as u64;
        if sample_cache_bytes((w as u64) * (h as u64), per_pixel as u64) > self.cache_budget {
            self.cache = None;
            self.retraced = sample_count as usize;
            let hits_of = |x: u32, y: u32, buf: &mut Vec<SampleHit>| {
                buf.clear();
                buf.extend((0..per_pixel as u32).map(|k| tracer.trace(x, y, k % n, k / n)));
                tracer.refine_edges(x, y, buf);
            };
            let (image, direct, unlit) = shade_image((w, h), &hits_of, &vrad, &self.detail, pixel_light.as_ref());
            self.count_unlit(unlit, per_pixel);
            return (image, direct);
        }
        // Reuse what the samples saw last frame when the camera is the same.
        let cached = match self.cache.take() {
            Some((cam, samples, flags)) if cam == record && samples.len() == (w * h) as usize * per_pixel => {
                Some((samples, flags))
            }
            _ => None,
        };
        let (samples, flags, retraced) = match cached {
            Some((mut samples, mut flags)) => {
                let retraced = self.retrace_stale(&tracer, &mut samples, &mut flags);
                (samples, flags, retraced)
            }
            None => self.trace_all(&tracer),
        };
        self.retraced = retraced;
        let hits_of = |x: u32, y: u32, buf: &mut Vec<SampleHit>| {
            let at = (y as usize * w as usize + x as usize) * per_pixel;
            buf.clear();
            buf.extend_from_slice(&samples[at..at + per_pixel]);
            tracer.refine_edges(x, y, buf);
        };
        let (image, direct_image, unlit) = shade_image((w, h), &hits_of, &vrad, &self.detail, pixel_light.as_ref());
        self.count_unlit(unlit, per_pixel);
        let images = (image, direct_image);
        self.cache = Some((record, samples, flags));
        images
    }

    /// Re-traces the last frame's samples `cached` that moving geometry
    /// may have changed, `flags` telling per pixel whether one of its
    /// samples saw a temporal primitive (then updated): only a sample of a
    /// temporal primitive, or one a moving primitive present now may hide,
    /// can be stale. Pixels with neither kind are not read. Returns the
    /// samples re-traced.
    fn retrace_stale(&self, tracer: &FrameTracer<'_>, cached: &mut [SampleHit], flags: &mut [bool]) -> usize {
        let (w, n) = (tracer.camera.width, tracer.n);
        let per_pixel = (n * n) as usize;
        let retraced = AtomicUsize::new(0);
        let temporal = &self.temporal[..];
        // Temporal primitives present now, in a small BVH of their own.
        let moving: Vec<u32> = tracer.kept.iter().copied().filter(|&i| self.temporal[i as usize]).collect();
        let moving_prims: Vec<Primitive> = moving.iter().map(|&i| self.all_prims[i as usize]).collect();
        let moving_bvh = (!moving_prims.is_empty()).then(|| PrimitiveBvh::new(&moving_prims));
        let covered = moving_cover(tracer.camera, &moving_prims);
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
                    let stale = sees_temporal(temporal, sample)
                        || moving_bvh.as_ref().filter(|_| near).is_some_and(|b| {
                            let (o, d) = tracer.sample_ray(x, y, sx, sy);
                            b.closest_hit(o, d, 0.0).is_some_and(|hit| hit.hit.t <= sample.t)
                        });
                    if stale {
                        *sample = tracer.trace(x, y, sx, sy);
                        retraced.fetch_add(1, Ordering::Relaxed);
                    }
                }
                *flag = on_temporal(temporal, pixel);
            }
        });
        retraced.into_inner()
    }

    /// Every sample of the frame traced afresh, per pixel whether one of
    /// its samples sees a temporal primitive, and how many were traced.
    fn trace_all(&self, tracer: &FrameTracer<'_>) -> (Vec<SampleHit>, Vec<bool>, usize) {
        let (w, h, n) = (tracer.camera.width, tracer.camera.height, tracer.n);
        let per_pixel = (n * n) as usize;
        let temporal = &self.temporal[..];
        let mut fresh = vec![NO_HIT; (w * h) as usize * per_pixel];
        fresh.par_chunks_mut(w as usize * per_pixel).enumerate().for_each(|(y, row)| {
            for (i, sample) in row.iter_mut().enumerate() {
                let (x, k) = ((i / per_pixel) as u32, i % per_pixel);
                *sample = tracer.trace(x, y as u32, (k as u32) % n, (k as u32) / n);
            }
        });
        let traced = fresh.len();
        let flags = fresh.par_chunks(per_pixel).map(|pixel| on_temporal(temporal, pixel)).collect();
        (fresh, flags, traced)
    }
}

/// Whether sample `s` sees a primitive of a temporal instance.
fn sees_temporal(temporal: &[bool], s: &SampleHit) -> bool {
    s.primitive != u32::MAX && temporal[s.primitive as usize]
}

/// Whether one of a pixel's samples sees a temporal primitive.
fn on_temporal(temporal: &[bool], pixel: &[SampleHit]) -> bool {
    pixel.iter().any(|s| sees_temporal(temporal, s))
}

/// Per pixel of `camera`'s image, whether one of the moving primitives
/// may cover it: each one's projected bounding rectangle (the whole image
/// if it reaches behind the camera), widened by a pixel. (One rectangle
/// around all of them covered 2–3× the pixels in the fan room: the fan
/// and the lamp are far apart on screen.)
fn moving_cover(camera: &PinholeCamera, moving_prims: &[Primitive]) -> Vec<bool> {
    let (w, h) = (camera.width, camera.height);
    let mut covered = vec![false; (w * h) as usize];
    for p in moving_prims {
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
    covered
}
