//! `illumnet compare`: a linear EXR image judged against a reference —
//! relative L2 error, relative MSE and mean absolute error over the pixels
//! below a radiance — with a heat map of the error per pixel if asked.

use std::path::Path;

use anyhow::Result;
use clap::Args;
use illumnet::render::image_io;

use super::common::require_extension;
use super::exit::{BadInput, IoFailure};

/// `illumnet compare`'s arguments.
#[derive(Args)]
pub struct CompareCommand {
    /// Image to judge.
    image: std::path::PathBuf,
    /// Reference image (same size).
    reference: std::path::PathBuf,
    /// Write a PNG heat map of per-pixel relative luminance error.
    #[arg(long, value_name = "MAP.png")]
    heatmap: Option<std::path::PathBuf>,
    /// Relative error shown as white in the heat map.
    #[arg(long, default_value_t = 0.25, value_name = "X")]
    full_scale: f32,
    /// Compare only pixels whose reference is below this in every
    /// channel: above the brightest surface, below the emitters'
    /// radiance (a bright highlight needs more than the default).
    #[arg(long, default_value_t = 1.0, value_name = "RADIANCE")]
    below: f32,
}

/// Runs `illumnet compare` with its parsed arguments.
pub fn run(command: CompareCommand) -> Result<()> {
    let CompareCommand { image, reference, heatmap, full_scale, below } = command;
    compare(&image, &reference, heatmap.as_deref(), full_scale, below)
}

/// Prints the errors of the linear EXR `image` against `reference` over
/// pixels whose reference is below `below`, and writes the heat map of
/// per-pixel error if asked.
pub fn compare(image: &Path, reference: &Path, heatmap: Option<&Path>, full_scale: f32, below: f32) -> Result<()> {
    if !(below > 0.0 && below.is_finite()) {
        return Err(anyhow::Error::new(BadInput(format!("--below must be a positive radiance, got {below}"))));
    }
    for (path, what) in [(image, "IMAGE"), (reference, "REFERENCE")] {
        let is_image = path.extension().and_then(|e| e.to_str()).is_some_and(|e| {
            ["png", "jpg", "jpeg", "tif", "tiff", "bmp", "gif", "hdr"].contains(&e.to_ascii_lowercase().as_str())
        });
        let why = if is_image {
            "compare measures linear radiance and takes OpenEXR images; PNG and other 8-bit formats hold \
             sRGB-encoded values (write linear images with `render --exr`)"
        } else {
            "compare measures linear radiance and takes OpenEXR images (`render --exr` writes one)"
        };
        require_extension(path, "exr", what, why)?;
    }
    if let Some(map) = heatmap {
        require_extension(map, "png", "--heatmap", "--heatmap writes a PNG: name it .png")?;
    }
    let read = |p: &Path| {
        image_io::read_exr(p).map_err(|e| {
            let hint = if e.contains("missing bytes") || e.contains("end of file") {
                " (the file looks truncated)"
            } else {
                ""
            };
            IoFailure(format!("{e}{hint}"))
        })
    };
    let (a, r) = (read(image)?, read(reference)?);
    let (err, map) = image_io::compare_below(&a, &r, below).map_err(BadInput)?;
    println!(
        "relative L2 {:.4}, relative MSE {:.3e}, mean absolute error {:.4e} over {} pixels",
        err.relative_l2, err.relative_mse, err.mean_abs, err.pixels
    );
    if let Some(path) = heatmap {
        image_io::write_heatmap(a.width, a.height, &map, full_scale, path).map_err(IoFailure)?;
        println!("wrote heat map {} (white = relative error ≥ {full_scale})", path.display());
    }
    Ok(())
}
