//! Opening the archive a render reads, the way its memory plan says: link
//! ends mapped whole, or streamed a window at a time within the budget;
//! the plan said before the archive's long check starts.

use std::path::Path;

use anyhow::Result;
use illumnet::archive::{Archive, ArchiveSummary};
use illumnet::memory::MemoryBudget;
use illumnet::progress::Progress;
use illumnet::render::plan;

use crate::cli::common::{open_archive, opened};
use crate::cli::exit::bail_input;

use super::options::RenderArgs;

/// The archive at `path` opened within `budget` for `job` (refused before
/// work when it cannot fit), with the plan it was opened by.
pub fn open_within_budget(
    path: &Path,
    summary: &ArchiveSummary,
    job: &plan::RenderJob,
    budget: MemoryBudget,
    args: &RenderArgs,
    progress: &dyn Progress,
) -> Result<(Archive, plan::MemoryPlan)> {
    let memory = plan::plan(summary, job, budget)?;
    let samples = job.width as f64 * job.height as f64 * (args.samples * args.samples) as f64 * job.frames as f64;
    if samples >= 2e9 {
        progress.note(&format!(
            "this render shades {samples:.2e} image samples ({}×{} pixels, {}×{} samples each, {} frame{}): \
             expect minutes; fewer --samples or --frames make it cheaper",
            job.width,
            job.height,
            args.samples,
            args.samples,
            job.frames,
            if job.frames == 1 { "" } else { "s" }
        ));
    }
    if memory.access == plan::LinkAccess::Mapped && args.evict_each_pass {
        bail_input!("--evict-each-pass needs the link ends streamed: give a --memory-budget below the archive's size")
    }
    // Opening checks every checksum and link: about a minute for 15 GB.
    progress.busy("opening and checking the archive");
    let archive = match memory.access {
        plan::LinkAccess::Mapped => open_archive(path),
        plan::LinkAccess::Streamed { window_ends, .. } => opened(path, Archive::open_streamed(path, window_ends)),
    };
    progress.finish();
    let archive = archive?;
    // The checks' buffers, freed, are not held through the render.
    crate::return_freed_memory();
    if let Some(stream) = archive.link_stream() {
        stream.evict_each_pass(args.evict_each_pass);
        if let plan::LinkAccess::Streamed { in_flight, .. } = memory.access {
            stream.limit_windows_in_flight(in_flight);
        }
    }
    Ok((archive, memory))
}
