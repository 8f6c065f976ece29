//! Exit codes: what a script can tell from `$?` (documented in the README).
//!
//! | code | meaning |
//! |---|---|
//! | 0 | success |
//! | 1 | failure not covered below |
//! | 2 | usage: unknown option, missing argument (clap) |
//! | 3 | bad input: a scene file, an option's value out of its range, a frame the archive does not have |
//! | 4 | corrupt or unsupported archive, or one in an older format (`illumnet upgrade`) |
//! | 5 | I/O: a file could not be read or written |
//! | 6 | the job does not fit the memory budget (said before work starts) |
//! | 7 | the result is not finite, or did not converge (without `--allow-unconverged`) |
//! | 8 | `frames check`: some frames are missing, partial, stale or foreign |
//! | 101 | internal error (a panic: a bug, please report it) |
//!
//! Errors carry their kind as a typed source in the `anyhow` chain
//! (`SceneError`, `ArchiveError`, `DistributeError`, I/O errors, or the
//! [`BadInput`] and [`IoFailure`] of the CLI's own checks); the code is
//! that of the first classified source.

use std::fmt;

use illumnet::archive::ArchiveError;
use illumnet::distribute::DistributeError;
use illumnet::render::plan::BudgetError;
use illumnet::scene::SceneError;

/// Failure not covered by another code.
pub const FAILURE: u8 = 1;
/// An input (scene, option value, frame) is wrong.
pub const BAD_INPUT: u8 = 3;
/// The archive is corrupt, needs a newer reader, or is in an older format.
pub const CORRUPT_ARCHIVE: u8 = 4;
/// Reading or writing a file failed.
pub const IO: u8 = 5;
/// The job does not fit the memory budget.
pub const BUDGET: u8 = 6;

/// The result is refused: not finite, or not converged.
pub const RESULT: u8 = 7;
/// `frames check` found frames that are not complete.
pub const FRAMES_INCOMPLETE: u8 = 8;

/// Error kinds that are a message: the type says which exit code.
macro_rules! message_errors {
    ($($(#[$doc:meta])* $name:ident;)*) => {$(
        $(#[$doc])*
        #[derive(Debug)]
        pub struct $name(pub String);

        impl fmt::Display for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str(&self.0)
            }
        }

        impl std::error::Error for $name {}
    )*};
}

message_errors! {
    /// A result the CLI will not write: not converged, or not finite.
    ResultRefused;
    /// What `verify` found wrong with an archive (listed before it): exits
    /// as a corrupt archive does, without calling every finding corruption
    /// (an archive in an older format is sound but must be upgraded).
    Findings;
    /// An option value or other input the CLI refuses.
    BadInput;
    /// A file the CLI could not read or write (image encoders report strings).
    IoFailure;
    /// `frames check` found frames missing, partial, stale or foreign
    /// (listed before it).
    FramesIncomplete;
}

/// `Err(BadInput(format!(…)))` from the enclosing function.
macro_rules! bail_input {
    ($($t:tt)*) => {
        return Err(anyhow::Error::new($crate::cli::exit::BadInput(format!($($t)*))))
    };
}
pub(crate) use bail_input;

/// `.input(|| message)`: a missing value or a parse failure as [`BadInput`].
pub trait InputContext<T> {
    /// The value, or a [`BadInput`] with `message`.
    fn input(self, message: impl FnOnce() -> String) -> anyhow::Result<T>;
}

impl<T> InputContext<T> for Option<T> {
    fn input(self, message: impl FnOnce() -> String) -> anyhow::Result<T> {
        self.ok_or_else(|| anyhow::Error::new(BadInput(message())))
    }
}

impl<T, E> InputContext<T> for Result<T, E> {
    fn input(self, message: impl FnOnce() -> String) -> anyhow::Result<T> {
        self.map_err(|_| anyhow::Error::new(BadInput(message())))
    }
}

/// A `--json` command's failure already written to stdout as JSON (the
/// findings of `verify --json`): `main` adds no JSON error object. Displays
/// as nothing, so the message on stderr is the error it wraps.
#[derive(Debug)]
pub struct JsonReported;

impl fmt::Display for JsonReported {
    fn fmt(&self, _: &mut fmt::Formatter<'_>) -> fmt::Result {
        Ok(())
    }
}

/// The name of an exit code's kind, for `--json` error objects.
pub fn kind(code: u8) -> &'static str {
    match code {
        BAD_INPUT => "bad_input",
        CORRUPT_ARCHIVE => "corrupt_archive",
        IO => "io",
        BUDGET => "memory_budget",
        RESULT => "result_refused",
        FRAMES_INCOMPLETE => "frames_incomplete",
        _ => "failure",
    }
}

fn archive_code(e: &ArchiveError) -> u8 {
    match e {
        ArchiveError::Io { .. } => IO,
        ArchiveError::Corrupt(_) | ArchiveError::UnsupportedVersion { .. } | ArchiveError::Outdated { .. } => {
            CORRUPT_ARCHIVE
        }
    }
}

/// The exit code of `err` (module docs).
pub fn code(err: &anyhow::Error) -> u8 {
    for cause in err.chain() {
        if let Some(e) = cause.downcast_ref::<SceneError>() {
            return if e.unreadable { IO } else { BAD_INPUT };
        }
        if cause.is::<BadInput>() {
            return BAD_INPUT;
        }
        if cause.is::<IoFailure>() || cause.is::<std::io::Error>() {
            return IO;
        }
        if cause.is::<Findings>() {
            return CORRUPT_ARCHIVE;
        }
        if cause.is::<ResultRefused>() {
            return RESULT;
        }
        if cause.is::<FramesIncomplete>() {
            return FRAMES_INCOMPLETE;
        }
        if cause.is::<BudgetError>() {
            return BUDGET;
        }
        if cause.is::<illumnet::bake::shard::ShardError>() {
            return CORRUPT_ARCHIVE;
        }
        if let Some(e) = cause.downcast_ref::<illumnet::bake::BuildError>() {
            return match e {
                illumnet::bake::BuildError::OverBudget { .. } => BUDGET,
                illumnet::bake::BuildError::Scratch(_) => IO,
                illumnet::bake::BuildError::Failed(_) => BAD_INPUT,
            };
        }
        if let Some(e) = cause.downcast_ref::<ArchiveError>() {
            return archive_code(e);
        }
        if let Some(e) = cause.downcast_ref::<DistributeError>() {
            return match e {
                DistributeError::Archive(a) => archive_code(a),
                DistributeError::TooLarge(_) | DistributeError::Unsupported(_) | DistributeError::Cancelled => FAILURE,
                DistributeError::NotFinite { .. } => RESULT,
                DistributeError::Scratch { .. } => IO,
                _ => BAD_INPUT,
            };
        }
    }
    FAILURE
}
