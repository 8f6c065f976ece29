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
pub mod image_io;
pub mod view;

use glam::{Vec2, Vec3};
use rayon::prelude::*;

pub use camera::PinholeCamera;
pub use view::{frame_radiance, radiance_seen_from};

use crate::archive::InetView;
use crate::archive::layout::PrimitiveRecord;
use crate::geometry::accel::PrimitiveBvh;
use crate::geometry::grid::{NO_VERTEX, PatchGrid};
use crate::geometry::{Primitive, PrimitiveKind};

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

/// Options for [`render`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderOptions {
    /// Samples per pixel along each axis (`n×n` per pixel).
    pub samples_per_axis: u32,
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self { samples_per_axis: 4 }
    }
}

/// Radiance at every patch vertex: area-weighted mean of adjacent patches.
pub fn vertex_radiance(v: &InetView<'_>, patch_radiance: &[[f32; 3]]) -> Vec<[f32; 3]> {
    let mut sum = vec![[0.0f64; 4]; v.vertex_position.len()];
    for (p, corners) in v.patch_corners.iter().enumerate() {
        let a = v.patch_area[p] as f64;
        for &c in corners.iter().filter(|&&c| c != NO_VERTEX) {
            let s = &mut sum[c as usize];
            for k in 0..3 {
                s[k] += a * patch_radiance[p][k] as f64;
            }
            s[3] += a;
        }
    }
    sum.iter().map(|s| if s[3] > 0.0 { [0, 1, 2].map(|k| (s[k] / s[3]) as f32) } else { [0.0; 3] }).collect()
}

fn primitive_of(r: &PrimitiveRecord) -> (Primitive, PatchGrid) {
    let kind = if r.kind == 0 { PrimitiveKind::Quad } else { PrimitiveKind::Triangle };
    let p = r.corners.map(Vec3::from);
    (Primitive { kind, p }, PatchGrid { kind, n_u: r.grid_u, n_v: r.grid_v })
}

/// Renders the archive's camera view from per-patch radiance.
pub fn render(v: &InetView<'_>, patch_radiance: &[[f32; 3]], opts: &RenderOptions) -> Image {
    render_frame(v, 0, patch_radiance, opts)
}

/// Renders `frame` of a sequence archive: only the primitives present then.
pub fn render_frame(v: &InetView<'_>, frame: u32, patch_radiance: &[[f32; 3]], opts: &RenderOptions) -> Image {
    let record = v.sequence.and_then(|s| s.cameras).and_then(|c| c.get(frame as usize)).unwrap_or(v.camera);
    let camera = PinholeCamera::from_record(record);
    let present = v.present_primitives(frame);
    let (all_prims, grids): (Vec<Primitive>, Vec<PatchGrid>) = v.primitives.iter().map(primitive_of).unzip();
    let normals: Vec<Vec3> = all_prims.iter().map(|p| p.normal()).collect();
    let kept: Vec<u32> = (0..all_prims.len() as u32).filter(|&i| present[i as usize]).collect();
    let prims: Vec<Primitive> = kept.iter().map(|&i| all_prims[i as usize]).collect();
    let bvh = PrimitiveBvh::new(&prims);
    let vrad = vertex_radiance(v, patch_radiance);
    let n = opts.samples_per_axis.max(1);
    let inv = 1.0 / (n * n) as f32;
    let (w, h) = (camera.width, camera.height);
    let mut pixels = vec![[0.0f32; 3]; (w * h) as usize];
    pixels.par_chunks_mut(w as usize).enumerate().for_each(|(y, row)| {
        for (x, px) in row.iter_mut().enumerate() {
            let mut acc = Vec3::ZERO;
            for sy in 0..n {
                for sx in 0..n {
                    let s = Vec2::new((sx as f32 + 0.5) / n as f32, (sy as f32 + 0.5) / n as f32);
                    let (o, d) = camera.ray(x as f32 + s.x, y as f32 + s.y);
                    let Some(hit) = bvh.closest_hit(o, d, 0.0) else {
                        continue;
                    };
                    let pi = kept[hit.primitive as usize] as usize;
                    if normals[pi].dot(d) >= 0.0 {
                        continue; // back face: surfaces are one-sided
                    }
                    let loc = grids[pi].locate(hit.hit.uv);
                    let first_vertex = v.primitives[pi].first_vertex;
                    for k in 0..4 {
                        if loc.corners[k] != NO_VERTEX && loc.weights[k] != 0.0 {
                            acc += loc.weights[k] * Vec3::from(vrad[(first_vertex + loc.corners[k]) as usize]);
                        }
                    }
                }
            }
            *px = (acc * inv).to_array();
        }
    });
    Image { width: w, height: h, pixels }
}
