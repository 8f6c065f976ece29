//! Limits every stage agrees on: what the scene reader accepts, what the
//! build makes, what the archive format allows (`format-spec/archive.md`)
//! and what the readers check. One home, so that a scene that parses also
//! builds, and an archive a build writes also opens.

/// Largest geodesic subdivision frequency (10f² + 2 = 64 002 directions).
pub const MAX_FREQUENCY: u32 = 80;

/// Widest bucket of §3.4 (a 4-ring of a grid holds 41 patches).
pub const MAX_BUCKET: u32 = 4;

/// Largest emitted radiance (W·sr⁻¹·m⁻² per band; the sun's disc is about
/// 2·10⁷): bounds every power the distribution sums, so that it stays finite.
pub const MAX_RADIANCE: f32 = 1e9;

/// Largest patch area (m²; a square 10 000 km on a side): with
/// [`MAX_RADIANCE`], a patch's emitted power stays far inside f32.
pub const MAX_PATCH_AREA: f32 = 1e14;

/// Largest coordinate magnitude (m) of a camera, primitive corner or
/// vertex: ray arithmetic with it stays finite in f32.
pub const MAX_COORDINATE: f32 = 1e9;
