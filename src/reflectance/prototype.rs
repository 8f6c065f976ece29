//! The prototype reflectance function (§3.6.1): for the prototype
//! orientation (normal +y, grain +x) and each incoming direction `i` of the
//! global set, the sparse list of outgoing directions `o` and the fraction of
//! the power arriving from `i` that leaves along `o`.
//!
//! A factor is `T(i→o) = f(i, o)·cos θ_o·Ω_o` (`Ω_o` the direction's Voronoi
//! cell), so `Σ_o T(i→o)` is the discrete directional albedo. Two
//! corrections make the discrete table behave as the continuous function:
//!
//! - **Energy.** The discrete sum differs from the continuous albedo
//!   `a(i) = ∫ f cos θ_o dω_o` by the quadrature error of the direction set
//!   (a few percent near the horizon, more for sharp lobes).
//! - **Reciprocity.** Scaling each row alone would break `f(i,o) = f(o,i)`.
//!
//! Both hold at once with a symmetric scaling `f'(i,o) = s_i·f(i,o)·s_o`,
//! the `s_i` found by a symmetric Sinkhorn iteration so that every row sums to
//! `a(i)`. Entries whose factor is below `threshold` times their row's
//! largest factor in either direction (so that the kept pattern is
//! symmetric) are dropped before the scaling, which puts their energy back
//! into the kept ones ([`TableStats::dropped`] says how much that was).

use rayon::prelude::*;

use super::model::TableModel;

/// Default relative threshold below which a factor is dropped.
pub const DEFAULT_THRESHOLD: f64 = 1e-2;

/// A prototype reflectance table over one direction set.
#[derive(Debug, Clone, PartialEq)]
pub struct PrototypeTable {
    /// The function tabulated.
    pub model: TableModel,
    /// Factors per entry: 1 (one generic factor, times the surface colour)
    /// or 3 (bands reflect differently).
    pub bands: usize,
    /// `offsets[i]..offsets[i+1]` are incoming direction `i`'s entries
    /// (empty for directions below the prototype surface).
    pub offsets: Vec<u32>,
    /// Outgoing direction of each entry, ascending within a row.
    pub outgoing: Vec<u32>,
    /// `bands` factors per entry.
    pub factors: Vec<f32>,
}

/// What building a table measured.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TableStats {
    /// Directions above the prototype surface (table rows that have entries).
    pub rows: usize,
    /// Entries kept.
    pub entries: usize,
    /// Worst relative difference between the discrete and the continuous
    /// albedo before the scaling (rows with albedo > 1e-3).
    pub albedo_error_before: f64,
    /// Mean of the same.
    pub albedo_error_before_mean: f64,
    /// Worst relative difference after the scaling.
    pub albedo_error_after: f64,
    /// Largest discrete albedo of any row and band after the scaling.
    pub max_albedo: f64,
    /// Largest share of a row's discrete albedo in the dropped entries.
    pub dropped: f64,
    /// Scaling iterations run.
    pub iterations: u32,
    /// Rows (per band) scaled down after the scaling because it could not
    /// bring them to their albedo symmetrically (lobes too sharp for the set).
    pub clamped_rows: usize,
}

impl PrototypeTable {
    /// Incoming direction `i`'s outgoing directions and factors.
    pub fn row(&self, i: usize) -> (&[u32], &[f32]) {
        let (a, b) = (self.offsets[i] as usize, self.offsets[i + 1] as usize);
        (&self.outgoing[a..b], &self.factors[a * self.bands..b * self.bands])
    }

    /// Discrete albedo `Σ_o T(i→o)` of row `i`, per band.
    pub fn row_albedo(&self, i: usize) -> [f64; 3] {
        let (_, f) = self.row(i);
        let mut s = [0.0; 3];
        for e in f.chunks_exact(self.bands) {
            for (c, x) in s.iter_mut().enumerate() {
                *x += e[c.min(self.bands - 1)] as f64;
            }
        }
        s
    }

    /// The factor of `i → o`, per band (0 when not stored).
    pub fn factor(&self, i: usize, o: usize) -> [f32; 3] {
        let (dirs, f) = self.row(i);
        match dirs.binary_search(&(o as u32)) {
            Ok(e) => [0, 1, 2].map(|c| f[e * self.bands + c.min(self.bands - 1)]),
            Err(_) => [0.0; 3],
        }
    }
}

/// A direction in the prototype's local frame (`t = +x`, `b = n × t = −z`, `n = +y`).
fn local(d: [f32; 3]) -> [f64; 3] {
    [d[0] as f64, -(d[2] as f64), d[1] as f64]
}

/// Builds the table of `model` over `directions` (unit vectors) with Voronoi
/// cells `solid_angle`.
pub fn build(
    model: TableModel,
    directions: &[[f32; 3]],
    solid_angle: &[f64],
    threshold: f64,
) -> (PrototypeTable, TableStats) {
    let n = directions.len();
    let bands = model.bands();
    let up: Vec<usize> = (0..n).filter(|&i| directions[i][1] > 0.0).collect();
    let m = up.len();
    let w: Vec<[f64; 3]> = up.iter().map(|&i| local(directions[i])).collect();
    // c_o = cos θ_o · Ω_o: the weight of direction o in the quadrature.
    let c: Vec<f64> = up.iter().zip(&w).map(|(&i, w)| w[2] * solid_angle[i]).collect();
    let eval = |a: usize, b: usize, band: usize| model.eval(band, w[a], w[b]);
    // Continuous and discrete albedo per row and band.
    let target: Vec<[f64; 3]> = (0..m)
        .into_par_iter()
        .map(|a| [0, 1, 2].map(|k| if k < bands { model.albedo(k, w[a]) } else { 0.0 }))
        .collect();
    // Discrete albedo per band, and the largest factor of band 0, per row.
    let discrete: Vec<([f64; 3], f64)> = (0..m)
        .into_par_iter()
        .map(|a| {
            let (mut s, mut peak) = ([0.0; 3], 0.0f64);
            for b in 0..m {
                for (k, x) in s.iter_mut().enumerate().take(bands) {
                    *x += eval(a, b, k) * c[b];
                }
                peak = peak.max(eval(a, b, 0) * c[b]);
            }
            (s, peak)
        })
        .collect();
    let rows = sparse_rows(&eval, &c, &discrete, bands, threshold);
    let (s, iterations) = symmetric_scaling(&rows, &c, &target, bands);
    let rows = ScaledRows { up: &up, c: &c, rows: &rows, s: &s, target: &target, discrete: &discrete, bands };
    let (offsets, outgoing, factors, mut stats) = rows.assemble(n);
    stats.iterations = iterations;
    (PrototypeTable { model, bands, offsets, outgoing, factors }, stats)
}

/// A row's kept entries: the columns (positions among the directions
/// above the surface) and `bands` unscaled values of `f` each.
type SparseRow = (Vec<u32>, Vec<f64>);

/// Sparse symmetric pattern: keep (a, b) if either direction's factor is
/// above `threshold` relative to its row's peak (band 0 decides); the
/// kept entries' values of `eval` (`f(a, b)` per band), per row.
fn sparse_rows(
    eval: &(impl Fn(usize, usize, usize) -> f64 + Sync),
    c: &[f64],
    discrete: &[([f64; 3], f64)],
    bands: usize,
    threshold: f64,
) -> Vec<SparseRow> {
    let m = c.len();
    (0..m)
        .into_par_iter()
        .map(|a| {
            let (mut cols, mut vals) = (Vec::new(), Vec::new());
            for b in 0..m {
                let f0 = eval(a, b, 0);
                if f0 <= 0.0 {
                    continue;
                }
                let rel_ab = if discrete[a].1 > 0.0 { f0 * c[b] / discrete[a].1 } else { 0.0 };
                let rel_ba = if discrete[b].1 > 0.0 { f0 * c[a] / discrete[b].1 } else { 0.0 };
                if rel_ab.max(rel_ba) >= threshold {
                    cols.push(b as u32);
                    for k in 0..bands {
                        vals.push(eval(a, b, k));
                    }
                }
            }
            (cols, vals)
        })
        .collect()
}

/// Symmetric Sinkhorn scaling, per band: the `s_i` that bring every row
/// of `f'(i,o) = s_i·f(i,o)·s_o` to its `target` albedo (at most 200
/// iterations), and the iterations run.
fn symmetric_scaling(rows: &[SparseRow], c: &[f64], target: &[[f64; 3]], bands: usize) -> (Vec<[f64; 3]>, u32) {
    let m = rows.len();
    let mut s = vec![[1.0f64; 3]; m];
    let row_sum = |s: &[[f64; 3]], a: usize, k: usize| -> f64 {
        let (cols, vals) = &rows[a];
        cols.iter().enumerate().map(|(e, &b)| vals[e * bands + k] * s[b as usize][k] * c[b as usize]).sum::<f64>()
            * s[a][k]
    };
    let mut iterations = 0;
    for it in 0..200 {
        iterations = it + 1;
        let sums: Vec<[f64; 3]> = (0..m)
            .into_par_iter()
            .map(|a| [0, 1, 2].map(|k| if k < bands { row_sum(&s, a, k) } else { 0.0 }))
            .collect();
        let mut worst = 0.0f64;
        for a in 0..m {
            for k in 0..bands {
                if sums[a][k] > 0.0 && target[a][k] > 0.0 {
                    let r = target[a][k] / sums[a][k];
                    worst = worst.max((r - 1.0).abs());
                    s[a][k] *= r.sqrt();
                }
            }
        }
        if worst < 1e-7 {
            break;
        }
    }
    (s, iterations)
}

/// The sparse rows with their scaling, to assemble into the table: per
/// row (a direction above the surface, `up[a]` in the whole set) its
/// entries, scale `s`, quadrature weight `c`, continuous (`target`) and
/// discrete albedo.
struct ScaledRows<'a> {
    up: &'a [usize],
    c: &'a [f64],
    rows: &'a [SparseRow],
    s: &'a [[f64; 3]],
    target: &'a [[f64; 3]],
    discrete: &'a [([f64; 3], f64)],
    bands: usize,
}

impl ScaledRows<'_> {
    /// The table's offsets, outgoing directions and factors in whole-set
    /// direction ids (`n` directions), and what they measured (all but the
    /// iterations).
    fn assemble(&self, n: usize) -> (Vec<u32>, Vec<u32>, Vec<f32>, TableStats) {
        let Self { up, c, rows, s, target, discrete, bands } = *self;
        let m = up.len();
        // Assemble, in whole-set direction ids.
        let mut offsets = vec![0u32; n + 1];
        let (mut outgoing, mut factors) = (Vec::new(), Vec::new());
        let mut row_of = vec![usize::MAX; n];
        for (a, &i) in up.iter().enumerate() {
            row_of[i] = a;
        }
        let mut stats = TableStats { rows: m, ..Default::default() };
        let mut err_sum = 0.0;
        let mut err_rows = 0usize;
        for i in 0..n {
            if let Some(&a) = row_of.get(i).filter(|&&a| a != usize::MAX) {
                let (cols, vals) = &rows[a];
                let mut got = [0.0f64; 3];
                let start = factors.len();
                for (e, &b) in cols.iter().enumerate() {
                    outgoing.push(up[b as usize] as u32);
                    for k in 0..bands {
                        let t = vals[e * bands + k] * s[a][k] * s[b as usize][k] * c[b as usize];
                        got[k] += t as f32 as f64;
                        factors.push(t as f32);
                    }
                }
                // Where no symmetric scaling exists (a lobe too sharp for the
                // set: rows of one or two entries), the iteration settles with
                // some rows above their albedo: scale those down, so that no row
                // ever returns more than it receives (reciprocity yields there).
                for k in 0..bands {
                    if got[k] > target[a][k] * (1.0 + 1e-6) && got[k] > 0.0 {
                        let f = (target[a][k] / got[k]) as f32;
                        for x in factors[start..].iter_mut().skip(k).step_by(bands) {
                            *x *= f;
                        }
                        got[k] = factors[start..].iter().skip(k).step_by(bands).map(|&x| x as f64).sum();
                        stats.clamped_rows += 1;
                    }
                }
                let kept: f64 = vals.iter().step_by(bands).zip(cols).map(|(f, &b)| f * c[b as usize]).sum();
                if discrete[a].0[0] > 0.0 {
                    stats.dropped = stats.dropped.max(1.0 - kept / discrete[a].0[0]);
                }
                for k in 0..bands {
                    stats.max_albedo = stats.max_albedo.max(got[k]);
                    if target[a][k] > 1e-3 {
                        let before = (discrete[a].0[k] - target[a][k]).abs() / target[a][k];
                        stats.albedo_error_before = stats.albedo_error_before.max(before);
                        stats.albedo_error_after =
                            stats.albedo_error_after.max((got[k] - target[a][k]).abs() / target[a][k]);
                        err_sum += before;
                        err_rows += 1;
                    }
                }
            }
            offsets[i + 1] = outgoing.len() as u32;
        }
        stats.entries = outgoing.len();
        stats.albedo_error_before_mean = if err_rows > 0 { err_sum / err_rows as f64 } else { 0.0 };
        (offsets, outgoing, factors, stats)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geodesic::DirectionSet;
    use crate::reflectance::model::Lobe;

    #[test]
    fn white_lambertian_table_returns_all_it_receives() {
        let dirs = DirectionSet::new(8).unwrap();
        let (t, stats) = build(TableModel::Lambertian, &dirs.directions, &dirs.solid_angle, DEFAULT_THRESHOLD);
        assert_eq!(stats.rows, (0..dirs.len()).filter(|&i| dirs.directions[i][1] > 0.0).count());
        for i in 0..dirs.len() {
            let a = t.row_albedo(i)[0];
            if dirs.directions[i][1] > 0.0 {
                assert!((a - 1.0).abs() < 0.01, "row {i}: albedo {a}");
            } else {
                assert_eq!(a, 0.0);
            }
        }
        // Before the scaling the discrete sum is off by the quadrature error.
        assert!(stats.albedo_error_before > 1e-4 && stats.albedo_error_after < 1e-5, "{stats:?}");
    }

    #[test]
    fn ggx_table_conserves_energy_and_is_reciprocal() {
        let dirs = DirectionSet::new(8).unwrap();
        let lobe = Lobe { alpha_u: 0.2, alpha_v: 0.4, ior: Some([1.3, 1.5, 2.0]) };
        let (t, stats) = build(TableModel::Ggx(lobe), &dirs.directions, &dirs.solid_angle, DEFAULT_THRESHOLD);
        assert_eq!(t.bands, 3);
        assert!(stats.max_albedo <= 1.0 + 1e-6, "{stats:?}");
        assert!(stats.albedo_error_after < 1e-4, "{stats:?}");
        let cos_omega = |i: usize| dirs.directions[i][1] as f64 * dirs.solid_angle[i];
        let mut worst = 0.0f64;
        for i in 0..dirs.len() {
            let (outs, _) = t.row(i);
            for &o in outs {
                let (fi, fo) = (t.factor(i, o as usize), t.factor(o as usize, i));
                for k in 0..3 {
                    let a = fi[k] as f64 / cos_omega(o as usize);
                    let b = fo[k] as f64 / cos_omega(i);
                    worst = worst.max((a - b).abs() / a.max(b));
                }
            }
        }
        assert!(worst < 1e-4, "reciprocity error {worst}");
    }

    #[test]
    fn lobes_too_sharp_for_the_set_never_return_more_than_they_receive() {
        // α = 0.01 on 162 directions: rows of a single entry or two.
        for (f, alpha) in [(4, 0.01), (4, 0.05), (8, 0.01), (8, 0.02), (16, 0.01)] {
            let dirs = DirectionSet::new(f).unwrap();
            let lobe = Lobe { alpha_u: alpha, alpha_v: 2.0 * alpha, ior: None };
            let (t, stats) = build(TableModel::Ggx(lobe), &dirs.directions, &dirs.solid_angle, DEFAULT_THRESHOLD);
            for i in 0..dirs.len() {
                let a = t.row_albedo(i)[0];
                assert!(a <= 1.0 + 1e-6, "α = {alpha}, row {i}: {a} ({stats:?})");
            }
        }
    }
}
