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
    /// How a quad's patches are numbered: tiles (default), or rows as
    /// archives before version 7 (for comparisons).
    pub cell_order: crate::geometry::grid::CellOrder,
    /// How patches are numbered across primitives: along a Morton curve
    /// over the primitives' centres (default; applied to still scenes
    /// only: sequences, frames of sequences and stills built on a
    /// sequence's ray grid keep primitive order, so that their patch ids
    /// agree), or in primitive order as archives before version 11.
    pub patch_order: crate::patch::order::PatchOrder,
    /// Whether small triangles of still, diffuse surfaces are grouped into
    /// patches of several (`patch::mesh`; default), or each keeps its own.
    pub group_triangles: bool,
    /// How rays find their hits: BVH traversal per ray (default) or scan
    /// conversion (groundwork, not faster yet). The archive is the same
    /// byte for byte either way.
    pub trace_method: super::trace::TraceMethod,
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

/// A preset of build resolution relative to the scene's size (`--quality`):
/// what a user picks before tuning absolute lengths. Cornell box
/// (docs/ACCURACY.md, "Quality presets"): draft 2.3% in 0.6 s and 27 MB,
/// default 1.9% in 4.5 s and 182 MB, high 1.8% in 31 s and 742 MB.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Quality {
    /// Frequency 11, patches of diagonal/48, rays diagonal/64 apart.
    Draft,
    /// Frequency 16, patches of diagonal/64, rays diagonal/128 apart.
    #[default]
    Default,
    /// Frequency 24, patches of diagonal/64, rays diagonal/256 apart.
    High,
}

impl Quality {
    /// Frequency, patch size and ray spacing as fractions of the diagonal.
    pub fn fractions(self) -> (u32, f32, f32) {
        match self {
            Quality::Draft => (11, 1.0 / 48.0, 1.0 / 64.0),
            Quality::Default => (DEFAULT_FREQUENCY, DEFAULT_PATCH_FRACTION, DEFAULT_SPACING_FRACTION),
            Quality::High => (24, DEFAULT_PATCH_FRACTION, 1.0 / 256.0),
        }
    }
}

impl BuildSettings {
    /// Settings for `scene`: explicit `overrides` first, then the scene's
    /// `[build]` table, then defaults scaled to the scene's size, so that a
    /// scene costs the same to build whatever its units.
    pub fn resolve(scene: &Scene, overrides: BuildHints) -> Self {
        Self::resolve_with(scene, overrides, Quality::Default)
    }

    /// [`BuildSettings::resolve`] with the scene-relative defaults of
    /// `quality`; explicit overrides and the scene's `[build]` table still
    /// come first.
    pub fn resolve_with(scene: &Scene, overrides: BuildHints, quality: Quality) -> Self {
        let (lo, hi) = scene.bounds();
        let diagonal = (hi - lo).length().max(f32::MIN_POSITIVE);
        let (frequency, patch, spacing) = quality.fractions();
        Self {
            patch_size: overrides.patch_size.or(scene.build.patch_size).unwrap_or(diagonal * patch),
            frequency: overrides.frequency.or(scene.build.frequency).unwrap_or(frequency),
            ray_spacing: overrides.ray_spacing.or(scene.build.ray_spacing).unwrap_or(diagonal * spacing),
            direction_set: DirectionSetKind::Geodesic,
            max_bucket: overrides.buckets.or(scene.build.buckets).unwrap_or(DEFAULT_MAX_BUCKET),
            grid_bounds: None,
            prototype_library: crate::reflectance::library::Library::default_location(),
            map_method: crate::reflectance::MapMethod::default(),
            table_threshold: crate::reflectance::prototype::DEFAULT_THRESHOLD,
            cell_order: crate::patch::DEFAULT_CELL_ORDER,
            patch_order: crate::patch::order::PatchOrder::Spatial,
            group_triangles: true,
            trace_method: Default::default(),
        }
    }

    /// Rejects settings no build can use.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.patch_size.is_finite() && self.patch_size > 0.0) {
            return Err(format!("patch size must be a positive length, got {}", self.patch_size));
        }
        if !(self.ray_spacing.is_finite() && self.ray_spacing >= crate::limits::MIN_RAY_SPACING) {
            return Err(format!(
                "ray spacing must be a length of at least {:e} m, got {}",
                crate::limits::MIN_RAY_SPACING,
                self.ray_spacing
            ));
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quality_presets_scale_with_the_scene_and_give_way_to_explicit_values() {
        let scene = Scene::cornell_box();
        let (lo, hi) = scene.bounds();
        let d = (hi - lo).length();
        let draft = BuildSettings::resolve_with(&scene, BuildHints::default(), Quality::Draft);
        let default = BuildSettings::resolve(&scene, BuildHints::default());
        let high = BuildSettings::resolve_with(&scene, BuildHints::default(), Quality::High);
        assert_eq!((draft.frequency, default.frequency, high.frequency), (11, 16, 24));
        assert!((draft.patch_size - d / 48.0).abs() < 1e-6 && (draft.ray_spacing - d / 64.0).abs() < 1e-6);
        assert!((default.patch_size - d / 64.0).abs() < 1e-6 && (default.ray_spacing - d / 128.0).abs() < 1e-6);
        assert!((high.patch_size - d / 64.0).abs() < 1e-6 && (high.ray_spacing - d / 256.0).abs() < 1e-6);
        assert_eq!(default, BuildSettings::resolve_with(&scene, BuildHints::default(), Quality::Default));
        // An explicit value wins over the preset; the rest follow it.
        let hints = BuildHints { frequency: Some(7), ..Default::default() };
        let mixed = BuildSettings::resolve_with(&scene, hints, Quality::High);
        assert_eq!(mixed.frequency, 7);
        assert_eq!(mixed.ray_spacing, high.ray_spacing);
    }
}
