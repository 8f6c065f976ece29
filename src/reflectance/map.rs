//! Actual-to-prototype maps (§3.6.2, Figures 8–9): for a surface
//! orientation (normal `n`, grain `t`), a bijection on direction ids taking
//! each direction to the one playing its part on the prototype surface
//! (normal +y, grain +x). One prototype table then serves every orientation:
//! light from actual direction `i` is looked up in row `map[i]`, and the
//! table's outgoing prototype direction `o_p` is sent along `map⁻¹[o_p]`.
//!
//! Two constructions:
//!
//! - [`MapMethod::Rings`], the paper's: the direction nearest the actual
//!   normal goes to the one nearest the prototype normal, then each
//!   concentric ring of neighbours (breadth-first over the neighbour lists)
//!   to the corresponding ring, numbered counter-clockwise from the direction
//!   with the largest dot product with the grain. Where the two rings differ
//!   in size (a five-fold direction nearby) the numbering runs on into the
//!   next ring, which keeps the map a bijection.
//! - [`MapMethod::Nearest`]: rotate each direction into the prototype frame
//!   and take the nearest direction not yet taken, directions nearest the
//!   normal first.
//!
//! [`MapStats`] measures the angular error of a map: the angle between the
//! rotated actual direction and the prototype direction it is mapped to, over
//! the directions above the actual surface.

/// How to build a map.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum MapMethod {
    /// The paper's concentric rings.
    Rings,
    /// Rotate and take the nearest free direction (the default: lower error,
    /// see `docs/ACCURACY.md`).
    #[default]
    Nearest,
}

/// A bijection on direction ids for one orientation.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OrientationMap {
    /// Actual direction → prototype direction.
    pub to_prototype: Vec<u32>,
}

/// Angular error of a map over the directions above the actual surface.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MapStats {
    /// Mean error (radians).
    pub mean_rad: f64,
    /// Largest error (radians).
    pub max_rad: f64,
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

fn f64x3(d: [f32; 3]) -> [f64; 3] {
    [d[0] as f64, d[1] as f64, d[2] as f64]
}

/// An orthonormal frame `(t, b, n)` with `b = n × t`, from a normal and a
/// grain direction (projected onto the surface; any direction if parallel).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frame {
    /// Along the grain.
    pub t: [f64; 3],
    /// `n × t`.
    pub b: [f64; 3],
    /// The normal.
    pub n: [f64; 3],
}

impl Frame {
    /// The frame of normal `n` and grain `grain`.
    pub fn new(n: [f32; 3], grain: [f32; 3]) -> Self {
        let n = f64x3(n);
        let l = dot(n, n).sqrt();
        let n = [n[0] / l, n[1] / l, n[2] / l];
        let project = |g: [f64; 3]| {
            let k = dot(g, n);
            let p = [g[0] - k * n[0], g[1] - k * n[1], g[2] - k * n[2]];
            let l = dot(p, p).sqrt();
            (l > 1e-6).then(|| [p[0] / l, p[1] / l, p[2] / l])
        };
        let t = project(f64x3(grain))
            .or_else(|| project([1.0, 0.0, 0.0]))
            .or_else(|| project([0.0, 0.0, 1.0]))
            .expect("a unit normal is not parallel to both x and z");
        Self { t, b: cross(n, t), n }
    }

    /// The prototype frame: normal +y, grain +x.
    pub fn prototype() -> Self {
        Self::new([0.0, 1.0, 0.0], [1.0, 0.0, 0.0])
    }

    /// Coordinates of `d` in this frame.
    pub fn local(&self, d: [f64; 3]) -> [f64; 3] {
        [dot(d, self.t), dot(d, self.b), dot(d, self.n)]
    }

    /// The direction with local coordinates `l`.
    pub fn world(&self, l: [f64; 3]) -> [f64; 3] {
        [0, 1, 2].map(|k| l[0] * self.t[k] + l[1] * self.b[k] + l[2] * self.n[k])
    }
}

impl OrientationMap {
    /// The map for `frame` over `directions` with their `neighbours`
    /// (counter-clockwise, `u32::MAX` = none).
    pub fn new(directions: &[[f32; 3]], neighbours: &[[u32; 6]], frame: &Frame, method: MapMethod) -> Self {
        match method {
            MapMethod::Rings => rings(directions, neighbours, frame),
            MapMethod::Nearest => nearest(directions, neighbours, frame),
        }
    }

    /// The inverse map: prototype direction → actual direction.
    pub fn inverse(&self) -> Vec<u32> {
        let mut inv = vec![u32::MAX; self.to_prototype.len()];
        for (a, &p) in self.to_prototype.iter().enumerate() {
            inv[p as usize] = a as u32;
        }
        inv
    }

    /// Whether the map is a bijection on `0..len`.
    pub fn is_bijection(&self) -> bool {
        let mut seen = vec![false; self.to_prototype.len()];
        for &p in &self.to_prototype {
            match seen.get_mut(p as usize) {
                Some(s) if !*s => *s = true,
                _ => return false,
            }
        }
        true
    }

    /// Angular error against the exact rotation into the prototype frame.
    pub fn stats(&self, directions: &[[f32; 3]], frame: &Frame) -> MapStats {
        let proto = Frame::prototype();
        let (mut sum, mut max, mut count) = (0.0, 0.0f64, 0usize);
        for (a, &p) in self.to_prototype.iter().enumerate() {
            let d = f64x3(directions[a]);
            let l = frame.local(d);
            if l[2] <= 0.0 {
                continue;
            }
            let r = proto.world(l);
            let q = f64x3(directions[p as usize]);
            let c = cross(r, q);
            let e = dot(c, c).sqrt().atan2(dot(r, q));
            sum += e;
            max = max.max(e);
            count += 1;
        }
        MapStats { mean_rad: if count > 0 { sum / count as f64 } else { 0.0 }, max_rad: max }
    }
}

fn nearest_to(directions: &[[f32; 3]], v: [f64; 3]) -> usize {
    let mut best = (f64::MIN, 0);
    for (i, d) in directions.iter().enumerate() {
        let k = dot(f64x3(*d), v);
        if k > best.0 {
            best = (k, i);
        }
    }
    best.1
}

/// Breadth-first rings of neighbours around the direction nearest
/// `frame.n`, each ring numbered counter-clockwise (seen from outside) from
/// its direction with the largest dot product with the grain. Each entry is
/// `(direction, position in ring in [0, 1))`.
fn rings_around(directions: &[[f32; 3]], neighbours: &[[u32; 6]], frame: &Frame) -> Vec<Vec<(u32, f64)>> {
    let n = directions.len();
    let mut level = vec![false; n];
    let centre = nearest_to(directions, frame.n);
    level[centre] = true;
    let mut out = vec![vec![(centre as u32, 0.0)]];
    let mut ring = vec![centre as u32];
    loop {
        let mut next = Vec::new();
        for &d in &ring {
            for &m in &neighbours[d as usize] {
                if m != u32::MAX && !level[m as usize] {
                    level[m as usize] = true;
                    next.push(m);
                }
            }
        }
        if next.is_empty() {
            break;
        }
        let angle = |d: u32| {
            let l = frame.local(f64x3(directions[d as usize]));
            l[1].atan2(l[0])
        };
        let start = *next
            .iter()
            .max_by(|&&a, &&b| {
                let (la, lb) = (f64x3(directions[a as usize]), f64x3(directions[b as usize]));
                dot(la, frame.t).total_cmp(&dot(lb, frame.t)).then(b.cmp(&a))
            })
            .expect("ring is not empty");
        let a0 = angle(start);
        let tau = std::f64::consts::TAU;
        let mut labelled: Vec<(u32, f64)> =
            next.iter().map(|&d| (d, if d == start { 0.0 } else { (angle(d) - a0).rem_euclid(tau) / tau })).collect();
        labelled.sort_by(|x, y| x.1.total_cmp(&y.1).then(x.0.cmp(&y.0)));
        out.push(labelled.clone());
        ring = next;
    }
    // Directions the neighbour graph does not reach (none in a valid set).
    let rest: Vec<(u32, f64)> = (0..n).filter(|&i| !level[i]).map(|i| (i as u32, 0.0)).collect();
    if !rest.is_empty() {
        out.push(rest);
    }
    out
}

fn rings(directions: &[[f32; 3]], neighbours: &[[u32; 6]], frame: &Frame) -> OrientationMap {
    let actual = rings_around(directions, neighbours, frame);
    let proto = rings_around(directions, neighbours, &Frame::prototype());
    let mut to_prototype = vec![u32::MAX; directions.len()];
    // Ring r goes to ring r, in numbering order. Where the rings differ in
    // size, the k-th of the smaller ring takes the element at the same
    // fraction of the larger, and the larger ring's unmatched directions
    // carry over into the next ring (keeping their positions).
    let mut carry_a: Vec<(u32, f64)> = Vec::new();
    let mut carry_p: Vec<(u32, f64)> = Vec::new();
    let rings = actual.len().max(proto.len());
    for r in 0..rings {
        let mut a = std::mem::take(&mut carry_a);
        a.extend(actual.get(r).into_iter().flatten().copied());
        let mut p = std::mem::take(&mut carry_p);
        p.extend(proto.get(r).into_iter().flatten().copied());
        a.sort_by(|x, y| x.1.total_cmp(&y.1).then(x.0.cmp(&y.0)));
        p.sort_by(|x, y| x.1.total_cmp(&y.1).then(x.0.cmp(&y.0)));
        let last = r + 1 == rings;
        let (small, large, small_is_a) = if a.len() <= p.len() { (&a, &p, true) } else { (&p, &a, false) };
        let mut used = vec![false; large.len()];
        for (k, s) in small.iter().enumerate() {
            let mut j = ((k as f64 * large.len() as f64 / small.len() as f64).round() as usize).min(large.len() - 1);
            while used[j] {
                j = (j + 1) % large.len();
            }
            used[j] = true;
            let (x, y) = if small_is_a { (s.0, large[j].0) } else { (large[j].0, s.0) };
            to_prototype[x as usize] = y;
        }
        let left: Vec<(u32, f64)> = large.iter().zip(&used).filter(|(_, u)| !**u).map(|(e, _)| *e).collect();
        if last {
            debug_assert!(left.is_empty(), "both sides hold every direction");
        } else if small_is_a {
            carry_p = left;
        } else {
            carry_a = left;
        }
    }
    OrientationMap { to_prototype }
}

fn nearest(directions: &[[f32; 3]], neighbours: &[[u32; 6]], frame: &Frame) -> OrientationMap {
    let n = directions.len();
    let proto = Frame::prototype();
    // Directions nearest the normal choose first.
    let mut order: Vec<u32> = (0..n as u32).collect();
    let height: Vec<f64> = directions.iter().map(|d| dot(f64x3(*d), frame.n)).collect();
    order.sort_by(|&a, &b| height[b as usize].total_cmp(&height[a as usize]).then(a.cmp(&b)));
    let mut free: Vec<u32> = (0..n as u32).collect();
    let mut to_prototype = vec![0u32; n];
    for &a in &order {
        let r = proto.world(frame.local(f64x3(directions[a as usize])));
        let mut best = (f64::MIN, 0usize);
        for (k, &p) in free.iter().enumerate() {
            let d = dot(r, f64x3(directions[p as usize]));
            if d > best.0 {
                best = (d, k);
            }
        }
        to_prototype[a as usize] = free.swap_remove(best.1);
    }
    improve_by_swaps(directions, neighbours, frame, &mut to_prototype);
    OrientationMap { to_prototype }
}

/// Local improvement of a greedy map: swap the targets of two directions
/// above the surface when that lowers their summed angular error, trying the
/// prototype neighbours of each target, until no swap helps (or 8 sweeps).
fn improve_by_swaps(directions: &[[f32; 3]], neighbours: &[[u32; 6]], frame: &Frame, map: &mut [u32]) {
    let proto = Frame::prototype();
    let n = directions.len();
    let rotated: Vec<[f64; 3]> = directions.iter().map(|d| proto.world(frame.local(f64x3(*d)))).collect();
    let above: Vec<bool> = directions.iter().map(|d| dot(f64x3(*d), frame.n) > 0.0).collect();
    let mut inverse = vec![0u32; n];
    for (a, &p) in map.iter().enumerate() {
        inverse[p as usize] = a as u32;
    }
    // Error as 1 − cos (monotone in the angle).
    let cost = |a: usize, p: u32| if above[a] { 1.0 - dot(rotated[a], f64x3(directions[p as usize])) } else { 0.0 };
    for _ in 0..8 {
        let mut swapped = 0;
        for a in 0..n {
            if !above[a] {
                continue;
            }
            for &q in &neighbours[map[a] as usize] {
                if q == u32::MAX {
                    continue;
                }
                let b = inverse[q as usize] as usize;
                let (pa, pb) = (map[a], map[b]);
                if cost(a, pb) + cost(b, pa) < cost(a, pa) + cost(b, pb) - 1e-12 {
                    map[a] = pb;
                    map[b] = pa;
                    inverse[pb as usize] = a as u32;
                    inverse[pa as usize] = b as u32;
                    swapped += 1;
                }
            }
        }
        if swapped == 0 {
            break;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geodesic::DirectionSet;

    #[test]
    fn prototype_orientation_maps_to_itself() {
        let dirs = DirectionSet::new(6).unwrap();
        for method in [MapMethod::Rings, MapMethod::Nearest] {
            let m = OrientationMap::new(&dirs.directions, &dirs.neighbours, &Frame::prototype(), method);
            assert!(m.is_bijection());
            assert!(m.stats(&dirs.directions, &Frame::prototype()).max_rad < 1e-6, "{method:?}");
        }
    }

    #[test]
    fn maps_are_bijections_with_small_error() {
        let dirs = DirectionSet::new(12).unwrap();
        let spacing = dirs.uniformity().spacing_mean_rad;
        let frames = [
            Frame::new([0.0, 0.0, 1.0], [1.0, 0.0, 0.0]),
            Frame::new([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
            Frame::new([0.3, 0.8, -0.5], [1.0, 0.2, 0.1]),
            Frame::new([0.0, 1.0, 0.0], [1.0, 0.0, 1.0]),
        ];
        for f in &frames {
            for method in [MapMethod::Rings, MapMethod::Nearest] {
                let m = OrientationMap::new(&dirs.directions, &dirs.neighbours, f, method);
                assert!(m.is_bijection(), "{method:?}");
                let s = m.stats(&dirs.directions, f);
                if method == MapMethod::Nearest {
                    assert!(s.mean_rad < 0.5 * spacing, "{method:?} {f:?}: {s:?}, spacing {spacing}");
                }
                // Both keep directions within a few spacings.
                assert!(s.max_rad < 4.0 * spacing, "{method:?} {f:?}: {s:?}, spacing {spacing}");
            }
        }
    }
}
