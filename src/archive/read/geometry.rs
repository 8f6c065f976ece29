//! The geometry's rules (§5.5 to §5.9): primitives whose patch blocks
//! tile the patches and whose vertices and grouped triangles are covered,
//! unit directions, finite patches with their counts bounded by their
//! area, and a symmetric adjacency.

use super::views::InetView;
use super::{check, csr, finite, within};
use crate::archive::ArchiveError;
use crate::archive::layout;
use crate::limits::{MAX_PATCH_AREA, MIN_PATCH_AREA};

/// Whether the primitives' patch blocks tile the patches `0..P` (§5.5):
/// blocks in primitive order are checked by where the last ended, with no
/// memory; from the first block out of that order on (a spatial patch
/// order, since version 11), by a bit per patch (P/8 bytes, 1/128 of the
/// distribution's per-patch state), so that no block overlaps another.
/// Blocks within 0..P that do not overlap and cover P patches in all tile
/// them.
struct BlockTiling {
    patches: u64,
    covered: u64,
    /// Set once a block comes out of primitive order: every patch of the
    /// blocks seen so far.
    seen: Option<Vec<u64>>,
}

impl BlockTiling {
    fn new(patches: u64) -> Self {
        Self { patches, covered: 0, seen: None }
    }

    /// Adds a block of `cells` patches from `first`: false when it lies
    /// beyond the patches or overlaps a block added before.
    fn add(&mut self, first: u64, cells: u64) -> bool {
        let Some(end) = first.checked_add(cells).filter(|&e| e <= self.patches) else { return false };
        if self.seen.is_none() {
            if first == self.covered {
                self.covered = end;
                return true;
            }
            // Out of order: the blocks so far cover 0..covered.
            let mut bits = vec![0u64; self.patches.div_ceil(64) as usize];
            for q in 0..self.covered {
                bits[(q / 64) as usize] |= 1 << (q % 64);
            }
            self.seen = Some(bits);
        }
        let bits = self.seen.as_mut().expect("set above");
        for q in first..end {
            let (w, b) = ((q / 64) as usize, 1u64 << (q % 64));
            if bits[w] & b != 0 {
                return false;
            }
            bits[w] |= b;
        }
        self.covered += cells;
        true
    }

    /// Patches the blocks cover (P when they tile them).
    fn covered(&self) -> u64 {
        self.covered
    }

    /// Whether every block so far began where the one before it ended.
    fn in_order(&self) -> bool {
        self.seen.is_none()
    }
}

/// `PRIM`: kinds, cell orders, surfaces and corners in range; each
/// primitive's patch block (since version 11 in any order, tiling the
/// patches; out of primitive order only where `version_read` allows it,
/// and not in a sequence); grids' vertices contiguous, grouped
/// triangles' `TVTX` rows in order, after the grids' vertices.
pub(super) fn check_primitives(v: &InetView<'_>, version_read: u32) -> Result<(), ArchiveError> {
    let b = v.build;
    let (p, nv) = (b.patch_count as usize, b.vertex_count as usize);
    let (mut next_vertex, mut next_grouped) = (0u64, 0u64);
    // Each primitive's patch block: since version 11 in any order, tiling
    // the patches.
    let mut tiling = BlockTiling::new(p as u64);
    let tiles = |i: usize, first: u32, cells: u64, ok: bool| {
        check(ok, || {
            format!(
                "PRIM[{i}]: its patches {first}..{} overlap another primitive's or lie beyond the {p} patches \
                 (a grid's cells, or a grouped triangle's patch, new or its predecessor's)",
                first as u64 + cells
            )
        })
    };
    for (i, r) in v.primitives.iter().enumerate() {
        check(r.kind <= layout::kind::GROUPED_TRIANGLE, || format!("PRIM[{i}]: unknown kind {}", r.kind))?;
        check(
            (r.cell_order == layout::cell_order::ROWS
                || (r.kind == layout::kind::QUAD && r.cell_order == layout::cell_order::TILES))
                && r.reserved == 0,
            || format!("PRIM[{i}]: unknown cell order {} for kind {} (or reserved not zero)", r.cell_order, r.kind),
        )?;
        check((r.surface as usize) < v.surfaces.len(), || format!("PRIM[{i}]: surface out of range"))?;
        check(r.corners.iter().all(|c| within(c)), || format!("PRIM[{i}]: corner non-finite or beyond ±1e9 m"))?;
        let (gu, gv) = (r.grid_u as u64, r.grid_v as u64);
        if r.kind == layout::kind::GROUPED_TRIANGLE {
            // One cell: a new patch, or the patch of the previous
            // primitive, a grouped triangle of the same surface.
            let joins = i > 0 && {
                let q = &v.primitives[i - 1];
                q.kind == layout::kind::GROUPED_TRIANGLE && q.surface == r.surface && q.first_patch == r.first_patch
            };
            check(gu == 1 && gv == 1 && r.first_vertex as u64 == next_grouped, || {
                format!("PRIM[{i}]: a grouped triangle must have one cell and its TVTX row in order")
            })?;
            if !joins {
                tiles(i, r.first_patch, 1, tiling.add(r.first_patch as u64, 1))?;
            }
            next_grouped += 1;
            continue;
        }
        check(gu >= 1 && gv >= 1 && gu <= 1 << 16 && gv <= 1 << 16 && (r.kind == 0 || gu == gv), || {
            format!("PRIM[{i}]: bad grid {gu}×{gv}")
        })?;
        let (cells, verts) =
            if r.kind == 0 { (gu * gv, (gu + 1) * (gv + 1)) } else { (gu * gu, (gu + 1) * (gu + 2) / 2) };
        check(r.first_vertex as u64 == next_vertex, || format!("PRIM[{i}]: vertices not contiguous"))?;
        tiles(i, r.first_patch, cells, tiling.add(r.first_patch as u64, cells))?;
        next_vertex += verts;
    }
    check(tiling.covered() == p as u64, || {
        format!("PRIM: the primitives' patch blocks cover {} of the {p} patches", tiling.covered())
    })?;
    // A spatial patch order (§5.5): version 10 readers refuse it, so the
    // file must say it needs 11; a sequence's instances keep their
    // patches together (the warm starts pair an instance's patches with
    // its predecessor's as ranges).
    if !tiling.in_order() {
        check(version_read >= layout::VERSION_READ_SPATIAL, || {
            format!("PRIM: patch blocks out of primitive order in a file whose version_read is {version_read}, not 11")
        })?;
        check(v.sequence.is_none(), || "PRIM: patch blocks out of primitive order in a sequence archive".into())?;
    }
    // Grouped triangles' corners come after the grids' vertices.
    check(
        next_vertex <= nv as u64
            && (next_grouped > 0 || next_vertex == nv as u64)
            && next_grouped == v.grouped_triangles.len() as u64,
        || "PRIM: grids and grouped triangles do not cover all vertices and TVTX rows".into(),
    )?;
    for (i, t) in v.grouped_triangles.iter().enumerate() {
        check(t.iter().all(|&c| c as u64 >= next_vertex && (c as usize) < nv), || {
            format!("TVTX[{i}]: a corner is not a vertex after the grids' ({next_vertex}..{nv})")
        })?;
    }
    Ok(())
}

/// The whole sphere's solid angle (sr).
const SPHERE: f32 = 4.0 * std::f32::consts::PI;

/// `DIRS`: finite unit vectors with a solid angle, neighbours in range,
/// the solid angles summing to 4π.
pub(super) fn check_directions(v: &InetView<'_>) -> Result<(), ArchiveError> {
    let nd = v.build.direction_count as usize;
    for (i, d) in v.directions.iter().enumerate() {
        check(finite(&d.direction), || format!("DIRS[{i}]: non-finite"))?;
        let len2: f32 = d.direction.iter().map(|x| x * x).sum();
        check((len2 - 1.0).abs() < 1e-3, || format!("DIRS[{i}]: not a unit vector"))?;
        check(d.solid_angle_sr.is_finite() && d.solid_angle_sr > 1e-9 && d.solid_angle_sr <= SPHERE, || {
            format!("DIRS[{i}]: solid angle {:e} sr outside (1e-9, 4π]", d.solid_angle_sr)
        })?;
        check(d.neighbours.iter().all(|&n| n == u32::MAX || (n as usize) < nd), || {
            format!("DIRS[{i}]: neighbour out of range")
        })?;
    }
    // They tile the sphere: the gather weighs light by them, so a set
    // summing far from 4π scales every bounce (3e38 each made infinite
    // light, issue 42, §1).
    let sum: f64 = v.directions.iter().map(|d| d.solid_angle_sr as f64).sum();
    check((sum - SPHERE as f64).abs() <= 1e-3 * SPHERE as f64, || {
        format!("DIRS: solid angles sum to {sum} sr, not 4π")
    })?;
    Ok(())
}

/// Every patch: finite geometry, its primitive and corners in range, its
/// area bounded and its expected hits no more than its area can have;
/// then `VPOS`, every vertex finite and in range.
pub(super) fn check_patches(v: &InetView<'_>) -> Result<(), ArchiveError> {
    let b = v.build;
    let (p, nv, nd) = (b.patch_count as usize, b.vertex_count as usize, b.direction_count as usize);
    for i in 0..p {
        check(
            within(&v.patch_centre[i])
                && finite(&v.patch_normal[i])
                && v.patch_area[i].is_finite()
                && v.patch_area[i] >= 0.0,
            || format!("patch {i}: non-finite geometry"),
        )?;
        check((v.patch_primitive[i] as usize) < v.primitives.len(), || format!("PPRM[{i}]: out of range"))?;
        check(v.patch_corners[i].iter().all(|&c| c == u32::MAX || (c as usize) < nv), || {
            format!("PCOR[{i}]: out of range")
        })?;
        check(v.patch_area[i] <= MAX_PATCH_AREA, || {
            format!("PARE[{i}]: area {} m² above {MAX_PATCH_AREA:e}", v.patch_area[i])
        })?;
        // The distribution divides by the area: 0 (no light) or at least
        // the least a scene's primitive has.
        check(v.patch_area[i] == 0.0 || v.patch_area[i] >= MIN_PATCH_AREA, || {
            format!("PARE[{i}]: area {:e} m² neither 0 nor at least {MIN_PATCH_AREA:e}", v.patch_area[i])
        })?;
        // PEXP = A·Σ_d max(0, n·d)·Ω_d/Ω̄/δ² ≤ A·N/δ² (the ray-space
        // baseline's is below it too): so A·H/PEXP ≥ H·δ²/N, the least
        // area the distribution divides by. Relative slack only: an
        // absolute one let a denormal area carry 10⁻³ expected hits and
        // divide by nearly nothing (issue 42, §1).
        let most = v.patch_area[i] as f64 * nd as f64 / (b.ray_spacing_m as f64).powi(2);
        check(
            v.patch_expected_hits[i].is_finite()
                && v.patch_expected_hits[i] >= 0.0
                && v.patch_expected_hits[i] as f64 <= most * (1.0 + 1e-3),
            || {
                format!(
                    "PEXP[{i}]: {} expected hits, more than area {} m² can have ({most:.3e})",
                    v.patch_expected_hits[i], v.patch_area[i]
                )
            },
        )?;
    }
    check(v.vertex_position.iter().all(|x| within(x)), || "VPOS: vertex non-finite or beyond ±1e9 m".into())?;
    Ok(())
}

/// `ADJO`, `ADJI` (§5.9): rows of patch ids in range, ascending, without
/// self-loops, symmetric.
pub(super) fn check_adjacency(v: &InetView<'_>) -> Result<(), ArchiveError> {
    let p = v.build.patch_count as usize;
    csr("ADJO", v.adjacency_offsets.iter().map(|&x| x as u64), v.adjacency.len())?;
    check(v.adjacency.iter().all(|&a| (a as usize) < p), || "ADJI: patch id out of range".into())?;
    // Ascending, no self-loops, symmetric (§5.9): bucket rings rely on it.
    let row = |q: usize| &v.adjacency[v.adjacency_offsets[q] as usize..v.adjacency_offsets[q + 1] as usize];
    for q in 0..p {
        let r = row(q);
        check(r.windows(2).all(|w| w[0] < w[1]) && !r.contains(&(q as u32)), || format!("ADJI[{q}]: not ascending"))?;
        check(r.iter().all(|&o| row(o as usize).binary_search(&(q as u32)).is_ok()), || {
            format!("ADJI[{q}]: adjacency not symmetric")
        })?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::BlockTiling;

    /// Adds the blocks `(first, cells)` in turn: whether each was taken,
    /// and the patches covered.
    fn tile(patches: u64, blocks: &[(u64, u64)]) -> (Vec<bool>, u64) {
        let mut t = BlockTiling::new(patches);
        (blocks.iter().map(|&(f, c)| t.add(f, c)).collect(), t.covered())
    }

    #[test]
    fn blocks_tile_the_patches_in_any_order_and_never_overlap() {
        // In primitive order, and out of it (a spatial order).
        assert_eq!(tile(10, &[(0, 4), (4, 1), (5, 5)]), (vec![true; 3], 10));
        assert_eq!(tile(10, &[(6, 4), (0, 4), (4, 2)]), (vec![true; 3], 10));
        assert_eq!(tile(10, &[(0, 4), (7, 3), (4, 3)]), (vec![true; 3], 10));
        // Overlapping a block of the in-order stretch, or a later one.
        assert_eq!(tile(10, &[(0, 4), (7, 3), (3, 2)]).0, vec![true, true, false]);
        assert_eq!(tile(10, &[(5, 3), (0, 5), (7, 1)]).0, vec![true, true, false]);
        // Beyond the patches, or wrapping.
        assert_eq!(tile(10, &[(8, 3)]).0, vec![false]);
        assert_eq!(tile(10, &[(u64::MAX, 2)]).0, vec![false]);
        // A gap is left uncovered.
        assert_eq!(tile(10, &[(0, 4), (5, 5)]), (vec![true, true], 9));
    }
}
