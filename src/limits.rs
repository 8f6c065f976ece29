//! Limits every stage agrees on: what the scene reader accepts, what the
//! build makes, what the archive format allows (`format-spec/archive.md`)
//! and what the readers check. One home, so that a scene that parses also
//! builds, and an archive a build writes also opens.

/// Largest geodesic subdivision frequency (10f² + 2 = 64 002 directions).
pub const MAX_FREQUENCY: u32 = 80;

/// Widest bucket of §3.4 (a 4-ring of a grid holds 41 patches).
pub const MAX_BUCKET: u32 = 4;
