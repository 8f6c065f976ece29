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
/// excluded), `A..=B`, `A..` (to the end), `..B`, a single frame `A`, or
/// `auto/K`: this array task's share ([`task_share`], [`array_task`]).
pub fn parse_frames(text: &str, total: u32) -> Result<std::ops::Range<u32>> {
    if let Some(k) = text.strip_prefix("auto/") {
        let k: u32 = k.trim().parse().ok().filter(|&k| k > 0).input(|| {
            format!("--frames `{text}`: expected auto/K with K ≥ 1 the number of tasks sharing the frames")
        })?;
        let task = array_task(|name| std::env::var(name).ok())?;
        return task_share(total, task, k);
    }
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

/// This array task's index: `SLURM_ARRAY_TASK_ID` less
/// `SLURM_ARRAY_TASK_MIN` (an array `--array=1-4` has tasks 0 to 3), or
/// else `JOB_COMPLETION_INDEX` (Kubernetes Indexed Jobs); `var` reads the
/// environment.
pub fn array_task(var: impl Fn(&str) -> Option<String>) -> Result<u32> {
    let number = |name: &str| -> Result<Option<u32>> {
        match var(name) {
            None => Ok(None),
            Some(v) => v.trim().parse().map(Some).input(|| format!("{name}=`{v}` is not a task index")),
        }
    };
    if let Some(id) = number("SLURM_ARRAY_TASK_ID")? {
        let min = number("SLURM_ARRAY_TASK_MIN")?.unwrap_or(0);
        return id.checked_sub(min).input(|| format!("SLURM_ARRAY_TASK_ID={id} is below SLURM_ARRAY_TASK_MIN={min}"));
    }
    match number("JOB_COMPLETION_INDEX")? {
        Some(index) => Ok(index),
        None => bail_input!(
            "--frames auto/K takes this task's share from SLURM_ARRAY_TASK_ID (a Slurm job array) or \
             JOB_COMPLETION_INDEX (a Kubernetes Indexed Job), and neither is set: give the frames as A..B"
        ),
    }
}

/// Task `task`'s share of `total` frames split into `k` contiguous shares
/// whose sizes differ by at most one: frames `task·total/k` to
/// `(task+1)·total/k` (empty when there are more tasks than frames).
pub fn task_share(total: u32, task: u32, k: u32) -> Result<std::ops::Range<u32>> {
    if task >= k {
        bail_input!("--frames auto/{k}: this task's index {task} is not below {k}, the number of shares");
    }
    let bound = |i: u32| (u64::from(i) * u64::from(total) / u64::from(k)) as u32;
    Ok(bound(task)..bound(task + 1))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Shares cover every frame once, contiguous, sizes within one.
    #[test]
    fn task_shares_cover_the_frames_once() {
        let shares: Vec<_> = (0..3).map(|t| task_share(8, t, 3).unwrap()).collect();
        assert_eq!(shares, vec![0..2, 2..5, 5..8]);
        // More tasks than frames: some shares are empty, none overlap.
        let shares: Vec<_> = (0..4).map(|t| task_share(2, t, 4).unwrap()).collect();
        assert_eq!(shares, vec![0..0, 0..1, 1..1, 1..2]);
        let e = task_share(8, 3, 3).unwrap_err().to_string();
        assert_eq!(e, "--frames auto/3: this task's index 3 is not below 3, the number of shares");
    }

    /// The task index comes from Slurm (offset by the array's first
    /// index) or Kubernetes, and neither is an error that says so.
    #[test]
    fn the_array_task_comes_from_slurm_or_kubernetes() {
        let env = |pairs: &'static [(&'static str, &'static str)]| {
            move |name: &str| pairs.iter().find(|(k, _)| *k == name).map(|(_, v)| v.to_string())
        };
        assert_eq!(array_task(env(&[("SLURM_ARRAY_TASK_ID", "5"), ("SLURM_ARRAY_TASK_MIN", "3")])).unwrap(), 2);
        assert_eq!(array_task(env(&[("JOB_COMPLETION_INDEX", "1")])).unwrap(), 1);
        let e = array_task(env(&[])).unwrap_err().to_string();
        assert!(e.contains("neither is set"), "{e}");
        let e = array_task(env(&[("SLURM_ARRAY_TASK_ID", "x")])).unwrap_err().to_string();
        assert_eq!(e, "SLURM_ARRAY_TASK_ID=`x` is not a task index");
    }
}
