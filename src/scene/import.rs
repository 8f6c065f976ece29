//! What the OBJ and glTF importers share: [`Notes`] (what they could not
//! map, each said once), unique surface and material names, and the
//! re-merging of exported triangle pairs into the quads they were. Kept
//! below both importers, so that neither imports the other.

use glam::Vec3;

use super::Surface;
use super::check::check_primitive;
use crate::geometry::Primitive;

/// What the importer could not map, each said once; after
/// [`Notes::MAX`] different notes the rest are counted.
#[derive(Default)]
pub(in crate::scene) struct Notes {
    said: Vec<String>,
    seen: std::collections::HashSet<String>,
    more: usize,
}

impl Notes {
    const MAX: usize = 50;

    pub(in crate::scene) fn into_vec(mut self) -> Vec<String> {
        if self.more > 0 {
            self.said.push(format!("… and {} more notes", self.more));
        }
        self.said
    }

    pub(in crate::scene) fn add(&mut self, note: impl Into<String>) {
        let note = note.into();
        if self.seen.contains(&note) {
            return;
        }
        if self.said.len() >= Self::MAX {
            self.more += 1;
            if self.seen.len() < 10 * Self::MAX {
                self.seen.insert(note);
            }
            return;
        }
        self.seen.insert(note.clone());
        self.said.push(note);
    }
}

/// Makes surface names unique (`name`, `name~2`, …): a file may reuse node
/// names, and `--set NAME.FIELD` needs one surface per name.
pub(in crate::scene) fn unique_names(surfaces: &mut [Surface]) {
    let mut taken: std::collections::HashSet<String> = std::collections::HashSet::new();
    for s in surfaces.iter_mut() {
        s.name = unique_name(&s.name, |c| taken.contains(c));
        taken.insert(s.name.clone());
    }
}

/// `name`, or the first of `name~2`, `name~3`, … that is not `taken`.
pub(in crate::scene) fn unique_name(name: &str, taken: impl Fn(&str) -> bool) -> String {
    if !taken(name) {
        return name.to_string();
    }
    (2..).map(|k| format!("{name}~{k}")).find(|c| !taken(c)).expect("unbounded")
}

/// Consecutive triangles `(a, b, c)`, `(c, d, a)` (in any rotation) that make
/// a planar convex quad, as that quad; the rest as triangles.
/// Also returns each primitive's corners as vertex indices (a triangle
/// repeats its corner 2).
pub(in crate::scene) fn merge_quads_indexed(pos: &[Vec3], tri: &[[u32; 3]]) -> (Vec<Primitive>, Vec<[u32; 4]>) {
    let mut out = Vec::with_capacity(tri.len());
    let mut corners = Vec::with_capacity(tri.len());
    let mut i = 0;
    while i < tri.len() {
        if i + 1 < tri.len()
            && let Some((q, c)) = quad_of(pos, tri[i], tri[i + 1])
        {
            out.push(q);
            corners.push(c);
            i += 2;
            continue;
        }
        let t = tri[i].map(|k| pos[k as usize]);
        out.push(Primitive::triangle(t[0], t[1], t[2]));
        corners.push([tri[i][0], tri[i][1], tri[i][2], tri[i][2]]);
        i += 1;
    }
    (out, corners)
}

fn quad_of(pos: &[Vec3], t1: [u32; 3], t2: [u32; 3]) -> Option<(Primitive, [u32; 4])> {
    for r1 in 0..3 {
        let (a, b, c) = (t1[r1], t1[(r1 + 1) % 3], t1[(r1 + 2) % 3]);
        for r2 in 0..3 {
            if t2[r2] == c && t2[(r2 + 2) % 3] == a {
                let d = t2[(r2 + 1) % 3];
                let q = Primitive::quad([a, b, c, d].map(|k| pos[k as usize]));
                let size = (q.p[2] - q.p[0]).length().max((q.p[3] - q.p[1]).length());
                let n = q.normal();
                let off = (q.p[3] - q.p[0]).dot(n).abs().max((q.p[1] - q.p[0]).dot(n).abs());
                if off <= 1e-6 * size && check_primitive(&q).is_ok() {
                    return Some((q, [a, b, c, d]));
                }
                return None;
            }
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::PrimitiveKind;

    #[test]
    fn triangle_pairs_become_quads_only_when_planar_and_convex() {
        let pos = [Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y, Vec3::new(1.0, 1.0, 0.5)];
        // (0,1,2),(0,2,3): the usual split; any rotation of either triangle.
        for (t1, t2) in [([0, 1, 2], [0, 2, 3]), ([1, 2, 0], [2, 3, 0]), ([2, 0, 1], [3, 0, 2])] {
            let (out, corners) = merge_quads_indexed(&pos, &[t1, t2]);
            assert_eq!(out.len(), 1);
            // The corners' vertices, in the quad's order.
            assert_eq!(corners[0].map(|i| pos[i as usize]), out[0].p);
            assert_eq!(out[0].kind, PrimitiveKind::Quad);
            assert!((out[0].area() - 1.0).abs() < 1e-6);
        }
        // Not planar: the fourth corner is lifted.
        let (out, corners) = merge_quads_indexed(&pos, &[[0, 1, 4], [0, 4, 3]]);
        assert_eq!(out.len(), 2);
        assert_eq!(corners, vec![[0, 1, 4, 4], [0, 4, 3, 3]]);
        // Not sharing a reversed diagonal (opposite windings).
        assert_eq!(merge_quads_indexed(&pos, &[[0, 1, 2], [0, 3, 2]]).0.len(), 2);
        // Not convex: a dart.
        let dart = [Vec3::ZERO, Vec3::new(2.0, 0.0, 0.0), Vec3::new(0.5, 0.5, 0.0), Vec3::new(0.0, 2.0, 0.0)];
        assert_eq!(merge_quads_indexed(&dart, &[[0, 1, 2], [0, 2, 3]]).0.len(), 2);
    }
}
