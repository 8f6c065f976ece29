//! `render`'s closing line: frames and files written, the image size, the
//! time of each stage and the distribution's rates, and the peak memory.

use illumnet::memory::{self, Bytes};

use super::RenderSetup;
use super::options::Shading;

/// Sums over a render's frames, for its summary.
#[derive(Default)]
pub struct Totals {
    /// The last frame's image size.
    pub size: (u32, u32),
    /// Distribution iterations over all frames.
    pub iterations: u32,
    /// Seconds solving the light (delta application included).
    pub distribution_s: f64,
    /// Of those, seconds applying frames' deltas.
    pub delta_s: f64,
    /// Link ends gathered.
    pub ends_gathered: f64,
    /// Seconds shading images.
    pub render_s: f64,
    /// Frames `--skip-done` found done and did not render.
    pub skipped: u32,
}

impl Totals {
    /// Nothing summed yet, the image size the archive's camera's.
    pub fn starting_at(size: (u32, u32)) -> Self {
        Self { size, ..Self::default() }
    }
}

/// Prints the render's summary line.
pub fn print_summary(setup: &RenderSetup<'_>, totals: &Totals, t_open: f64, t_setup: f64) {
    let rendered = setup.frames.range.len() - totals.skipped as usize;
    let (exr, size, gather_rays) = (setup.exr, totals.size, setup.gather_rays);
    let (t_dist, t_delta) = (totals.distribution_s, totals.delta_s);
    let direct_shading = setup.args.shading == Shading::Direct;
    println!(
        "rendered {} frame{} to {}{}: {}×{}, open {:.3} s, setup {:.3} s, delta apply {:.3} s, distribution {:.3} s ({} iterations, {:.0} M link ends/s; gather {:.0} M ends/s), render {:.3} s{}{}",
        rendered,
        if rendered == 1 { "" } else { "s" },
        setup.png.display(),
        exr.map(|e| format!(" and {}", e.display())).unwrap_or_default(),
        size.0,
        size.1,
        t_open,
        t_setup,
        t_delta,
        t_dist - t_delta,
        totals.iterations,
        totals.ends_gathered / (t_dist - t_delta).max(1e-9) / 1e6,
        {
            let (seconds, gathered) = setup.distributor.gather_totals();
            gathered as f64 / seconds.max(1e-9) / 1e6
        },
        totals.render_s,
        if direct_shading && gather_rays > 0 {
            format!(" (one-bounce gather near corners: {gather_rays} rays per pixel)")
        } else {
            String::new()
        },
        memory::peak_resident().map(|b| format!(", peak memory {}", Bytes(b))).unwrap_or_default()
    );
    if let Some(team) = setup.distributor.team() {
        print_team(setup, team);
    }
}

/// `--mpi`: the ranks, rank 0's share of the link ends, and what it
/// exchanged.
fn print_team(setup: &RenderSetup<'_>, team: &dyn illumnet::distribute::Team) {
    let d = setup.distributor;
    let own = d.own_receivers();
    let offsets = setup.view.link_offsets;
    let share = (offsets[own.end] - offsets[own.start]) as f64 / (*offsets.last().unwrap_or(&0)).max(1) as f64;
    let (bytes, seconds) = d.exchange_totals();
    let exchanges = d.exchanges().max(1);
    println!(
        "MPI: {} ranks; rank 0 gathered for patches {}..{} ({:.1}% of the link ends); exchanged {:.2} MB in {} exchanges ({:.3} MB each, {:.3} s in all)",
        team.size(),
        own.start,
        own.end,
        100.0 * share,
        bytes as f64 / 1e6,
        d.exchanges(),
        bytes as f64 / exchanges as f64 / 1e6,
        seconds
    );
}
