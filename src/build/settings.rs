//! Build settings and their defaults.

use crate::geodesic::DirectionSetKind;
use crate::scene::{BuildHints, Scene};

/// Resolution of an I-net build.
#[derive(Debug, Clone, PartialEq)]
pub struct BuildSettings {
    /// Target patch edge length (m).
    pub patch_size: f32,
    /// Geodesic frequency `f` (`10f² + 2` directions).
    pub frequency: u32,
    /// Distance `δ` between parallel rays (m).
    pub ray_spacing: f32,
    /// Geodesic directions (default) or the 1989 ray-space baseline. With
    /// ray space, `frequency` f picks `m = round(√((10f²+2)/6))` slope
    /// divisions so the direction count matches the geodesic set's.
    pub direction_set: DirectionSetKind,
    /// Widest bucket (§3.4) a link end may get; 0 turns buckets off.
    pub max_bucket: u32,
    /// Bounds the ray grids cover; `None`: the scene's (all frames'). Set it to
    /// a sequence's bounds to build one frame with the sequence's ray grid.
    pub grid_bounds: Option<(glam::Vec3, glam::Vec3)>,
    /// Where prototype tables are cached (§3.6.2); `None`: tables are built
    /// every time. Default: [`Library::default_location`](crate::reflectance::library::Library::default_location).
    pub prototype_library: Option<std::path::PathBuf>,
    /// How actual-to-prototype maps are made.
    pub map_method: crate::reflectance::MapMethod,
    /// Relative threshold below which prototype factors are dropped.
    pub table_threshold: f64,
}

/// Widest bucket supported (the archive's limit).
pub const MAX_BUCKET: u32 = crate::limits::MAX_BUCKET;
/// Default widest bucket: rings of up to 5 patches (chosen in docs/ACCURACY.md).
pub const DEFAULT_MAX_BUCKET: u32 = 1;

/// Ray-space slope divisions whose `6m²` directions match a geodesic set of frequency `f`.
pub fn ray_space_divisions(frequency: u32) -> u32 {
    (((10.0 * (frequency as f64).powi(2) + 2.0) / 6.0).sqrt().round() as u32).max(1)
}

/// Default frequency: 2 562 directions, ~4.1° apart.
pub const DEFAULT_FREQUENCY: u32 = 16;
/// Default patch size as a fraction of the scene's bounding-box diagonal.
pub const DEFAULT_PATCH_FRACTION: f32 = 1.0 / 64.0;
/// Default ray spacing as a fraction of the scene's bounding-box diagonal.
pub const DEFAULT_SPACING_FRACTION: f32 = 1.0 / 128.0;

impl BuildSettings {
    /// Settings for `scene`: explicit `overrides` first, then the scene's
    /// `[build]` table, then defaults scaled to the scene's size, so that a
    /// scene costs the same to build whatever its units.
    pub fn resolve(scene: &Scene, overrides: BuildHints) -> Self {
        let (lo, hi) = scene.bounds();
        let diagonal = (hi - lo).length().max(f32::MIN_POSITIVE);
        Self {
            patch_size: overrides.patch_size.or(scene.build.patch_size).unwrap_or(diagonal * DEFAULT_PATCH_FRACTION),
            frequency: overrides.frequency.or(scene.build.frequency).unwrap_or(DEFAULT_FREQUENCY),
            ray_spacing: overrides
                .ray_spacing
                .or(scene.build.ray_spacing)
                .unwrap_or(diagonal * DEFAULT_SPACING_FRACTION),
            direction_set: DirectionSetKind::Geodesic,
            max_bucket: overrides.buckets.or(scene.build.buckets).unwrap_or(DEFAULT_MAX_BUCKET),
            grid_bounds: None,
            prototype_library: crate::reflectance::library::Library::default_location(),
            map_method: crate::reflectance::MapMethod::default(),
            table_threshold: crate::reflectance::prototype::DEFAULT_THRESHOLD,
        }
    }

    /// Rejects settings no build can use.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.patch_size.is_finite() && self.patch_size > 0.0) {
            return Err(format!("patch size must be a positive length, got {}", self.patch_size));
        }
        if !(self.ray_spacing.is_finite() && self.ray_spacing > 0.0) {
            return Err(format!("ray spacing must be a positive length, got {}", self.ray_spacing));
        }
        if !(1..=crate::geodesic::MAX_FREQUENCY).contains(&self.frequency) {
            return Err(format!("frequency must be in 1..={}, got {}", crate::geodesic::MAX_FREQUENCY, self.frequency));
        }
        if !(self.table_threshold.is_finite() && (0.0..1.0).contains(&self.table_threshold)) {
            return Err(format!("table threshold must be in [0, 1), got {}", self.table_threshold));
        }
        if self.max_bucket > MAX_BUCKET {
            return Err(format!("buckets must be in 0..={MAX_BUCKET}, got {}", self.max_bucket));
        }
        Ok(())
    }
}
