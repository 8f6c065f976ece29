//! `illumnet inspect`: what an archive holds, in one of four answers —
//! the `overview` (header, sections and counts), one patch (`patch`), one
//! surface (`surface`), or `histograms` (with `charts` of them).

mod charts;
mod histograms;
mod overview;
mod patch;
pub mod surface;

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

/// `illumnet inspect`'s arguments.
#[derive(Args)]
pub struct InspectCommand {
    /// Archive to read.
    archive: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// Explain one patch instead: its surface, geometry, hit counts,
    /// neighbours, and where its link ends lead (grouped by the patch
    /// at their other end, heaviest first).
    #[arg(long, value_name = "N", conflicts_with_all = ["histograms", "surface"])]
    patch: Option<u32>,
    /// Explain one surface instead: material, emission, patches, ray
    /// coverage (Σ H_p over its expectation), and the surfaces its links
    /// exchange light with (heaviest first).
    #[arg(long, value_name = "NAME", conflicts_with = "histograms")]
    surface: Option<String>,
    /// Print histograms instead: link ends per patch and per direction,
    /// link lengths, H_p over its expectation, bucket use, and a
    /// sequence's changes per frame.
    #[arg(long)]
    histograms: bool,
    /// With --histograms: also draw each as a PNG bar chart in DIR
    /// (DIR/KEY.png, KEY as in the JSON).
    #[arg(long, value_name = "DIR", requires = "histograms")]
    charts: Option<PathBuf>,
}

/// Runs `illumnet inspect` with its parsed arguments: the answer its
/// options ask for.
pub fn run(command: InspectCommand) -> Result<()> {
    match command {
        InspectCommand { archive, json, patch: Some(p), .. } => patch::inspect_patch(&archive, p, json),
        InspectCommand { archive, json, surface: Some(s), .. } => surface::inspect_surface(&archive, &s, json),
        InspectCommand { archive, json, histograms: true, charts, .. } => {
            histograms::inspect_histograms(&archive, json, charts.as_deref())
        }
        InspectCommand { archive, json, .. } => overview::inspect(&archive, json),
    }
}
