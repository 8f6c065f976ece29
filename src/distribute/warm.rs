//! Warm starts: a frame of a sequence starts from an earlier frame's light.
//!
//! The balance is linear, `O = E + ρ·G(O)` for the power `O` patches send
//! out: the first iteration sends a guess `O₀` and keeps the residual
//! `E + ρ·G(O₀) − O₀` (which may be negative) as unshot power, so the
//! iteration converges to the same answer, in fewer iterations when the
//! guess is close. The energy bookkeeping stays exact.
//!
//! * [`WarmStart::Cold`]: no guess; the first step sends the emission.
//! * [`WarmStart::Guess`]: `O₀ = E + ρ·received(start)`, then a full gather.
//! * [`WarmStart::SparseJump`]: from this [`Distributor`]'s own earlier
//!   frame, whose totals it kept ([`Carry`]): the first send is what that
//!   frame sent in all, plus the change in emission, and the light it
//!   delivers is that frame's total received light, plus this frame's
//!   overlay applied to it, minus that frame's overlay applied to that
//!   frame's light: two sparse gathers instead of a full one.

use std::sync::Arc;

use super::overlay::Ends;
use super::setup::FrameSetup;
use super::{Distributor, Solution};
use crate::archive::layout::InstanceRecord;

/// Sparse warm jumps in a row before a full gather (see [`Carry::chain`]).
pub(super) const MAX_SPARSE_CHAIN: u32 = 32;

/// A frame's totals kept for the next frame's warm start (diffuse archives):
/// everything sent and received over its iterations, its overlay and
/// emission. Because the balance is linear, `received = G(sent)` for the
/// frame's link operator G, so the next frame's operator applied to (nearly)
/// the same power differs from `received` only through the two frames'
/// overlays (see [`Distributor::sparse_jump`]).
pub(super) struct Carry {
    /// The [`Distributor`] that made it (sums from another archive, options
    /// or link set are not reused).
    pub distributor: u64,
    /// Frame.
    pub frame: u32,
    /// Sparse jumps in a row that led to this frame: rounding in the sums
    /// is carried from jump to jump, so every [`MAX_SPARSE_CHAIN`]-th frame
    /// gathers in full.
    pub chain: u32,
    /// Σ power sent over the iterations, per patch (f64: the sums are
    /// carried from frame to frame).
    pub sent: Vec<[f64; 3]>,
    /// Σ power received over the iterations, per patch and bucket (before
    /// spreading).
    pub received: Vec<[f64; 3]>,
    /// Power emitted per patch (the frame's emission).
    pub emitted: Vec<[f32; 4]>,
    /// The frame's overlay of present ends (None for frame 0 of a still).
    pub overlay: Option<Arc<Ends>>,
}

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

/// How a frame's iteration starts (module docs).
pub(super) enum WarmStart<'s> {
    /// From zero: the first step sends the emission.
    Cold,
    /// The first step sends this guess, then gathers in full.
    Guess(Vec<[f32; 4]>),
    /// The first step sends `send` and finds what it delivers from
    /// `carry`'s totals and the two frames' overlays.
    SparseJump {
        /// The earlier frame's totals.
        carry: &'s Carry,
        /// The first send.
        send: Vec<[f32; 4]>,
    },
}

impl<'s> WarmStart<'s> {
    /// The warm start for `frame`, set up as `s`, from `start` (typically
    /// the previous frame's solution), or [`WarmStart::Cold`].
    pub fn choose(d: &Distributor<'_>, s: &FrameSetup<'_>, frame: u32, start: Option<&'s Solution>) -> Self {
        let n = d.v.patch_count();
        let emitted_total = s.emitted_total();
        let carry = start
            .and_then(|st| st.carry.as_deref())
            .filter(|c| d.nd.is_none() && emitted_total > 0.0 && c.distributor == d.id && c.chain < MAX_SPARSE_CHAIN);
        if let Some(c) = carry
            && let Some(send) = d.sparse_jump(c, frame, &s.emitted_powers(), s.absent_mask())
        {
            return Self::SparseJump { carry: c, send };
        }
        match start.filter(|st| st.received.len() == n && emitted_total > 0.0) {
            Some(st) => Self::Guess(d.guess(st, frame, s)),
            None => Self::Cold,
        }
    }

    /// What the first step sends, unless cold.
    pub fn first_send(&self) -> Option<&[[f32; 4]]> {
        match self {
            Self::Cold => None,
            Self::Guess(g) => Some(g),
            Self::SparseJump { send, .. } => Some(send),
        }
    }

    /// The carried totals of a sparse jump.
    pub fn carry(&self) -> Option<&'s Carry> {
        match self {
            Self::SparseJump { carry, .. } => Some(carry),
            _ => None,
        }
    }
}

impl Distributor<'_> {
    /// `O₀ = E + ρ·received(start)` on the patches that emit or link;
    /// patches that enter take what the same cell of the instance they
    /// replace received.
    fn guess(&self, start: &Solution, frame: u32, s: &FrameSetup<'_>) -> Vec<[f32; 4]> {
        let n = self.v.patch_count();
        let mut source: Vec<u32> = (0..n as u32).collect();
        for (p, q) in self.predecessors(start.frame, frame) {
            source[p as usize] = q;
        }
        (0..n)
            .map(|p| {
                let e = s.emitted_power(p);
                let r = start.received[source[p] as usize];
                let rho = self.rho(p);
                let on = e[0] + e[1] + e[2] > 0.0 || s.linked[p] > 0.0;
                if on { [e[0] + rho[0] * r[0], e[1] + rho[1] * r[1], e[2] + rho[2] * r[2], 0.0] } else { [0.0; 4] }
            })
            .collect()
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
    pub(super) fn sparse_jump(
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
        let presence_e = self.v.sequence.map(|_| self.v.presence(c.frame));
        let present_e = presence_e.as_ref().map(|p| &p.patches[..]);
        let here = |set: Option<&[bool]>, p: usize| set.is_none_or(|s| s[p]);
        let sent = |q: usize, k: usize| if k < 3 { c.sent[q][k] as f32 } else { 0.0 };
        let mut x = vec![[0.0f32; 4]; n];
        for p in 0..n {
            let (in_e, in_f) = (here(present_e, p), here(present, p));
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
        let patches_of = |i: &InstanceRecord| {
            let prims = i.primitive_range();
            let start = v.primitives[prims.start].first_patch;
            let stop = v.primitives.get(prims.end).map_or(n, |p| p.first_patch);
            start..stop
        };
        let grids = |i: &InstanceRecord| {
            v.primitives[i.primitive_range()].iter().map(|p| (p.kind, p.grid_u, p.grid_v, p.cell_order))
        };
        let mut out = Vec::new();
        for i in s.instances.iter().filter(|i| i.span().contains(frame) && !i.span().contains(earlier)) {
            let Some(j) = s.instances.iter().find(|j| j.surface == i.surface && j.span().contains(earlier)) else {
                continue;
            };
            let (pi, pj) = (patches_of(i), patches_of(j));
            if i.primitive_count == j.primitive_count && pi.len() == pj.len() && grids(i).eq(grids(j)) {
                out.extend(pi.zip(pj));
            }
        }
        out
    }
}
