//! `render`'s settings (`RenderArgs`, shared with `demo`) and the checks
//! made of them and of the files to write before any work: values and
//! combinations, output names, the `--false-color error` reference.

use std::path::Path;

use anyhow::Result;
use clap::Args;
use illumnet::distribute::{self, DistributeOptions};
use illumnet::render::{self, image_io};

use super::Extras;
use super::explain::FalseColour;
use crate::cli::common::require_extension;
use crate::cli::exit::{IoFailure, bail_input};

/// `render`'s settings: the distribution's, the image's and the output's
/// (shared with `demo`, which renders what it builds).
#[derive(Args, Clone, Copy)]
pub struct RenderArgs {
    /// Stop distributing when unshot power falls below this fraction of the emitted power.
    #[arg(long, default_value_t = 1e-4, value_name = "FRACTION")]
    pub tolerance: f64,
    /// Samples per pixel along each axis (N×N per pixel, box filter).
    #[arg(long, default_value_t = 4, value_name = "N")]
    pub samples: u32,
    /// Samples per axis of pixels on an edge (a corner, a silhouette: their
    /// samples see surfaces that are not one plane), traced again N×N
    /// (0: off). Default: 16 for one frame with `--shading direct`; 0 for
    /// several (a sequence or a walkthrough: each frame's cost counts) and
    /// for the paper's shading. Edges are found among the pixel's --samples
    /// (none with one sample per pixel).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(0..=64))]
    pub edge_samples: Option<u32>,
    /// Multiply radiance by this before tone mapping and sRGB encoding the
    /// PNG (the EXR keeps radiance as it is).
    #[arg(long, default_value_t = 1.0, value_name = "X", allow_negative_numbers = true)]
    pub exposure: f32,
    /// How the PNG maps radiance to display values: `clamp` (exact below
    /// 1, highlights clipped), `reinhard` (x/(1+x): nothing clipped),
    /// `aces` (a filmic curve with a soft shoulder).
    #[arg(long, value_enum, default_value_t = ToneMapArg::Clamp, value_name = "CURVE")]
    pub tone_map: ToneMapArg,
    /// For measurement: ignore the archive's buckets (no spreading).
    #[arg(long)]
    pub no_buckets: bool,
    /// Secant pairs the Anderson acceleration of the distribution keeps
    /// (0: plain iteration; at most 8; diffuse archives only).
    #[arg(long, default_value_t = 5, value_name = "N")]
    pub anderson: usize,
    /// For measurement: glossy patches reflect through their tables every
    /// iteration, and iteration is plain (the default reflects what has
    /// waited when it outweighs the diffuse residual, same balance).
    #[arg(long)]
    pub glossy_every_step: bool,
    /// For measurement: drop the H_p/H_u patch-size correction of §3.4.
    #[arg(long)]
    pub no_patch_size_correction: bool,
    /// Start every frame's distribution from zero instead of from the
    /// previous frame's light (same answer, more iterations).
    #[arg(long)]
    pub cold: bool,
    /// `direct`: light straight from the emitters computed per image
    /// sample (exact, with shadows), the I-net giving the indirect light;
    /// `inet`: the paper's rendering, all light interpolated from the
    /// patches (§3.5).
    #[arg(long, value_enum, default_value_t = Shading::Direct)]
    pub shading: Shading,
    /// Shadow rays, N×N per pixel and primitive, that pixels near a
    /// blocked first ray take again, shared by all emitters in proportion
    /// to their light; only those to the emitters found blocked nearby are
    /// traced (`--shading direct`; every pixel first takes four).
    #[arg(long, default_value_t = illumnet::render::direct::DEFAULT_LIGHT_SAMPLES, value_name = "N")]
    pub light_samples: u32,
    /// One-bounce gather: diffuse image samples near other geometry
    /// (corners, contacts) take their indirect light from rays of their
    /// own, N per pixel, each computing the direct light where it lands
    /// and looking up the I-net's indirect light there, instead of
    /// interpolating it between patch vertices (`--shading direct`; 0:
    /// off). Default: 256 for one frame; 0 for several (a sequence or a
    /// walkthrough, where each frame's cost counts and fresh noise would
    /// flicker) and for a `--false-color` picture other than `error`
    /// written alone (it does not show the shaded image; with `--exr`,
    /// `--gif` or `--contact-sheet`, which do, the default is a frame's).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(0..=4096))]
    pub gather: Option<u32>,
    /// Where the gather applies: samples whose nearest geometry is within
    /// X patch sides take it whole, fading out to 2X (`inf`: every diffuse
    /// sample; the interpolated light is smooth elsewhere and the gather
    /// only adds noise there).
    #[arg(long, default_value_t = 1.0, value_name = "X")]
    pub gather_reach: f32,
    /// With --exr and `--shading direct`: also write the direct and the
    /// indirect light as IMAGE.direct.exr and IMAGE.indirect.exr.
    #[arg(long)]
    pub layers: bool,
    /// Most distribution iterations per frame.
    #[arg(long, default_value_t = 1000, value_name = "N")]
    pub max_iterations: u32,
    /// Write images even when the distribution stops at --max-iterations
    /// before unshot power is below --tolerance (otherwise an error,
    /// exit 7, after the frame's energy balance is printed).
    #[arg(long)]
    pub allow_unconverged: bool,
    /// From [`BudgetArgs`], as in [`BuildArgs`].
    #[arg(skip)]
    pub memory_budget: Option<u64>,
    /// For measurement: drop the archive's pages from the kernel's cache
    /// before every pass over its link ends, so each distribution
    /// iteration reads them from disk (needs a --memory-budget that
    /// streams them; Linux).
    #[arg(long)]
    pub evict_each_pass: bool,
}

/// `--tone-map` curves.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum ToneMapArg {
    /// Clamped at 1.
    Clamp,
    /// x / (1 + x).
    Reinhard,
    /// The ACES filmic fit.
    Aces,
}

impl From<ToneMapArg> for illumnet::render::image_io::ToneMap {
    fn from(t: ToneMapArg) -> Self {
        match t {
            ToneMapArg::Clamp => Self::Clamp,
            ToneMapArg::Reinhard => Self::Reinhard,
            ToneMapArg::Aces => Self::Aces,
        }
    }
}

/// How images are shaded (see `--shading`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Shading {
    /// Direct light per pixel, indirect light from the I-net.
    Direct,
    /// All light from the I-net (the paper's §3.5).
    Inet,
}

/// `render`'s options checked on their own (values and combinations), so
/// that `demo` refuses a bad one before it builds.
pub fn check_render_args(args: &RenderArgs) -> Result<()> {
    if args.anderson > distribute::MAX_ANDERSON_DEPTH {
        bail_input!("--anderson keeps at most {} secant pairs, got {}", distribute::MAX_ANDERSON_DEPTH, args.anderson);
    }
    if !(args.tolerance > 0.0 && args.tolerance < 1.0) {
        bail_input!("--tolerance must be in (0, 1), got {}", args.tolerance);
    }
    if !(args.exposure > 0.0 && args.exposure.is_finite()) {
        bail_input!("--exposure multiplies radiance: it must be a positive number, got {}", args.exposure);
    }
    if !(1..=1_000_000).contains(&args.max_iterations) {
        bail_input!("--max-iterations must be in 1..=1000000, got {}", args.max_iterations);
    }
    if !(1..=64).contains(&args.samples) {
        bail_input!("--samples must be in 1..=64, got {}", args.samples);
    }
    if !(1..=64).contains(&args.light_samples) {
        bail_input!("--light-samples must be in 1..=64, got {}", args.light_samples);
    }
    if args.gather.is_some_and(|n| n > 0) && args.shading != Shading::Direct {
        bail_input!("--gather takes the indirect light of direct shading from rays: it needs --shading direct");
    }
    if args.gather_reach.is_nan() || args.gather_reach < 0.0 {
        bail_input!("--gather-reach {}: expected a number of patch sides ≥ 0, or inf", args.gather_reach);
    }
    Ok(())
}

/// Refuses outputs that cannot be written as asked: `--layers` without
/// what it needs, previews of all frames with `--skip-done` (which
/// renders some), and a file named for another format than its option's.
pub fn check_outputs(png: &Path, exr: Option<&Path>, args: &RenderArgs, extras: &Extras<'_>) -> Result<()> {
    if extras.skip_done && (extras.gif.is_some() || extras.contact_sheet.is_some()) {
        bail_input!("--skip-done renders only some frames: --gif and --contact-sheet need them all");
    }
    let direct_shading = args.shading == Shading::Direct;
    if args.layers && (exr.is_none() || !direct_shading) {
        bail_input!("--layers writes EXR layers of direct and indirect light: it needs --exr and --shading direct");
    }
    require_extension(
        png,
        "png",
        "-o",
        "-o writes a PNG image (sRGB, 8-bit): name it .png (linear OpenEXR is --exr IMAGE.exr)",
    )?;
    if let Some(exr) = exr {
        require_extension(exr, "exr", "--exr", "--exr writes OpenEXR: name it .exr")?;
    }
    if let Some(gif) = extras.gif {
        require_extension(gif, "gif", "--gif", "--gif writes an animated GIF: name it .gif")?;
    }
    if let Some(sheet) = extras.contact_sheet {
        require_extension(sheet, "png", "--contact-sheet", "--contact-sheet writes a PNG: name it .png")?;
    }
    Ok(())
}

/// The reference image of `--false-color error`, read and its options
/// checked; `None` for other pictures (which take no `--reference`).
pub fn read_reference(extras: &Extras<'_>) -> Result<Option<render::Image>> {
    let reference = match (extras.false_colour, extras.reference) {
        (Some(FalseColour::Error), Some(r)) => {
            require_extension(r, "exr", "--reference", "--reference takes a linear OpenEXR image")?;
            if !(extras.error_scale > 0.0 && extras.error_scale.is_finite()) {
                bail_input!("--error-scale must be a positive number, got {}", extras.error_scale);
            }
            Some(image_io::read_exr(r).map_err(IoFailure)?)
        }
        (Some(FalseColour::Error), None) => bail_input!("--false-color error needs --reference REF.exr"),
        (_, Some(_)) => bail_input!("--reference is for --false-color error"),
        _ => None,
    };
    Ok(reference)
}

/// The distribution's options from `render`'s.
pub fn distribute_options(args: &RenderArgs) -> DistributeOptions {
    DistributeOptions {
        tolerance: args.tolerance,
        buckets: !args.no_buckets,
        patch_size_correction: !args.no_patch_size_correction,
        anderson_depth: args.anderson,
        split_direct: args.shading == Shading::Direct,
        max_iterations: args.max_iterations,
        defer_glossy: !args.glossy_every_step,
    }
}

/// Rays per pixel of the one-bounce gather: `--gather`, else the default
/// for one frame, and none for several or for a picture that does not
/// show the shaded image.
pub fn gather_rays(args: &RenderArgs, exr: Option<&Path>, extras: &Extras<'_>, sequence_output: bool) -> u32 {
    // A false-colour picture other than the error's does not show the
    // shaded image: no gather for it by default.
    let picture_only = extras.false_colour.is_some_and(|f| !matches!(f, FalseColour::Error))
        && exr.is_none()
        && extras.gif.is_none()
        && extras.contact_sheet.is_none();
    args.gather.unwrap_or(if sequence_output || picture_only {
        0
    } else {
        illumnet::render::direct::DEFAULT_GATHER_RAYS
    })
}

/// Samples per axis of edge pixels: `--edge-samples`, else the default
/// for one frame of direct shading, and none otherwise.
pub fn edge_samples(args: &RenderArgs, sequence_output: bool) -> u32 {
    args.edge_samples.unwrap_or(match sequence_output || args.shading != Shading::Direct {
        true => 0,
        false => illumnet::render::DEFAULT_EDGE_SAMPLES,
    })
}
