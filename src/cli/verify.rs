//! `illumnet verify`: an archive checked beyond what opening it checks —
//! every link end between patches that face each other, every link stored
//! at both its ends, every frame's changes applicable — with its findings
//! listed (exit 4) or the archive called sound.

use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::Args;
use illumnet::archive;
use illumnet::memory::Bytes;

use super::common::looks_like_scene;
use super::exit::{self, bail_input};

/// `illumnet verify`'s arguments.
#[derive(Args)]
pub struct VerifyCommand {
    /// Archive to check.
    archive: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Runs `illumnet verify` with its parsed arguments.
pub fn run(command: VerifyCommand) -> Result<()> {
    verify(&command.archive, command.json)
}

/// Checks the archive at `path` beyond what opening it checks and prints
/// what it found (text or JSON); findings are an error (exit 4).
pub fn verify(path: &Path, json: bool) -> Result<()> {
    let r = archive::verify::verify(path)?;
    // Whether the file opened as an archive (else its one finding says why).
    let opened_at_all = r.findings.first().is_none_or(|f| f.section != "file");
    if !opened_at_all && looks_like_scene(path) {
        let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("scene");
        bail_input!(
            "{} is a scene, not an archive: build it first with `illumnet build {} -o {stem}.inet`",
            path.display(),
            path.display()
        );
    }
    let rate = r.bytes as f64 / r.seconds.max(1e-9) / 1e9;
    if json {
        let findings: Vec<serde_json::Value> = r
            .findings
            .iter()
            .map(|f| serde_json::json!({ "section": f.section, "record": f.record, "what": f.what }))
            .collect();
        let out = serde_json::json!({
            "archive": path.display().to_string(),
            "sound": r.sound(),
            "finding_count": r.finding_count,
            "findings": findings,
            "bytes": r.bytes,
            "patches": r.patches,
            "link_ends": r.link_ends,
            "frames": r.frames,
            "seconds": r.seconds,
            "gb_per_s": if opened_at_all { serde_json::json!(rate) } else { serde_json::Value::Null },
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else if r.sound() {
        println!(
            "{}: sound: {} patches, {} link ends, {} frame{} checked; {} in {:.2} s ({rate:.2} GB/s)",
            path.display(),
            r.patches,
            r.link_ends,
            r.frames,
            if r.frames == 1 { "" } else { "s" },
            Bytes(r.bytes),
            r.seconds
        );
    } else {
        println!("{}: {} finding{}", path.display(), r.finding_count, if r.finding_count == 1 { "" } else { "s" });
        for f in &r.findings {
            let at = f.record.map(|i| format!("[{i}]")).unwrap_or_default();
            println!("  {}{at}: {}", f.section, f.what);
        }
        if r.findings.len() as u64 != r.finding_count {
            println!("  ({} more not listed)", r.finding_count - r.findings.len() as u64);
        }
    }
    if r.sound() {
        Ok(())
    } else {
        let e = exit::Findings(format!(
            "{} finding{} in {}",
            r.finding_count,
            if r.finding_count == 1 { "" } else { "s" },
            path.display()
        ));
        let e = anyhow::Error::new(e);
        // With --json the findings are the answer, already on stdout.
        if json { Err(e.context(exit::JsonReported)) } else { Err(e) }
    }
}
