//! `illumnet render`: distribute light over an archive's links and render
//! its camera view (or any other), frame by frame. Its arguments and the
//! order of its steps are here; the steps live in the files below:
//! `options` (settings and their checks), `relight` (`--set`),
//! `frame_plan` (which frames, which files), `open` (the memory plan and
//! the archive), `frame_loop` (each frame solved, shaded and checked),
//! `balance` (each frame's energy balance and what it warns of),
//! `outputs` (the files written), `explain` (`--false-color`) and
//! `summary` (the closing line).

mod balance;
mod explain;
mod frame_loop;
pub(crate) mod frame_plan;
mod open;
mod options;
mod outputs;
pub(crate) mod relight;
mod summary;

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Result;
use clap::Args;
use illumnet::archive::{self, Archive};
use illumnet::distribute;
use illumnet::memory::BudgetSource;
use illumnet::progress::Progress;
use illumnet::render::{self, RenderOptions, plan};

use super::camera::{self, RenderCameras};
use super::common::{BudgetArgs, memory_budget, opened};
use super::exit::bail_input;
use summary::{Totals, print_summary};

pub use explain::FalseColour;
pub use options::{RenderArgs, check_render_args};

/// `illumnet render`'s arguments.
#[derive(Args)]
pub struct RenderCommand {
    /// Archive written by `illumnet build`.
    archive: PathBuf,
    /// PNG image to write (sRGB, 8-bit).
    #[arg(short, long, value_name = "IMAGE.png")]
    output: PathBuf,
    /// Also write linear radiance as OpenEXR.
    #[arg(long, value_name = "IMAGE.exr")]
    exr: Option<PathBuf>,
    /// Frames of a sequence archive to render: `A..B` (B excluded),
    /// `A..=B`, `A..` (to the end), `..B` or one frame `N`; default all.
    /// `auto/K`: this task's share of K contiguous near-equal shares, the
    /// task from SLURM_ARRAY_TASK_ID (less SLURM_ARRAY_TASK_MIN) or
    /// JOB_COMPLETION_INDEX (Kubernetes Indexed Jobs). Several frames
    /// need a frame number pattern, e.g. out/frame_%04d.png.
    #[arg(long, value_name = "A..B")]
    frames: Option<String>,
    /// Skip frames whose files are complete and match this render (this
    /// archive, frame, camera and settings); render again those missing,
    /// partial (truncated, undecodable) or stale (another archive, other
    /// settings). The frame after a skipped one starts cold.
    #[arg(long)]
    skip_done: bool,
    /// Also write the rendered frames as a looping animated GIF preview.
    #[arg(long, value_name = "PREVIEW.gif")]
    gif: Option<PathBuf>,
    /// Also write the rendered frames side by side as one PNG, 10 per row.
    #[arg(long, value_name = "SHEET.png")]
    contact_sheet: Option<PathBuf>,
    /// Also write the solved light per patch: outgoing radiance as
    /// little-endian `f32` R, G, B per patch in patch order, nothing else
    /// (one frame only): for tools that compare solutions.
    #[arg(long, value_name = "FILE")]
    patch_radiance: Option<PathBuf>,
    #[command(flatten)]
    render: RenderArgs,
    #[command(flatten)]
    budget: BudgetArgs,
    #[command(flatten)]
    camera: camera::CameraArgs,
    #[command(flatten)]
    explain: explain::ExplainArgs,
    #[command(flatten)]
    relight: relight::RelightArgs,
    /// Share the distribution among the processes of an MPI job (launched
    /// by Open MPI's `mpirun`): each reads and gathers over the link ends
    /// of its own range of receivers, and they exchange what those
    /// received after every gather; the images are bit-identical to one
    /// process's, written by rank 0. Needs a binary built with
    /// `--features mpi` (docs/CLUSTER.md).
    #[arg(long)]
    mpi: bool,
}

/// Runs `illumnet render` with its parsed arguments.
pub fn run(command: RenderCommand, progress: &dyn Progress) -> Result<()> {
    let RenderCommand {
        archive,
        output,
        exr,
        frames,
        skip_done,
        gif,
        contact_sheet,
        patch_radiance,
        render: mut settings,
        budget,
        camera,
        explain,
        relight,
        mpi,
    } = command;
    settings.memory_budget = budget.memory_budget;
    let sets = relight.all()?;
    let extras = Extras {
        gif: gif.as_deref(),
        contact_sheet: contact_sheet.as_deref(),
        false_colour: explain.false_color,
        reference: explain.reference.as_deref(),
        error_scale: explain.error_scale,
        skip_done,
        team: None,
        patch_radiance: patch_radiance.as_deref(),
    };
    let go_with = |settings: RenderArgs, extras: Extras<'_>, progress: &dyn Progress| {
        RenderCameras::new(&camera).and_then(|cameras| {
            render(&archive, &output, exr.as_deref(), frames.as_deref(), settings, &cameras, &sets, extras, progress)
        })
    };
    match mpi {
        // Only rank 0 shows progress. Ranks on one node share its memory:
        // the default budget is divided among them.
        true => super::mpi::in_job(|team, on_this_node| {
            let quiet = illumnet::progress::NoProgress;
            let progress = if team.rank() == 0 { progress } else { &quiet };
            let mut settings = settings;
            if settings.memory_budget.is_none() && on_this_node > 1 {
                let share = super::common::memory_budget(None).bytes / on_this_node as u64;
                settings.memory_budget = Some(share);
                if team.rank() == 0 {
                    println!(
                        "memory: {on_this_node} ranks on this node: each takes 1/{on_this_node} of the default budget ({})",
                        illumnet::memory::Bytes(share)
                    );
                }
            }
            go_with(settings, Extras { team: Some(team), ..extras }, progress)
        }),
        false => go_with(settings, extras, progress),
    }
}

/// Optional parts of `render`: whole-sequence previews, a false-colour
/// picture instead of the shaded PNG, and the MPI job it shares the
/// distribution with.
#[derive(Clone, Copy, Default)]
pub struct Extras<'a> {
    pub gif: Option<&'a Path>,
    pub contact_sheet: Option<&'a Path>,
    pub false_colour: Option<FalseColour>,
    pub reference: Option<&'a Path>,
    pub error_scale: f32,
    /// `--skip-done`: frames whose files are complete and match are not
    /// rendered again.
    pub skip_done: bool,
    /// `--mpi`: the processes sharing the distribution; rank 0 alone
    /// prints and writes.
    pub team: Option<&'a dyn distribute::Team>,
    /// `--patch-radiance`: where the frame's per-patch radiance goes.
    pub patch_radiance: Option<&'a Path>,
}

impl Extras<'_> {
    /// Whether this process prints and writes: the only one, or rank 0 of
    /// an MPI job.
    pub fn leader(&self) -> bool {
        self.team.is_none_or(|t| t.rank() == 0)
    }
}

/// What every frame of one render shares: what was asked (options,
/// cameras, outputs), the archive's view and the distribution set up over
/// it. Made once all is checked, before the first frame.
pub struct RenderSetup<'a> {
    /// The archive's path (recorded in the images).
    pub path: &'a Path,
    /// The archive's identity (its section table's checksum), recorded in
    /// the images.
    pub archive_id: String,
    /// The archive, checked unchanged on disk after each frame's
    /// distribution and before each output is written.
    pub archive: &'a Archive,
    /// The PNG to write (a frame number pattern for several frames).
    pub png: &'a Path,
    /// The EXR to write, if asked (a pattern as `png`).
    pub exr: Option<&'a Path>,
    pub args: &'a RenderArgs,
    pub cameras: &'a RenderCameras,
    /// The `--set` changes (recorded in the images).
    pub sets: &'a [String],
    pub extras: Extras<'a>,
    /// The reference image of `--false-color error`.
    pub reference: Option<&'a render::Image>,
    pub frames: &'a frame_plan::FramePlan,
    pub view: &'a archive::InetView<'a>,
    pub distributor: &'a distribute::Distributor<'a>,
    /// Rays per pixel of the one-bounce gather (0: none).
    pub gather_rays: u32,
    /// Samples per axis of edge pixels (0: none).
    pub edge_samples: u32,
}

/// Renders the frames of the archive at `path` (all, or `frames`) to
/// `png` (and `exr`), through `cameras`, relit by `sets`, with the
/// optional outputs of `extras`; checks everything it can before work.
#[allow(clippy::too_many_arguments)]
pub fn render(
    path: &Path,
    png: &Path,
    exr: Option<&Path>,
    frames: Option<&str>,
    args: RenderArgs,
    cameras: &RenderCameras,
    sets: &[String],
    extras: Extras<'_>,
    progress: &dyn Progress,
) -> Result<()> {
    check_render_args(&args)?;
    options::check_outputs(png, exr, &args, &extras)?;
    let reference = options::read_reference(&extras)?;
    let budget = memory_budget(args.memory_budget);
    let t = Instant::now();
    let summary = opened(path, Archive::summary(path))?;
    let frame_plan = frame_plan::plan_frames(&summary, cameras, frames, reference.as_ref())?;
    if frame_plan.range.is_empty() {
        // `--frames auto/K` with more tasks than frames.
        if extras.leader() {
            println!("no frames to render: {} has none for this task", frames.unwrap_or_default());
        }
        return Ok(());
    }
    if extras.patch_radiance.is_some() && frame_plan.range.len() != 1 {
        bail_input!("--patch-radiance writes one frame's light: give one frame (--frames N)");
    }
    let (width, height) = frame_plan.largest;
    let job = plan::RenderJob {
        width,
        height,
        samples_per_axis: args.samples,
        frames: frame_plan.range.len() as u32,
        keep_images: extras.gif.is_some() || extras.contact_sheet.is_some(),
        anderson_depth: args.anderson as u32,
        buckets: !args.no_buckets,
        threads: rayon::current_num_threads() as u32,
        keeps_solving: false,
    };
    let (archive, memory) = open::open_within_budget(path, &summary, &job, budget, &args, progress)?;
    if extras.leader() && (budget.source == BudgetSource::Given || memory.access != plan::LinkAccess::Mapped) {
        println!("memory: {memory}");
    }
    let view = archive.view();
    let t_open = t.elapsed().as_secs_f64();
    let sequence_output = frame_plan.sequence_output();
    let gather_rays = options::gather_rays(&args, exr, &extras, sequence_output);
    // Check the pattern before any work.
    frame_plan.out_path(png, frame_plan.range.start)?;
    if let Some(exr) = exr {
        frame_plan.out_path(exr, frame_plan.range.start)?;
    }
    let opts = options::distribute_options(&args);
    let mut lighting = distribute::Lighting::from_view(&view);
    relight::relight(&mut lighting, &archive, sets)?;
    let t_s = Instant::now();
    let mut distributor = distribute::Distributor::new_in(&view, &opts, &lighting, extras.team)?;
    if memory.spill {
        // Beside the images: where the user has room for outputs (a system
        // temporary directory may be memory); an MPI rank on a node without
        // the output's directory, in the system's.
        let out = frame_plan.out_path(png, frame_plan.range.start)?;
        let dir = illumnet::scratch::dir_of(&out);
        let dir = if dir.is_dir() { dir.to_path_buf() } else { std::env::temp_dir() };
        distributor = distributor.spill_in(&dir);
    }
    let t_setup = t_s.elapsed().as_secs_f64();
    let edge_samples = options::edge_samples(&args, sequence_output);
    let render_opts = RenderOptions { samples_per_axis: args.samples, edge_samples_per_axis: edge_samples };
    let mut renderer = render::Renderer::new(&view, render_opts).with_cache_budget(memory.cache_bytes);
    let setup = RenderSetup {
        path,
        archive_id: summary.identity(),
        archive: &archive,
        png,
        exr,
        args: &args,
        cameras,
        sets,
        extras,
        reference: reference.as_ref(),
        frames: &frame_plan,
        view: &view,
        distributor: &distributor,
        gather_rays,
        edge_samples,
    };
    let mut totals = Totals::starting_at((summary.camera.width, summary.camera.height));
    let images = frame_loop::render_frames(&setup, &mut renderer, &mut totals, progress)?;
    archive.check_unchanged()?;
    if extras.leader() {
        outputs::write_previews(&setup, &images)?;
        print_summary(&setup, &totals, t_open, t_setup);
    }
    Ok(())
}
