//! `illumnet demo`: the embedded Cornell box built and rendered into a
//! folder, with `build`'s resolution options, `render`'s settings, and one
//! memory budget for both stages.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::Args;
use illumnet::progress::Progress;
use illumnet::scene::Scene;
use illumnet::scratch::OutputDir;

use super::build::{BuildArgs, build_scene};
use super::camera::RenderCameras;
use super::common::BudgetArgs;
use super::exit::bail_input;
use super::render::{Extras, RenderArgs, check_render_args, render};

/// `illumnet demo`'s arguments.
#[derive(Args)]
pub struct DemoCommand {
    /// Directory for cornell_box.inet, .png and .exr.
    #[arg(short, long, default_value = "demo-output", value_name = "DIR")]
    output: PathBuf,
    #[command(flatten)]
    settings: BuildArgs,
    #[command(flatten)]
    render: RenderArgs,
    #[command(flatten)]
    pub budget: BudgetArgs,
}

/// Runs `illumnet demo` with its parsed arguments: one budget for its
/// build and its render.
pub fn run(command: DemoCommand, progress: &dyn Progress) -> Result<()> {
    let DemoCommand { output, mut settings, mut render, budget } = command;
    (settings.memory_budget, render.memory_budget) = (budget.memory_budget, budget.memory_budget);
    demo(&output, settings, render, progress)
}

/// Builds the embedded Cornell box into `dir` and renders it there, as
/// `build` and `render` would with the settings given.
pub fn demo(dir: &Path, build_args: BuildArgs, render_args: RenderArgs, progress: &dyn Progress) -> Result<()> {
    if dir.is_file() {
        bail_input!("-o {}: demo writes its archive and images into a folder, and this is a file", dir.display());
    }
    check_render_args(&render_args)?;
    let archive = dir.join("cornell_box.inet");
    let (png, exr) = (dir.join("cornell_box.png"), dir.join("cornell_box.exr"));
    // The folder and its missing parents, made now: when demo fails (a
    // full disk), what it wrote into a folder it made goes, and the folder.
    let folder = OutputDir::make(&archive).with_context(|| format!("cannot create the folder {}", dir.display()))?;
    let made = !folder.is_empty();
    let result = build_and_render(&archive, &png, &exr, build_args, render_args, progress);
    match result {
        Ok(()) => folder.keep(),
        Err(_) if made => {
            for f in [&archive, &png, &exr] {
                let _ = std::fs::remove_file(f);
            }
        }
        Err(_) => {}
    }
    result
}

fn build_and_render(
    archive: &Path,
    png: &Path,
    exr: &Path,
    build_args: BuildArgs,
    render_args: RenderArgs,
    progress: &dyn Progress,
) -> Result<()> {
    build_scene(&Scene::cornell_box(), archive, &build_args, progress)?;
    // The render's summary reports its own peak, not the build's.
    crate::return_freed_memory();
    illumnet::memory::reset_peak_resident();
    render(archive, png, Some(exr), None, render_args, &RenderCameras::default(), &[], Extras::default(), progress)
}
