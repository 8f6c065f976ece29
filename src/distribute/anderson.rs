//! Anderson acceleration of the energy balance.
//!
//! The distribution is a fixed-point iteration on `x`, the power each patch
//! sends: `x ← E + K·x`, with `K` the links followed by reflection. In the
//! shooting form of `mod.rs`, each iteration sends a change `δ` and keeps the
//! residual `f(x) = E + K·x − x` as the power still to send; plain iteration
//! sends `δ = f`. Its error shrinks by the dominant eigenvalue of `K` per
//! iteration (≈ 0.55 in the fan room: 7–8 warm-started iterations per frame
//! to reach 10⁻⁴, most of them spent on that one slow mode).
//!
//! Anderson mixing (Walker & Ni, 2011) uses the last `m` secant pairs
//! `(Δx_i, Δf_i)` the iteration produced: it chooses `γ` minimising
//! `‖f − Σ γ_i Δf_i‖₂` and sends `δ = f − Σ γ_i (Δx_i + Δf_i)`. For a linear
//! map this is a GMRES-like Krylov step, with no eigenvalue bounds to know
//! (over-relaxation needs them: radiosity operators have negative
//! eigenvalues). Each band is an independent linear system and gets its own
//! `γ`. Nothing changes what "converged" means: the loop still stops on the
//! true residual, which the shooting form carries exactly (`f` after sending
//! `δ` is `f − δ + K·δ`).
//!
//! Non-diffuse patches carry per-direction state that the mixing does not
//! cover. With deferred glossy reflection (`step.rs`, the default) that
//! state changes only in table steps: the diffuse steps between are mixed,
//! and a step that shoots a table step's directional light records no
//! secant pair (that light does not come from what was sent). Without it,
//! archives with non-diffuse patches iterate plainly.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};

use rayon::prelude::*;

use super::spill::PatchVec;

/// One value of a secant pair, stored as bfloat16: the upper half of the
/// f32 (its range, 8 bits of mantissa). The pairs only steer the step (the
/// residual is tracked exactly whatever they say), so a relative error of
/// 2⁻⁹ costs no iterations (measured: the same counts on the Cornell box,
/// the fan room and the test scenes) and halves their memory.
pub(super) type Half = u16;

/// `x` rounded to the nearest bfloat16 (ties to even).
#[inline]
pub(super) fn to_half(x: f32) -> Half {
    let b = x.to_bits();
    (b.wrapping_add(0x7fff + ((b >> 16) & 1)) >> 16) as Half
}

/// The f32 a bfloat16 stands for.
#[inline]
fn from_half(h: Half) -> f32 {
    f32::from_bits((h as u32) << 16)
}

/// One secant pair, per patch, RGB (6 bytes a vector): how the residual
/// changed (`Δf = K·Δx − Δx`) and what the step reflected (`Δx + Δf =
/// K·Δx`, the only combination of `Δx` the mixing uses). In memory, or in
/// scratch files under a tight memory budget (`spill.rs`).
type Pair = (PatchVec<[Half; 3]>, PatchVec<[Half; 3]>);

/// A pair's two vectors to write: `(Δf, K·Δx)`.
pub(super) type PairMut<'a> = (&'a mut PatchVec<[Half; 3]>, &'a mut PatchVec<[Half; 3]>);

/// Secant history and the mixing step.
pub struct Anderson {
    depth: usize,
    pairs: VecDeque<Pair>,
    /// The pair the current step writes (`Self::slot`), kept once the step
    /// is judged ([`Self::commit`]) or dropped with the history
    /// ([`Self::reset`]).
    pending: Option<Pair>,
    /// Pairs forgotten by [`Self::reset`], kept for reuse: fresh memory is
    /// zeroed page by page when first touched (a tenth of a distribution's
    /// time before).
    spare: Vec<Pair>,
    /// Where the pairs are kept when not in memory.
    spill: Option<PathBuf>,
}

/// The history, without the spare buffers. A spilled history is copied to
/// new scratch files; one that cannot be (the disk full) is dropped: it
/// only steers the steps. The distribution itself copies a history with
/// [`Anderson::try_clone`], which says so instead.
impl Clone for Anderson {
    fn clone(&self) -> Self {
        self.try_clone().unwrap_or_else(|_| Self::new_in(self.depth, self.spill.as_deref()))
    }
}

/// Equal histories, whatever buffers each keeps spare and wherever they
/// are kept.
impl PartialEq for Anderson {
    fn eq(&self, other: &Self) -> bool {
        let same = |(a, b): (&Pair, &Pair)| a.0.same_as(&b.0).unwrap_or(false) && a.1.same_as(&b.1).unwrap_or(false);
        self.depth == other.depth
            && self.pairs.len() == other.pairs.len()
            && self.pairs.iter().zip(&other.pairs).all(same)
    }
}

impl Anderson {
    /// Keeps at most `depth` pairs (at most [`MAX_DEPTH`]) in memory.
    pub fn new(depth: usize) -> Self {
        Self::new_in(depth, None)
    }

    /// Keeps at most `depth` pairs, in memory or, given `spill`, in
    /// scratch files in that directory.
    pub fn new_in(depth: usize, spill: Option<&Path>) -> Self {
        let depth = depth.min(MAX_DEPTH);
        let spill = spill.map(Path::to_path_buf);
        Self { depth, pairs: VecDeque::with_capacity(depth + 1), pending: None, spare: Vec::new(), spill }
    }

    /// The history, without the spare buffers: a spilled one copied to new
    /// scratch files (which can fail, the disk full).
    pub fn try_clone(&self) -> std::io::Result<Self> {
        let pairs =
            self.pairs.iter().map(|(a, b)| Ok((a.try_clone()?, b.try_clone()?))).collect::<std::io::Result<_>>()?;
        Ok(Self { depth: self.depth, pairs, pending: None, spare: Vec::new(), spill: self.spill.clone() })
    }

    /// Whether this history can steer a problem of `n` patches with `depth`
    /// pairs (and has something to offer).
    pub fn fits(&self, n: usize, depth: usize) -> bool {
        self.depth == depth.min(MAX_DEPTH) && self.depth > 0 && self.pairs.front().is_some_and(|p| p.0.len() == n)
    }

    /// Secant pairs held.
    pub fn pairs(&self) -> usize {
        self.pairs.len()
    }

    /// Forgets the history (after a step that did not reduce the residual),
    /// the pair being written included.
    pub fn reset(&mut self) {
        self.spare.extend(self.pairs.drain(..));
        self.spare.extend(self.pending.take());
    }

    /// Buffers for the pair of the step under way, `(Δf, K·Δx)` for `n`
    /// patches, written whole by the step's reflection (no vector of its
    /// own); `None` without acceleration. Once the history is full, the
    /// oldest pair's buffers are reused: the step that mixed with it is
    /// done, and the step is then either kept ([`Self::commit`]), which
    /// would drop that pair anyway, or the whole history is
    /// ([`Self::reset`]). Fails only when a scratch file cannot be made.
    pub fn slot(&mut self, n: usize) -> std::io::Result<Option<PairMut<'_>>> {
        if self.depth == 0 {
            return Ok(None);
        }
        if self.pending.is_none() {
            let pair = match self.pairs.len() >= self.depth {
                true => self.pairs.pop_front(),
                false => self.spare.pop(),
            };
            let pair = match pair {
                Some(p) if p.0.len() == n => p,
                _ => {
                    let spill = self.spill.as_deref();
                    (PatchVec::zeroed(n, spill)?, PatchVec::zeroed(n, spill)?)
                }
            };
            self.pending = Some(pair);
        }
        Ok(self.pending.as_mut().map(|(df, kdx)| (df, kdx)))
    }

    /// Keeps the pair [`Self::slot`] handed out as the newest.
    pub fn commit(&mut self) {
        if let Some(pair) = self.pending.take() {
            self.pairs.push_back(pair);
        }
    }

    /// Records one iteration: it sent `sent`, and the residual changed by
    /// `df` (`K·sent − sent`).
    #[cfg(test)]
    pub fn record(&mut self, sent: &[[f32; 3]], df: &[[f32; 3]]) {
        if let Some((d, k)) = self.slot(sent.len()).unwrap() {
            let mut buf = Vec::new();
            for block in d.blocks_mut(sent.len()) {
                block.with(false, &mut buf, |d| (0..sent.len()).for_each(|p| d[p] = df[p].map(to_half))).unwrap();
            }
            for block in k.blocks_mut(sent.len()) {
                block
                    .with(false, &mut buf, |k| {
                        (0..sent.len()).for_each(|p| k[p] = [0, 1, 2].map(|c| to_half(sent[p][c] + df[p][c])))
                    })
                    .unwrap();
            }
            self.commit();
        }
    }

    /// What to send for residual `f`: the mixed step, or `f` itself while
    /// there is no history (or a band's least-squares system is singular).
    /// Fails only when spilled pairs cannot be read back.
    pub fn step(&self, f: &[[f32; 3]], send: &mut [[f32; 3]]) -> std::io::Result<()> {
        let m = self.pairs.len();
        if m == 0 {
            send.copy_from_slice(f);
            return Ok(());
        }
        // Normal equations A γ = b of min ‖f − Σ γ_i Δf_i‖², all bands at
        // once (lane c = band c): one pass over the patches in parallel
        // chunks, partial sums in f64 added in chunk order (deterministic).
        let terms = m * (m + 1) / 2 + m;
        let partial: std::io::Result<Vec<Vec<[f64; 3]>>> = (0..f.len().div_ceil(CHUNK))
            .into_par_iter()
            .map(|k| {
                let range = k * CHUNK..((k + 1) * CHUNK).min(f.len());
                let mut bufs: [Vec<[Half; 3]>; MAX_DEPTH] = Default::default();
                let mut dfs: [&[[Half; 3]]; MAX_DEPTH] = [&[]; MAX_DEPTH];
                for ((pair, buf), df) in self.pairs.iter().zip(&mut bufs).zip(&mut dfs) {
                    *df = pair.0.range(range.clone(), buf)?;
                }
                let mut acc = vec![[0.0f64; 3]; terms];
                let mut d = [[0.0f64; 3]; MAX_DEPTH];
                for p in range.clone() {
                    for i in 0..m {
                        d[i] = dfs[i][p - range.start].map(|h| from_half(h) as f64);
                    }
                    let mut t = 0;
                    for i in 0..m {
                        for j in i..m {
                            for c in 0..3 {
                                acc[t][c] += d[i][c] * d[j][c];
                            }
                            t += 1;
                        }
                        for c in 0..3 {
                            acc[t][c] += d[i][c] * f[p][c] as f64;
                        }
                        t += 1;
                    }
                }
                Ok(acc)
            })
            .collect();
        let mut sums = vec![[0.0f64; 3]; terms];
        for chunk in &partial? {
            for (s, x) in sums.iter_mut().zip(chunk) {
                for c in 0..3 {
                    s[c] += x[c];
                }
            }
        }
        let mut gamma = [[0.0f32; 3]; MAX_DEPTH];
        for c in 0..3 {
            let (mut a, mut b) = (vec![0.0f64; m * m], vec![0.0f64; m]);
            let mut t = 0;
            for i in 0..m {
                for j in i..m {
                    a[i * m + j] = sums[t][c];
                    a[j * m + i] = sums[t][c];
                    t += 1;
                }
                b[i] = sums[t][c];
                t += 1;
            }
            // A singular band keeps γ = 0: the plain step.
            if let Some(g) = solve(&mut a, &mut b, m) {
                for i in 0..m {
                    gamma[i][c] = g[i] as f32;
                }
            }
        }
        let pairs = &self.pairs;
        send.par_chunks_mut(CHUNK).enumerate().try_for_each(|(k, out)| {
            let range = k * CHUNK..k * CHUNK + out.len();
            let mut bufs: [Vec<[Half; 3]>; MAX_DEPTH] = Default::default();
            let mut kdxs: [&[[Half; 3]]; MAX_DEPTH] = [&[]; MAX_DEPTH];
            for ((pair, buf), kdx) in pairs.iter().zip(&mut bufs).zip(&mut kdxs) {
                *kdx = pair.1.range(range.clone(), buf)?;
            }
            for (i, o) in out.iter_mut().enumerate() {
                let p = k * CHUNK + i;
                let mut v = f[p];
                for (g, kdx) in gamma.iter().zip(&kdxs[..m]) {
                    for c in 0..3 {
                        v[c] -= g[c] * from_half(kdx[i][c]);
                    }
                }
                // Subnormal floats would slow the gather by orders of magnitude.
                *o = v.map(|x| if x.abs() < f32::MIN_POSITIVE { 0.0 } else { x });
            }
            Ok(())
        })
    }
}

/// Patches per parallel task.
const CHUNK: usize = 2048;

/// Most secant pairs kept.
pub const MAX_DEPTH: usize = 8;

impl std::fmt::Debug for Anderson {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Anderson {{ depth: {}, pairs: {} }}", self.depth, self.pairs.len())
    }
}

/// Solves the symmetric `m × m` system by Gaussian elimination with partial
/// pivoting; `None` when it is (numerically) singular.
fn solve(a: &mut [f64], b: &mut [f64], m: usize) -> Option<Vec<f64>> {
    let scale = (0..m).map(|i| a[i * m + i]).fold(0.0f64, f64::max);
    if !(scale > 0.0 && scale.is_finite()) {
        return None;
    }
    for col in 0..m {
        let piv = (col..m).max_by(|&x, &y| a[x * m + col].abs().total_cmp(&a[y * m + col].abs()))?;
        if a[piv * m + col].abs() <= 1e-12 * scale {
            return None;
        }
        if piv != col {
            for k in 0..m {
                a.swap(piv * m + k, col * m + k);
            }
            b.swap(piv, col);
        }
        for r in col + 1..m {
            let f = a[r * m + col] / a[col * m + col];
            for k in col..m {
                a[r * m + k] -= f * a[col * m + k];
            }
            b[r] -= f * b[col];
        }
    }
    let mut x = vec![0.0; m];
    for r in (0..m).rev() {
        let s: f64 = (r + 1..m).map(|k| a[r * m + k] * x[k]).sum();
        x[r] = (b[r] - s) / a[r * m + r];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Plain and Anderson-accelerated iteration of `x ← e + K·x` for a small
    /// dense `K` with a positive dominant eigenvalue and negative ones.
    fn iterate(depth: usize, k: &[[f32; 3]; 3], e: [f32; 3], tol: f32) -> (Vec<[f32; 3]>, u32) {
        let mut anderson = Anderson::new(depth);
        let mut x = vec![[0.0f32; 3]; 3];
        let mut f: Vec<[f32; 3]> = e.iter().map(|&v| [v; 3]).collect();
        let mut send = vec![[0.0f32; 3]; 3];
        for it in 1..200 {
            anderson.step(&f, &mut send).unwrap();
            let kd: Vec<[f32; 3]> =
                (0..3).map(|r| [0, 1, 2].map(|c| (0..3).map(|j| k[r][j] * send[j][c]).sum())).collect();
            let df: Vec<[f32; 3]> = (0..3).map(|r| [0, 1, 2].map(|c| kd[r][c] - send[r][c])).collect();
            for r in 0..3 {
                for c in 0..3 {
                    x[r][c] += send[r][c];
                    f[r][c] += df[r][c];
                }
            }
            anderson.record(&send, &df);
            if f.iter().all(|v| v.iter().all(|y| y.abs() < tol)) {
                return (x, it);
            }
        }
        (x, 200)
    }

    #[test]
    fn mixing_reaches_the_same_fixed_point_in_fewer_iterations() {
        // Eigenvalues ≈ 0.85, −0.35, … : plain iteration converges slowly.
        let k = [[0.3, 0.5, 0.1], [0.5, 0.0, 0.3], [0.1, 0.3, 0.4]];
        let e = [1.0, 0.2, 0.5];
        let (plain, n_plain) = iterate(0, &k, e, 1e-6);
        let (fast, n_fast) = iterate(3, &k, e, 1e-6);
        for r in 0..3 {
            assert!((plain[r][0] - fast[r][0]).abs() < 1e-4, "{plain:?} vs {fast:?}");
        }
        assert!(n_plain > 40, "plain: {n_plain}");
        assert!(n_fast * 4 < n_plain, "plain {n_plain} iterations, Anderson {n_fast}");
    }

    #[test]
    fn singular_history_falls_back_to_the_plain_step() {
        let mut a = Anderson::new(2);
        let zero = vec![[0.0f32; 3]; 4];
        a.record(&zero, &zero);
        let f = vec![[1.0, 2.0, 3.0]; 4];
        let mut send = vec![[9.0f32; 3]; 4];
        a.step(&f, &mut send).unwrap();
        assert_eq!(send, f);
    }
}
