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
pub mod image_io;
mod pixels;
pub mod plan;
mod primary;
mod sampling;
mod shade;
mod vertex;
pub mod view;

use glam::{Vec2, Vec3};
use rayon::prelude::*;

pub use camera::PinholeCamera;
pub use direct::DirectLight;
pub use direct::gather::Gather;
pub use vertex::{vertex_radiance, vertex_radiance_seen};
pub use view::{frame_radiance, indirect_frame_radiance, indirect_radiance_seen_from, radiance_seen_from};

use crate::archive::InetView;
use crate::archive::layout::{self, PrimitiveRecord, cell_order};
use crate::geometry::accel::PrimitiveBvh;
use crate::geometry::grid::{CellOrder, PatchGrid};
use crate::geometry::{Primitive, PrimitiveKind};
use detail::SurfaceDetail;
use pixels::Unlit;
use primary::SampleHit;

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

/// The geometry and patch grid of an archive's primitive record.
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

/// Largest sample cache a [`Renderer`] keeps (1 GiB: 1920×1080 at 4×4
/// samples per pixel is 1.3 GB and is shaded without it).
const CACHE_BUDGET: u64 = 1 << 30;

/// A frame's camera and the BVH of the primitives present in it (`kept`:
/// the archive's primitive of each of the BVH's), `n × n` samples per pixel.
struct FrameRays {
    record: crate::archive::layout::CameraRecord,
    camera: PinholeCamera,
    kept: Vec<u32>,
    bvh: PrimitiveBvh,
    n: u32,
}

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
    /// (`direct`) added to `indirect`, the per-patch radiance without
    /// its direct part (see [`indirect_frame_radiance`]). Returns the
    /// image and its direct light alone (the indirect light is the
    /// difference).
    pub fn frame_direct(&mut self, frame: u32, indirect: &[[f32; 3]], direct: &DirectLight) -> (Image, Image) {
        let (total, direct) = self.shade(frame, indirect, Some(direct));
        (total, direct.expect("asked for"))
    }
}
