//! The files a render writes: each frame's PNG (or its false-colour
//! picture) and EXR (with `--layers`, its direct and indirect light apart),
//! each recording what made it; and the whole render's previews
//! (`--gif`, `--contact-sheet`).

use anyhow::Result;
use illumnet::archive::layout::CameraRecord;
use illumnet::distribute;
use illumnet::render::{self, image_io};

use crate::cli::exit::IoFailure;

use super::RenderSetup;
use super::explain::explain;

/// One rendered frame, as its outputs need it.
pub struct RenderedFrame<'f> {
    /// The output frame.
    pub number: u32,
    /// The archive frame whose light it shows.
    pub archive_frame: u32,
    pub camera: &'f CameraRecord,
    pub solution: &'f distribute::Solution,
    /// The shaded image.
    pub image: &'f render::Image,
    /// Its direct light (`--shading direct`).
    pub direct: Option<&'f render::Image>,
}

/// What made output frame `f` (showing archive frame `af` through
/// `camera`), recorded in each of its files: the software, the archive
/// (its path and its identity), the frame, the camera, the settings, how
/// its light started (`cold` or `warm`), `--set` changes and the
/// false-colour picture asked. `--skip-done` and `frames check` compare it
/// (all but the path) with what a render would record.
pub fn metadata(setup: &RenderSetup<'_>, f: u32, af: u32, camera: &CameraRecord) -> Vec<(String, String)> {
    let args = setup.args;
    let (gather_rays, edge_samples) = (setup.gather_rays, setup.edge_samples);
    let mut metadata = vec![
        ("Software".to_string(), format!("illumnet {}", env!("CARGO_PKG_VERSION"))),
        ("illumnet.archive".to_string(), setup.path.display().to_string()),
        ("illumnet.archive-id".to_string(), setup.archive_id.clone()),
        (
            "illumnet.frame".to_string(),
            format!("{f}{}", if af != f { format!(" (archive frame {af})") } else { String::new() }),
        ),
        (
            "illumnet.camera".to_string(),
            format!(
                "position {:?}, look_at {:?}, up {:?}, fov_y {} deg, {}x{}",
                camera.position, camera.look_at, camera.up, camera.fov_y_deg, camera.width, camera.height
            ),
        ),
        (
            "illumnet.settings".to_string(),
            format!(
                "shading {:?}, samples {}x{}, light samples {}, gather {} rays within {} patch sides, edge \
                 samples {}x{}, tolerance {:e}, exposure {}, tone map {:?}",
                args.shading,
                args.samples,
                args.samples,
                args.light_samples,
                gather_rays,
                args.gather_reach,
                edge_samples,
                edge_samples,
                args.tolerance,
                args.exposure,
                args.tone_map
            )
            .to_lowercase(),
        ),
        ("illumnet.start".to_string(), if args.cold { "cold" } else { "warm" }.to_string()),
    ];
    if !setup.sets.is_empty() {
        metadata.push(("illumnet.set".to_string(), setup.sets.join(" ")));
    }
    if let Some(what) = setup.extras.false_colour {
        metadata.push(("illumnet.false-color".to_string(), format!("{what:?}").to_lowercase()));
    }
    metadata
}

/// Writes a frame's PNG (the shaded image, or the false-colour picture
/// asked) and its EXR if asked (with `--layers`, its direct and indirect
/// light too).
pub fn write_frame(setup: &RenderSetup<'_>, renderer: &render::Renderer<'_>, frame: &RenderedFrame<'_>) -> Result<()> {
    let (args, png, extras) = (setup.args, setup.png, setup.extras);
    let (f, af, image, solution) = (frame.number, frame.archive_frame, frame.image, frame.solution);
    let metadata = metadata(setup, f, af, frame.camera);
    match extras.false_colour {
        None => image_io::write_png_with(
            image,
            &setup.frames.out_path(png, f)?,
            args.exposure,
            args.tone_map.into(),
            &metadata,
        )
        .map_err(IoFailure)?,
        Some(what) => {
            let picture = explain(setup.view, renderer, af, what, solution, image, setup.reference, extras)?;
            let path = setup.frames.out_path(png, f)?;
            image_io::write_png_with(&picture, &path, 1.0, image_io::ToneMap::Clamp, &metadata).map_err(IoFailure)?;
        }
    }
    if let Some(exr) = setup.exr {
        let path = setup.frames.out_path(exr, f)?;
        image_io::write_exr_with(image, &path, &metadata).map_err(IoFailure)?;
        if let (true, Some(direct)) = (args.layers, frame.direct) {
            let indirect = render::Image {
                pixels: image.pixels.iter().zip(&direct.pixels).map(|(t, d)| [0, 1, 2].map(|c| t[c] - d[c])).collect(),
                ..*direct
            };
            image_io::write_exr_with(direct, &path.with_extension("direct.exr"), &metadata).map_err(IoFailure)?;
            image_io::write_exr_with(&indirect, &path.with_extension("indirect.exr"), &metadata).map_err(IoFailure)?;
        }
    }
    Ok(())
}

/// Every file output frame `f` writes: its PNG, and with `--exr` its EXR
/// (and with `--layers` its direct and indirect light).
pub fn frame_files(setup: &RenderSetup<'_>, f: u32) -> Result<Vec<std::path::PathBuf>> {
    let mut files = vec![setup.frames.out_path(setup.png, f)?];
    if let Some(exr) = setup.exr {
        let path = setup.frames.out_path(exr, f)?;
        if setup.args.layers {
            files.push(path.with_extension("direct.exr"));
            files.push(path.with_extension("indirect.exr"));
        }
        files.push(path);
    }
    Ok(files)
}

/// Writes the previews of all frames `images`: the animated GIF
/// (`--gif`, at the sequence's frame rate) and the contact sheet.
pub fn write_previews(setup: &RenderSetup<'_>, images: &[render::Image]) -> Result<()> {
    let (args, extras) = (setup.args, setup.extras);
    if let Some(gif) = extras.gif {
        let fps = setup.view.sequence.map_or(24.0, |s| s.record.fps);
        image_io::write_gif(images, fps, args.exposure, gif).map_err(IoFailure)?;
        println!("wrote preview {}", gif.display());
    }
    if let Some(sheet) = extras.contact_sheet {
        image_io::write_contact_sheet(images, 10, args.exposure, sheet).map_err(IoFailure)?;
        println!("wrote contact sheet {}", sheet.display());
    }
    Ok(())
}
