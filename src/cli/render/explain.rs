//! `render --false-color`: pictures that explain an archive instead of the
//! shaded image (link ends, hits, buckets, patches, residual per patch, or
//! the error per pixel against a reference), each with its scale printed.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use illumnet::archive;
use illumnet::distribute;
use illumnet::render;

use crate::cli::exit::BadInput;

use super::Extras;

/// `render`'s pictures that explain an archive (`--false-color`).
#[derive(Args, Clone)]
pub struct ExplainArgs {
    /// Write a false-colour picture to -o instead of the shaded image (the
    /// EXR, if asked, stays the shaded image): `links` (link ends per
    /// patch), `hits` (rays that reached a patch over those its area should
    /// catch), `buckets` (share of its rays in wide buckets), `patches` (the
    /// patch grid), `residual` (unshot over received power), `error` (per
    /// pixel against --reference); a colour bar beneath, its range printed.
    #[arg(long, value_enum, value_name = "WHAT")]
    pub false_color: Option<FalseColour>,
    /// Reference image (linear EXR, same size) for `--false-color error`.
    #[arg(long, value_name = "REF.exr")]
    pub reference: Option<PathBuf>,
    /// Relative error drawn brightest by `--false-color error`.
    #[arg(long, default_value_t = 0.25, value_name = "X")]
    pub error_scale: f32,
}

/// What `--false-color` draws.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum FalseColour {
    /// Link ends per patch (log scale).
    Links,
    /// H_p / E[H_p] per patch (0..2).
    Hits,
    /// Share of a patch's rays in wide buckets (0..1).
    Buckets,
    /// Every patch its own colour.
    Patches,
    /// Unshot over received power per patch (log scale).
    Residual,
    /// Relative luminance error per pixel against --reference.
    Error,
}

/// The false-colour picture `what` of frame `af` (`image`: its shaded
/// image, for `error`), its scale printed.
#[allow(clippy::too_many_arguments)]
pub fn explain(
    view: &archive::InetView<'_>,
    renderer: &render::Renderer<'_>,
    af: u32,
    what: FalseColour,
    solution: &distribute::Solution,
    image: &render::Image,
    reference: Option<&render::Image>,
    extras: Extras<'_>,
) -> Result<render::Image> {
    use render::false_colour::{self, Quantity};
    let q = match what {
        FalseColour::Error => {
            let reference = reference.expect("checked before the render");
            let picture = false_colour::error_picture(image, reference, extras.error_scale, 1.0).map_err(BadInput)?;
            println!(
                "false colour error: relative luminance error |a − r| / (r + 0.01) against the reference, 0 (dark) \
                 to {} (bright); emitters black",
                extras.error_scale
            );
            return Ok(picture);
        }
        FalseColour::Links => Quantity::Links,
        FalseColour::Hits => Quantity::Hits,
        FalseColour::Buckets => Quantity::Buckets,
        FalseColour::Patches => Quantity::Patches,
        FalseColour::Residual => Quantity::Residual,
    };
    let values = false_colour::patch_values(view, q, Some(&solution.residual)).map_err(anyhow::Error::new)?;
    let scale = false_colour::scale_of(q, &values);
    let what = match q {
        Quantity::Links => "link ends per patch",
        Quantity::Hits => "rays that reached a patch over those its area should catch (H_p / E[H_p])",
        Quantity::Buckets => "share of a patch's rays in wide buckets",
        Quantity::Patches => "every patch its own colour",
        Quantity::Residual => "power left unshot over power received, per patch",
    };
    if q == Quantity::Patches {
        println!("false colour patches: {what} ({} patches)", values.len());
    } else {
        println!(
            "false colour {}: {what}, {} scale from {} (dark) to {} (bright)",
            format!("{q:?}").to_lowercase(),
            if scale.log { "log" } else { "linear" },
            scale.min,
            scale.max
        );
    }
    Ok(false_colour::picture(&renderer.sample_patches(af), &values, q, &scale))
}
