//! Buckets (§3.4): spreading received light over rings of neighbouring patches.
//!
//! A link end in bucket `k` stands for a beam whose footprint on the
//! receiving patch covers about the patch's `k`-ring: the patches within `k`
//! steps over the adjacency graph (edge neighbours within a primitive and
//! across coplanar primitives of one surface). Light received in bucket `k`
//! is shared by that ring, the patch itself included; bucket 0 stays on the
//! patch. A ring member `q ≠ p` gets the fraction
//! `w_pq = 1/max(|ring_k(p)|, |ring_k(q)|)` and `p` keeps the rest
//! (Metropolis weights). The weights are symmetric and each patch's sum to 1,
//! so spreading conserves energy exactly *and* keeps uniform light uniform
//! up to surface borders, where rings are cut short. (Plain `1/|ring_k(p)|`
//! shares conserve energy but darken border patches: 2.7% in the closed-room
//! test.) Since `q` is in `p`'s ring exactly when `p` is in `q`'s, spreading is
//! computed as a gather, parallel and deterministic. It runs every iteration
//! ("periodically", as the paper suggests).

use rayon::prelude::*;

/// Largest mean ring size accepted (a 4-ring of a grid has 41 patches).
pub const MAX_RING_MEAN: u64 = 256;

/// The `k`-rings of every patch for `k = 1..=max`: the 1-ring is the
/// archive's adjacency row and the patch itself (rows are ascending,
/// without self-loops: checked when the archive is opened), wider rings
/// are CSR tables (4 bytes a member and an offset per patch and ring). The
/// weights `w_pq` follow from the rings' sizes and are computed where
/// they are used.
pub struct Rings<'a> {
    adj_offsets: &'a [u32],
    adj: &'a [u32],
    /// `offsets[k-2][p]..offsets[k-2][p+1]` index `members[k-2]`.
    offsets: Vec<Vec<u32>>,
    members: Vec<Vec<u32>>,
}

impl<'a> Rings<'a> {
    /// Breadth-first rings over the adjacency CSR `(adj_offsets, adj)`.
    /// Fails when the rings would hold more than [`MAX_RING_MEAN`] patches
    /// per patch on average (only a malformed adjacency gets there: grid
    /// rings hold at most 2k²+2k+1).
    pub fn new(adj_offsets: &'a [u32], adj: &'a [u32], max: usize) -> Result<Self, String> {
        let n = adj_offsets.len() - 1;
        let cap = (MAX_RING_MEAN * n as u64).clamp(1024, u32::MAX as u64);
        // Reserved at a grid's sizes, so that the tables are not copied as
        // they grow (a copy is a second table resident at once); pages
        // reserved and never written are not resident.
        let wide = max.saturating_sub(1);
        let mut offsets: Vec<Vec<u32>> = (0..wide).map(|_| Vec::with_capacity(n + 1)).collect();
        offsets.iter_mut().for_each(|o| o.push(0));
        let grid = |k: u64| (2 * k * k + 2 * k + 1) * n as u64;
        let mut members: Vec<Vec<u32>> =
            (2..=max as u64).map(|k| Vec::with_capacity(grid(k).min(cap) as usize)).collect();
        if wide == 0 {
            return Ok(Self { adj_offsets, adj, offsets, members });
        }
        let mut seen = vec![u32::MAX; n];
        let mut frontier = Vec::new();
        let mut next = Vec::new();
        let mut ring = Vec::new();
        for p in 0..n {
            seen[p] = p as u32;
            ring.clear();
            ring.push(p as u32);
            frontier.clear();
            frontier.push(p as u32);
            for k in 0..max {
                next.clear();
                for &f in &frontier {
                    for &q in &adj[adj_offsets[f as usize] as usize..adj_offsets[f as usize + 1] as usize] {
                        if seen[q as usize] != p as u32 {
                            seen[q as usize] = p as u32;
                            next.push(q);
                        }
                    }
                }
                ring.extend_from_slice(&next);
                std::mem::swap(&mut frontier, &mut next);
                if k == 0 {
                    continue;
                }
                let (offsets, members) = (&mut offsets[k - 1], &mut members[k - 1]);
                let start = members.len();
                members.extend_from_slice(&ring);
                members[start..].sort_unstable();
                if members.len() as u64 > cap {
                    return Err(format!(
                        "bucket rings exceed {} patches per patch: malformed adjacency",
                        MAX_RING_MEAN.min(cap / n.max(1) as u64)
                    ));
                }
                offsets.push(members.len() as u32);
            }
        }
        Ok(Self { adj_offsets, adj, offsets, members })
    }

    /// Patch `q`'s adjacency row (ascending, without `q`).
    #[inline]
    fn row(&self, q: usize) -> &[u32] {
        &self.adj[self.adj_offsets[q] as usize..self.adj_offsets[q + 1] as usize]
    }

    /// Calls `f(p)` for each member `p` of `q`'s `k`-ring, ascending.
    #[inline]
    fn each_member(&self, k: usize, q: usize, mut f: impl FnMut(usize)) {
        if k == 1 {
            let row = self.row(q);
            let at = row.partition_point(|&p| (p as usize) < q);
            row[..at].iter().for_each(|&p| f(p as usize));
            f(q);
            row[at..].iter().for_each(|&p| f(p as usize));
        } else {
            let (o, m) = (&self.offsets[k - 2], &self.members[k - 2]);
            m[o[q] as usize..o[q + 1] as usize].iter().for_each(|&p| f(p as usize));
        }
    }

    /// The size of `q`'s `k`-ring.
    #[inline]
    fn len(&self, k: usize, q: usize) -> usize {
        match k {
            1 => self.row(q).len() + 1,
            _ => (self.offsets[k - 2][q + 1] - self.offsets[k - 2][q]) as usize,
        }
    }

    /// Calls `add(p, w_pq)` for each member `p` of `q`'s `k`-ring in
    /// ascending order: `w_pq = 1/max(|ring_k(p)|, |ring_k(q)|)` for the
    /// others, and what they leave, `1 − Σ w`, for `q` itself (summed in
    /// the same order each time: the same bits).
    #[inline]
    fn weighted(&self, k: usize, q: usize, mut add: impl FnMut(usize, f32)) {
        let len = |p: usize| self.len(k, p) as f32;
        let lq = len(q);
        let mut others = 0.0f32;
        self.each_member(k, q, |p| {
            if p != q {
                others += 1.0 / len(p).max(lq);
            }
        });
        self.each_member(k, q, |p| add(p, if p == q { 1.0 - others } else { 1.0 / len(p).max(lq) }));
    }

    /// The `k`-ring of patch `p` (`k ≥ 1`), ascending, `p` included.
    #[cfg(test)]
    pub fn ring(&self, k: usize, p: usize) -> Vec<u32> {
        let mut out = Vec::new();
        self.each_member(k, p, |q| out.push(q as u32));
        out
    }

    /// `Σ_{k≥1} Σ_{p ∈ ring_k(q)} w_pq · recv[p·B + k]`, with
    /// `B = buckets`: what patch `q` gets from its rings (bucket 0 is left
    /// to the caller). Computed where it is used, per patch, so that no
    /// vector of it is kept.
    #[inline]
    pub fn spread_onto(&self, recv: &[[f32; 3]], buckets: usize, q: usize) -> [f32; 3] {
        let mut acc = [0.0f32; 3];
        for k in 1..buckets {
            self.weighted(k, q, |p, w| {
                let r = recv[p * buckets + k];
                for c in 0..3 {
                    acc[c] += r[c] * w;
                }
            });
        }
        acc
    }

    /// [`Self::spread_onto`] of every patch into `out`.
    pub fn spread(&self, recv: &[[f32; 3]], buckets: usize, out: &mut [[f32; 3]]) {
        out.par_chunks_mut(512).enumerate().for_each(|(block, chunk)| {
            for (i, o) in chunk.iter_mut().enumerate() {
                *o = self.spread_onto(recv, buckets, block * 512 + i);
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 5×4 grid of patches, edge-adjacent.
    fn grid(w: u32, h: u32) -> (Vec<u32>, Vec<u32>) {
        let mut offsets = vec![0];
        let mut adj = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let p = y * w + x;
                if y > 0 {
                    adj.push(p - w);
                }
                if x > 0 {
                    adj.push(p - 1);
                }
                if x + 1 < w {
                    adj.push(p + 1);
                }
                if y + 1 < h {
                    adj.push(p + w);
                }
                offsets.push(adj.len() as u32);
            }
        }
        (offsets, adj)
    }

    #[test]
    fn rings_have_manhattan_sizes_and_spreading_conserves_energy() {
        let (o, a) = grid(9, 7);
        let rings = Rings::new(&o, &a, 3).unwrap();
        let centre = 3 * 9 + 4;
        assert_eq!(rings.ring(1, centre).len(), 5);
        assert_eq!(rings.ring(2, centre).len(), 13);
        assert_eq!(rings.ring(3, centre).len(), 25);
        assert_eq!(rings.ring(1, 0).len(), 3, "corner");
        // Arbitrary received light in every bucket.
        let n = 63;
        let recv: Vec<[f32; 3]> = (0..n * 4).map(|i| [((i * 37) % 11) as f32 + 0.5, (i % 5) as f32, 1.0]).collect();
        let mut out = vec![[0.0; 3]; n];
        rings.spread(&recv, 4, &mut out);
        // Uniform light stays uniform, borders included.
        let flat: Vec<[f32; 3]> = (0..n * 4).map(|i| if i % 4 == 0 { [0.0; 3] } else { [1.0; 3] }).collect();
        rings.spread(&flat, 4, &mut out);
        for o in &out {
            assert!((o[0] - 3.0).abs() < 1e-5, "{o:?}");
        }
        rings.spread(&recv, 4, &mut out);
        for c in 0..3 {
            let given: f64 =
                (0..n).flat_map(|p| (1..4).map(move |k| (p, k))).map(|(p, k)| recv[p * 4 + k][c] as f64).sum();
            let spread: f64 = out.iter().map(|o| o[c] as f64).sum();
            assert!((spread / given - 1.0).abs() < 1e-6, "band {c}: {spread} vs {given}");
        }
    }
}
