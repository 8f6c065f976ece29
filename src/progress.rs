//! Progress reporting for long stages, decoupled from any terminal library.
//!
//! The library reports coarse progress (one call per direction bundle or per
//! distribution iteration, never per ray or link); the CLI turns it into
//! progress bars. Tests and library users pass [`NoProgress`].

/// A receiver of coarse progress events from a long-running stage.
pub trait Progress: Sync {
    /// A stage named `stage` starts with `total` units of work.
    fn start(&self, stage: &str, total: u64);
    /// `units` more units of the current stage are done.
    fn advance(&self, units: u64);
    /// The current stage is finished.
    fn finish(&self);
    /// Something the user should know before a long stage starts (what it
    /// will cost). Shown even when progress bars are not; ignored by default.
    fn note(&self, _message: &str) {}
    /// A stage named `stage` starts whose work is neither known nor counted
    /// (a check of a written file, say): shown as busy until
    /// [`Progress::finish`], so a long wait is never silent. Ignored by
    /// default.
    fn busy(&self, _stage: &str) {}
    /// Whether the work should stop at its next clean point (a newer
    /// request superseded it: `illumnet serve`); work that can, checks it
    /// between steps and returns a cancellation error. Never, by default.
    fn cancelled(&self) -> bool {
        false
    }
}

/// Progress sink that ignores every event.
#[derive(Debug, Default, Clone, Copy)]
pub struct NoProgress;

impl Progress for NoProgress {
    fn start(&self, _stage: &str, _total: u64) {}
    fn advance(&self, _units: u64) {}
    fn finish(&self) {}
}
