//! The 1989 "ray-space" direction set, kept as a measured baseline (§3.2).
//!
//! Directions are uniform in slope over the faces of a cube: on face `±a`,
//! `d = normalize(±(e_a + s·e_b + t·e_c))` with `s, t` at the centres of an
//! `m × m` grid over `[-1, 1]²`, giving `N = 6m²` directions that bunch up
//! towards the cube's corners by up to 3√3 ≈ 5.2 in solid angle. Its rays
//! pass through common points of an intercept plane perpendicular to `e_a`
//! (see `bake::trace`), so oblique rays are denser by `1/cos`. Both defects
//! are what geodesic I-nets remove; this set exists to measure that.

use glam::DVec3;

use super::{DirectionSet, DirectionSetKind};

/// Solid angle of the cell `[s0, s1] × [t0, t1]` of a cube face at distance 1.
fn face_cell_solid_angle(s0: f64, s1: f64, t0: f64, t1: f64) -> f64 {
    let f = |s: f64, t: f64| (s * t / (1.0 + s * s + t * t).sqrt()).atan();
    f(s1, t1) - f(s0, t1) - f(s1, t0) + f(s0, t0)
}

/// The ray-space set with `m` slope divisions per face axis (`6m²` directions),
/// stored in antipodal pairs like the geodesic set.
pub fn ray_space(m: u32) -> Result<DirectionSet, String> {
    if m == 0 || m > 100 {
        return Err(format!("ray-space divisions must be in 1..=100, got {m}"));
    }
    let mut directions = Vec::with_capacity(6 * (m * m) as usize);
    let mut neighbours = Vec::new();
    let mut solid_angle = Vec::new();
    let step = 2.0 / m as f64;
    let index = |a: u32, i: u32, j: u32| 2 * ((a * m + i) * m + j);
    for a in 0..3u32 {
        let (ea, eb, ec) = {
            let e = [DVec3::X, DVec3::Y, DVec3::Z];
            (e[a as usize], e[(a as usize + 1) % 3], e[(a as usize + 2) % 3])
        };
        for i in 0..m {
            for j in 0..m {
                let s = -1.0 + (i as f64 + 0.5) * step;
                let t = -1.0 + (j as f64 + 0.5) * step;
                let d = (ea + s * eb + t * ec).normalize().as_vec3();
                directions.push(d.to_array());
                directions.push((-d).to_array());
                let w = face_cell_solid_angle(s - step / 2.0, s + step / 2.0, t - step / 2.0, t + step / 2.0);
                solid_angle.extend([w, w]);
                let mut n = [u32::MAX; 6];
                let mut k = 0;
                for (di, dj) in [(1i64, 0i64), (0, 1), (-1, 0), (0, -1)] {
                    let (ni, nj) = (i as i64 + di, j as i64 + dj);
                    if (0..m as i64).contains(&ni) && (0..m as i64).contains(&nj) {
                        n[k] = index(a, ni as u32, nj as u32);
                        k += 1;
                    }
                }
                neighbours.push(n);
                neighbours.push(n.map(|x| if x == u32::MAX { x } else { x + 1 }));
            }
        }
    }
    Ok(DirectionSet { kind: DirectionSetKind::RaySpace, frequency: m, directions, neighbours, solid_angle })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ray_space_set_is_symmetric_and_bunched() {
        let s = ray_space(8).unwrap();
        assert_eq!(s.len(), 6 * 64);
        for (i, d) in s.directions.iter().enumerate() {
            assert_eq!(s.directions[i ^ 1], d.map(|x| -x));
        }
        let total: f64 = s.solid_angle.iter().sum();
        assert!((total - 4.0 * std::f64::consts::PI).abs() < 1e-9, "{total}");
        let u = s.uniformity_of_cells();
        // Face-centre cells are larger than corner cells: 3√3 in the limit.
        assert!(u > 3.5 && u < 5.2, "cell max/min {u}");
    }
}
