//! Which frames a render makes and the files they go to: `--frames`
//! ranges, a walkthrough's frames (over a still archive or a sequence),
//! every frame's camera checked before work, and `%04d` file name patterns.

use std::ops::Range;
use std::path::{Path, PathBuf};

use anyhow::Result;
use illumnet::archive::{self, ArchiveSummary};
use illumnet::render;

use crate::cli::camera::RenderCameras;
use crate::cli::exit::{InputContext, bail_input};

/// The frames one render makes, decided before any work.
pub struct FramePlan {
    /// Output frames to render (of the sequence, or of the walkthrough).
    pub range: Range<u32>,
    /// A walkthrough over a still archive: every frame shows frame 0's
    /// light, solved once.
    pub still_walk: bool,
    /// The largest image any frame makes, for the memory plan.
    pub largest: (u32, u32),
}

impl FramePlan {
    /// The archive frame whose light output frame `f` shows.
    pub fn archive_frame(&self, f: u32) -> u32 {
        if self.still_walk { 0 } else { f }
    }

    /// Whether the render writes several frames (whose file names need a
    /// frame number pattern).
    pub fn sequence_output(&self) -> bool {
        self.range.len() > 1
    }

    /// The file frame `f` writes for the name `pattern` given: its `%04d`
    /// filled in, or the name itself for a single frame.
    pub fn out_path(&self, pattern: &Path, f: u32) -> Result<PathBuf> {
        let range = &self.range;
        match frame_path(pattern, f) {
            Some(p) => Ok(p),
            None if !self.sequence_output() => Ok(pattern.to_path_buf()),
            None => bail_input!(
                "{} needs a frame number pattern such as frame_%04d.png to render the {} frames {}..{} \
                 (or --frames N for one frame)",
                pattern.display(),
                range.len(),
                range.start,
                range.end
            ),
        }
    }
}

/// The frames to render of the archive `summary` describes: those of
/// `--frames` (default all, or the walkthrough's), each frame's camera
/// checked, and the reference of `--false-color error` checked against
/// every frame's size.
pub fn plan_frames(
    summary: &ArchiveSummary,
    cameras: &RenderCameras,
    frames: Option<&str>,
    reference: Option<&render::Image>,
) -> Result<FramePlan> {
    let archive_frames = summary.section_count(archive::layout::tag::DELTA_INDEX).max(1) as u32;
    // A walkthrough renders its path's frames; over a still archive they
    // all show frame 0's light, solved once.
    let still_walk = cameras.walkthrough_frames().is_some() && archive_frames == 1;
    let total_frames = match cameras.walkthrough_frames() {
        Some(n) if archive_frames > 1 && n > archive_frames => bail_input!(
            "the camera path has {n} frames but the archive's sequence only {archive_frames}: a path over a \
             sequence shows frame k at path frame k"
        ),
        Some(n) => n,
        None => archive_frames,
    };
    // All frames of a sequence (or a walkthrough) unless told otherwise.
    let range = match frames {
        Some(f) => parse_frames(f, total_frames)?,
        None => 0..total_frames,
    };
    if range.end > total_frames {
        if total_frames == 1 {
            bail_input!("--frames: the archive is a still (its one frame is 0)");
        }
        bail_input!(
            "frames {}..{} are outside the archive's sequence 0..{total_frames} (frames 0 to {})",
            range.start,
            range.end,
            total_frames - 1
        );
    }
    // Every frame's camera, checked before any work.
    let mut frame_cameras = Vec::new();
    if cameras.given() {
        for f in range.clone() {
            frame_cameras.push(cameras.at(summary.camera, f)?);
        }
    }
    // The largest image any frame makes, for the memory plan.
    let (width, height) = match frame_cameras.is_empty() {
        true => (summary.camera.width, summary.camera.height),
        false => frame_cameras.iter().fold((1, 1), |(w, h), c| (w.max(c.width), h.max(c.height))),
    };
    // An error picture compares each frame's image with the reference.
    if let Some(r) = reference {
        let sizes: Vec<(u32, u32)> = match frame_cameras.is_empty() {
            true => vec![(summary.camera.width, summary.camera.height)],
            false => frame_cameras.iter().map(|c| (c.width, c.height)).collect(),
        };
        if let Some(&(w, h)) = sizes.iter().find(|&&s| s != (r.width, r.height)) {
            bail_input!(
                "--reference is {}×{} pixels but the image is {w}×{h}: render at the reference's size (--size {}x{})",
                r.width,
                r.height,
                r.width,
                r.height
            );
        }
    }
    Ok(FramePlan { range, still_walk, largest: (width, height) })
}

/// Replaces a printf-style `%d` / `%0Nd` in `pattern` with `frame`.
fn frame_path(pattern: &Path, frame: u32) -> Option<std::path::PathBuf> {
    let text = pattern.to_str()?;
    let start = text.find('%')?;
    let rest = &text[start + 1..];
    let digits: String = rest.chars().take_while(|c| c.is_ascii_digit()).collect();
    if !rest[digits.len()..].starts_with('d') {
        return None;
    }
    let width: usize = if digits.is_empty() { 0 } else { digits.parse().ok().filter(|&w| w <= 16)? };
    let number = format!("{frame:0width$}");
    Some(format!("{}{}{}", &text[..start], number, &rest[digits.len() + 1..]).into())
}

/// Parses a frame range of a sequence of `total` frames: `A..B` (B
/// excluded), `A..=B`, `A..` (to the end), `..B`, or a single frame `A`.
pub fn parse_frames(text: &str, total: u32) -> Result<std::ops::Range<u32>> {
    let parse = |t: &str| {
        t.trim()
            .parse::<u32>()
            .input(|| format!("--frames `{text}`: expected a range like 0..60, 2.., 0..=4 or one frame like 7"))
    };
    let (a, b) = match text.split_once("..") {
        Some((a, b)) => {
            let a = if a.trim().is_empty() { 0 } else { parse(a)? };
            let b = match b.strip_prefix('=') {
                Some(b) => parse(b)?.checked_add(1).input(|| format!("--frames `{text}`: frame out of range"))?,
                None if b.trim().is_empty() => total,
                None => parse(b)?,
            };
            (a, b)
        }
        None => {
            let a = parse(text)?;
            (a, a.checked_add(1).input(|| format!("frame {a} is out of range"))?)
        }
    };
    if a >= b {
        bail_input!("--frames `{text}` is empty (the archive has frames 0..{total})");
    }
    Ok(a..b)
}
