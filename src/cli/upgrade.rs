//! `illumnet upgrade`: an archive in an older format rewritten in the
//! current one (or copied, when it needs no rewriting), through a
//! temporary file validated before it is renamed into place.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Result;
use clap::Args;
use illumnet::archive;

/// `illumnet upgrade`'s arguments.
#[derive(Args)]
pub struct UpgradeCommand {
    /// Archive to rewrite.
    archive: PathBuf,
    /// Where to write the result (default: replace ARCHIVE).
    #[arg(short, long, value_name = "ARCHIVE")]
    output: Option<PathBuf>,
}

/// Runs `illumnet upgrade` with its parsed arguments.
pub fn run(command: UpgradeCommand) -> Result<()> {
    let UpgradeCommand { archive, output } = command;
    upgrade(&archive, output.as_deref().unwrap_or(&archive))
}

/// Rewrites the archive `input` in the current format to `output` (or
/// copies it there when it needs no rewriting).
pub fn upgrade(input: &Path, output: &Path) -> Result<()> {
    let started = Instant::now();
    let done = archive::upgrade::upgrade(input, output)?;
    if done.already_current {
        let v = done.version_before;
        if archive::upgrade::same_file(input, output) {
            println!("{} is in the current format (version {v}) already: nothing to do", input.display());
        } else {
            println!(
                "{} is in the current format (version {v}) already: copied to {}",
                input.display(),
                output.display()
            );
        }
        return Ok(());
    }
    println!(
        "upgraded {} to format version {}: {:.1} MB -> {:.1} MB ({} weights kept apart in LCNX), {:.2} s",
        output.display(),
        archive::layout::VERSION_WRITE,
        done.bytes_before as f64 / 1e6,
        done.bytes_after as f64 / 1e6,
        done.escapes,
        started.elapsed().as_secs_f64()
    );
    Ok(())
}
