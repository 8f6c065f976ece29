//! A plain reference solver: Jacobi iteration of the same energy balance
//! over the same links, written for clarity, not speed, so that tests can
//! hold the fast path ([`super::Distributor`]: blocked kernels, bucket runs,
//! overlays, Anderson acceleration, warm starts, sparse jumps) to it.
//!
//! For a frame k it lists the frame's link ends once, plainly: frame 0's
//! ends and the frame's delta records, both ends of each, keeping those
//! whose two patches are present (§5.13). Then it iterates
//! `O ← E + ρ·(direct(O) + spread(O))` in `f64`, where `direct` gathers
//! `w · O[other] / H_other` over a patch's ends of bucket 0 and `spread`
//! shares wider buckets over rings of neighbours (the `buckets` module),
//! until the change in `O` is below the tolerance. Diffuse archives only.

use super::buckets::Rings;
use super::{DistributeError, DistributeOptions, Lighting, patch_materials};
use crate::archive::presence::FramePresence;
use crate::archive::{ArchiveError, Columns, InetView};

/// What the reference solver found.
#[derive(Debug, Clone, PartialEq)]
pub struct ReferenceSolution {
    /// Outgoing radiance per patch (W·sr⁻¹·m⁻², RGB), as
    /// [`super::Solution::radiance`].
    pub radiance: Vec<[f64; 3]>,
    /// Power each patch sends at the fixed point (W, RGB).
    pub sent: Vec<[f64; 3]>,
    /// Jacobi iterations run.
    pub iterations: u32,
    /// Whether the change fell below the tolerance.
    pub converged: bool,
}

/// One link end of the frame: `owner` receives over it from `other`.
struct End {
    owner: u32,
    other: u32,
    weight: f64,
    bucket: u8,
}

/// Solves `frame` of `v` under `lighting` with the options' tolerance
/// (on the summed change of sent power relative to emitted power),
/// iteration limit, buckets and patch-size correction; Anderson depth is
/// ignored. Fails for archives with non-diffuse patches.
pub fn solve(
    v: &InetView<'_>,
    frame: u32,
    lighting: &Lighting,
    opts: &DistributeOptions,
) -> Result<ReferenceSolution, DistributeError> {
    if v.reflectance.is_some() {
        return Err(DistributeError::Unsupported("the reference solver handles diffuse archives only".into()));
    }
    let frames = v.sequence.map_or(1, |s| s.frames());
    if frame >= frames {
        return Err(match v.sequence {
            Some(_) => DistributeError::FrameOutOfRange { frame, frames },
            None => DistributeError::NotASequence { frame },
        });
    }
    let presence = v.presence(frame);
    let (rho, emit) = frame_materials(v, frame, lighting);
    let balance = Balance::new(v, frame, opts, &presence)?;
    let n = balance.n;
    let emitted: Vec<[f64; 3]> = (0..n)
        .map(|p| {
            let k = std::f64::consts::PI * v.patch_area[p] as f64;
            let on = presence.patch(p);
            [0, 1, 2].map(|c| if on { emit[p][c] as f64 * k } else { 0.0 })
        })
        .collect();
    let (sent, iterations, converged) = balance.iterate(&rho, emitted, opts);
    let (direct, spread) = balance.receive(&sent);
    let pi = std::f64::consts::PI;
    let radiance = (0..n)
        .map(|p| {
            let kd = if balance.area_eff[p] > 0.0 { 1.0 / (pi * balance.area_eff[p]) } else { 0.0 };
            let ks = if v.patch_area[p] > 0.0 { 1.0 / (pi * v.patch_area[p] as f64) } else { 0.0 };
            let on = presence.patch(p);
            [0, 1, 2].map(|c| {
                let e = if on { emit[p][c] as f64 } else { 0.0 };
                e + rho[p][c] as f64 * (direct[p][c] * kd + spread[p][c] * ks)
            })
        })
        .collect();
    Ok(ReferenceSolution { radiance, sent, iterations, converged })
}

/// Reflectance and emission per patch at `frame`: the lighting's, with
/// the keyframed emission of surfaces whose emission is not fixed.
fn frame_materials(v: &InetView<'_>, frame: u32, lighting: &Lighting) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    let (rho, mut emit) = patch_materials(v, lighting);
    if let Some(keyed) = v.keyed_emission(frame) {
        for p in 0..v.patch_count() {
            let surface = v.primitives[v.patch_primitive[p] as usize].surface as usize;
            if !lighting.emission_fixed[surface] {
                emit[p] = keyed[surface];
            }
        }
    }
    (rho, emit)
}

/// The frame's transport, plainly: its link ends, the share of a
/// patch's power each end carries, the area irradiance is over, and the
/// rings wider buckets spread over.
struct Balance<'a> {
    /// Patches.
    n: usize,
    /// Buckets per patch (1 without buckets).
    buckets: usize,
    ends: Vec<End>,
    /// Share of a patch's power per end.
    share: Vec<f64>,
    /// The area a patch's irradiance is over.
    area_eff: Vec<f64>,
    rings: Option<Rings<'a>>,
}

impl<'a> Balance<'a> {
    /// Lists `frame`'s link ends (frame 0's and the frame's delta records,
    /// both ends of each, between present patches) and each patch's share
    /// and area under `opts`.
    fn new(
        v: &InetView<'a>,
        frame: u32,
        opts: &DistributeOptions,
        presence: &FramePresence,
    ) -> Result<Self, DistributeError> {
        let n = v.patch_count();
        let use_buckets = opts.buckets && v.build.max_bucket > 0;
        let buckets = if use_buckets { v.build.max_bucket as usize + 1 } else { 1 };
        let mut ends = Vec::new();
        v.links.for_each_window(Columns::GATHER, n, |w| {
            for q in w.patches.clone() {
                for (e, other, bucket) in w.ends_of(q) {
                    let bucket = if use_buckets { bucket } else { 0 };
                    ends.push(End { owner: q as u32, other, weight: w.weight.get(e) as f64, bucket });
                }
            }
            Ok::<(), ArchiveError>(())
        })?;
        if v.sequence.is_some() {
            for d in v.frame_links(frame)? {
                let (ba, bb) = if use_buckets { (d.bucket_a, d.bucket_b) } else { (0, 0) };
                ends.push(End { owner: d.a, other: d.b, weight: d.count as f64, bucket: ba });
                ends.push(End { owner: d.b, other: d.a, weight: d.count as f64, bucket: bb });
            }
        }
        ends.retain(|e| presence.link(e.owner, e.other));
        let rings = match use_buckets {
            true => Some(
                Rings::new(v.adjacency_offsets, v.adjacency, buckets - 1)
                    .map_err(|e| DistributeError::Archive(ArchiveError::Corrupt(e)))?,
            ),
            false => None,
        };
        let (share, area_eff): (Vec<f64>, Vec<f64>) = (0..n)
            .map(|p| {
                let (h, hx, a) = (v.patch_hits[p] as f64, v.patch_expected_hits[p] as f64, v.patch_area[p] as f64);
                if opts.patch_size_correction {
                    (if h > 0.0 { 1.0 / h } else { 0.0 }, if h > 0.0 && hx > 0.0 { a * h / hx } else { a })
                } else {
                    (if hx > 0.0 { 1.0 / hx } else { 0.0 }, a)
                }
            })
            .unzip();
        Ok(Self { n, buckets, ends, share, area_eff, rings })
    }

    /// Received light of `sent`: bucket 0 on the patch itself, the rest
    /// spread over the rings.
    fn receive(&self, sent: &[[f64; 3]]) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
        let (n, buckets) = (self.n, self.buckets);
        let mut recv = vec![[0.0f64; 3]; n * buckets];
        for e in &self.ends {
            let (o, slot) = (e.other as usize, e.owner as usize * buckets + e.bucket as usize);
            for c in 0..3 {
                recv[slot][c] += e.weight * self.share[o] * sent[o][c];
            }
        }
        let direct = (0..n).map(|q| recv[q * buckets]).collect();
        let spread = match &self.rings {
            Some(r) => {
                let wide: Vec<[f32; 3]> = recv.iter().map(|x| x.map(|c| c as f32)).collect();
                let mut out = vec![[0.0f32; 3]; n];
                r.spread(&wide, buckets, &mut out);
                out.iter().map(|x| [x[0] as f64, x[1] as f64, x[2] as f64]).collect()
            }
            None => vec![[0.0; 3]; n],
        };
        (direct, spread)
    }

    /// Jacobi iteration `O ← E + ρ·(direct(O) + spread(O))` from the
    /// emitted power until the summed change is below the tolerance
    /// (relative to the emitted power) or the iterations run out: the
    /// power sent, the iterations run and whether it converged.
    fn iterate(
        &self,
        rho: &[[f32; 3]],
        emitted: Vec<[f64; 3]>,
        opts: &DistributeOptions,
    ) -> (Vec<[f64; 3]>, u32, bool) {
        let emitted_total: f64 = emitted.iter().flatten().sum();
        let mut sent = emitted.clone();
        let (mut iterations, mut converged) = (0, emitted_total == 0.0);
        while !converged && iterations < opts.max_iterations {
            let (direct, spread) = self.receive(&sent);
            let mut change = 0.0;
            for p in 0..self.n {
                for c in 0..3 {
                    let next = emitted[p][c] + rho[p][c] as f64 * (direct[p][c] + spread[p][c]);
                    change += (next - sent[p][c]).abs();
                    sent[p][c] = next;
                }
            }
            iterations += 1;
            converged = change <= opts.tolerance * emitted_total;
        }
        (sent, iterations, converged)
    }
}
