//! The view-dependent term of non-diffuse patches (§3.5): the radiance a
//! patch sends towards the eye, evaluated once per patch for the ray from
//! the eye to the patch centre and added to its diffuse radiance, so that
//! rendering then proceeds as for diffuse patches. Valid while a patch
//! covers a small part of the screen.
//!
//! The direction to the eye generally falls between directions of the set:
//! the radiance is interpolated barycentrically over the spherical triangle
//! of neighbouring directions that contains it.

use glam::Vec3;
use rayon::prelude::*;

use crate::archive::InetView;
use crate::archive::layout::DirectionRecord;
use crate::distribute::Solution;

/// Patch radiance as seen from `eye`: each patch's diffuse radiance plus,
/// for non-diffuse patches, their directional radiance towards `eye`.
pub fn radiance_seen_from(v: &InetView<'_>, solution: &Solution, eye: Vec3) -> Vec<[f32; 3]> {
    seen_from(v, solution, eye, false)
}

/// [`radiance_seen_from`], with the directional radiance's direct part
/// (the emitters' highlights) taken off when `indirect` and split.
fn seen_from(v: &InetView<'_>, solution: &Solution, eye: Vec3, indirect: bool) -> Vec<[f32; 3]> {
    let mut out = solution.radiance.clone();
    let Some(d) = &solution.directional else {
        return out;
    };
    let extra: Vec<[f32; 3]> = d
        .patches
        .par_iter()
        .enumerate()
        .map(|(k, &q)| {
            let to_eye = (eye - Vec3::from(v.patch_centre[q as usize])).normalize_or_zero();
            let all = interpolate(v.directions, d.of(k), to_eye);
            match d.direct_of(k).filter(|_| indirect) {
                // Interpolated with the same weights: the difference is the
                // interpolated indirect part, non-negative up to rounding.
                Some(direct) => {
                    let once = interpolate(v.directions, direct, to_eye);
                    [0, 1, 2].map(|c| (all[c] - once[c]).max(0.0))
                }
                None => all,
            }
        })
        .collect();
    for (&q, e) in d.patches.iter().zip(extra) {
        for c in 0..3 {
            out[q as usize][c] += e[c];
        }
    }
    out
}

/// Patch radiance for `frame`, seen from that frame's camera.
pub fn frame_radiance(v: &InetView<'_>, frame: u32, solution: &Solution) -> Vec<[f32; 3]> {
    radiance_seen_from(v, solution, frame_eye(v, frame))
}

/// Where `frame`'s camera is.
fn frame_eye(v: &InetView<'_>, frame: u32) -> Vec3 {
    Vec3::from(v.camera_at(frame).position)
}

/// [`frame_radiance`] less the solution's direct light
/// ([`Solution::direct`], and the direct part of non-diffuse patches'
/// directional radiance, [`crate::distribute::DirectionalRadiance::direct`]):
/// what a renderer that computes direct light per image sample
/// ([`super::DirectLight`], highlights included) interpolates between patch
/// vertices. Without a direct part in the solution, all of
/// [`frame_radiance`].
pub fn indirect_frame_radiance(v: &InetView<'_>, frame: u32, solution: &Solution) -> Vec<[f32; 3]> {
    indirect_radiance_seen_from(v, solution, frame_eye(v, frame))
}

/// [`indirect_frame_radiance`] seen from `eye` (a camera given at render
/// time).
pub fn indirect_radiance_seen_from(v: &InetView<'_>, solution: &Solution, eye: Vec3) -> Vec<[f32; 3]> {
    let mut out = seen_from(v, solution, eye, true);
    if let Some(direct) = &solution.direct {
        for (o, d) in out.iter_mut().zip(direct) {
            // Exactly non-negative in exact arithmetic (emission plus light
            // that bounced twice); rounding may leave −1e-7.
            *o = [0, 1, 2].map(|c| (o[c] - d[c]).max(0.0));
        }
    }
    out
}

/// `values` (one per direction) at unit vector `w`, interpolated over the
/// triangle of the nearest direction and two consecutive neighbours that
/// contains `w` (the nearest direction's value if none does).
pub fn interpolate(dirs: &[DirectionRecord], values: &[[f32; 3]], w: Vec3) -> [f32; 3] {
    if w == Vec3::ZERO {
        return [0.0; 3];
    }
    let mut best = (f32::MIN, 0usize);
    for (i, d) in dirs.iter().enumerate() {
        let k = Vec3::from(d.direction).dot(w);
        if k > best.0 {
            best = (k, i);
        }
    }
    let i0 = best.1;
    let d0 = Vec3::from(dirs[i0].direction);
    let nb: Vec<u32> = dirs[i0].neighbours.iter().copied().filter(|&x| x != u32::MAX).collect();
    for j in 0..nb.len() {
        let (i1, i2) = (nb[j] as usize, nb[(j + 1) % nb.len()] as usize);
        let (d1, d2) = (Vec3::from(dirs[i1].direction), Vec3::from(dirs[i2].direction));
        // w = a·d0 + b·d1 + c·d2 (Cramer's rule).
        let det = d0.dot(d1.cross(d2));
        if det.abs() < 1e-12 {
            continue;
        }
        let a = w.dot(d1.cross(d2)) / det;
        let b = d0.dot(w.cross(d2)) / det;
        let c = d0.dot(d1.cross(w)) / det;
        if a >= -1e-6 && b >= -1e-6 && c >= -1e-6 {
            let s = a + b + c;
            let (a, b, c) = (a / s, b / s, c / s);
            return [0, 1, 2].map(|k| a * values[i0][k] + b * values[i1][k] + c * values[i2][k]);
        }
    }
    values[i0]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geodesic::DirectionSet;

    #[test]
    fn interpolation_reproduces_linear_functions() {
        let set = DirectionSet::new(6).unwrap();
        let dirs: Vec<DirectionRecord> = set
            .directions
            .iter()
            .zip(&set.neighbours)
            .map(|(d, n)| DirectionRecord { direction: *d, solid_angle_sr: 0.0, neighbours: *n })
            .collect();
        let f = |v: Vec3| 1.0 + v.dot(Vec3::new(0.3, -0.5, 0.8));
        let values: Vec<[f32; 3]> = set.directions.iter().map(|d| [f(Vec3::from(*d)); 3]).collect();
        // Exact at the directions; within the linearisation error between them.
        for (i, d) in set.directions.iter().enumerate() {
            assert!((interpolate(&dirs, &values, Vec3::from(*d))[0] - values[i][0]).abs() < 1e-5);
        }
        for w in [Vec3::new(0.31, 0.77, -0.2), Vec3::new(-0.9, 0.1, 0.42), Vec3::new(0.0, -1.0, 0.05)] {
            let w = w.normalize();
            let got = interpolate(&dirs, &values, w)[0];
            assert!((got - f(w)).abs() < 0.02, "{w}: {got} vs {}", f(w));
        }
    }
}
