//! `illumnet frames check`: whether a farm's frames are all there, whole
//! and made from the archive, so that a dependent job can gate on it; and
//! the rule it shares with `render --skip-done`: what makes a frame's
//! files complete and matching.
//!
//! A frame is *complete* when every file it writes (its PNG; with `--exr`
//! its EXR, with `--layers` its two layers) exists, decodes whole, and
//! records this archive's identity (`illumnet.archive-id`, the section
//! table's checksum) and this frame number, its files agreeing on the
//! settings. Otherwise it is *missing* (a file is absent), *partial* (a
//! file does not decode: truncated, damaged), *foreign* (a file records
//! another archive, another frame, or nothing of illumnet's) or *stale*
//! (the archive's, with other settings: those `render` would use now for
//! `--skip-done`; for `frames check`, other than most frames').

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::{Args, Subcommand};
use illumnet::archive::Archive;
use illumnet::render::image_io;

use super::common::opened;
use super::exit::FramesIncomplete;
use super::render::frame_plan;

/// `illumnet frames`'s arguments.
#[derive(Args)]
pub struct FramesCommand {
    #[command(subcommand)]
    action: FramesAction,
}

#[derive(Subcommand)]
enum FramesAction {
    /// Report which frames of a render are complete, missing, partial
    /// (truncated or undecodable), stale (other settings than most
    /// frames') or foreign (another archive or frame, or not illumnet's).
    /// Exit 0 when every frame is complete, 8 otherwise.
    Check(CheckCommand),
}

/// `illumnet frames check`'s arguments: the archive and the outputs as
/// `render` was given them.
#[derive(Args)]
pub struct CheckCommand {
    /// The archive the frames were rendered from.
    archive: PathBuf,
    /// The PNG frame pattern given to render, e.g. out/frame_%04d.png.
    #[arg(short, long, value_name = "PATTERN.png")]
    output: PathBuf,
    /// The EXR pattern given to render, if any.
    #[arg(long, value_name = "PATTERN.exr")]
    exr: Option<PathBuf>,
    /// The render wrote `--layers` (IMAGE.direct.exr and IMAGE.indirect.exr).
    #[arg(long)]
    layers: bool,
    /// The frames to check, as render takes them (`A..B`, `auto/K`, …);
    /// default every frame of the archive's sequence.
    #[arg(long, value_name = "A..B")]
    frames: Option<String>,
    /// Print the report as one JSON object.
    #[arg(long)]
    json: bool,
}

/// The state of one frame's files.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum FrameState {
    /// Every file whole, recording this archive, frame and settings.
    Complete,
    /// This file does not exist.
    Missing(PathBuf),
    /// This file does not decode (why).
    Partial(PathBuf, String),
    /// This file records another archive or frame, or nothing (why).
    Foreign(PathBuf, String),
    /// This file records other settings (why).
    Stale(PathBuf, String),
}

impl FrameState {
    /// The state's name, as reports print it.
    pub fn name(&self) -> &'static str {
        match self {
            FrameState::Complete => "complete",
            FrameState::Missing(_) => "missing",
            FrameState::Partial(..) => "partial",
            FrameState::Foreign(..) => "foreign",
            FrameState::Stale(..) => "stale",
        }
    }

    /// The file and what is wrong with it (none when complete).
    fn detail(&self) -> Option<(&Path, String)> {
        match self {
            FrameState::Complete => None,
            FrameState::Missing(p) => Some((p, "does not exist".into())),
            FrameState::Partial(p, why) | FrameState::Foreign(p, why) | FrameState::Stale(p, why) => {
                Some((p, why.clone()))
            }
        }
    }
}

/// The keys of a frame's record that say how it was rendered (the
/// archive's path is left out: nodes may mount it elsewhere).
const SETTINGS_KEYS: [&str; 6] =
    ["Software", "illumnet.settings", "illumnet.start", "illumnet.set", "illumnet.false-color", "illumnet.camera"];

/// A record as compared: keys sorted, the path left out, text as OpenEXR
/// stores it (Latin-1, other characters as `?`), so that a PNG and an EXR
/// of one frame compare equal.
fn comparable(record: &[(String, String)]) -> BTreeMap<String, String> {
    let latin1 = |t: &str| -> String { t.chars().map(|c| if (c as u32) < 256 { c } else { '?' }).collect() };
    record.iter().filter(|(k, _)| k != "illumnet.archive").map(|(k, v)| (latin1(k), latin1(v))).collect()
}

/// The state of output frame `frame`'s `files` for the archive whose
/// identity is `archive_id`: each must exist, decode whole, record that
/// archive and frame, and agree with the first on the settings; with
/// `expected` (what `render` would record now), record exactly that.
/// Returns the settings the frame's first file records, for
/// `frames check`'s comparison across frames.
pub fn frame_state(
    files: &[PathBuf],
    archive_id: &str,
    frame: u32,
    expected: Option<&[(String, String)]>,
) -> (FrameState, Option<BTreeMap<String, String>>) {
    let mut first: Option<BTreeMap<String, String>> = None;
    for file in files {
        if !file.exists() {
            return (FrameState::Missing(file.clone()), None);
        }
        let record = match image_io::read_metadata(file) {
            Ok(r) => comparable(&r),
            Err(e) => return (FrameState::Partial(file.clone(), format!("does not decode: {e}")), None),
        };
        let foreign = |why: String| (FrameState::Foreign(file.clone(), why), None);
        match record.get("illumnet.archive-id") {
            None => return foreign("records no archive identity (not written by this illumnet's render)".into()),
            Some(id) if id != archive_id => {
                return foreign(format!("was rendered from another archive ({id}, this one is {archive_id})"));
            }
            Some(_) => {}
        }
        let recorded_frame = record.get("illumnet.frame").map(String::as_str).unwrap_or("");
        let number = recorded_frame.split(' ').next().unwrap_or("");
        if number != frame.to_string() {
            return foreign(format!("records frame `{recorded_frame}`, not {frame}"));
        }
        if let Some(expected) = expected {
            let expected = comparable(expected);
            if record != expected {
                return (FrameState::Stale(file.clone(), differences(&record, &expected)), None);
            }
        }
        let settings: BTreeMap<String, String> =
            record.into_iter().filter(|(k, _)| SETTINGS_KEYS.contains(&k.as_str())).collect();
        match &first {
            Some(f) if *f != settings => {
                let why = format!("its files disagree: {}", differences(&settings, f));
                return (FrameState::Stale(file.clone(), why), None);
            }
            Some(_) => {}
            None => first = Some(settings),
        }
    }
    (FrameState::Complete, first)
}

/// What `found` records differently from `wanted`, key by key.
fn differences(found: &BTreeMap<String, String>, wanted: &BTreeMap<String, String>) -> String {
    let mut keys: Vec<&String> = found.keys().chain(wanted.keys()).collect();
    keys.sort();
    keys.dedup();
    let none = String::from("(none)");
    keys.into_iter()
        .filter(|k| found.get(*k) != wanted.get(*k))
        .map(|k| format!("{k} `{}` instead of `{}`", found.get(k).unwrap_or(&none), wanted.get(k).unwrap_or(&none)))
        .collect::<Vec<_>>()
        .join("; ")
}

/// Runs `illumnet frames`.
pub fn run(command: FramesCommand) -> Result<()> {
    let FramesAction::Check(c) = command.action;
    let summary = opened(&c.archive, Archive::summary(&c.archive))?;
    let archive_id = summary.identity();
    let total = summary.section_count(illumnet::archive::layout::tag::DELTA_INDEX).max(1) as u32;
    let range = match c.frames.as_deref() {
        Some(text) => frame_plan::parse_frames(text, total)?,
        None => 0..total,
    };
    let plan = frame_plan::FramePlan { range: range.clone(), still_walk: false, largest: (1, 1) };
    let mut states = Vec::new();
    for f in range.clone() {
        let mut files = vec![plan.out_path(&c.output, f)?];
        if let Some(exr) = &c.exr {
            let path = plan.out_path(exr, f)?;
            if c.layers {
                files.push(path.with_extension("direct.exr"));
                files.push(path.with_extension("indirect.exr"));
            }
            files.push(path);
        }
        states.push((f, frame_state(&files, &archive_id, f, None)));
    }
    // Complete frames whose settings differ from most frames' are stale
    // (of equally many, the settings seen first).
    let mut counts: Vec<(&BTreeMap<String, String>, usize)> = Vec::new();
    for (_, (_, s)) in &states {
        if let Some(s) = s {
            match counts.iter_mut().find(|(c, _)| *c == s) {
                Some((_, n)) => *n += 1,
                None => counts.push((s, 1)),
            }
        }
    }
    let top = counts.iter().map(|(_, n)| *n).max().unwrap_or(0);
    let most = counts.iter().find(|(_, n)| *n == top).map(|(s, _)| (*s).clone());
    let mut report: Vec<(u32, FrameState)> = Vec::new();
    for (f, (state, settings)) in &states {
        let state = match (settings, &most) {
            (Some(s), Some(m)) if s != m => {
                let file = plan.out_path(&c.output, *f)?;
                FrameState::Stale(file, format!("other settings than most frames': {}", differences(s, m)))
            }
            _ => state.clone(),
        };
        report.push((*f, state));
    }
    print_report(&c, &archive_id, &range, &report);
    let bad = report.iter().filter(|(_, s)| *s != FrameState::Complete).count();
    if bad > 0 {
        return Err(anyhow::Error::new(FramesIncomplete(format!(
            "{bad} of the {} frames {}..{} of {} are not complete",
            range.len(),
            range.start,
            range.end,
            c.archive.display()
        ))));
    }
    Ok(())
}

/// Prints `frames check`'s report: a line per frame that is not complete
/// and the counts (or one JSON object).
fn print_report(c: &CheckCommand, archive_id: &str, range: &std::ops::Range<u32>, report: &[(u32, FrameState)]) {
    let classes = ["complete", "missing", "partial", "stale", "foreign"];
    let count = |name: &str| report.iter().filter(|(_, s)| s.name() == name).count();
    if c.json {
        let frames: Vec<serde_json::Value> = report
            .iter()
            .map(|(f, s)| {
                let mut v = serde_json::json!({ "frame": f, "state": s.name() });
                if let Some((file, why)) = s.detail() {
                    v["file"] = file.display().to_string().into();
                    v["why"] = why.into();
                }
                v
            })
            .collect();
        let mut counts = serde_json::Map::new();
        for class in classes {
            counts.insert(class.into(), count(class).into());
        }
        let all = count("complete") == report.len();
        println!(
            "{}",
            serde_json::json!({
                "archive": c.archive.display().to_string(),
                "archive_id": archive_id,
                "frames": { "start": range.start, "end": range.end },
                "complete": all,
                "counts": counts,
                "report": frames,
            })
        );
        return;
    }
    for (f, state) in report {
        if let Some((file, why)) = state.detail() {
            println!("frame {f}: {}: {} {why}", state.name(), file.display());
        }
    }
    let counts: Vec<String> = classes.iter().map(|c| format!("{} {c}", count(c))).collect();
    println!("frames {}..{} of {} ({archive_id}): {}", range.start, range.end, c.archive.display(), counts.join(", "));
}
