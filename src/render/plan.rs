//! Planning a render under a memory budget, from the archive's summary
//! alone (header, table, `BILD`, `DIDX`): whether the archive can be
//! mapped whole, or its link ends must be streamed and in windows of what
//! size, and how large a sample cache fits; or, before any work, that the
//! job cannot be done within the budget and what it would need.
//!
//! Everything resident counts: a mapped archive's pages (all of them: a
//! distribution reads every link end each iteration), or a streamed one's
//! copied sections, chunk checksums and its link windows (one per worker
//! where the budget has room, else as many as fit, at least two); the
//! distribution's
//! state ([`crate::distribute::memory`]); the images, vertex radiance,
//! primitives and the sample cache of the renderer.

use std::fmt;

use crate::archive::{ArchiveSummary, CHUNK_ENDS, layout::tag};
use crate::distribute::memory::{StateShape, kept_patch_bytes, patch_bytes, spilled_bytes, state_bytes};
use crate::memory::{Bytes, MemoryBudget};

/// Bytes per link end a window's buffers hold for the columns (`LOTH`,
/// `LCNT`, `LDIR`); its runs (`LRUN`, 8 bytes each) come on top.
const WINDOW_BYTES_PER_END: u64 = 7;
/// The largest window planned: 0.75 MiB of `LOTH` and `LCNT` stays in the
/// cache between the reader and the gather (2^18 ends measured 1.5× the
/// rate of 2^22, 1.3× that of 2^16, on the Cornell box, at 5 bytes an
/// end).
const MAX_WINDOW_ENDS: u64 = 1 << 18;
/// The smallest window planned (a chunk).
const MIN_WINDOW_ENDS: u64 = CHUNK_ENDS as u64;
/// The buffer a streamed open reads its columns through (16 chunks of
/// `LDIR`, the widest column).
const OPEN_BUFFER: u64 = 16 * CHUNK_ENDS as u64 * 4;
/// The largest sample cache kept (as without a budget).
const MAX_CACHE: u64 = 1 << 30;

/// What will be rendered, as far as memory goes.
#[derive(Clone, Copy, Debug)]
pub struct RenderJob {
    /// Image width and height.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Samples per pixel along each axis.
    pub samples_per_axis: u32,
    /// Frames rendered.
    pub frames: u32,
    /// Whether every frame's image is kept (for a GIF or a contact sheet).
    pub keep_images: bool,
    /// Secant pairs of the distribution's acceleration.
    pub anderson_depth: u32,
    /// Whether the distribution uses the archive's buckets.
    pub buckets: bool,
    /// Worker threads: a streamed gather reads a window per worker, as
    /// many at once as the budget has room for (at least two).
    pub threads: u32,
    /// Whether the job keeps solving after its frames are shaded (`serve`,
    /// which solves again on every change): then nothing is freed after a
    /// frame (received power, link windows) and the state is never
    /// spilled. A render solves each frame once.
    pub keeps_solving: bool,
}

/// How the archive's link ends are held.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LinkAccess {
    /// The file mapped whole ([`crate::archive::Archive::open`]).
    Mapped,
    /// Read in windows of about this many ends
    /// ([`crate::archive::Archive::open_streamed`]), at most
    /// `in_flight` of them held at once
    /// ([`crate::archive::LinkStream::limit_windows_in_flight`]).
    Streamed {
        /// Link ends per window.
        window_ends: usize,
        /// Windows read and used at once: one per worker thread where the
        /// budget has room, fewer (at least two) where it has not.
        in_flight: usize,
    },
}

/// A render's memory plan: how to open the archive, the sample cache, and
/// what is expected resident, part by part.
#[derive(Clone, Debug)]
pub struct MemoryPlan {
    /// How to open the archive.
    pub access: LinkAccess,
    /// The sample cache's budget (0: trace every sample every frame).
    pub cache_bytes: u64,
    /// Frames the job renders (a cache serves only later frames).
    pub frames: u32,
    /// The budget planned against.
    pub budget: MemoryBudget,
    /// Planned resident bytes, by part.
    pub parts: Vec<(&'static str, u64)>,
    /// The archive's patches (for the per-patch figures the plan states).
    pub patches: u64,
    /// Whether the distribution keeps its secant pairs and received totals
    /// in scratch files (beside the output) instead of memory: where the
    /// budget has no room for them (`Distributor::spill_in`).
    pub spill: bool,
    /// Bytes those scratch files hold at most (on disk, in the page cache:
    /// not counted in the parts).
    pub spilled_bytes: u64,
}

/// Bytes of some parts in all.
fn sum(parts: &[(&'static str, u64)]) -> u64 {
    parts.iter().map(|p| p.1).sum()
}

impl MemoryPlan {
    /// Planned resident bytes in all.
    pub fn total(&self) -> u64 {
        sum(&self.parts)
    }
}

impl fmt::Display for MemoryPlan {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.access {
            LinkAccess::Mapped => write!(f, "archive mapped whole")?,
            LinkAccess::Streamed { window_ends, in_flight } => {
                write!(f, "link ends streamed from disk in windows of {window_ends} ends, {in_flight} held at once")?
            }
        }
        write!(f, ", {} planned of a budget of {} (", Bytes(self.total()), self.budget)?;
        for (i, (name, b)) in self.parts.iter().filter(|p| p.1 > 0).enumerate() {
            write!(f, "{}{name} {}", if i > 0 { ", " } else { "" }, Bytes(*b))?;
            if *name == DISTRIBUTION && self.patches > 0 {
                write!(f, ", {} bytes a patch", b / self.patches)?;
                if self.spill {
                    write!(f, "; its secant pairs and totals, {}, in a scratch file", Bytes(self.spilled_bytes))?;
                }
            }
        }
        write!(f, "; {} bytes a patch in all)", self.total() / self.patches.max(1))?;
        if self.cache_bytes == 0 && self.frames > 1 {
            write!(f, ", no sample cache (every frame traces all its image samples)")?;
        }
        Ok(())
    }
}

/// A job that does not fit its budget: what it needs at least, by part.
#[derive(Clone, Debug)]
pub struct BudgetError {
    /// The budget.
    pub budget: MemoryBudget,
    /// The least the job needs, by part.
    pub parts: Vec<(&'static str, u64)>,
}

impl BudgetError {
    /// The least the job needs in all.
    pub fn needed(&self) -> u64 {
        sum(&self.parts)
    }
}

impl fmt::Display for BudgetError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "the render needs at least {} of memory, more than the budget of {} (",
            Bytes(self.needed()),
            self.budget
        )?;
        for (i, (name, b)) in self.parts.iter().filter(|p| p.1 > 0).enumerate() {
            write!(f, "{}{name} {}", if i > 0 { ", " } else { "" }, Bytes(*b))?;
        }
        // Advice for the largest part: only the images shrink with the job.
        let (largest, bytes) = self.parts.iter().max_by_key(|p| p.1).copied().unwrap_or(("", 0));
        if largest == IMAGES {
            write!(f, "); raise --memory-budget, or render a smaller image or fewer samples")
        } else {
            write!(
                f,
                "); raise --memory-budget to at least {} (the largest part, {largest} {}, does not shrink with \
                 the image)",
                Bytes(self.needed()),
                Bytes(bytes)
            )
        }
    }
}

impl std::error::Error for BudgetError {}

/// The distribution's state for the archive `s` summarises at its peak,
/// what of it is still held once a frame is solved, and what it keeps in
/// scratch files when `spill`.
fn distribution_bytes(s: &ArchiveSummary, job: &RenderJob, spill: bool) -> (u64, u64, u64) {
    let b = &s.build;
    let (p, e) = (b.patch_count as u64, b.link_end_count);
    let nd = s.section_count(tag::NONDIFFUSE_PATCHES);
    let buckets = if job.buckets && b.max_bucket > 0 { b.max_bucket as u64 + 1 } else { 1 };
    let shape = StateShape {
        patches: p,
        buckets,
        anderson_depth: job.anderson_depth as u64,
        sequence: s.section_count(tag::ANIMATION) > 0,
        nondiffuse_slots: nd * b.direction_count as u64,
        nondiffuse_ends: (e * nd).checked_div(p).unwrap_or(0),
        // Entries (u32) and factors (f32), as records: the sections may be compressed.
        table_bytes: 4 * (s.section_count(tag::PROTOTYPE_DIRECTIONS) + s.section_count(tag::PROTOTYPE_FACTORS)),
        max_delta_records: s.max_delta_records,
        spill,
    };
    let peak = state_bytes(&shape);
    // Glossy light and a sequence's overlays are held throughout. A
    // render's last frame frees the received power no later frame starts
    // from (`Solution::release_warm_start`): a still's only frame.
    let released = if job.frames == 1 && !shape.sequence && !job.keeps_solving { 12 * p } else { 0 };
    let kept = peak - p * (patch_bytes(&shape) - kept_patch_bytes(&shape)) - released;
    (peak, kept, spilled_bytes(&shape))
}

/// The renderer's own memory: images, primitives and their BVH (the
/// sample cache apart); and vertex and patch radiance, made once the
/// frame's light is solved.
fn renderer_bytes(s: &ArchiveSummary, job: &RenderJob) -> (u64, u64) {
    let pixels = job.width as u64 * job.height as u64;
    let b = &s.build;
    // Per pixel: the image and its direct part (12 each), the encoded
    // PNG and EXR rows, the shading passes' per-pixel flags and samples.
    let images = pixels * 64 + if job.keep_images { pixels * 12 * job.frames as u64 } else { 0 };
    // Radiance, made once the light is solved, at its larger of two
    // moments (`render::direct::gather`, `render::shade`): the gather's
    // per-patch reflected light and its direct-free copy (12 each) while
    // its vertex light is made from them (12 a vertex, and f64 sums for at
    // most 2¹⁷ vertices at a time, `render::vertex`); then the view's patch
    // radiance (12) and the gather's vertex light (12) while the view's
    // vertex radiance is made (12, and the sums).
    let (p, v) = (b.patch_count as u64, b.vertex_count as u64);
    let sums = v.min(1 << 17) * 32;
    // A grouped mesh's triangle corners with their groups (8 bytes each).
    let grouped = s.section_count(tag::GROUPED_TRIANGLE_VERTICES) * 3 * 8;
    let radiance = (24 * p + 12 * v).max(12 * p + 24 * v) + sums + grouped;
    let primitives = b.primitive_count as u64 * 320;
    (images + primitives, radiance)
}

/// The distribution's part of a plan.
const DISTRIBUTION: &str = "distribution";

/// The part of a plan that the image size and samples set.
const IMAGES: &str = "images and radiance";

/// Plans rendering `job` from the archive `s` summarises within `budget`:
/// the archive mapped whole, else its link ends streamed, else streamed
/// with the distribution's secant pairs and totals spilled to scratch
/// files; or, when none fits, what the last would need.
pub fn plan(s: &ArchiveSummary, job: &RenderJob, budget: MemoryBudget) -> Result<MemoryPlan, BudgetError> {
    let mut plan = plan_with(s, job, budget, false);
    if plan.is_err() && !job.keeps_solving {
        plan = plan_with(s, job, budget, true);
    }
    plan
}

/// [`plan`] with the distribution spilling (`spill`) or not, as the
/// caller decides.
pub fn plan_with(
    s: &ArchiveSummary,
    job: &RenderJob,
    budget: MemoryBudget,
    spill: bool,
) -> Result<MemoryPlan, BudgetError> {
    let (distribution, kept, spilled_bytes) = distribution_bytes(s, job, spill);
    let (images, radiance) = renderer_bytes(s, job);
    // A single frame's radiance is made in the room its distribution's
    // loop left (`distribute::memory`): the peak is the larger of the two
    // phases. Frames after the first solve their light beside the last
    // frame's radiance: both count.
    let reused = match job.frames {
        1 => radiance.min(distribution - kept),
        _ => 0,
    };
    let renderer = images + radiance - reused;
    // Streamed, a single frame's link windows are freed before it is
    // shaded (`release_buffers`): its radiance is made in their room too.
    let shading = |windows: u64| match job.frames == 1 && !job.keeps_solving {
        true => images + (kept + radiance).saturating_sub(distribution + windows),
        false => renderer,
    };
    let pixels = job.width as u64 * job.height as u64;
    // The cache pays off only when a later frame reuses the samples.
    let cache = match job.frames > 1 {
        true => super::sample_cache_bytes(pixels, (job.samples_per_axis as u64).pow(2)).min(MAX_CACHE),
        false => 0,
    };
    let fixed = [(DISTRIBUTION, distribution), (IMAGES, renderer)];
    let patches = s.build.patch_count as u64;
    let with = |mut parts: Vec<(&'static str, u64)>| {
        parts.extend(fixed);
        parts
    };
    let fits = |parts: &[(&'static str, u64)]| sum(parts) <= budget.bytes;
    // Mapped whole, with the cache, then without (never spilling: a budget
    // with no room for the state has none for the mapped archive).
    for cache in [cache, 0].into_iter().filter(|_| !spill) {
        let parts = with(vec![("archive (mapped)", s.file_length), ("sample cache", cache)]);
        if fits(&parts) {
            return Ok(MemoryPlan {
                access: LinkAccess::Mapped,
                cache_bytes: cache,
                frames: job.frames,
                budget,
                parts,
                patches,
                spill,
                spilled_bytes,
            });
        }
    }
    // Streamed: the copied sections, a checksum per column per chunk, the
    // open's read buffer, and the link windows.
    let ends = s.build.link_end_count;
    // Three columns' XXH3 per chunk of ends, and one per window for its runs.
    let sums = ends.div_ceil(CHUNK_ENDS as u64) * 32;
    // `DELT` stays on disk: one frame's stored bytes at a time.
    let held = s.held_bytes() + sums + OPEN_BUFFER + s.max_delta_stored;
    // One window per worker where there is room, else as many as fit at
    // the smallest size, and never fewer than two: the least a streamed
    // render needs does not grow with the machine's cores.
    let workers = job.threads.max(2) as u64;
    // A window's runs: twice the archive's mean per end (windows vary),
    // at most one an end.
    let runs = s.section_count(tag::LINK_RUNS);
    let per_end = WINDOW_BYTES_PER_END + (16 * runs).div_ceil(ends.max(1)).min(8);
    let one_window = |w: u64| (w + 2 * CHUNK_ENDS as u64) * per_end;
    const WINDOWS: &str = "link windows";
    let base = vec![("archive sections held", held), (DISTRIBUTION, distribution)];
    let with_windows = |windows: u64| {
        let mut parts = base.clone();
        parts.extend([(IMAGES, shading(windows)), (WINDOWS, windows)]);
        parts
    };
    let least = with_windows(2 * one_window(MIN_WINDOW_ENDS));
    if !fits(&least) {
        return Err(BudgetError { budget, parts: least });
    }
    // The room for windows and the cache, as if the shading reused none of
    // it (so that any windows chosen fit).
    let room = budget.bytes.saturating_sub(sum(&base) + shading(0));
    // The cache only where it leaves room for the largest windows, one
    // per worker (so on many cores the cache needs a larger budget: 250
    // MB of windows on 64).
    let cache = if cache > 0 && room >= cache + workers * one_window(MAX_WINDOW_ENDS) { cache } else { 0 };
    let in_flight = ((room - cache) / one_window(MIN_WINDOW_ENDS)).clamp(2, workers);
    let per_window = (room - cache) / (in_flight * per_end);
    let window = per_window.saturating_sub(2 * CHUNK_ENDS as u64).clamp(MIN_WINDOW_ENDS, MAX_WINDOW_ENDS);
    let mut parts = with_windows(in_flight * one_window(window));
    parts.push(("sample cache", cache));
    let access = LinkAccess::Streamed { window_ends: window as usize, in_flight: in_flight as usize };
    Ok(MemoryPlan { access, cache_bytes: cache, frames: job.frames, budget, parts, patches, spill, spilled_bytes })
}
