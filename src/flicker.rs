//! Flicker: how much patch radiance jumps between frames when an object
//! moves a little (§3, "animation shows every artefact as flicker").
//!
//! The measure moves a surface by small steps, rebuilds and redistributes
//! each step, and averages the frame-to-frame relative change of radiance on
//! watched patches whose true change is small (typically the moving object's
//! own patches: a shift of a few millimetres barely changes their light, but
//! changes which rays hit them); what remains is sampling noise changing
//! with the geometry.

use glam::Vec3;

use crate::archive::{self, Archive};
use crate::bake::{self, BuildSettings};
use crate::distribute::{self, DistributeOptions};
use crate::progress::NoProgress;
use crate::scene::Scene;

/// Result of [`measure`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Flicker {
    /// Mean over frames and watched patches of `|ΔL| / L` (luminance).
    pub mean_relative_change: f64,
    /// 95th percentile of the same.
    pub p95_relative_change: f64,
    /// Link ends per frame (mean), for comparing at equal cost.
    pub link_ends: f64,
}

/// Moves surface `moving` by `step` per frame for `frames` frames; watches
/// the patches of every surface in `watched` (which may include `moving`:
/// its patches move with it and keep their ids).
pub fn measure(
    scene: &Scene,
    settings: &BuildSettings,
    options: &DistributeOptions,
    moving: usize,
    step: Vec3,
    frames: u32,
    watched: &[usize],
) -> Result<Flicker, String> {
    // Patches in primitive order: every frame's keep their ids (a
    // spatial order would follow the moving surface).
    let settings = &BuildSettings { patch_order: bake::PatchOrder::Primitives, ..settings.clone() };
    let mut previous: Option<Vec<f32>> = None;
    let mut changes = Vec::new();
    let mut ends = 0.0;
    for f in 0..frames {
        let mut s = scene.clone();
        for p in &mut s.surfaces[moving].primitives {
            for v in &mut p.p {
                *v += step * f as f32;
            }
        }
        let (contents, stats) = bake::build(&s, settings, &NoProgress)?;
        ends += stats.link_ends as f64 / frames as f64;
        let archive = Archive::from_bytes(&archive::write_to_vec(&contents).map_err(|e| e.to_string())?)
            .map_err(|e| e.to_string())?;
        let v = archive.view();
        let sol = distribute::distribute(&v, options, &NoProgress).map_err(|e| e.to_string())?;
        let lum: Vec<f32> = v
            .patch_primitive
            .iter()
            .zip(&sol.radiance)
            .map(|(&prim, l)| {
                let surf = v.primitives[prim as usize].surface as usize;
                if watched.contains(&surf) { 0.2126 * l[0] + 0.7152 * l[1] + 0.0722 * l[2] } else { f32::NAN }
            })
            .collect();
        if let Some(prev) = &previous {
            for (a, b) in prev.iter().zip(&lum) {
                if a.is_finite() && *a > 0.0 {
                    changes.push(((b - a) / a).abs() as f64);
                }
            }
        }
        previous = Some(lum);
    }
    if changes.is_empty() {
        return Err("no watched patches, or fewer than two frames".into());
    }
    let mean = changes.iter().sum::<f64>() / changes.len() as f64;
    changes.sort_by(f64::total_cmp);
    let p95 = changes[(changes.len() * 95 / 100).min(changes.len() - 1)];
    Ok(Flicker { mean_relative_change: mean, p95_relative_change: p95, link_ends: ends })
}
