//! The global direction set: a geodesic tessellation of the unit sphere (§3.3).
//!
//! An icosahedron's 20 faces are each cut into `f²` triangles (frequency `f`)
//! and the vertices projected onto the sphere, giving `10f² + 2` directions,
//! nearly evenly spread (the paper's cure for ray-space "bunching", §3.2).
//! Each direction keeps its 5 or 6 neighbours, ordered counter-clockwise seen
//! from outside the sphere, for the rings of the actual-to-prototype maps
//! (§3.6.2) and the buckets of §3.4.
//!
//! The set is centrally symmetric and stored in antipodal pairs: direction
//! `2k+1` is exactly `−(direction 2k)` (bitwise), so `antipode(i) = i ^ 1` and
//! one bundle of rays serves both directions of a pair.
//!
//! Construction is exact: every vertex is an integer combination
//! `(a·A + b·B + c·C)/f` of icosahedron corners, keyed by those integers, so
//! shared edge vertices are found without floating-point tolerances.

mod ray_space;

use std::collections::BTreeMap;

pub use ray_space::ray_space;

use glam::DVec3;

/// Largest supported frequency (`10·80² + 2 = 64 002` directions).
pub const MAX_FREQUENCY: u32 = crate::limits::MAX_FREQUENCY;

/// Which construction a [`DirectionSet`] came from. The discriminants are the
/// on-disk values (`format-spec/archive.md`, `BILD.direction_set`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum DirectionSetKind {
    /// Icosahedral geodesic set (§3.3), `10f² + 2` directions.
    Geodesic = 0,
    /// The 1989 ray-space baseline (§3.2), `6m²` directions; see [`ray_space`].
    RaySpace = 1,
}

/// The geodesic direction set with neighbour lists.
#[derive(Debug, Clone)]
pub struct DirectionSet {
    /// How the set was made.
    pub kind: DirectionSetKind,
    /// Subdivision frequency `f` (ray-space: slope divisions `m`).
    pub frequency: u32,
    /// Unit directions; `directions[2k+1] == -directions[2k]`.
    pub directions: Vec<[f32; 3]>,
    /// Up to six neighbour indices per direction, counter-clockwise seen from
    /// outside; unused slots hold `u32::MAX`.
    pub neighbours: Vec<[u32; 6]>,
    /// Solid angle of each direction's spherical Voronoi cell (sr); sums to 4π.
    /// The build spaces each bundle's rays so that every ray carries the same
    /// étendue `δ_k²·Ω_k`, which removes what unevenness the tessellation has left.
    pub solid_angle: Vec<f64>,
}

/// Uniformity of a direction set, measured on its spherical Voronoi cells.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Uniformity {
    /// Smallest Voronoi cell solid angle (sr).
    pub cell_min_sr: f64,
    /// Largest Voronoi cell solid angle (sr).
    pub cell_max_sr: f64,
    /// Sum of all cells (sr); 4π up to rounding.
    pub cell_sum_sr: f64,
    /// Smallest angle between neighbouring directions (radians).
    pub spacing_min_rad: f64,
    /// Largest angle between neighbouring directions (radians).
    pub spacing_max_rad: f64,
    /// Mean angle between neighbouring directions (radians).
    pub spacing_mean_rad: f64,
}

/// A vertex key: up to three (corner, weight) pairs, sorted by corner.
type Key = [(u8, u32); 3];

fn icosahedron() -> (Vec<DVec3>, Vec<[usize; 3]>) {
    let phi = (1.0 + 5f64.sqrt()) / 2.0;
    let mut v = Vec::new();
    for &s1 in &[-1.0, 1.0] {
        for &s2 in &[-1.0, 1.0] {
            v.push(DVec3::new(0.0, s1, s2 * phi));
            v.push(DVec3::new(s1, s2 * phi, 0.0));
            v.push(DVec3::new(s2 * phi, 0.0, s1));
        }
    }
    // Faces: triples of mutually adjacent corners (edge length 2).
    let adjacent = |a: usize, b: usize| ((v[a] - v[b]).length() - 2.0).abs() < 1e-9;
    let mut faces = Vec::new();
    for a in 0..12 {
        for b in a + 1..12 {
            for c in b + 1..12 {
                if adjacent(a, b) && adjacent(b, c) && adjacent(a, c) {
                    let n = (v[b] - v[a]).cross(v[c] - v[a]);
                    faces.push(if n.dot(v[a]) > 0.0 { [a, b, c] } else { [a, c, b] });
                }
            }
        }
    }
    debug_assert_eq!(faces.len(), 20);
    (v, faces)
}

fn make_key(mut parts: Vec<(u8, u32)>) -> Key {
    parts.retain(|p| p.1 != 0);
    parts.sort_unstable();
    let mut k = [(u8::MAX, 0); 3];
    k[..parts.len()].copy_from_slice(&parts);
    k
}

impl DirectionSet {
    /// Builds the set for frequency `f` (1 ≤ f ≤ [`MAX_FREQUENCY`]).
    ///
    /// ```
    /// use illumnet::geodesic::DirectionSet;
    /// let set = DirectionSet::new(16).unwrap();
    /// assert_eq!(set.len(), 2562); // 10f² + 2
    /// assert_eq!(set.directions[1], set.directions[0].map(|x| -x)); // antipodal pairs
    /// ```
    pub fn new(frequency: u32) -> Result<Self, String> {
        if frequency == 0 || frequency > MAX_FREQUENCY {
            return Err(format!("direction frequency must be in 1..={MAX_FREQUENCY}, got {frequency}"));
        }
        let f = frequency;
        let (corners, faces) = icosahedron();
        // Antipodal corner of each corner.
        let anti: Vec<u8> =
            (0..12).map(|a| (0..12).find(|&b| (corners[a] + corners[b]).length() < 1e-9).unwrap() as u8).collect();
        // Spherical (slerp-like) weights: exact great-circle spacing along
        // the icosahedron's edges and far more even cells inside the faces
        // than projecting the flat subdivision (cell-size ratio 1.93 at f = 16).
        let theta = corners[faces[0][0]].angle_between(corners[faces[0][1]]);
        let position = |k: &Key| {
            let mut p = DVec3::ZERO;
            for &(c, w) in k.iter().filter(|p| p.0 != u8::MAX) {
                p += corners[c as usize].normalize() * (w as f64 / f as f64 * theta).sin();
            }
            p.normalize()
        };
        // Every sub-triangle of every face, as vertex keys.
        let mut keys: BTreeMap<Key, u32> = BTreeMap::new();
        let mut tris: Vec<[Key; 3]> = Vec::new();
        for face in &faces {
            let key =
                |i: u32, j: u32| make_key(vec![(face[0] as u8, f - i - j), (face[1] as u8, i), (face[2] as u8, j)]);
            for j in 0..f {
                for i in 0..f - j {
                    tris.push([key(i, j), key(i + 1, j), key(i, j + 1)]);
                    if i + j + 2 <= f {
                        tris.push([key(i + 1, j), key(i + 1, j + 1), key(i, j + 1)]);
                    }
                }
            }
        }
        for t in &tris {
            for k in t {
                keys.entry(*k).or_insert(0);
            }
        }
        // Pair each key with its antipode; number pairs in key order.
        let antikey =
            |k: &Key| make_key(k.iter().filter(|p| p.0 != u8::MAX).map(|&(c, w)| (anti[c as usize], w)).collect());
        let mut directions = Vec::with_capacity(keys.len());
        let all: Vec<Key> = keys.keys().copied().collect();
        for k in &all {
            if keys[k] != 0 {
                continue;
            }
            let ak = antikey(k);
            let p = position(k);
            let idx = directions.len() as u32;
            directions.push(p);
            directions.push(-p);
            keys.insert(*k, idx + 1); // store index + 1; 0 = unassigned
            keys.insert(ak, idx + 2);
        }
        let index = |k: &Key| keys[k] - 1;
        let n = directions.len();
        debug_assert_eq!(n as u32, 10 * f * f + 2);
        let mut sets: Vec<Vec<u32>> = vec![Vec::new(); n];
        for t in &tris {
            let ids = [index(&t[0]), index(&t[1]), index(&t[2])];
            for a in 0..3 {
                for b in 0..3 {
                    if a != b && !sets[ids[a] as usize].contains(&ids[b]) {
                        sets[ids[a] as usize].push(ids[b]);
                    }
                }
            }
        }
        let mut neighbours = vec![[u32::MAX; 6]; n];
        for (d, set) in sets.iter_mut().enumerate() {
            // Counter-clockwise around d seen from outside: sort by angle in
            // the tangent plane with basis (e1, e2 = d × e1).
            let dir = directions[d];
            let helper = if dir.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
            let e1 = (helper - dir * dir.dot(helper)).normalize();
            let e2 = dir.cross(e1);
            set.sort_by(|&a, &b| {
                let ang = |x: u32| {
                    let v = directions[x as usize];
                    v.dot(e2).atan2(v.dot(e1))
                };
                ang(a).total_cmp(&ang(b)).then(a.cmp(&b))
            });
            debug_assert!(set.len() == 5 || set.len() == 6 || f == 1 && set.len() == 5);
            neighbours[d][..set.len()].copy_from_slice(set);
        }
        let directions = directions.iter().map(|p| p.as_vec3().to_array()).collect();
        let mut set =
            Self { kind: DirectionSetKind::Geodesic, frequency: f, directions, neighbours, solid_angle: Vec::new() };
        set.solid_angle = set.voronoi_cells();
        Ok(set)
    }

    /// Number of directions `N = 10f² + 2`.
    pub fn len(&self) -> usize {
        self.directions.len()
    }

    /// Always false: a direction set has at least 12 directions.
    pub fn is_empty(&self) -> bool {
        self.directions.is_empty()
    }

    /// Index of `−d` for direction `d`.
    pub fn antipode(index: u32) -> u32 {
        index ^ 1
    }

    /// The neighbours of direction `index` (5 or 6 of them).
    pub fn neighbours_of(&self, index: usize) -> impl Iterator<Item = u32> + '_ {
        self.neighbours[index].iter().copied().filter(|&n| n != u32::MAX)
    }

    /// Solid angle each direction stands for if the set were perfectly even (4π/N).
    pub fn mean_solid_angle(&self) -> f64 {
        4.0 * std::f64::consts::PI / self.len() as f64
    }

    /// Solid angle of every direction's spherical Voronoi cell, bounded by the
    /// circumcentres of the triangles around it (sr).
    fn voronoi_cells(&self) -> Vec<f64> {
        let dir = |i: u32| DVec3::from(self.directions[i as usize].map(f64::from)).normalize();
        // Van Oosterom–Strackee: solid angle of the spherical triangle a b c.
        let tri_area = |a: DVec3, b: DVec3, c: DVec3| {
            let num = a.dot(b.cross(c)).abs();
            let den = 1.0 + a.dot(b) + b.dot(c) + c.dot(a);
            2.0 * num.atan2(den)
        };
        (0..self.len())
            .map(|d| {
                let c = dir(d as u32);
                let ns: Vec<DVec3> = self.neighbours_of(d).map(dir).collect();
                let m = ns.len();
                let centres: Vec<DVec3> = (0..m)
                    .map(|k| {
                        let (a, b) = (ns[k], ns[(k + 1) % m]);
                        let cc = (a - c).cross(b - c).normalize();
                        if cc.dot(c) < 0.0 { -cc } else { cc }
                    })
                    .collect();
                (0..m).map(|k| tri_area(c, centres[k], centres[(k + 1) % m])).sum()
            })
            .collect()
    }

    /// Ratio of the largest to the smallest direction cell.
    pub fn uniformity_of_cells(&self) -> f64 {
        let max = self.solid_angle.iter().copied().fold(0.0, f64::max);
        let min = self.solid_angle.iter().copied().fold(f64::MAX, f64::min);
        max / min
    }

    /// Measures cell sizes and neighbour spacing.
    pub fn uniformity(&self) -> Uniformity {
        let dir = |i: u32| DVec3::from(self.directions[i as usize].map(f64::from)).normalize();
        let cells = &self.solid_angle;
        let (mut smin, mut smax, mut ssum, mut scount) = (f64::MAX, 0.0f64, 0.0, 0u64);
        for d in 0..self.len() {
            let c = dir(d as u32);
            for nb in self.neighbours_of(d).map(dir) {
                let ang = c.dot(nb).clamp(-1.0, 1.0).acos();
                smin = smin.min(ang);
                smax = smax.max(ang);
                ssum += ang;
                scount += 1;
            }
        }
        Uniformity {
            cell_min_sr: cells.iter().copied().fold(f64::MAX, f64::min),
            cell_max_sr: cells.iter().copied().fold(0.0, f64::max),
            cell_sum_sr: cells.iter().sum(),
            spacing_min_rad: smin,
            spacing_max_rad: smax,
            spacing_mean_rad: ssum / scount as f64,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_symmetry_and_neighbours() {
        for f in [1, 2, 3, 8, 16] {
            let s = DirectionSet::new(f).unwrap();
            assert_eq!(s.len() as u32, 10 * f * f + 2);
            let mut fives = 0;
            for (i, d) in s.directions.iter().enumerate() {
                let a = s.directions[DirectionSet::antipode(i as u32) as usize];
                assert_eq!([-d[0], -d[1], -d[2]], a, "exact antipodes");
                let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                assert!((len - 1.0).abs() < 1e-6);
                let n: Vec<u32> = s.neighbours_of(i).collect();
                assert!(n.len() == 5 || n.len() == 6);
                fives += (n.len() == 5) as u32;
                for &j in &n {
                    assert!(s.neighbours_of(j as usize).any(|k| k == i as u32), "symmetric");
                }
            }
            assert_eq!(fives, 12, "only the icosahedron's corners have five neighbours");
        }
    }

    #[test]
    fn voronoi_cells_tile_the_sphere_and_are_even() {
        let s = DirectionSet::new(16).unwrap();
        let u = s.uniformity();
        assert!((u.cell_sum_sr - 4.0 * std::f64::consts::PI).abs() < 1e-6, "{u:?}");
        // Measured 1.235 at f = 16 (docs/GEODESIC.md); projecting the flat
        // subdivision instead gives 1.93.
        assert!(u.cell_max_sr / u.cell_min_sr < 1.25, "{u:?}");
        assert!(u.spacing_max_rad / u.spacing_min_rad < 1.2, "{u:?}");
        for (i, w) in s.solid_angle.iter().enumerate() {
            assert!(
                (*w - s.solid_angle[DirectionSet::antipode(i as u32) as usize]).abs() < 1e-12,
                "antipodes share a cell"
            );
        }
    }
}
