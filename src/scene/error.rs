//! [`SceneError`]: what every reader of scene files (TOML, OBJ, glTF)
//! returns when a file cannot be read or says something wrong, naming the
//! file and where in it. It lives below the readers so that each can make
//! one without importing another.

use std::fmt;
use std::path::{Path, PathBuf};

/// A scene that could not be read: where, which field, and why.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneError {
    /// The scene file.
    pub file: PathBuf,
    /// 1-based line (0 when unknown, e.g. the file could not be read).
    pub line: usize,
    /// 1-based column (0 when unknown).
    pub column: usize,
    /// The offending field, e.g. `surface[3].quad` (empty when unknown).
    pub field: String,
    /// What is wrong.
    pub message: String,
    /// The file could not be read at all (an I/O failure, not a mistake
    /// in it): the CLI exits with its I/O code.
    pub unreadable: bool,
}

impl SceneError {
    pub(in crate::scene) fn io(path: &Path, e: std::io::Error) -> Self {
        // Text that is not UTF-8 was read: a mistake in the file.
        let (message, unreadable) = match e.kind() {
            std::io::ErrorKind::InvalidData => ("is not UTF-8 text".to_string(), false),
            _ => (format!("cannot read: {e}"), true),
        };
        Self { file: path.into(), line: 0, column: 0, field: String::new(), message, unreadable }
    }
}

impl fmt::Display for SceneError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.display())?;
        if self.line > 0 {
            write!(f, ":{}:{}", self.line, self.column)?;
        }
        if !self.field.is_empty() {
            write!(f, ": field `{}`", self.field)?;
        }
        write!(f, ": {}", self.message)
    }
}

impl std::error::Error for SceneError {}

/// An error at a field of an imported file (a JSON pointer for glTF; an
/// object or material for OBJ): no line or column.
pub(in crate::scene) fn error(file: &Path, pointer: impl Into<String>, message: impl Into<String>) -> SceneError {
    SceneError {
        file: file.into(),
        line: 0,
        column: 0,
        field: pointer.into(),
        message: message.into(),
        unreadable: false,
    }
}
