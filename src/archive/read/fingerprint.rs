//! What an opened archive's file was when opened (length, modification
//! and change times to the nanosecond, inode, device), re-checked during a
//! render: a file cut short or rewritten in place under a render is then
//! an error (exit 5 or 4) however its bytes are read, mapped or streamed.
//! A file replaced by a rename (how illumnet writes archives) or removed
//! is not a change: the open file is the old one, intact; unlinking it
//! changes its change time, which is then not compared (its link count is
//! 0; length and modification time still are).

use std::fs::File;
use std::path::{Path, PathBuf};

use crate::archive::ArchiveError;

/// The file an archive was opened from and its fingerprint at open.
pub(super) struct Source {
    file: File,
    path: PathBuf,
    at_open: Stamp,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Stamp {
    len: u64,
    modified: (i64, i64),
    changed: (i64, i64),
    inode: u64,
    device: u64,
    /// Names the file has (0: replaced by a rename, or removed).
    links: u64,
}

fn stamp(file: &File) -> std::io::Result<Stamp> {
    let m = file.metadata()?;
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        Ok(Stamp {
            len: m.len(),
            modified: (m.mtime(), m.mtime_nsec()),
            changed: (m.ctime(), m.ctime_nsec()),
            inode: m.ino(),
            device: m.dev(),
            links: m.nlink(),
        })
    }
    #[cfg(not(unix))]
    {
        let nanos = |t: std::io::Result<std::time::SystemTime>| {
            t.ok()
                .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
                .map_or((0, 0), |d| (d.as_secs() as i64, i64::from(d.subsec_nanos())))
        };
        Ok(Stamp { len: m.len(), modified: nanos(m.modified()), changed: (0, 0), inode: 0, device: 0, links: 1 })
    }
}

impl Source {
    /// Fingerprints `file`, open at `path`.
    pub(super) fn new(file: File, path: &Path) -> Result<Self, ArchiveError> {
        let at_open = stamp(&file).map_err(|e| ArchiveError::Io { path: path.into(), source: e })?;
        Ok(Source { file, path: path.into(), at_open })
    }

    /// `Ok` when the file is as it was at open; a shorter file is an I/O
    /// error ("ended early", exit 5, as the streamed reader says), any
    /// other change corruption ("changed on disk", exit 4).
    pub(super) fn check(&self) -> Result<(), ArchiveError> {
        let mut now = stamp(&self.file).map_err(|e| ArchiveError::Io { path: self.path.clone(), source: e })?;
        if now.links == 0 {
            // Unlinked (replaced by a rename): the unlink changed `changed`.
            (now.changed, now.links) = (self.at_open.changed, self.at_open.links);
        }
        if now == self.at_open {
            return Ok(());
        }
        if now.len < self.at_open.len {
            let source = std::io::Error::new(
                std::io::ErrorKind::UnexpectedEof,
                format!(
                    "the file ended early (truncated while in use?): {} bytes, {} at open",
                    now.len, self.at_open.len
                ),
            );
            return Err(ArchiveError::Io { path: self.path.clone(), source });
        }
        Err(ArchiveError::corrupt(format!(
            "{}: the file changed on disk while in use (was the archive rewritten?)",
            self.path.display()
        )))
    }
}
