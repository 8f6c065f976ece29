//! Distribution: light spreads along the links until the energy balance
//! converges (§3.1, §3.4).
//!
//! Every patch `p` holds unshot power `U_p` (W, per RGB band), initially its
//! emission `π·L_e·A_p`. One iteration sends every patch's unshot power out
//! along its link ends, each end carrying the share `U_p / H_p`: a patch hit
//! by `H_p` rays in the build stands for `H_p` equal beams, so the share
//! already holds the cosine of §3.3 and the patch-size correction `H_p/H_u` of
//! §3.4, and the power sent out equals the power removed, exactly. Ends with
//! no link (the ray left the scene or met a back face) lose their share:
//! that power has escaped. Each patch then reflects `ρ` of what it received
//! (diffuse: outgoing radiance `ρE/π`) as its new unshot power and absorbs
//! the rest. Iterations stop when the unshot power falls below `tolerance`
//! times the emitted power. (A Jacobi iteration of progressive radiosity.)
//! With Anderson acceleration (`anderson.rs`) an iteration sends a mix of
//! the unshot power and earlier steps instead; the unshot power is still
//! tracked exactly, and still decides when to stop.
//!
//! Radiance for display is `L = L_e + ρ·Φ_in/(π·A_eff)` with
//! `A_eff = A_p·H_p/E[H_p]`, the area the rays "saw".
//!
//! The hot loop is a gather over the CSR link-end columns (`LOFF`, `LOTH`,
//! `LWGT`: 8 bytes per end), parallel over blocks of patches; the per-patch
//! state it gathers from is 16 bytes per patch, cache-resident for scenes of
//! up to ~10⁵ patches.

mod anderson;

pub use anderson::MAX_DEPTH as MAX_ANDERSON_DEPTH;
mod buckets;
mod nondiffuse;

use rayon::prelude::*;

use crate::archive::InetView;
use crate::archive::layout::model;
use crate::progress::Progress;

/// Options for [`distribute`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DistributeOptions {
    /// Stop when unshot power ≤ `tolerance` × emitted power (summed over bands).
    pub tolerance: f64,
    /// Stop after this many iterations even if not converged.
    pub max_iterations: u32,
    /// Use the `H_p/H_u` patch-size correction of §3.4 (default on). Off, each
    /// link carries `U_p/E[H_p]` and irradiance uses the geometric area: the
    /// uncorrected method, kept for measurement.
    pub patch_size_correction: bool,
    /// Spread light over the rings of neighbours its link end's bucket names
    /// (§3.4), when the archive has buckets (default on).
    pub buckets: bool,
    /// Secant pairs kept for Anderson acceleration (`anderson.rs`; default
    /// 5, at most [`MAX_ANDERSON_DEPTH`]); 0 iterates plainly. Archives
    /// with non-diffuse patches always iterate plainly.
    pub anderson_depth: usize,
}

impl Default for DistributeOptions {
    fn default() -> Self {
        Self { tolerance: 1e-4, max_iterations: 1000, patch_size_correction: true, buckets: true, anderson_depth: 5 }
    }
}

/// Where the emitted power went, per RGB band (W).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct EnergyBalance {
    /// Power emitted by all emitters.
    pub emitted: [f64; 3],
    /// Power absorbed by surfaces.
    pub absorbed: [f64; 3],
    /// Power that left the scene (rays that met nothing or a back face).
    pub escaped: [f64; 3],
    /// Power still unshot when iteration stopped.
    pub residual: [f64; 3],
    /// Iterations run.
    pub iterations: u32,
    /// Link ends gathered over the iterations (a warm start's first step
    /// may gather only the ends two frames' overlays hold).
    pub ends_gathered: u64,
    /// Whether the tolerance was reached.
    pub converged: bool,
}

impl EnergyBalance {
    /// `emitted − absorbed − escaped − residual` relative to emitted, summed
    /// over bands: zero up to rounding when energy is conserved.
    pub fn imbalance(&self) -> f64 {
        let s = |a: &[f64; 3]| a.iter().sum::<f64>();
        let e = s(&self.emitted);
        if e == 0.0 { 0.0 } else { (e - s(&self.absorbed) - s(&self.escaped) - s(&self.residual)) / e }
    }
}

/// The converged light of a scene.
#[derive(Debug, Clone, PartialEq)]
pub struct Solution {
    /// Outgoing radiance per patch (W·sr⁻¹·m⁻², RGB).
    pub radiance: Vec<[f32; 3]>,
    /// Total power received per patch over all iterations (W, RGB).
    pub received: Vec<[f32; 3]>,
    /// Energy bookkeeping.
    pub balance: EnergyBalance,
    /// Seconds spent decoding and applying the frame's delta (0 for stills).
    pub delta_s: f64,
    /// Outgoing radiance of non-diffuse patches per direction (the
    /// view-dependent term of §3.5), when the archive has any.
    pub directional: Option<DirectionalRadiance>,
    /// The acceleration's secant history, which the next frame of a
    /// sequence starts from when warm-started from this solution.
    history: anderson::Anderson,
    /// What a frame warm-started from this solution reuses to find the
    /// light its first step delivers without a full gather.
    carry: Option<std::sync::Arc<Carry>>,
    /// The frame solved.
    frame: u32,
}

/// A frame's totals kept for the next frame's warm start (diffuse archives):
/// everything sent and received over its iterations, its overlay and
/// emission. Because the balance is linear, `received = G(sent)` for the
/// frame's link operator G, so the next frame's operator applied to (nearly)
/// the same power differs from `received` only through the two frames'
/// overlays (see `Distributor::sparse_jump`).
struct Carry {
    /// The [`Distributor`] that made it (sums from another archive, options
    /// or link set are not reused).
    distributor: u64,
    /// Frame.
    frame: u32,
    /// Sparse jumps in a row that led to this frame: rounding in the sums
    /// is carried from jump to jump, so every [`MAX_SPARSE_CHAIN`]-th frame
    /// gathers in full.
    chain: u32,
    /// Σ power sent over the iterations, per patch (f64: the sums are
    /// carried from frame to frame).
    sent: Vec<[f64; 3]>,
    /// Σ power received over the iterations, per patch and bucket (before
    /// spreading).
    received: Vec<[f64; 3]>,
    /// Power emitted per patch (the frame's emission).
    emitted: Vec<[f32; 4]>,
    /// The frame's overlay of present ends (None for frame 0 of a still).
    overlay: Option<std::sync::Arc<Ends>>,
}

/// Sparse warm jumps in a row before a full gather (see [`Carry::chain`]).
const MAX_SPARSE_CHAIN: u32 = 32;

/// A carry is a cache for the next frame, not part of a solution's value.
impl PartialEq for Carry {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl std::fmt::Debug for Carry {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Carry {{ frame: {}, chain: {}, patches: {} }}", self.frame, self.chain, self.sent.len())
    }
}

/// Radiance leaving non-diffuse patches along each direction of the set,
/// beyond their diffuse radiance.
#[derive(Debug, Clone, PartialEq)]
pub struct DirectionalRadiance {
    /// The non-diffuse patches, ascending.
    pub patches: Vec<u32>,
    /// Directions in the set.
    pub directions: usize,
    /// `patches × directions` radiances (W·sr⁻¹·m⁻², RGB).
    pub radiance: Vec<[f32; 3]>,
}

impl DirectionalRadiance {
    /// Patch `k`'s (index into [`Self::patches`]) radiance per direction.
    pub fn of(&self, k: usize) -> &[[f32; 3]] {
        &self.radiance[k * self.directions..(k + 1) * self.directions]
    }
}

/// Emission and reflectance per surface: the archive's, or changed without
/// a rebuild (the I-net holds geometry only: relighting needs no new build).
#[derive(Debug, Clone, PartialEq)]
pub struct Lighting {
    /// Emitted radiance per surface.
    pub emission: Vec<[f32; 3]>,
    /// Diffuse reflectance `k_d` per surface, each component in [0, 1].
    pub reflectance: Vec<[f32; 3]>,
    /// Specular colour `k_s` per surface (zero for diffuse surfaces): the
    /// prototype table's generic factors are multiplied by it.
    pub specular: Vec<[f32; 3]>,
    /// Surfaces whose emission was set here: it then replaces the archive's
    /// keyframed emission in every frame.
    pub emission_fixed: Vec<bool>,
}

impl Lighting {
    /// The lighting stored in the archive.
    pub fn from_view(v: &InetView<'_>) -> Self {
        let emission = v.surfaces.iter().map(|s| s.emission).collect();
        let material = |s: &crate::archive::layout::SurfaceRecord| &v.materials[s.material as usize];
        let reflectance = v.surfaces.iter().map(|s| [0, 1, 2].map(|c| material(s).params[c])).collect();
        let specular = v
            .surfaces
            .iter()
            .map(|s| match material(s).model {
                model::DIFFUSE => [0.0; 3],
                _ => [3, 4, 5].map(|c| material(s).params[c]),
            })
            .collect();
        Self { emission, reflectance, specular, emission_fixed: vec![false; v.surfaces.len()] }
    }
}

/// Per-patch reflectance and emitted radiance, from primitive → surface.
pub fn patch_materials(v: &InetView<'_>, lighting: &Lighting) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    let surface = |prim: u32| v.primitives[prim as usize].surface as usize;
    let rho = v.patch_primitive.iter().map(|&p| lighting.reflectance[surface(p)]).collect();
    let emit = v.patch_primitive.iter().map(|&p| lighting.emission[surface(p)]).collect();
    (rho, emit)
}

/// Patches per parallel task: large enough to amortise scheduling, small
/// enough to balance two to dozens of cores.
const BLOCK: usize = 512;

/// Link-end patch indices known to be below `bound` (checked once, when
/// made), so that the gather indexes per-patch state with them without a
/// bounds check per end (9% of the distribution's time, measured).
#[derive(Clone, Copy)]
struct Bounded<'a> {
    other: &'a [u32],
    bound: usize,
}

impl<'a> Bounded<'a> {
    /// `None` unless every index is below `bound`.
    fn new(other: &'a [u32], bound: usize) -> Option<Self> {
        other.iter().all(|&o| (o as usize) < bound).then_some(Self { other, bound })
    }

    /// The indices in `range` (which must lie within them).
    fn slice(self, range: std::ops::Range<usize>) -> Self {
        Self { other: &self.other[range], bound: self.bound }
    }
}

/// `Σ w·shoot[other]` over a run of link ends, in four partial sums (ends
/// `4i + j` go to sum `j`): one sum would chain every addition on the one
/// before it, and the latency of that chain (4 cycles per end) was the
/// gather's limit.
#[inline(always)]
fn weighted_sum(other: Bounded<'_>, weight: &[f32], shoot: &[[f32; 4]]) -> [f32; 4] {
    assert!(shoot.len() >= other.bound, "per-patch state shorter than the patch indices allow");
    let n = other.other.len().min(weight.len());
    let (other, weight) = (&other.other[..n], &weight[..n]);
    // SAFETY (both `get_unchecked`): every index of a `Bounded` is below its
    // `bound` (checked when it was made), and `bound ≤ shoot.len()` (the
    // assertion above).
    let at = |o: u32| unsafe { *shoot.get_unchecked(o as usize) };
    let mut acc = [[0.0f32; 4]; 4];
    let (o4, w4) = (other.chunks_exact(4), weight.chunks_exact(4));
    let (o_rest, w_rest) = (o4.remainder(), w4.remainder());
    for (o, w) in o4.zip(w4) {
        for j in 0..4 {
            let s = at(o[j]);
            for c in 0..4 {
                acc[j][c] += w[j] * s[c];
            }
        }
    }
    for (j, (&o, &w)) in o_rest.iter().zip(w_rest).enumerate() {
        let s = at(o);
        for c in 0..4 {
            acc[j][c] += w * s[c];
        }
    }
    [0, 1, 2, 3].map(|c| (acc[0][c] + acc[1][c]) + (acc[2][c] + acc[3][c]))
}

/// Gathers `recv[q] = Σ w·shoot[other]` over each patch's link ends;
/// patches not `present` (temporal instances absent from the frame)
/// receive nothing.
fn gather(
    offsets: &[u64],
    other: Bounded<'_>,
    weight: &[f32],
    present: Option<&[bool]>,
    shoot: &[[f32; 4]],
    recv: &mut [[f32; 4]],
) {
    recv.par_chunks_mut(BLOCK).enumerate().for_each(|(block, out)| {
        let first = block * BLOCK;
        for (i, r) in out.iter_mut().enumerate() {
            let q = first + i;
            if present.is_some_and(|p| !p[q]) {
                *r = [0.0; 4];
                continue;
            }
            let (a, b) = (offsets[q] as usize, offsets[q + 1] as usize);
            *r = weighted_sum(other.slice(a..b), &weight[a..b], shoot);
        }
    });
}

/// The runs of equal bucket in each patch's link ends (`LBKT`), found once
/// per archive: the gather then sums each run without looking at the
/// bucket of every end (that scan took a quarter of the gather's time).
struct BucketRuns {
    /// Per patch, its runs `offsets[q]..offsets[q + 1]`.
    offsets: Vec<u64>,
    /// Per run, the link end after its last one.
    end: Vec<u64>,
    /// Per run, its bucket.
    bucket: Vec<u8>,
}

impl BucketRuns {
    fn new(link_offsets: &[u64], bucket: &[u8]) -> Self {
        let n = link_offsets.len().saturating_sub(1);
        let mut runs = Self { offsets: Vec::with_capacity(n + 1), end: Vec::new(), bucket: Vec::new() };
        runs.offsets.push(0);
        for q in 0..n {
            let (a, b) = (link_offsets[q] as usize, link_offsets[q + 1] as usize);
            for (i, k) in bucket[a..b].iter().enumerate() {
                if i + 1 == b - a || bucket[a + i + 1] != *k {
                    runs.end.push((a + i + 1) as u64);
                    runs.bucket.push(*k);
                }
            }
            runs.offsets.push(runs.end.len() as u64);
        }
        runs
    }
}

/// Like [`gather`], but sorts what arrives into buckets: `recv[q·B + k]`
/// holds the light patch `q` received over ends of bucket `k` (B = buckets).
#[allow(clippy::too_many_arguments)]
fn gather_buckets(
    offsets: &[u64],
    other: Bounded<'_>,
    weight: &[f32],
    runs: &BucketRuns,
    buckets: usize,
    present: Option<&[bool]>,
    shoot: &[[f32; 4]],
    recv: &mut [[f32; 4]],
) {
    recv.par_chunks_mut(BLOCK * buckets).enumerate().for_each(|(block, out)| {
        let first = block * BLOCK;
        for (i, r) in out.chunks_exact_mut(buckets).enumerate() {
            let q = first + i;
            r.fill([0.0; 4]);
            if present.is_some_and(|p| !p[q]) {
                continue;
            }
            // Buckets are validated to be < `buckets`.
            let mut e = offsets[q] as usize;
            for run in runs.offsets[q] as usize..runs.offsets[q + 1] as usize {
                let end = runs.end[run] as usize;
                let acc = weighted_sum(other.slice(e..end), &weight[e..end], shoot);
                let slot = &mut r[runs.bucket[run] as usize];
                for c in 0..4 {
                    slot[c] += acc[c];
                }
                e = end;
            }
        }
    });
}

/// Adds `sign · Σ w·shoot[other]` over the ends of `ends` to each owner's
/// bucket slot of `recv` (a sparse gather: owners without ends cost one
/// offset comparison per bucket), and, given the non-diffuse patches and
/// their per-ray power `phi`, what non-diffuse senders send along the ends.
fn add_ends(
    ends: &Ends,
    buckets: usize,
    shoot: &[[f32; 4]],
    sign: f32,
    nd: Option<(&nondiffuse::NonDiffuse<'_>, &[[f32; 4]])>,
    recv: &mut [[f32; 4]],
) {
    recv.par_chunks_mut(BLOCK * buckets).enumerate().for_each(|(block, out)| {
        let first = block * BLOCK;
        for (i, r) in out.chunks_exact_mut(buckets).enumerate() {
            let q = first + i;
            for (k, slot) in r.iter_mut().enumerate() {
                let run = ends.run(q, buckets, k);
                if run.is_empty() {
                    continue;
                }
                let acc = weighted_sum(ends.bounded().slice(run.clone()), &ends.weight[run.clone()], shoot);
                for c in 0..4 {
                    slot[c] += sign * acc[c];
                }
                if let Some((nd, phi)) = nd {
                    for e in run {
                        let j = nd.nd_of[ends.other[e] as usize];
                        if j != u32::MAX {
                            let p = phi[nd.slot(j, ends.direction[e] ^ 1)];
                            for c in 0..4 {
                                slot[c] += sign * ends.weight[e] * p[c];
                            }
                        }
                    }
                }
            }
        }
    });
}

/// Zeroes the rows (`buckets` entries per patch) of patches absent from the
/// frame: what they received through the correction list of non-diffuse
/// senders, which holds frame 0's ends (the diffuse gathers skip absent
/// patches already), and what a mixed step would have them send.
fn silence_absent(present: Option<&[bool]>, buckets: usize, recv: &mut [[f32; 4]]) {
    if let Some(present) = present {
        for (p, r) in recv.chunks_exact_mut(buckets).enumerate() {
            if !present[p] {
                r.fill([0.0; 4]);
            }
        }
    }
}

/// Runs the energy balance on an archive's links.
pub fn distribute(v: &InetView<'_>, opts: &DistributeOptions, progress: &dyn Progress) -> Solution {
    distribute_frame(v, 0, opts, progress).expect("frame 0 of a validated archive has no delta to decode")
}

/// Link ends as CSR by owner patch, each owner's ends split into one run
/// per bucket (`offsets[q·B + k]..offsets[q·B + k + 1]`, B buckets).
#[derive(Debug, Default, PartialEq)]
struct Ends {
    offsets: Vec<u32>,
    /// Other patches, each below `patches`.
    other: Vec<u32>,
    weight: Vec<f32>,
    direction: Vec<u32>,
    /// Patches in the archive.
    patches: usize,
}

impl Ends {
    /// The ends of `records` (both ends of each) that `keep(owner, other)`.
    fn new(
        n: usize,
        buckets: usize,
        records: &[crate::archive::layout::DeltaRecord],
        keep: impl Fn(u32, u32) -> bool,
    ) -> Self {
        let slot = |me: u32, k: u8| me as usize * buckets + if buckets > 1 { k as usize } else { 0 };
        let ends = |d: &crate::archive::layout::DeltaRecord| {
            [(d.a, d.b, d.bucket_a, 2 * d.pair), (d.b, d.a, d.bucket_b, 2 * d.pair + 1)]
        };
        // Records come validated (patches below n); `bounded` relies on it.
        assert!(records.iter().all(|d| (d.a as usize) < n && (d.b as usize) < n), "delta record patch out of range");
        let mut count = vec![0u32; n * buckets + 1];
        for d in records {
            for (me, them, k, _) in ends(d) {
                if keep(me, them) {
                    count[slot(me, k) + 1] += 1;
                }
            }
        }
        for i in 0..n * buckets {
            count[i + 1] += count[i];
        }
        let offsets = count.clone();
        let mut cursor = count;
        let m = offsets[n * buckets] as usize;
        let (mut other, mut weight, mut direction) = (vec![0; m], vec![0.0; m], vec![0; m]);
        for d in records {
            for (me, them, k, dir) in ends(d) {
                if keep(me, them) {
                    let e = cursor[slot(me, k)] as usize;
                    other[e] = them;
                    weight[e] = d.count as f32;
                    direction[e] = dir;
                    cursor[slot(me, k)] += 1;
                }
            }
        }
        Self { offsets, other, weight, direction, patches: n }
    }

    /// The other patches, as indices below the patch count.
    fn bounded(&self) -> Bounded<'_> {
        // Every `other` is a record's patch, checked below `patches` in `new`.
        Bounded { other: &self.other, bound: self.patches }
    }

    /// Patch `q`'s ends of bucket `k`.
    fn run(&self, q: usize, buckets: usize, k: usize) -> std::ops::Range<usize> {
        self.offsets[q * buckets + k] as usize..self.offsets[q * buckets + k + 1] as usize
    }
}

/// What a frame changes in frame 0's links: link ends added (positive
/// weights) or removed (negative).
struct Overlay {
    /// Every end between two present patches, by owner (one bucket run
    /// each): what non-diffuse patches send and receive along. Built only
    /// for archives with non-diffuse patches.
    all: Option<Ends>,
    /// The ends between two patches present in the frame, by owner and
    /// bucket: what the gather adds. Ends that touch an absent patch are
    /// left out: absent patches receive nothing and so send nothing,
    /// where adding frame 0's ends and subtracting them again would leave
    /// rounding residue.
    gather: std::sync::Arc<Ends>,
    /// Per patch, the change of its summed link weight.
    linked: Vec<f64>,
}

impl Overlay {
    fn new(
        n: usize,
        buckets: usize,
        records: &[crate::archive::layout::DeltaRecord],
        present: &[bool],
        nondiffuse: bool,
    ) -> Self {
        // Links with an end at an absent patch are not links of the frame
        // (§5.13): files before version 6 list frame 0's such links as
        // removals, later files leave them out; both are skipped here, and
        // frame 0's links to patches absent from the frame are taken off
        // the linked weights by `Distributor::absent_ends`.
        let both = |me: u32, them: u32| present[me as usize] && present[them as usize];
        let mut linked = vec![0.0f64; n];
        for d in records.iter().filter(|d| both(d.a, d.b)) {
            linked[d.a as usize] += d.count as f64;
            linked[d.b as usize] += d.count as f64;
        }
        let gather = std::sync::Arc::new(Ends::new(n, buckets, records, both));
        let all = nondiffuse.then(|| Ends::new(n, 1, records, both));
        Self { all, gather, linked }
    }

    /// Adds the overlay's contribution to `recv` (bucketed as in
    /// [`gather_buckets`]), including what non-diffuse senders send;
    /// parallel over blocks of patches like the main gather.
    fn gather(
        &self,
        buckets: usize,
        shoot: &[[f32; 4]],
        nd: Option<(&nondiffuse::NonDiffuse<'_>, &[[f32; 4]])>,
        recv: &mut [[f32; 4]],
    ) {
        add_ends(&self.gather, buckets, shoot, 1.0, nd, recv);
    }
}

/// Runs the energy balance for `frame` of a sequence archive (frame 0 for a
/// still): frame 0's links plus the frame's delta; patches of temporal
/// instances absent from the frame neither emit nor take part.
pub fn distribute_frame(
    v: &InetView<'_>,
    frame: u32,
    opts: &DistributeOptions,
    progress: &dyn Progress,
) -> Result<Solution, crate::archive::ArchiveError> {
    distribute_frame_from(v, frame, opts, None, progress)
}

/// [`distribute_frame`] warm-started from `start`, typically the previous
/// frame's solution. The balance is linear, `O = E + ρ·G(O)` for the power
/// `O` patches send out: the first iteration sends the guess
/// `O₀ = E + ρ·received(start)` and keeps the residual `E + ρ·G(O₀) − O₀`
/// (which may be negative) as unshot power, so the iteration converges to
/// the same answer, in fewer iterations when the guess is close. The energy
/// bookkeeping stays exact: emitted = absorbed + escaped + residual.
pub fn distribute_frame_from(
    v: &InetView<'_>,
    frame: u32,
    opts: &DistributeOptions,
    start: Option<&Solution>,
    progress: &dyn Progress,
) -> Result<Solution, crate::archive::ArchiveError> {
    distribute_lit(v, frame, opts, &Lighting::from_view(v), start, progress)
}

/// [`distribute_frame_from`] with the given `lighting` instead of the
/// archive's (its vectors must have one entry per surface).
pub fn distribute_lit(
    v: &InetView<'_>,
    frame: u32,
    opts: &DistributeOptions,
    lighting: &Lighting,
    start: Option<&Solution>,
    progress: &dyn Progress,
) -> Result<Solution, crate::archive::ArchiveError> {
    Distributor::new(v, opts, lighting)?.frame(frame, start, progress)
}

/// What distributing light over one archive needs whatever the frame:
/// per-patch reflectance, emission and link shares, and the bucket rings,
/// computed once and reused for every frame of a sequence.
pub struct Distributor<'a> {
    /// Distinct for every distributor made in the process (see [`Carry`]).
    id: u64,
    v: InetView<'a>,
    opts: DistributeOptions,
    rho: Vec<[f32; 3]>,
    emit: Vec<[f32; 3]>,
    share: Vec<f32>,
    area_eff: Vec<f32>,
    linked: Vec<f64>,
    bucket_runs: Option<BucketRuns>,
    /// `LOTH`, checked below the patch count once.
    link_other: Bounded<'a>,
    /// Per patch, whether frame 0's links reach it (see [`Self::sparse_jump`]).
    in_base: Vec<bool>,
    nb: usize,
    rings: Option<buckets::Rings>,
    patch_surface: Vec<u32>,
    emission_fixed: Vec<bool>,
    nd: Option<nondiffuse::NonDiffuse<'a>>,
    /// Patches of instances present at frame 0 but not in every frame,
    /// with the last frame they are present in: their frame 0 link ends
    /// are not links of the later frames.
    leaving: Vec<(u32, u32)>,
}

impl<'a> Distributor<'a> {
    /// Prepares `v` with `lighting` (one entry per surface).
    pub fn new(
        v: &InetView<'a>,
        opts: &DistributeOptions,
        lighting: &Lighting,
    ) -> Result<Self, crate::archive::ArchiveError> {
        let n = v.patch_count();
        if lighting.emission.len() != v.surfaces.len()
            || lighting.reflectance.len() != v.surfaces.len()
            || lighting.specular.len() != v.surfaces.len()
        {
            return Err(crate::archive::ArchiveError::Corrupt("lighting does not have one entry per surface".into()));
        }
        let (rho, emit) = patch_materials(v, lighting);
        // Share of a patch's power each link end carries, and the area used for irradiance.
        let mut share = vec![0.0f32; n];
        let mut area_eff = vec![0.0f32; n];
        let mut linked = vec![0.0f64; n];
        for p in 0..n {
            let (h, hx, a) = (v.patch_hits[p] as f32, v.patch_expected_hits[p], v.patch_area[p]);
            if opts.patch_size_correction {
                share[p] = if h > 0.0 { 1.0 / h } else { 0.0 };
                area_eff[p] = if h > 0.0 && hx > 0.0 { a * h / hx } else { a };
            } else {
                share[p] = if hx > 0.0 { 1.0 / hx } else { 0.0 };
                area_eff[p] = a;
            }
            let (_, w, _) = v.link_ends(p);
            linked[p] = w.iter().map(|&x| x as f64).sum();
        }
        // Buckets (§3.4): rings of neighbours to spread light over.
        let bucket_column = v.link_bucket.filter(|_| opts.buckets && v.build.max_bucket > 0);
        let bucket_runs = bucket_column.map(|b| BucketRuns::new(v.link_offsets, b));
        let link_other = Bounded::new(v.link_other, n)
            .ok_or_else(|| crate::archive::ArchiveError::Corrupt("LOTH: a link end's patch is out of range".into()))?;
        // Patches with frame 0 link ends of their own or at another's end
        // (the same, when every link is stored at both ends).
        let mut in_base: Vec<bool> = linked.iter().map(|&l| l > 0.0).collect();
        for &o in v.link_other {
            in_base[o as usize] = true;
        }
        let nb = bucket_column.map_or(1, |_| v.build.max_bucket as usize + 1);
        let rings = match bucket_column {
            Some(_) => Some(
                buckets::Rings::new(v.adjacency_offsets, v.adjacency, nb - 1)
                    .map_err(crate::archive::ArchiveError::Corrupt)?,
            ),
            None => None,
        };
        let patch_surface = v.patch_primitive.iter().map(|&p| v.primitives[p as usize].surface).collect();
        let emission_fixed = lighting.emission_fixed.clone();
        if let Some(r) = v.reflectance
            && (r.patches.len() as u64) * (v.directions.len() as u64) >= u32::MAX as u64
        {
            return Err(crate::archive::ArchiveError::Corrupt(format!(
                "{} non-diffuse patches × {} directions exceed what the distribution indexes (2³²)",
                r.patches.len(),
                v.directions.len()
            )));
        }
        let nd = nondiffuse::NonDiffuse::new(v, &lighting.specular);
        let leaving = match &v.sequence {
            Some(s) => {
                let mut last = vec![u32::MAX; v.primitives.len()];
                for i in s.instances.iter().filter(|i| i.frame_first == 0 && i.frame_last + 1 < s.frames()) {
                    let first = i.first_primitive as usize;
                    last[first..first + i.primitive_count as usize].fill(i.frame_last);
                }
                (0..n as u32)
                    .filter_map(|p| {
                        let l = last[v.patch_primitive[p as usize] as usize];
                        (l != u32::MAX && !v.link_ends(p as usize).0.is_empty()).then_some((p, l))
                    })
                    .collect()
            }
            None => Vec::new(),
        };
        static NEXT_ID: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        Ok(Self {
            id: NEXT_ID.fetch_add(1, std::sync::atomic::Ordering::Relaxed),
            v: *v,
            opts: *opts,
            rho,
            emit,
            share,
            area_eff,
            linked,
            bucket_runs,
            link_other,
            in_base,
            nb,
            rings,
            patch_surface,
            emission_fixed,
            nd,
            leaving,
        })
    }

    /// The first send `X` of a sparse warm jump from `c` (an earlier
    /// frame e of this distributor) to `frame` f, whose patches are
    /// `present` and emit `emitted`, or `None` when the jump
    /// needs a full gather. `X` is what e sent in all, `S`, plus the change
    /// in emitted power, on the patches present in f. By linearity
    /// `c.received = G_e(S)`, and for a patch q present in f,
    /// `G_f(X)[q] = base(q)·X + overlay_f(q)·X` while
    /// `G_e(S)[q] = base(q)·S + overlay_e(q)·S`; so
    /// `G_f(X) = G_e(S) + overlay_f(X) − overlay_e(S)` exactly when
    /// `base(q)·(X − S) = 0`, that is when no patch with frame 0 links
    /// changes presence or emission between e and f. (Patches present in
    /// f but not in e have no frame 0 links, and receive nothing in e.)
    fn sparse_jump(
        &self,
        c: &Carry,
        frame: u32,
        emitted: &[[f32; 4]],
        present: Option<&[bool]>,
    ) -> Option<Vec<[f32; 4]>> {
        let n = self.v.patch_count();
        if c.sent.len() != n || c.emitted.len() != n || c.received.len() != n * self.nb {
            return None;
        }
        let present_e: Option<Vec<bool>> = self.v.sequence.map(|_| {
            let prims = self.v.present_primitives(c.frame);
            self.v.patch_primitive.iter().map(|&p| prims[p as usize]).collect()
        });
        let here = |set: &Option<&[bool]>, p: usize| set.is_none_or(|s| s[p]);
        let (present_e, present_f) = (present_e.as_deref(), present);
        let sent = |q: usize, k: usize| if k < 3 { c.sent[q][k] as f32 } else { 0.0 };
        let mut x = vec![[0.0f32; 4]; n];
        for p in 0..n {
            let (in_e, in_f) = (here(&present_e, p), here(&present_f, p));
            if self.in_base[p] && (in_e != in_f || (in_f && emitted[p] != c.emitted[p])) {
                return None;
            }
            if in_f {
                x[p] = [0, 1, 2, 3].map(|k| sent(p, k) + (emitted[p][k] - c.emitted[p][k]));
            }
        }
        // A patch that enters (no frame 0 links, so X is free there) sends
        // what the same cell of the instance it replaces sent, changed by
        // the change in emission: the blades and the lamp reflect light too,
        // and leaving that out of X left it in the first residual.
        for (p, q) in self.predecessors(c.frame, frame) {
            let (p, q) = (p as usize, q as usize);
            x[p] = [0, 1, 2, 3].map(|k| sent(q, k) + (emitted[p][k] - c.emitted[q][k]));
        }
        Some(x)
    }

    /// Pairs `(p, q)`: patch `p` of an instance present at `frame` but not
    /// at `earlier`, and the same cell `q` of the instance of its surface
    /// present at `earlier`, when the two instances have the same primitive
    /// grids (rigid motion keeps them; a keyframed scale may not).
    fn predecessors(&self, earlier: u32, frame: u32) -> Vec<(u32, u32)> {
        let (Some(s), v) = (&self.v.sequence, &self.v) else { return Vec::new() };
        let n = v.patch_count() as u32;
        let patches_of = |i: &crate::archive::layout::InstanceRecord| {
            let first = i.first_primitive as usize;
            let end = first + i.primitive_count as usize;
            let start = v.primitives[first].first_patch;
            let stop = v.primitives.get(end).map_or(n, |p| p.first_patch);
            start..stop
        };
        let present = |i: &crate::archive::layout::InstanceRecord, f: u32| i.frame_first <= f && f <= i.frame_last;
        let mut out = Vec::new();
        for i in s.instances.iter().filter(|i| present(i, frame) && !present(i, earlier)) {
            let Some(j) = s.instances.iter().find(|j| j.surface == i.surface && present(j, earlier)) else {
                continue;
            };
            let grids = |r: &crate::archive::layout::InstanceRecord| {
                let first = r.first_primitive as usize;
                v.primitives[first..first + r.primitive_count as usize].iter().map(|p| (p.kind, p.grid_u, p.grid_v))
            };
            let (pi, pj) = (patches_of(i), patches_of(j));
            if i.primitive_count == j.primitive_count && pi.len() == pj.len() && grids(i).eq(grids(j)) {
                out.extend(pi.zip(pj));
            }
        }
        out
    }

    /// Calls `out(q, w, d)` for every frame 0 link end of a patch `q` whose
    /// other patch is absent from `frame`: `w` rays leaving `q` along
    /// direction `d` that no longer link (§5.13: a link with an end at an
    /// absent patch is not a link of the frame).
    fn absent_ends(&self, frame: u32, mut out: impl FnMut(usize, f32, u32)) {
        for &(t, last) in &self.leaving {
            if frame > last {
                let (other, weight, direction) = self.v.link_ends(t as usize);
                for ((&q, &w), &d) in other.iter().zip(weight).zip(direction) {
                    out(q as usize, w, d ^ 1);
                }
            }
        }
    }

    /// Distributes light for `frame` (0 for a still), warm-started from
    /// `start` when given (see [`distribute_frame_from`]).
    pub fn frame(
        &self,
        frame: u32,
        start: Option<&Solution>,
        progress: &dyn Progress,
    ) -> Result<Solution, crate::archive::ArchiveError> {
        let v = &self.v;
        let opts = &self.opts;
        let n = v.patch_count();
        let (rho, share, area_eff, nb, bucket_runs, rings) =
            (&self.rho, &self.share, &self.area_eff, self.nb, &self.bucket_runs, &self.rings);
        let mut emit = self.emit.clone();
        let t_delta = std::time::Instant::now();
        let (overlay, present_patch) = match &v.sequence {
            Some(s) => {
                if frame >= s.frames() {
                    return Err(crate::archive::ArchiveError::Corrupt(format!(
                        "frame {frame} is outside the sequence 0..{}",
                        s.frames()
                    )));
                }
                let present = v.present_primitives(frame);
                let keyed = s.emissions.map(|e| &e[frame as usize * v.surfaces.len()..][..v.surfaces.len()]);
                for p in 0..n {
                    let surface = self.patch_surface[p] as usize;
                    if !present[v.patch_primitive[p] as usize] {
                        emit[p] = [0.0; 3];
                    } else if let Some(keyed) = keyed
                        && !self.emission_fixed.get(surface).copied().unwrap_or(false)
                    {
                        emit[p] = keyed[surface];
                    }
                }
                let present_patch: Vec<bool> = v.patch_primitive.iter().map(|&p| present[p as usize]).collect();
                let records = s.frame_delta(frame)?;
                (Some(Overlay::new(n, nb, &records, &present_patch, self.nd.is_some())), Some(present_patch))
            }
            None if frame == 0 => (None, None),
            None => {
                return Err(crate::archive::ArchiveError::Corrupt(format!(
                    "frame {frame} requested from a still archive"
                )));
            }
        };
        let mut linked = self.linked.clone();
        if let Some(o) = &overlay {
            for (l, d) in linked.iter_mut().zip(&o.linked) {
                *l += d;
            }
            self.absent_ends(frame, |q, w, _| linked[q] -= w as f64);
        }
        let delta_s = if overlay.is_some() { t_delta.elapsed().as_secs_f64() } else { 0.0 };
        let mut unshot: Vec<[f32; 4]> = (0..n)
            .map(|p| {
                let k = std::f32::consts::PI * v.patch_area[p];
                [emit[p][0] * k, emit[p][1] * k, emit[p][2] * k, 0.0]
            })
            .collect();
        let mut bal = EnergyBalance::default();
        for u in &unshot {
            for c in 0..3 {
                bal.emitted[c] += u[c] as f64;
            }
        }
        let emitted_total: f64 = bal.emitted.iter().sum();
        // Received power, split into what hit the patch itself (bucket 0, whose
        // density follows the patch's hit count) and what was spread onto it.
        let mut total_direct = vec![[0.0f32; 4]; n];
        let mut total_spread = vec![[0.0f32; 4]; n];
        let mut shoot = vec![[0.0f32; 4]; n];
        let mut recv = vec![[0.0f32; 4]; n * nb];
        let mut spread = vec![[0.0f32; 4]; n];
        let emitted_power = unshot.clone();
        // A warm start from this distributor's solution of an earlier frame
        // (diffuse archives) first sends what that frame sent in all, plus
        // the change in emission: the light that delivers is that frame's
        // total received light, plus this frame's overlay ends applied to
        // it, minus that frame's overlay ends applied to that frame's
        // light; two sparse gathers instead of a full one (§ `sparse_jump`).
        let sparse = start
            .and_then(|s| s.carry.as_deref())
            .filter(|c| {
                self.nd.is_none() && emitted_total > 0.0 && c.distributor == self.id && c.chain < MAX_SPARSE_CHAIN
            })
            .and_then(|c| self.sparse_jump(c, frame, &emitted_power, present_patch.as_deref()).map(|x| (c, x)));
        // Warm start: send O₀ first (the residual then carries E − O₀).
        let guess: Option<Vec<[f32; 4]>> = match &sparse {
            Some((_, x)) => Some(x.clone()),
            None => start.filter(|s| s.received.len() == n && emitted_total > 0.0).map(|s| {
                // Patches that enter take what the same cell of the instance
                // they replace received.
                let mut source: Vec<u32> = (0..n as u32).collect();
                for (p, q) in self.predecessors(s.frame, frame) {
                    source[p as usize] = q;
                }
                (0..n)
                    .map(|p| {
                        let e = unshot[p];
                        let r = s.received[source[p] as usize];
                        let on = e[0] + e[1] + e[2] > 0.0 || linked[p] > 0.0;
                        if on {
                            [e[0] + rho[p][0] * r[0], e[1] + rho[p][1] * r[1], e[2] + rho[p][2] * r[2], 0.0]
                        } else {
                            [0.0; 4]
                        }
                    })
                    .collect()
            }),
        };
        // Totals over the iterations, for the next frame's sparse jump.
        let carrying = self.nd.is_none() && v.sequence.is_some();
        let mut sent_total = vec![[0.0f64; 3]; if carrying { n } else { 0 }];
        let mut received_total = vec![[0.0f64; 3]; if carrying { n * nb } else { 0 }];
        // `unshot` is the residual: the power still to send. What an
        // iteration sends is `send`: the residual itself, the warm guess
        // first, or Anderson's mixed step.
        let mut send = vec![[0.0f32; 4]; n];
        // A warm start also starts from the previous frame's secant pairs:
        // its operator differs a little, but the pairs only steer the step,
        // and its slowest mode is this frame's too.
        let mut anderson = match start {
            Some(s) if guess.is_some() && s.history.fits(n, opts.anderson_depth) => s.history.clone(),
            _ => anderson::Anderson::new(if self.nd.is_none() { opts.anderson_depth } else { 0 }),
        };
        let mut residual_change = vec![[0.0f32; 4]; n];
        // Non-diffuse patches (nondiffuse.rs): per-ray directional power to
        // shoot, its running total, the power it carries, and per frame the
        // rays of each direction that reach a facing patch.
        let nd = self.nd.as_ref();
        let nn = nd.map_or(0, |x| x.patches.len() * x.n);
        let mut phi = vec![[0.0f32; 4]; nn];
        let mut phi_next = vec![[0.0f32; 4]; nn];
        let mut dir_total = vec![[0.0f32; 4]; nn];
        let mut pending = vec![[0.0f64; 3]; nd.map_or(0, |x| x.patches.len())];
        // Borrowed unless the frame's overlay changes it.
        let all_ends = overlay.as_ref().and_then(|o| o.all.as_ref());
        let linked_dir: std::borrow::Cow<'_, [f32]> = match (nd, all_ends) {
            (Some(x), Some(o)) => {
                let mut l = x.linked.clone();
                for (k, &q) in x.patches.iter().enumerate() {
                    for e in o.run(q as usize, 1, 0) {
                        l[k * x.n + o.direction[e] as usize] += o.weight[e];
                    }
                }
                self.absent_ends(frame, |q, w, d| {
                    let k = x.nd_of[q];
                    if k != u32::MAX {
                        l[x.slot(k, d)] -= w;
                    }
                });
                std::borrow::Cow::Owned(l)
            }
            (Some(x), None) => std::borrow::Cow::Borrowed(&x.linked[..]),
            _ => std::borrow::Cow::Borrowed(&[][..]),
        };
        let overlay_ends = |q: usize, add: &mut dyn FnMut(u32, f32, u32)| {
            if let Some(o) = all_ends {
                for e in o.run(q, 1, 0) {
                    add(o.other[e], o.weight[e], o.direction[e]);
                }
            }
        };
        progress.start("distributing light", 0);
        let mut residual_total = emitted_total;
        // A mixed step leaves a residual shaped by the least-squares fit, not
        // by the light: converged after one, the loop takes one plain step,
        // which spreads what is left like plain iteration would (per-patch
        // errors as small as plain iteration's at the same tolerance).
        let mut last_mixed = false;
        while (residual_total > opts.tolerance * emitted_total || last_mixed) && bal.iterations < opts.max_iterations {
            let warm_jump = bal.iterations == 0 && guess.is_some();
            let converged = residual_total <= opts.tolerance * emitted_total;
            match &guess {
                Some(g) if warm_jump => send.copy_from_slice(g),
                _ if converged => send.copy_from_slice(&unshot),
                _ => anderson.step(&unshot, &mut send),
            }
            // A mixed step may hand absent patches (present in an earlier
            // frame of the history) something to send: they send nothing.
            silence_absent(present_patch.as_deref(), 1, &mut send);
            last_mixed = !warm_jump && !converged && anderson.pairs() > 0;
            let previous_residual = residual_total;
            // Per-patch passes run in parallel blocks; their sums are added
            // in block order, so the result does not depend on the threads.
            let escaped: Vec<[f64; 3]> = shoot
                .par_chunks_mut(BLOCK)
                .enumerate()
                .map(|(block, out)| {
                    let mut sum = [0.0f64; 3];
                    for (i, sh) in out.iter_mut().enumerate() {
                        let p = block * BLOCK + i;
                        let s = share[p];
                        let escape = 1.0 - linked[p] * s as f64;
                        for c in 0..3 {
                            sh[c] = send[p][c] * s;
                            sum[c] += send[p][c] as f64 * escape;
                        }
                    }
                    sum
                })
                .collect();
            for e in &escaped {
                for c in 0..3 {
                    bal.escaped[c] += e[c];
                }
            }
            if let Some(x) = nd {
                // Directional power leaves along every ray of its direction;
                // rays that reach no facing patch lose it.
                for (k, g) in pending.iter_mut().enumerate() {
                    let mut sent = [0.0f64; 3];
                    for o in 0..x.n {
                        let l = linked_dir[k * x.n + o];
                        if l != 0.0 {
                            for c in 0..3 {
                                sent[c] += (l * phi[k * x.n + o][c]) as f64;
                            }
                        }
                    }
                    for c in 0..3 {
                        bal.escaped[c] += g[c] - sent[c];
                    }
                    *g = [0.0; 3];
                }
            }
            let nd_phi = nd.map(|x| (x, &phi[..]));
            match (&sparse, bucket_runs) {
                (Some((c, _)), _) if warm_jump => {
                    // G_f(X) = G_e(S) + overlay_f(X) − overlay_e(S) for the
                    // earlier frame e (see `sparse_jump`).
                    for (r, t) in recv.iter_mut().zip(&c.received) {
                        *r = [t[0] as f32, t[1] as f32, t[2] as f32, 0.0];
                    }
                    if let Some(o) = &overlay {
                        add_ends(&o.gather, nb, &shoot, 1.0, None, &mut recv);
                    }
                    if let Some(e) = &c.overlay {
                        let shoot_e: Vec<[f32; 4]> = c
                            .sent
                            .iter()
                            .zip(share)
                            .map(|(x, &s)| [x[0] as f32 * s, x[1] as f32 * s, x[2] as f32 * s, 0.0])
                            .collect();
                        add_ends(e, nb, &shoot_e, -1.0, None, &mut recv);
                    }
                    silence_absent(present_patch.as_deref(), nb, &mut recv);
                    bal.ends_gathered += [overlay.as_ref().map(|o| &o.gather), c.overlay.as_ref()]
                        .iter()
                        .flatten()
                        .map(|e| e.other.len() as u64)
                        .sum::<u64>();
                }
                (_, Some(runs)) => {
                    gather_buckets(
                        v.link_offsets,
                        self.link_other,
                        v.link_weight,
                        runs,
                        nb,
                        present_patch.as_deref(),
                        &shoot,
                        &mut recv,
                    );
                    if let Some(o) = &overlay {
                        o.gather(nb, &shoot, nd_phi, &mut recv);
                    }
                    if let Some(x) = nd {
                        x.gather_corrections(nb, true, &phi, &mut recv);
                        silence_absent(present_patch.as_deref(), nb, &mut recv);
                    }
                }
                (_, None) => {
                    gather(v.link_offsets, self.link_other, v.link_weight, present_patch.as_deref(), &shoot, &mut recv);
                    if let Some(o) = &overlay {
                        o.gather(1, &shoot, nd_phi, &mut recv);
                    }
                    if let Some(x) = nd {
                        x.gather_corrections(1, false, &phi, &mut recv);
                        silence_absent(present_patch.as_deref(), 1, &mut recv);
                    }
                }
            }
            if !(sparse.is_some() && warm_jump) {
                bal.ends_gathered += (v.link_other.len() + overlay.as_ref().map_or(0, |o| o.gather.other.len())) as u64;
            }
            match &rings {
                Some(rings) if bucket_runs.is_some() => rings.spread(&recv, nb, &mut spread),
                _ => spread.fill([0.0; 4]),
            }
            if carrying {
                let add = |(t, x): (&mut [[f64; 3]], &[[f32; 4]])| {
                    for (t, x) in t.iter_mut().zip(x) {
                        for c in 0..3 {
                            t[c] += x[c] as f64;
                        }
                    }
                };
                sent_total.par_chunks_mut(BLOCK).zip(send.par_chunks(BLOCK)).for_each(add);
                received_total.par_chunks_mut(BLOCK * nb).zip(recv.par_chunks(BLOCK * nb)).for_each(add);
            }
            residual_total = 0.0;
            if let Some(x) = nd {
                let totals = x.step(v, &shoot, &phi, &overlay_ends, &mut phi_next);
                std::mem::swap(&mut phi, &mut phi_next);
                // Absent non-diffuse patches keep nothing to send: `step`
                // walks their frame 0 ends too, and what it finds there is
                // not light of this frame (the senders counted those ends
                // as escaped, `absent_ends`).
                if let Some(present) = &present_patch {
                    for (k, &q) in x.patches.iter().enumerate() {
                        if !present[q as usize] {
                            phi[k * x.n..(k + 1) * x.n].fill([0.0; 4]);
                        }
                    }
                }
                for (t, p) in dir_total.iter_mut().zip(&phi) {
                    for c in 0..4 {
                        t[c] += p[c];
                    }
                }
                for (k, t) in totals.iter().enumerate() {
                    if present_patch.as_ref().is_some_and(|p| !p[x.patches[k] as usize]) {
                        pending[k] = [0.0; 3];
                        continue;
                    }
                    pending[k] = t.reflected;
                    for c in 0..3 {
                        bal.absorbed[c] -= t.reflected[c];
                        residual_total += t.reflected[c].abs();
                    }
                }
            }
            let sums: Vec<([f64; 3], f64)> = (
                total_direct.par_chunks_mut(BLOCK),
                total_spread.par_chunks_mut(BLOCK),
                residual_change.par_chunks_mut(BLOCK),
                unshot.par_chunks_mut(BLOCK),
            )
                .into_par_iter()
                .enumerate()
                .map(|(block, (td, ts, rc, un))| {
                    let (mut absorbed, mut residual) = ([0.0f64; 3], 0.0f64);
                    for i in 0..td.len() {
                        let p = block * BLOCK + i;
                        for c in 0..3 {
                            let direct = recv[p * nb][c];
                            let r = direct + spread[p][c];
                            td[i][c] += direct;
                            ts[i][c] += spread[p][c];
                            let reflected = r * rho[p][c];
                            // f(x + δ) = f(x) − δ + K·δ.
                            rc[i][c] = reflected - send[p][c];
                            un[i][c] = un[i][c] - send[p][c] + reflected;
                            absorbed[c] += (r - reflected) as f64;
                            residual += un[i][c].abs() as f64;
                        }
                    }
                    (absorbed, residual)
                })
                .collect();
            for (a, r) in &sums {
                for c in 0..3 {
                    bal.absorbed[c] += a[c];
                }
                residual_total += r;
            }
            if !warm_jump {
                if residual_total < previous_residual {
                    anderson.record(&send, &residual_change);
                } else {
                    anderson.reset();
                }
            }
            bal.iterations += 1;
            progress.advance(1);
        }
        progress.finish();
        for u in &unshot {
            for c in 0..3 {
                bal.residual[c] += u[c] as f64;
            }
        }
        for g in &pending {
            for c in 0..3 {
                bal.residual[c] += g[c];
            }
        }
        bal.converged = residual_total <= opts.tolerance * emitted_total;
        let inv_pi = 1.0 / std::f32::consts::PI;
        let radiance = (0..n)
            .map(|p| {
                let kd = if area_eff[p] > 0.0 { inv_pi / area_eff[p] } else { 0.0 };
                let ks = if v.patch_area[p] > 0.0 { inv_pi / v.patch_area[p] } else { 0.0 };
                [0, 1, 2].map(|c| emit[p][c] + rho[p][c] * (total_direct[p][c] * kd + total_spread[p][c] * ks))
            })
            .collect();
        let received = (0..n).map(|p| [0, 1, 2].map(|c| total_direct[p][c] + total_spread[p][c])).collect();
        // Per-ray power → radiance: one ray stands for the étendue
        // π·A_p/E[H_p] of its patch (as for the diffuse radiance above).
        let directional = nd.map(|x| {
            let radiance = x
                .patches
                .iter()
                .enumerate()
                .flat_map(|(k, &q)| {
                    let q = q as usize;
                    let a = v.patch_area[q];
                    let to_l = if a > 0.0 { v.patch_expected_hits[q] / (std::f32::consts::PI * a) } else { 0.0 };
                    dir_total[k * x.n..(k + 1) * x.n].iter().map(move |t| [t[0] * to_l, t[1] * to_l, t[2] * to_l])
                })
                .collect();
            DirectionalRadiance { patches: x.patches.clone(), directions: x.n, radiance }
        });
        let carry = carrying.then(|| {
            std::sync::Arc::new(Carry {
                distributor: self.id,
                frame,
                chain: match &sparse {
                    Some((c, _)) => c.chain + 1,
                    None => 0,
                },
                sent: sent_total,
                received: received_total,
                emitted: emitted_power,
                overlay: overlay.as_ref().map(|o| o.gather.clone()),
            })
        });
        Ok(Solution { radiance, received, balance: bal, delta_s, directional, history: anderson, carry, frame })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bucketed_gather_equals_a_per_end_sum_whatever_the_bucket_order() {
        // Runs of equal bucket, found once, must give what adding every end
        // into its own bucket gives, also for ends not grouped by bucket
        // (the format does not require grouping) and for runs of every
        // length around the four partial sums.
        let n = 5;
        let lengths = [0usize, 1, 3, 4, 9, 13];
        let mut offsets = vec![0u64];
        let (mut other, mut weight, mut bucket) = (Vec::new(), Vec::new(), Vec::new());
        for q in 0..n {
            for e in 0..lengths[q % lengths.len()] + q {
                other.push(((q * 7 + e * 3) % n) as u32);
                weight.push(1.0 + e as f32 * 0.25);
                bucket.push(if q == 3 { (e % 2) as u8 } else { (e / 5).min(1) as u8 });
            }
            offsets.push(other.len() as u64);
        }
        let shoot: Vec<[f32; 4]> = (0..n).map(|p| [p as f32 + 1.0, 0.5, 2.0 - p as f32, 0.0]).collect();
        let runs = BucketRuns::new(&offsets, &bucket);
        assert_eq!(runs.offsets.len(), n + 1);
        let mut recv = vec![[0.0f32; 4]; n * 2];
        let bounded = Bounded::new(&other, n).unwrap();
        assert!(Bounded::new(&other, n - 1).is_none(), "the test reaches the last patch");
        gather_buckets(&offsets, bounded, &weight, &runs, 2, None, &shoot, &mut recv);
        let mut want = vec![[0.0f64; 4]; n * 2];
        for q in 0..n {
            for e in offsets[q] as usize..offsets[q + 1] as usize {
                for c in 0..4 {
                    want[q * 2 + bucket[e] as usize][c] += weight[e] as f64 * shoot[other[e] as usize][c] as f64;
                }
            }
        }
        for (got, want) in recv.iter().zip(&want) {
            for c in 0..4 {
                assert!((got[c] as f64 - want[c]).abs() <= 1e-5 * want[c].abs().max(1.0), "{got:?} vs {want:?}");
            }
        }
        // Patch 3 alternates buckets: one run per end.
        assert_eq!(runs.offsets[4] - runs.offsets[3], offsets[4] - offsets[3]);
    }
}
