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
//! tracked exactly, and still decides when to stop. Non-diffuse patches
//! (§3.6) reflect through their tables, which costs ~100× a diffuse
//! patch's step; they do so only when the light waiting at them outweighs
//! the diffuse power still to send ([`DistributeOptions::defer_glossy`]).
//!
//! Radiance for display is `L = L_e + ρ·Φ_in/(π·A_eff)` with
//! `A_eff = A_p·H_p/E[H_p]`, the area the rays "saw".
//!
//! The hot loop is a gather over the CSR link-end columns (`LOFF`, `LOTH`,
//! `LCNT`: 5 bytes per end), parallel over blocks of patches; the per-patch
//! state it gathers from is 16 bytes per patch, cache-resident for scenes of
//! up to ~10⁵ patches.
//!
//! The pieces: this file is the public API ([`Distributor`], options,
//! [`Solution`]); `setup` makes a frame's view (presence, emission, the
//! `overlay` of its link changes); `warm` chooses how its iteration starts
//! (`Cold`, `Guess` or `SparseJump`); `step` is the iteration, a loop of
//! small steps; `kernels` are the inner loops (the only `unsafe`);
//! `anderson`, `buckets` and `nondiffuse` are the acceleration, the
//! spreading of §3.4 and the reflectance tables of §3.6. [`reference`](mod@reference) is a
//! plain solver over the same links that tests hold the fast path to.

mod anderson;
mod buckets;
mod error;
mod kernels;
pub mod memory;
mod nondiffuse;
mod overlay;
pub mod reference;
mod setup;
mod spill;
mod step;
pub mod team;
mod totals;
mod warm;

pub use anderson::MAX_DEPTH as MAX_ANDERSON_DEPTH;
pub use error::DistributeError;
pub use team::Team;

use std::sync::Arc;

use crate::archive::layout::model;
use crate::archive::{ArchiveError, Columns, InetView, LinkRows};
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
    /// with non-diffuse patches iterate plainly unless
    /// [`Self::defer_glossy`].
    pub anderson_depth: usize,
    /// Also find the part of each patch's radiance that is light straight
    /// from the emitters ([`Solution::direct`]; default on): one more
    /// gather, so that a renderer can replace it by direct light computed
    /// per image sample and keep the rest (the indirect light).
    pub split_direct: bool,
    /// Non-diffuse patches read their tables (Figure 9), the costly part of
    /// a step, only when the light waiting at them outweighs the diffuse
    /// light still to send, and the steps between are Anderson-accelerated
    /// (default on). The same balance is reached (the reflection is linear:
    /// light that waits is reflected later, not lost), in fewer table
    /// steps. Off, they reflect every step and iteration is plain.
    pub defer_glossy: bool,
}

impl Default for DistributeOptions {
    fn default() -> Self {
        Self {
            tolerance: 1e-4,
            max_iterations: 1000,
            patch_size_correction: true,
            buckets: true,
            anderson_depth: 5,
            split_direct: true,
            defer_glossy: true,
        }
    }
}

/// Where the emitted power went, per RGB band (W).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct EnergyBalance {
    /// Power emitted by all emitters.
    pub emitted: [f64; 3],
    /// Power absorbed by surfaces.
    pub absorbed: [f64; 3],
    /// Power that left the scene: carried by rays that met nothing (and,
    /// in archives written before version 9, which do not count back-face
    /// rays, by rays that met a back face too).
    pub escaped: [f64; 3],
    /// Power absorbed by the back faces of one-sided surfaces: carried by
    /// rays whose next surface faced away (`PBAK`, `NDBK`). In a sequence,
    /// each patch splits what leaves it unlinked by its counts in the first
    /// frame it is in, so moving geometry makes this split (not the sum
    /// with `escaped`) approximate.
    pub back_faces: [f64; 3],
    /// Power still unshot when iteration stopped.
    pub residual: [f64; 3],
    /// Iterations run.
    pub iterations: u32,
    /// Of those, the ones in which non-diffuse patches read their tables
    /// ([`DistributeOptions::defer_glossy`]).
    pub table_steps: u32,
    /// Link ends gathered over the iterations (a warm start's first step
    /// may gather only the ends two frames' overlays hold).
    pub ends_gathered: u64,
    /// Whether the tolerance was reached.
    pub converged: bool,
}

impl EnergyBalance {
    /// `emitted − absorbed − back_faces − escaped − residual` relative to
    /// emitted, summed over bands: zero up to rounding when energy is
    /// conserved.
    pub fn imbalance(&self) -> f64 {
        let s = |a: &[f64; 3]| a.iter().sum::<f64>();
        let e = s(&self.emitted);
        let out = s(&self.absorbed) + s(&self.back_faces) + s(&self.escaped) + s(&self.residual);
        if e == 0.0 { 0.0 } else { (e - out) / e }
    }
}

/// The converged light of a scene.
#[derive(Debug, Clone, PartialEq)]
pub struct Solution {
    /// Outgoing radiance per patch (W·sr⁻¹·m⁻², RGB).
    pub radiance: Vec<[f32; 3]>,
    /// Total power received per patch over all iterations (W, RGB).
    pub received: Vec<[f32; 3]>,
    /// Per patch, the power left unshot when the iteration stopped over the
    /// power it received (summed over bands; 0 where it received none):
    /// where the distribution has not converged.
    pub residual: Vec<f32>,
    /// Energy bookkeeping.
    pub balance: EnergyBalance,
    /// Seconds spent decoding and applying the frame's delta (0 for stills).
    pub delta_s: f64,
    /// Outgoing radiance of non-diffuse patches per direction (the
    /// view-dependent term of §3.5), when the archive has any.
    pub directional: Option<DirectionalRadiance>,
    /// The part of [`Self::radiance`] (diffuse, per patch) that is emitted
    /// light reflected once: `ρ·G(E)/(π·A)` for the link operator G and the
    /// emitted power E. By linearity the rest, `radiance − direct`, is the
    /// emission plus the light that has bounced at least twice, whatever
    /// acceleration or warm start found the balance. Present with
    /// [`DistributeOptions::split_direct`].
    pub direct: Option<Vec<[f32; 3]>>,
    /// Emitted radiance per surface at this frame (keyed emission and
    /// relighting applied): what emitters a renderer samples.
    pub surface_emission: Vec<[f32; 3]>,
    /// Diffuse reflectance `k_d` per surface the frame was solved with.
    pub surface_reflectance: Vec<[f32; 3]>,
    /// Specular colour `k_s` per surface the frame was solved with (zero
    /// for diffuse surfaces): what a renderer's glossy direct light
    /// multiplies the lobe by.
    pub surface_specular: Vec<[f32; 3]>,
    /// The acceleration's secant history, which the next frame of a
    /// sequence starts from when warm-started from this solution.
    history: anderson::Anderson,
    /// What a frame warm-started from this solution reuses to find the
    /// light its first step delivers without a full gather.
    carry: Option<Arc<warm::Carry>>,
    /// The frame solved.
    frame: u32,
}

impl Solution {
    /// Frees what only a later frame's warm start reads: the received
    /// power ([`Self::received`] is empty after), the secant history and
    /// the carried totals. For a solution no frame will start from, before
    /// it is shaded (a render's last frame): 12 bytes a patch and more.
    pub fn release_warm_start(&mut self) {
        self.received = Vec::new();
        self.history = anderson::Anderson::new(0);
        self.carry = None;
    }

    /// The frame solved.
    pub fn frame(&self) -> u32 {
        self.frame
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
    /// The part of [`Self::radiance`] that is emitted light reflected once
    /// (the glossy highlights of the emitters), laid out the same; empty
    /// unless [`DistributeOptions::split_direct`]. A renderer that computes
    /// the highlights per image sample takes this off.
    pub direct: Vec<[f32; 3]>,
}

impl DirectionalRadiance {
    /// Patch `k`'s (index into [`Self::patches`]) radiance per direction.
    pub fn of(&self, k: usize) -> &[[f32; 3]] {
        &self.radiance[k * self.directions..(k + 1) * self.directions]
    }

    /// Patch `k`'s direct part per direction ([`Self::direct`]), when split.
    pub fn direct_of(&self, k: usize) -> Option<&[[f32; 3]]> {
        self.direct.get(k * self.directions..(k + 1) * self.directions)
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

/// The share of patch `p`'s power each link end carries (`1/H_p`, or
/// `1/E[H_p]` without the patch-size correction), and the area its
/// irradiance is over (`A_eff = A_p·H_p/E[H_p]`, or `A_p`): computed from
/// the archive's columns where they are needed rather than kept (8 bytes a
/// patch), the same bits every time.
#[inline]
fn share_and_area(v: &InetView<'_>, opts: &DistributeOptions, p: usize) -> (f32, f32) {
    let (h, hx, a) = (v.patch_hits[p] as f32, v.patch_expected_hits[p], v.patch_area[p]);
    if opts.patch_size_correction {
        (if h > 0.0 { 1.0 / h } else { 0.0 }, if h > 0.0 && hx > 0.0 { a * h / hx } else { a })
    } else {
        (if hx > 0.0 { 1.0 / hx } else { 0.0 }, a)
    }
}

/// Each patch's surface, through its primitive: nothing per patch is kept
/// for what the archive's two columns give.
#[derive(Clone, Copy)]
struct PatchSurfaces<'a> {
    patch_primitive: &'a [u32],
    primitives: &'a [crate::archive::layout::PrimitiveRecord],
}

impl PatchSurfaces<'_> {
    /// Patch `p`'s surface.
    #[inline]
    fn of(&self, p: usize) -> usize {
        self.primitives[self.patch_primitive[p] as usize].surface as usize
    }

    /// Patches.
    fn len(&self) -> usize {
        self.patch_primitive.len()
    }
}

/// Per-patch reflectance and emitted radiance, from primitive → surface.
pub fn patch_materials(v: &InetView<'_>, lighting: &Lighting) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    let surface = |prim: u32| v.primitives[prim as usize].surface as usize;
    let rho = v.patch_primitive.iter().map(|&p| lighting.reflectance[surface(p)]).collect();
    let emit = v.patch_primitive.iter().map(|&p| lighting.emission[surface(p)]).collect();
    (rho, emit)
}

/// Runs the energy balance on an archive's links.
pub fn distribute(
    v: &InetView<'_>,
    opts: &DistributeOptions,
    progress: &dyn Progress,
) -> Result<Solution, DistributeError> {
    distribute_frame(v, 0, opts, progress)
}

/// Runs the energy balance for `frame` of a sequence archive (frame 0 for a
/// still): frame 0's links plus the frame's delta; patches of temporal
/// instances absent from the frame neither emit nor take part.
pub fn distribute_frame(
    v: &InetView<'_>,
    frame: u32,
    opts: &DistributeOptions,
    progress: &dyn Progress,
) -> Result<Solution, DistributeError> {
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
) -> Result<Solution, DistributeError> {
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
) -> Result<Solution, DistributeError> {
    Distributor::new(v, opts, lighting)?.frame(frame, start, progress)
}

/// One pass over frame 0's link ends (this member's receivers' only, in a
/// team, the rest from the others): per patch the rays that link, and
/// whether frame 0's links reach it (link ends of its own or at another's
/// end: the same, when every link is stored at both ends).
fn linked_and_reached(
    v: &InetView<'_>,
    parts: &[std::ops::Range<usize>],
    team: Option<&dyn Team>,
) -> Result<(Vec<f64>, Vec<bool>), ArchiveError> {
    let n = v.patch_count();
    let own = parts[team.map_or(0, |t| t.rank())].clone();
    let mut linked = vec![0.0f64; n];
    let mut in_base = vec![false; n];
    v.links.for_each_window_in(Columns::GATHER, n, own, |w| {
        for q in w.patches.clone() {
            linked[q] = w.weight.slice(w.row(q)).iter().map(|x| x as f64).sum();
            in_base[q] |= linked[q] > 0.0;
            for run in w.runs_of(q) {
                for &o in run.ids().ids() {
                    in_base[run.base() + o as usize] = true;
                }
            }
        }
        Ok::<(), ArchiveError>(())
    })?;
    if let Some(t) = team.filter(|t| t.size() > 1) {
        t.share_f64(&mut linked, parts);
        let mut flags: Vec<u8> = in_base.iter().map(|&b| b as u8).collect();
        t.max_u8(&mut flags);
        in_base = flags.iter().map(|&b| b != 0).collect();
    }
    Ok((linked, in_base))
}

/// What distributing light over one archive needs whatever the frame:
/// per-patch reflectance, emission and link shares, and the bucket rings,
/// computed once and reused for every frame of a sequence.
pub struct Distributor<'a> {
    /// Distinct for every distributor made in the process (a warm start
    /// reuses only its own distributor's totals).
    id: u64,
    v: InetView<'a>,
    opts: DistributeOptions,
    linked: Vec<f64>,
    /// Whether light is sorted into buckets (and spread, §3.4).
    use_buckets: bool,
    /// Per patch, whether frame 0's links reach it (see [`Self::sparse_jump`]).
    in_base: Vec<bool>,
    nb: usize,
    rings: Option<buckets::Rings<'a>>,
    patch_surface: PatchSurfaces<'a>,
    emission_fixed: Vec<bool>,
    /// The lighting's emitted radiance and `k_d` per surface.
    surface_emission: Vec<[f32; 3]>,
    surface_reflectance: Vec<[f32; 3]>,
    surface_specular: Vec<[f32; 3]>,
    nd: Option<nondiffuse::NonDiffuse<'a>>,
    /// Patches of instances present at frame 0 but not in every frame,
    /// with the last frame they are present in: their frame 0 link ends
    /// are not links of the later frames.
    leaving: Vec<(u32, u32)>,
    /// Their frame 0 link ends.
    leaving_rows: LinkRows,
    /// Time spent in the gathers over frame 0's links (ns), and the ends
    /// they read: the gather's own throughput, apart from the per-patch
    /// work of an iteration (measurement only; nothing depends on it).
    gather_ns: std::sync::atomic::AtomicU64,
    gather_ends: std::sync::atomic::AtomicU64,
    /// The processes sharing this distribution, if any (`team.rs`).
    team: Option<&'a dyn Team>,
    /// Each member's receivers (one range, `0..n`, without a team).
    parts: Vec<std::ops::Range<usize>>,
    /// Bytes received from the other members, and the time spent
    /// exchanging (ns): measurement only.
    exchanged_bytes: std::sync::atomic::AtomicU64,
    exchange_ns: std::sync::atomic::AtomicU64,
    exchanges: std::sync::atomic::AtomicU64,
    /// Where an iteration keeps its secant pairs and received totals when
    /// not in memory ([`Self::spill_in`]).
    spill: Option<std::path::PathBuf>,
}

impl<'a> Distributor<'a> {
    /// Keeps each frame's Anderson secant pairs and received totals in
    /// unnamed scratch files in `dir` instead of memory (`spill.rs`): 84
    /// bytes a patch fewer at the default depth, for a few sequential
    /// passes over them per iteration. The solutions are the same, bit for
    /// bit. A render under a tight memory budget asks for it
    /// ([`crate::render::plan::MemoryPlan::spill`]).
    pub fn spill_in(mut self, dir: &std::path::Path) -> Self {
        self.spill = Some(dir.to_path_buf());
        self
    }

    /// Prepares `v` with `lighting` (one entry per surface).
    pub fn new(v: &InetView<'a>, opts: &DistributeOptions, lighting: &Lighting) -> Result<Self, DistributeError> {
        Self::new_in(v, opts, lighting, None)
    }

    /// [`Self::new`] as one member of `team` (see `team.rs`): this process
    /// reads and gathers over the link ends of its own receivers only, and
    /// every member's solutions are the same, bit for bit, as one
    /// process's. Every member must make its distributor, and then solve
    /// the same frames in the same order.
    pub fn new_in(
        v: &InetView<'a>,
        opts: &DistributeOptions,
        lighting: &Lighting,
        team: Option<&'a dyn Team>,
    ) -> Result<Self, DistributeError> {
        let n = v.patch_count();
        let parts = team::receiver_ranges(v.link_offsets, team.map_or(1, |t| t.size()));
        let given = lighting.emission.len().min(lighting.reflectance.len()).min(lighting.specular.len());
        let longest = lighting.emission.len().max(lighting.reflectance.len()).max(lighting.specular.len());
        if given != v.surfaces.len() || longest != v.surfaces.len() {
            return Err(DistributeError::LightingMismatch { surfaces: v.surfaces.len(), given });
        }
        let use_buckets = opts.buckets && v.build.max_bucket > 0;
        let (linked, in_base) = linked_and_reached(v, &parts, team)?;
        let nb = if use_buckets { v.build.max_bucket as usize + 1 } else { 1 };
        let rings = match use_buckets {
            true => Some(
                buckets::Rings::new(v.adjacency_offsets, v.adjacency, nb - 1)
                    .map_err(|e| DistributeError::Archive(ArchiveError::Corrupt(e)))?,
            ),
            false => None,
        };
        let patch_surface = PatchSurfaces { patch_primitive: v.patch_primitive, primitives: v.primitives };
        let emission_fixed = lighting.emission_fixed.clone();
        if let Some(r) = v.reflectance
            && (r.patches.len() as u64) * (v.directions.len() as u64) >= u32::MAX as u64
        {
            return Err(DistributeError::TooLarge(format!(
                "{} non-diffuse patches × {} directions exceed what the distribution indexes (2³²)",
                r.patches.len(),
                v.directions.len()
            )));
        }
        let nd = nondiffuse::NonDiffuse::new(v, &lighting.specular)?;
        // Patches of instances present at frame 0 but not in every frame,
        // with the last frame they are present in.
        let leaving: Vec<(u32, u32)> = match &v.sequence {
            Some(s) => {
                let spans = v.primitive_spans();
                (0..n as u32)
                    .filter_map(|p| {
                        let span = spans[v.patch_primitive[p as usize] as usize];
                        let leaves = span.first == 0 && span.last + 1 < s.frames();
                        let ends = v.link_offsets[p as usize + 1] - v.link_offsets[p as usize];
                        (leaves && ends > 0).then_some((p, span.last))
                    })
                    .collect()
            }
            None => Vec::new(),
        };
        let leaving_rows = v.link_rows(&leaving.iter().map(|l| l.0).collect::<Vec<_>>())?;
        static NEXT_ID: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        Ok(Self {
            id: NEXT_ID.fetch_add(1, std::sync::atomic::Ordering::Relaxed),
            v: *v,
            opts: *opts,
            linked,
            use_buckets,
            in_base,
            nb,
            rings,
            patch_surface,
            emission_fixed,
            surface_emission: lighting.emission.clone(),
            surface_reflectance: lighting.reflectance.clone(),
            surface_specular: lighting.specular.clone(),
            nd,
            leaving,
            leaving_rows,
            gather_ns: Default::default(),
            gather_ends: Default::default(),
            team,
            parts,
            exchanged_bytes: Default::default(),
            exchange_ns: Default::default(),
            exchanges: Default::default(),
            spill: None,
        })
    }

    /// The receivers this process gathers for (all patches without a
    /// team).
    pub fn own_receivers(&self) -> std::ops::Range<usize> {
        self.parts[self.team.map_or(0, |t| t.rank())].clone()
    }

    /// The link ends of this process's receivers.
    fn own_ends(&self) -> u64 {
        let own = self.own_receivers();
        self.v.link_offsets[own.end] - self.v.link_offsets[own.start]
    }

    /// Bytes received from the other members of the team and seconds
    /// spent exchanging, over every frame so far (zero without a team).
    pub fn exchange_totals(&self) -> (u64, f64) {
        use std::sync::atomic::Ordering::Relaxed;
        (self.exchanged_bytes.load(Relaxed), self.exchange_ns.load(Relaxed) as f64 * 1e-9)
    }

    /// Exchanges made so far (one a gather, with a team).
    pub fn exchanges(&self) -> u64 {
        self.exchanges.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// The team this distribution is shared with, if any.
    pub fn team(&self) -> Option<&'a dyn Team> {
        self.team
    }

    /// Gives the other members of the team what this one's receivers got
    /// (`recv`, `nb` slots a patch), and takes theirs: after it every
    /// member's `recv` is whole.
    fn share_received(&self, recv: &mut [[f32; 3]]) {
        let Some(t) = self.team.filter(|t| t.size() > 1) else { return };
        use std::sync::atomic::Ordering::Relaxed;
        let started = std::time::Instant::now();
        let per_patch = self.nb * 3;
        t.share_f32(bytemuck::cast_slice_mut(recv), &team::scaled(&self.parts, per_patch));
        let own = self.own_receivers().len();
        let bytes = ((self.v.patch_count() - own) * per_patch * 4) as u64;
        self.exchanged_bytes.fetch_add(bytes, Relaxed);
        self.exchange_ns.fetch_add(started.elapsed().as_nanos() as u64, Relaxed);
        self.exchanges.fetch_add(1, Relaxed);
    }

    /// Reflectance `k_d` of patch `p` (its surface's: nothing per patch
    /// is kept that the surface tables give).
    #[inline]
    fn rho(&self, p: usize) -> [f32; 3] {
        self.surface_reflectance[self.patch_surface.of(p)]
    }

    /// The share of patch `p`'s power that meets back faces (`PBAK ·
    /// share`; `None` for files without `PBAK`).
    #[inline]
    fn back_share(&self, p: usize) -> Option<f32> {
        self.v.patch_back_hits.map(|b| b[p] as f32 * self.share(p))
    }

    /// Share of patch `p`'s power each of its link ends carries.
    #[inline]
    fn share(&self, p: usize) -> f32 {
        share_and_area(&self.v, &self.opts, p).0
    }

    /// The area patch `p`'s irradiance is over (`A_eff`).
    #[inline]
    fn area_eff(&self, p: usize) -> f32 {
        share_and_area(&self.v, &self.opts, p).1
    }

    /// Seconds spent in the gathers over frame 0's link ends and the ends
    /// they read, over every frame so far: the gather's throughput, apart
    /// from the per-patch work of each iteration (which grows with
    /// patches, not links).
    pub fn gather_totals(&self) -> (f64, u64) {
        use std::sync::atomic::Ordering::Relaxed;
        (self.gather_ns.load(Relaxed) as f64 * 1e-9, self.gather_ends.load(Relaxed))
    }

    /// Distributes light for `frame` (0 for a still), warm-started from
    /// `start` when given (see [`distribute_frame_from`] and `warm.rs`).
    pub fn frame(
        &self,
        frame: u32,
        start: Option<&Solution>,
        progress: &dyn Progress,
    ) -> Result<Solution, DistributeError> {
        let setup = self.setup(frame)?;
        let warm = warm::WarmStart::choose(self, &setup, frame, start);
        let mut iteration = step::Iteration::new(self, &setup, warm, start)?;
        progress.start("distributing light", 0);
        while iteration.wants_step() {
            if progress.cancelled() {
                progress.finish();
                return Err(DistributeError::Cancelled);
            }
            iteration.step()?;
            progress.advance(1);
        }
        progress.finish();
        iteration.finish(frame)
    }
}
