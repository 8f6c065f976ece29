//! Temporary files and scratch directories next to an output, named after
//! it and locked while in use, so that what a killed process leaves behind
//! is found and removed by the next write of the same output, and a live
//! process's files never are.
//!
//! Names: `.illumnet-<output file name>.<pid>-<random>.tmp` for a file
//! renamed over the output when complete, `.illumnet-<output file
//! name>.<pid>-<random>.spill/` for a bounded build's runs (with a `lock`
//! file inside). A leftover is *stale* when its owner's process id is no
//! longer running and its lock can be taken (an exclusive `flock`, which
//! the kernel drops when the owner dies, however it dies); both are
//! checked, so that a file just created and not yet locked is safe too.

use std::fs::File;
use std::io;
use std::path::{Path, PathBuf};

/// The directory an output goes in (`.` for a bare file name).
pub fn dir_of(output: &Path) -> &Path {
    match output.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// The name every temporary of `output` starts with.
fn prefix(output: &Path) -> String {
    let name = output.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    format!(".illumnet-{name}.{}-", std::process::id())
}

/// The owner's process id in a temporary's name, if it is one of
/// `output`'s (`.illumnet-<name>.<pid>-…`).
fn owner(entry: &str, output: &Path) -> Option<u32> {
    let name = output.file_name()?.to_string_lossy();
    let rest = entry.strip_prefix(".illumnet-")?.strip_prefix(name.as_ref())?.strip_prefix('.')?;
    let (pid, tail) = rest.split_once('-')?;
    // The random part is alphanumeric: `a`'s sweep does not take the
    // temporaries of an output named `a.5-x`.
    let random = tail.strip_suffix(".tmp").or_else(|| tail.strip_suffix(".spill"))?;
    (!random.is_empty() && random.chars().all(|c| c.is_ascii_alphanumeric())).then_some(())?;
    pid.parse().ok()
}

/// Whether process `pid` is running (always "yes" where it cannot be told).
fn alive(pid: u32) -> bool {
    if pid == std::process::id() {
        return true;
    }
    let proc = Path::new("/proc");
    !proc.is_dir() || proc.join(pid.to_string()).exists()
}

/// Writes `output` whole or not at all: `write` fills a temporary file
/// next to it (after removing what killed writers left, `remove_stale`),
/// which is flushed and renamed over `output` only when `write` succeeds,
/// so a full disk or a crash never leaves a truncated file under the final
/// name. The one temporary-file-and-rename path every output takes.
pub fn write_atomic(
    output: &Path,
    write: impl FnOnce(&mut io::BufWriter<&mut File>) -> io::Result<()>,
) -> io::Result<()> {
    use io::Write;
    let _ = remove_stale(output);
    let mut tmp = temp_file(output)?;
    {
        let mut w = io::BufWriter::new(tmp.as_file_mut());
        write(&mut w)?;
        w.flush()?;
    }
    tmp.persist(output).map_err(|e| e.error)?;
    Ok(())
}

/// A temporary file for `output`, in its directory, locked while it lives
/// and removed when dropped unless persisted (renamed over `output`).
pub fn temp_file(output: &Path) -> io::Result<tempfile::NamedTempFile> {
    let name = prefix(output);
    let mut builder = tempfile::Builder::new();
    builder.prefix(&name).suffix(".tmp");
    // Created as a new file would be (0666 less the umask), not tempfile's 0600.
    #[cfg(unix)]
    builder.permissions(std::os::unix::fs::PermissionsExt::from_mode(0o666));
    let tmp = builder.tempfile_in(dir_of(output))?;
    lock(tmp.as_file())?;
    Ok(tmp)
}

/// A scratch directory for `output`, in its directory, locked while it
/// lives (through the returned `lock` file inside it) and removed with
/// everything in it when dropped.
pub fn scratch_dir(output: &Path) -> io::Result<(tempfile::TempDir, File)> {
    let dir = tempfile::Builder::new().prefix(&prefix(output)).suffix(".spill").tempdir_in(dir_of(output))?;
    let lock_file = File::create(dir.path().join("lock"))?;
    lock(&lock_file)?;
    Ok((dir, lock_file))
}

fn lock(f: &File) -> io::Result<()> {
    match f.try_lock() {
        Ok(()) => Ok(()),
        // A filesystem without locks: the process-id check alone guards.
        Err(std::fs::TryLockError::Error(e)) if e.kind() == io::ErrorKind::Unsupported => Ok(()),
        Err(std::fs::TryLockError::Error(e)) => Err(e),
        Err(std::fs::TryLockError::WouldBlock) => Err(io::Error::other("a new temporary file is locked")),
    }
}

/// Whether the leftover at `path` (a file, or a directory with a `lock`)
/// has no live owner.
fn unlocked(path: &Path, is_dir: bool) -> bool {
    let f = match File::open(if is_dir { path.join("lock") } else { path.to_path_buf() }) {
        Ok(f) => f,
        // A directory whose lock file was never made or is gone.
        Err(e) => return is_dir && e.kind() == io::ErrorKind::NotFound,
    };
    matches!(f.try_lock(), Ok(()))
}

/// The folder an output goes in, made with any missing parents when it
/// did not exist, so that a write to a new folder works as one to an old
/// one; dropped without [`OutputDir::keep`] (the write failed), it removes
/// the folders it made that are still empty: a failed write leaves no
/// empty folder behind, and never removes one it did not make or one
/// another process has put something in.
#[must_use = "dropped, the folders made are removed again"]
#[derive(Debug)]
pub struct OutputDir {
    /// The folders made, deepest first.
    made: Vec<PathBuf>,
}

impl OutputDir {
    /// Makes `output`'s folder ([`dir_of`]) and its missing parents.
    pub fn make(output: &Path) -> io::Result<Self> {
        let dir = dir_of(output);
        let mut missing = Vec::new();
        let mut at = Some(dir);
        while let Some(d) = at.filter(|d| !d.as_os_str().is_empty()) {
            match std::fs::metadata(d) {
                Ok(m) if m.is_dir() => break,
                Ok(_) => {
                    return Err(io::Error::new(
                        io::ErrorKind::NotADirectory,
                        format!("{} is a file, not a folder", d.display()),
                    ));
                }
                // Missing, or under a file (which the walk up then finds).
                Err(e) if matches!(e.kind(), io::ErrorKind::NotFound | io::ErrorKind::NotADirectory) => {
                    missing.push(d.to_path_buf())
                }
                Err(e) => return Err(e),
            }
            at = d.parent();
        }
        let mut made = OutputDir { made: Vec::with_capacity(missing.len()) };
        for d in missing.into_iter().rev() {
            match std::fs::create_dir(&d) {
                Ok(()) => made.made.insert(0, d),
                // Made meanwhile by another process: not ours to remove.
                Err(e) if e.kind() == io::ErrorKind::AlreadyExists && d.is_dir() => {}
                Err(e) if e.kind() == io::ErrorKind::AlreadyExists => {
                    return Err(io::Error::new(
                        e.kind(),
                        format!("{} exists and is not a folder (a broken link?)", d.display()),
                    ));
                }
                // `made` removes what it made so far as it drops.
                Err(e) => return Err(e),
            }
        }
        Ok(made)
    }

    /// Whether no folder was made (the output's folder existed).
    pub fn is_empty(&self) -> bool {
        self.made.is_empty()
    }

    /// The write succeeded: the folders stay.
    pub fn keep(mut self) {
        self.made.clear();
    }
}

impl Drop for OutputDir {
    fn drop(&mut self) {
        for d in &self.made {
            // Fails, leaving it, unless empty.
            if std::fs::remove_dir(d).is_err() {
                break;
            }
        }
    }
}

/// What [`remove_stale`] removed.
#[derive(Debug, Default, Clone, PartialEq, Eq)]
pub struct Removed {
    /// The leftovers removed.
    pub paths: Vec<PathBuf>,
    /// Their bytes.
    pub bytes: u64,
}

/// Removes the temporaries and scratch directories of `output` that killed
/// processes left (see the module docs), never one of a running process.
/// Errors reading the directory are returned; a leftover that cannot be
/// removed is left.
pub fn remove_stale(output: &Path) -> io::Result<Removed> {
    let mut removed = Removed::default();
    let dir = dir_of(output);
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(removed),
        Err(e) => return Err(e),
    };
    for entry in entries {
        let entry = entry?;
        let name = entry.file_name();
        let Some(pid) = owner(&name.to_string_lossy(), output) else { continue };
        let path = entry.path();
        let Ok(kind) = entry.file_type() else { continue };
        if alive(pid) || !unlocked(&path, kind.is_dir()) {
            continue;
        }
        let bytes = size(&path);
        let gone = if kind.is_dir() { std::fs::remove_dir_all(&path) } else { std::fs::remove_file(&path) };
        if gone.is_ok() {
            removed.bytes += bytes;
            removed.paths.push(path);
        }
    }
    Ok(removed)
}

fn size(path: &Path) -> u64 {
    match std::fs::symlink_metadata(path) {
        Ok(m) if m.is_dir() => std::fs::read_dir(path).map_or(0, |d| d.flatten().map(|e| size(&e.path())).sum()),
        Ok(m) => m.len(),
        Err(_) => 0,
    }
}

/// Test-only: when the environment variable `ILLUMNET_TEST_STOP_AT`
/// names `stage`, the process kills itself (SIGKILL, as a crash or the
/// OOM killer would) here, so that tests can reach each stage of a build
/// deterministically. Does nothing otherwise.
pub fn stop_point(stage: &str) {
    static STOP_AT: std::sync::OnceLock<Option<String>> = std::sync::OnceLock::new();
    let at = STOP_AT.get_or_init(|| std::env::var("ILLUMNET_TEST_STOP_AT").ok());
    if at.as_deref() == Some(stage) {
        #[cfg(unix)]
        // SAFETY: raise(2) with a valid signal number has no preconditions.
        unsafe {
            libc::raise(libc::SIGKILL);
        }
        std::process::abort();
    }
}

/// Test-only: when the environment variable `ILLUMNET_TEST_PAUSE_AT`
/// names `stage`, the process stops itself (SIGSTOP) here, once, so that
/// a test can change what it works on at a known point (truncate its
/// archive) and continue it (SIGCONT). Does nothing otherwise.
pub fn pause_point(stage: &str) {
    static PAUSE_AT: std::sync::OnceLock<Option<String>> = std::sync::OnceLock::new();
    static PAUSED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
    let at = PAUSE_AT.get_or_init(|| std::env::var("ILLUMNET_TEST_PAUSE_AT").ok());
    if at.as_deref() == Some(stage) && !PAUSED.swap(true, std::sync::atomic::Ordering::Relaxed) {
        #[cfg(unix)]
        // SAFETY: raise(2) with a valid signal number has no preconditions.
        unsafe {
            libc::raise(libc::SIGSTOP);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_matched_to_their_output_only() {
        let out = Path::new("dir/box.inet");
        assert_eq!(owner(".illumnet-box.inet.123-abc.tmp", out), Some(123));
        assert_eq!(owner(".illumnet-box.inet.123-abc.spill", out), Some(123));
        assert_eq!(owner(".illumnet-box.inet2.123-abc.tmp", out), None);
        assert_eq!(owner(".illumnet-box.inet.x-abc.tmp", out), None);
        assert_eq!(owner(".illumnet-box.inet.123-abc.png", out), None);
        assert_eq!(owner("box.inet", out), None);
        // Another output's, whose name starts like this one's.
        assert_eq!(owner(".illumnet-box.inet.5-x.123-abc.tmp", out), None);
    }

    #[test]
    fn output_folders_made_for_a_failed_write_are_removed_and_others_kept() {
        let root = tempfile::tempdir().unwrap();
        let out = root.path().join("a/b/c.inet");
        // Dropped: the write failed, both folders made go.
        let made = OutputDir::make(&out).unwrap();
        assert!(root.path().join("a/b").is_dir());
        drop(made);
        assert!(!root.path().join("a").exists());
        // Kept: the write succeeded.
        OutputDir::make(&out).unwrap().keep();
        assert!(root.path().join("a/b").is_dir());
        // Folders that existed are never removed; nor is one made but
        // no longer empty (another process wrote there), nor its parents.
        let deeper = root.path().join("a/b/d/e/f.inet");
        let made = OutputDir::make(&deeper).unwrap();
        std::fs::write(root.path().join("a/b/d/other.txt"), b"x").unwrap();
        drop(made);
        assert!(!root.path().join("a/b/d/e").exists());
        assert!(root.path().join("a/b/d/other.txt").exists());
        drop(OutputDir::make(&out).unwrap());
        assert!(root.path().join("a/b").is_dir());
        // A bare file name's folder is `.`, which exists.
        OutputDir::make(Path::new("x.inet")).unwrap().keep();
        // A file where a folder should be: an error naming it.
        std::fs::write(root.path().join("file"), b"x").unwrap();
        let e = OutputDir::make(&root.path().join("file/g/h.inet")).unwrap_err();
        assert!(e.to_string().contains("is a file, not a folder"), "{e}");
        assert!(!root.path().join("file/g").exists());
    }

    #[test]
    fn only_leftovers_of_dead_owners_are_removed() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("a.inet");
        // Ours, live and locked; a dead process's; one of another output.
        let live = temp_file(&out).unwrap();
        let dead = dir.path().join(".illumnet-a.inet.4294967295-zz.tmp");
        std::fs::write(&dead, b"left").unwrap();
        let dead_dir = dir.path().join(".illumnet-a.inet.4294967294-zz.spill");
        std::fs::create_dir(&dead_dir).unwrap();
        std::fs::write(dead_dir.join("run-0.bin"), b"12345678").unwrap();
        let other = dir.path().join(".illumnet-b.inet.4294967295-zz.tmp");
        std::fs::write(&other, b"x").unwrap();
        let removed = remove_stale(&out).unwrap();
        assert_eq!(removed.paths.len(), 2, "{removed:?}");
        assert_eq!(removed.bytes, 12);
        assert!(live.path().exists() && other.exists() && !dead.exists() && !dead_dir.exists());
    }
}
