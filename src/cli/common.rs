//! What several commands share: the `--memory-budget` argument and the
//! budget it resolves to, opening an archive with errors that tell a scene
//! given in its place from a corrupt archive, and extension checks of the
//! files a command reads or writes.

use std::path::Path;

use anyhow::{Context, Result};
use clap::Args;
use illumnet::archive::{self, Archive};
use illumnet::memory::{BudgetSource, MemoryBudget};

use super::exit::bail_input;

/// `--memory-budget`, one argument shared by `build`, `render` and `demo`
/// (which hands it to both its stages): flattened once per command, since
/// clap refuses two arguments of one name in a command.
#[derive(Args, Clone, Default)]
pub struct BudgetArgs {
    /// Resident memory to stay within, e.g. 512M or 4G (powers of 1024;
    /// default: 75% of physical memory or of the cgroup's limit, and at most
    /// half the address space `ulimit -v` leaves).
    /// A build spills links that would not fit as sorted runs to a scratch
    /// directory next to the output and merges them into the archive (the
    /// same bytes); a render streams the link ends of an archive that does
    /// not fit whole from disk. A job that cannot fit is refused before
    /// work starts (exit 6); peak memory stays below the budget plus 64 MiB.
    #[arg(long, value_name = "SIZE", value_parser = illumnet::memory::parse_size)]
    pub memory_budget: Option<u64>,
}

/// The budget a job stays within: the one given with `--memory-budget`,
/// else the machine's default.
pub fn memory_budget(given: Option<u64>) -> MemoryBudget {
    match given {
        Some(bytes) => MemoryBudget { bytes, source: BudgetSource::Given },
        None => MemoryBudget::default_for_machine(),
    }
}

/// Refuses an output (or input) path whose extension is not `ext`, naming
/// the option and what to do instead.
pub fn require_extension(path: &Path, ext: &str, option: &str, hint: &str) -> Result<()> {
    let given = path.extension().and_then(|e| e.to_str()).unwrap_or("");
    if !given.eq_ignore_ascii_case(ext) {
        bail_input!("{option} {}: {hint}", path.display());
    }
    Ok(())
}

/// Opens an archive, telling a scene file given in its place apart from a
/// corrupt archive.
pub fn open_archive(path: &Path) -> Result<Archive> {
    opened(path, Archive::open(path))
}

/// `result` of opening `path`, a scene file given in its place told apart
/// from a corrupt archive.
pub fn opened<T>(path: &Path, result: Result<T, illumnet::archive::ArchiveError>) -> Result<T> {
    match result {
        Ok(a) => Ok(a),
        Err(illumnet::archive::ArchiveError::Corrupt(_)) if looks_like_scene(path) => {
            let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("scene");
            bail_input!(
                "{} is a scene, not an archive: build it first with `illumnet build {} -o {stem}.inet`",
                path.display(),
                path.display()
            )
        }
        // The OS error names the file already.
        Err(e @ illumnet::archive::ArchiveError::Io { .. }) => Err(anyhow::Error::new(e)),
        Err(e) => Err(anyhow::Error::new(e)).with_context(|| format!("cannot open {}", path.display())),
    }
}

/// Whether `path` starts with the archive magic (§3).
pub fn is_archive(path: &Path) -> bool {
    let mut head = [0u8; 8];
    illumnet::limits::open_regular(path, u64::MAX)
        .and_then(|(mut f, _)| std::io::Read::read_exact(&mut f, &mut head))
        .is_ok()
        && head == archive::layout::MAGIC
}

/// Whether `path` holds a TOML scene rather than an archive: no archive
/// magic, and a `.toml` name or text that starts like TOML (a table, a
/// comment or a `key =` line).
pub fn looks_like_scene(path: &Path) -> bool {
    let mut head = [0u8; 256];
    let n = illumnet::limits::open_regular(path, u64::MAX)
        .and_then(|(mut f, _)| std::io::Read::read(&mut f, &mut head))
        .unwrap_or(0);
    let head = &head[..n];
    if head.starts_with(&archive::layout::MAGIC) {
        return false;
    }
    if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("toml")) {
        return true;
    }
    // The text up to the first byte that is not UTF-8 (the read may cut a
    // character in two).
    let text = match std::str::from_utf8(head) {
        Ok(t) => t,
        Err(e) => std::str::from_utf8(&head[..e.valid_up_to()]).unwrap_or(""),
    };
    let first = text.lines().map(str::trim).find(|l| !l.is_empty()).unwrap_or("");
    first.starts_with('[') || first.starts_with('#') || first.split_once('=').is_some_and(|(k, _)| !k.trim().is_empty())
}
