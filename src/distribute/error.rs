//! Why a distribution could not run: a caller's mistake (a frame the
//! archive does not have, lighting for other surfaces) or a fault in the
//! archive found only now (a corrupt frame delta).

use std::fmt;

use crate::archive::ArchiveError;

/// Why [`super::Distributor`] refused or failed.
#[derive(Debug)]
pub enum DistributeError {
    /// A frame beyond the sequence.
    FrameOutOfRange {
        /// The frame asked for.
        frame: u32,
        /// Frames in the sequence.
        frames: u32,
    },
    /// A frame other than 0 asked of a still archive.
    NotASequence {
        /// The frame asked for.
        frame: u32,
    },
    /// Lighting whose vectors do not have one entry per surface.
    LightingMismatch {
        /// Surfaces in the archive.
        surfaces: usize,
        /// Entries given (the shortest of the lighting's vectors).
        given: usize,
    },
    /// The archive is larger than the distribution indexes.
    TooLarge(String),
    /// The archive needs something this solver does not do.
    Unsupported(String),
    /// The result is not finite (a NaN or infinite radiance or power):
    /// what the archive's checks did not bound. Never handed out as a
    /// [`super::Solution`].
    NotFinite {
        /// The frame solved.
        frame: u32,
        /// The first non-finite quantity.
        what: String,
    },
    /// The archive holds something the distribution cannot use (found
    /// when a frame's delta is decoded, or by a check open does not make).
    Archive(ArchiveError),
    /// A scratch file of the spilled state (`Distributor::spill_in`)
    /// could not be made, written or read back.
    Scratch {
        /// The scratch directory.
        dir: std::path::PathBuf,
        /// The system's error.
        source: std::io::Error,
    },
    /// Stopped between two iterations because the caller asked
    /// ([`crate::progress::Progress::cancelled`]): a newer request made
    /// this one's light useless.
    Cancelled,
}

impl fmt::Display for DistributeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::FrameOutOfRange { frame, frames } => {
                write!(f, "frame {frame} is outside the sequence 0..{frames}")
            }
            Self::NotASequence { frame } => {
                write!(f, "frame {frame} requested from a still archive (it has frame 0 only)")
            }
            Self::LightingMismatch { surfaces, given } => {
                write!(f, "lighting has {given} entries for an archive of {surfaces} surfaces")
            }
            Self::TooLarge(m) => write!(f, "archive too large to distribute: {m}"),
            Self::Unsupported(m) => write!(f, "unsupported: {m}"),
            Self::NotFinite { frame, what } => write!(
                f,
                "frame {frame}: the distributed light is not finite ({what}); the archive holds values beyond \
                 what its checks bound: please report it, with the archive"
            ),
            Self::Archive(e) => e.fmt(f),
            Self::Scratch { dir, source } => write!(
                f,
                "the distribution's scratch file in {} (where a tight --memory-budget keeps its secant pairs \
                 and totals): {source}",
                dir.display()
            ),
            Self::Cancelled => write!(f, "the distribution was cancelled (a newer request superseded it)"),
        }
    }
}

impl std::error::Error for DistributeError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::Archive(e) => Some(e),
            Self::Scratch { source, .. } => Some(source),
            _ => None,
        }
    }
}

impl From<ArchiveError> for DistributeError {
    fn from(e: ArchiveError) -> Self {
        Self::Archive(e)
    }
}
