//! The iteration: one frame's state vectors and the step that the
//! distribution loop repeats until the unshot power is below tolerance.
//!
//! A step chooses what to send (the warm start's guess first, else the
//! unshot power, or Anderson's mix of it with earlier steps), turns it into
//! the per-end shares patches shoot, gathers what every patch receives
//! over its link ends (frame 0's CSR, the frame's overlay, the correction
//! list of non-diffuse senders), spreads bucketed light over rings of
//! neighbours, and reflects: `ρ` of what arrived becomes new unshot power,
//! the rest is absorbed; non-diffuse patches add what arrived to what waits
//! for their next table step ([`Glossy`]). Each of those is one small
//! method below; the kernels they call are in `kernels.rs`.

use rayon::prelude::*;

use super::anderson::{Anderson, Half, to_half};
use super::kernels::{BLOCK, PackedRgb, StateRows, add_ends, gather, silence_absent};
use super::setup::FrameSetup;
use super::spill::{BlockMut, PatchVec, scratch_error};
use super::totals;
use super::warm::{Carry, WarmStart};
use super::{DirectionalRadiance, DistributeError, Distributor, EnergyBalance, Solution};
use crate::archive::Columns;

/// Per-ray state of the non-diffuse patches (`nondiffuse.rs`).
///
/// Their tables are read only in *table steps*. Between two, what arrives
/// at them waits: `shot` sums what patches sent (the diffuse shares of
/// every step since the last table step) and the next table step reflects
/// all of it at once; by linearity that is the same light as reflecting
/// each step's arrivals as they come. With
/// [`super::DistributeOptions::defer_glossy`] a table step is taken only
/// when what waits outweighs the diffuse residual, and the diffuse steps
/// between are Anderson-accelerated; without it, every step is one. What
/// still waits when the loop stops (within the tolerance, when it
/// converged) is counted as absorbed.
struct Glossy {
    /// Per-ray directional power made by the last table step: shot once,
    /// in the step after it (`unsent` until then), and read again by the
    /// next table step as what non-diffuse senders delivered.
    phi: Vec<[f32; 4]>,
    /// Whether `phi` is still to be shot.
    unsent: bool,
    /// Per patch, what it shot (`send · U_p/H_p`) summed over the steps
    /// since the last table step.
    shot: Vec<[f32; 4]>,
    /// A bound on the power the arrivals since the last table step will
    /// reflect into directions: `k_s` times the largest albedo of the
    /// patch's table, times what arrived (all bands summed).
    waiting: f64,
    /// The next step's, swapped in after each step.
    phi_next: Vec<[f32; 4]>,
    /// The running total of `phi` as radiance (the view-dependent term of
    /// §3.5), the solution's directional radiance when the loop ends.
    radiance: Vec<[f32; 3]>,
    /// Per non-diffuse patch, the power its last reflection carries.
    pending: Vec<[f64; 3]>,
}

/// One frame's iteration state.
pub(super) struct Iteration<'d, 'f, 's> {
    d: &'d Distributor<'d>,
    s: &'f FrameSetup<'d>,
    warm: WarmStart<'s>,
    /// The residual: power still to send.
    unshot: Vec<[f32; 3]>,
    /// What this step sends: the residual itself, the warm guess first, or
    /// Anderson's mixed step.
    send: Vec<[f32; 3]>,
    /// `send` per link end (`send · U_p/H_p`), what the gathers read: RGB
    /// packed, 12 bytes a patch.
    packed: PackedRgb,
    /// Received per patch and bucket.
    recv: Vec<[f32; 3]>,
    /// Received power over the iterations: what hit the patch itself
    /// (bucket 0, whose density follows the patch's hit count) and what
    /// was spread onto it. Touched once per step, block by block: spilled
    /// to a scratch file with the secant pairs under a tight budget.
    total_direct: PatchVec<[f32; 3]>,
    total_spread: PatchVec<[f32; 3]>,
    /// Totals over the iterations, for the next frame's sparse jump
    /// (diffuse sequences only; empty otherwise).
    carrying: bool,
    sent_total: Vec<[f64; 3]>,
    received_total: Vec<[f64; 3]>,
    anderson: Anderson,
    glossy: Option<Glossy>,
    bal: EnergyBalance,
    /// Power still to send (summed over bands and patches), what waits at
    /// non-diffuse patches included: what convergence is judged on.
    residual_total: f64,
    /// Its diffuse part after the last step: what the acceleration's
    /// progress is judged on.
    diffuse_residual: f64,
    /// A mixed step leaves a residual shaped by the least-squares fit, not
    /// by the light: converged after one, the loop takes one plain step,
    /// which spreads what is left like plain iteration would (per-patch
    /// errors as small as plain iteration's at the same tolerance).
    last_mixed: bool,
}

impl<'d, 'f, 's> Iteration<'d, 'f, 's> {
    /// The state before the first step of frame `s`, started as `warm`
    /// (it fails only when a scratch file for the spilled state cannot be
    /// made).
    pub fn new(
        d: &'d Distributor<'d>,
        s: &'f FrameSetup<'d>,
        warm: WarmStart<'s>,
        start: Option<&Solution>,
    ) -> Result<Self, DistributeError> {
        let n = d.v.patch_count();
        let spill = d.spill.as_deref();
        let nb = d.nb;
        let carrying = d.nd.is_none() && d.v.sequence.is_some();
        // A warm start also starts from the previous frame's secant pairs:
        // its operator differs a little, but the pairs only steer the step,
        // and its slowest mode is this frame's too.
        let anderson = match start {
            Some(st) if warm.first_send().is_some() && st.history.fits(n, d.opts.anderson_depth) => {
                st.history.try_clone().map_err(|e| scratch_error(spill, e))?
            }
            _ => Anderson::new_in(if d.nd.is_none() || d.opts.defer_glossy { d.opts.anderson_depth } else { 0 }, spill),
        };
        let glossy = d.nd.as_ref().map(|x| {
            let nn = x.patches.len() * x.n;
            Glossy {
                phi: vec![[0.0; 4]; nn],
                unsent: false,
                shot: vec![[0.0; 4]; n],
                waiting: 0.0,
                phi_next: vec![[0.0; 4]; nn],
                radiance: vec![[0.0; 3]; nn],
                pending: vec![[0.0; 3]; x.patches.len()],
            }
        });
        let totals = || PatchVec::zeroed(n, spill).map_err(|e| scratch_error(spill, e));
        Ok(Self {
            d,
            s,
            warm,
            unshot: (0..n).map(|p| rgb(s.emitted_power(p))).collect(),
            send: vec![[0.0; 3]; n],
            packed: PackedRgb::new(n),
            recv: vec![[0.0; 3]; n * nb],
            total_direct: totals()?,
            total_spread: totals()?,
            carrying,
            sent_total: vec![[0.0; 3]; if carrying { n } else { 0 }],
            received_total: vec![[0.0; 3]; if carrying { n * nb } else { 0 }],
            anderson,
            glossy,
            bal: EnergyBalance { emitted: s.emitted, ..Default::default() },
            residual_total: s.emitted_total(),
            diffuse_residual: s.emitted_total(),
            last_mixed: false,
        })
    }

    /// Whether the residual is within tolerance.
    fn converged(&self) -> bool {
        self.residual_total <= self.d.opts.tolerance * self.s.emitted_total()
    }

    /// Whether another step is due: not converged (or the last step was
    /// mixed) and within the iteration limit.
    pub fn wants_step(&self) -> bool {
        (!self.converged() || self.last_mixed) && self.bal.iterations < self.d.opts.max_iterations
    }

    /// One iteration (it fails only when streamed link ends cannot be read).
    pub fn step(&mut self) -> Result<(), DistributeError> {
        let warm_jump = self.bal.iterations == 0 && self.warm.first_send().is_some();
        let converged = self.converged();
        self.choose_send(warm_jump, converged)?;
        self.last_mixed = !warm_jump && !converged && self.anderson.pairs() > 0;
        // Directional light shot this step does not come from `send`: the
        // step's change of the residual is no secant pair of the diffuse map.
        let injected = self.glossy.as_ref().is_some_and(|g| g.unsent);
        self.shoot();
        self.escape_directional();
        match self.warm.carry() {
            Some(c) if warm_jump => self.gather_sparse(c),
            _ => self.gather_full()?,
        }
        if let Some(g) = self.glossy.as_mut() {
            g.unsent = false;
        }
        self.add_to_carry();
        self.residual_total = 0.0;
        // The step's secant pair, unless it mixed in light that `send`
        // did not make (the warm jump's, a table step's).
        let recording = !warm_jump && !injected;
        self.reflect(recording)?;
        let previous_diffuse = std::mem::replace(&mut self.diffuse_residual, self.residual_total);
        self.reflect_directional();
        if let Some(g) = &self.glossy {
            self.residual_total += g.waiting;
        }
        if recording {
            if self.diffuse_residual < previous_diffuse {
                self.anderson.commit();
            } else {
                self.anderson.reset();
            }
        }
        self.bal.iterations += 1;
        Ok(())
    }

    /// Sets `send`: the warm start's first send, the residual (a plain
    /// step), or Anderson's mix.
    fn choose_send(&mut self, warm_jump: bool, converged: bool) -> Result<(), DistributeError> {
        match self.warm.first_send() {
            Some(g) if warm_jump => self.send.iter_mut().zip(g).for_each(|(s, g)| *s = rgb(*g)),
            _ if converged => self.send.copy_from_slice(&self.unshot),
            _ => {
                let spill = self.d.spill.as_deref();
                self.anderson.step(&self.unshot, &mut self.send).map_err(|e| scratch_error(spill, e))?
            }
        }
        // A mixed step may hand absent patches (present in an earlier
        // frame of the history) something to send: they send nothing.
        if let Some(present) = self.s.absent_mask() {
            for (s, _) in self.send.iter_mut().zip(present).filter(|(_, here)| !**here) {
                *s = [0.0; 3];
            }
        }
        Ok(())
    }

    /// `shoot = send · share` per patch (into `packed`); the shares of
    /// ends that link nowhere have escaped. Per-patch passes run in
    /// parallel blocks; their sums are added in block order, so the result
    /// does not depend on the threads.
    fn shoot(&mut self) {
        let (d, linked, send) = (self.d, &self.s.linked, &self.send);
        let lost: Vec<[[f64; 3]; 2]> = self
            .packed
            .blocks_mut()
            .enumerate()
            .map(|(block, out)| {
                // [escaped, into back faces]
                let mut sum = [[0.0f64; 3]; 2];
                for (i, sh) in out.chunks_exact_mut(3).enumerate() {
                    let p = block * BLOCK + i;
                    let s = d.share(p);
                    let unlinked = 1.0 - linked[p] * s as f64;
                    let back = d.back_share(p).map_or(0.0, |b| (b as f64).min(unlinked).max(0.0));
                    for c in 0..3 {
                        sh[c] = send[p][c] * s;
                        sum[0][c] += send[p][c] as f64 * (unlinked - back);
                        sum[1][c] += send[p][c] as f64 * back;
                    }
                }
                sum
            })
            .collect();
        for [e, b] in &lost {
            for c in 0..3 {
                self.bal.escaped[c] += e[c];
                self.bal.back_faces[c] += b[c];
            }
        }
    }

    /// Directional power leaves along every ray of its direction; rays that
    /// reach no facing patch lose it.
    fn escape_directional(&mut self) {
        let (Some(x), Some(g)) = (self.d.nd.as_ref(), self.glossy.as_mut()) else { return };
        if !g.unsent {
            return;
        }
        let (n, linked_dir, phi, back_rays) = (x.n, &self.s.linked_dir, &g.phi, &x.back_rays);
        // Per patch in parallel; the sums are added in patch order.
        let lost: Vec<[[f64; 3]; 2]> = g
            .pending
            .par_iter_mut()
            .enumerate()
            .map(|(k, pending)| {
                let (mut sent, mut back) = ([0.0f64; 3], [0.0f64; 3]);
                for o in 0..n {
                    let l = linked_dir[k * n + o];
                    if l != 0.0 {
                        for c in 0..3 {
                            sent[c] += (l * phi[k * n + o][c]) as f64;
                        }
                    }
                    if let Some(&b) = back_rays.get(k * n + o)
                        && b != 0.0
                    {
                        for c in 0..3 {
                            back[c] += (b * phi[k * n + o][c]) as f64;
                        }
                    }
                }
                let unlinked = [0, 1, 2].map(|c| pending[c] - sent[c]);
                let back = [0, 1, 2].map(|c| back[c].min(unlinked[c]).max(0.0));
                *pending = [0.0; 3];
                [[0, 1, 2].map(|c| unlinked[c] - back[c]), back]
            })
            .collect();
        for [e, b] in &lost {
            for c in 0..3 {
                self.bal.escaped[c] += e[c];
                self.bal.back_faces[c] += b[c];
            }
        }
    }

    /// The sparse jump's gather: `G_f(X) = G_e(S) + overlay_f(X) −
    /// overlay_e(S)` for the earlier frame e (see
    /// `Distributor::sparse_jump`).
    fn gather_sparse(&mut self, c: &Carry) {
        let (nb, s) = (self.d.nb, self.s);
        for (r, t) in self.recv.iter_mut().zip(&c.received) {
            *r = t.map(|c| c as f32);
        }
        if let Some(o) = &s.overlay {
            add_ends(&o.gather, nb, self.packed.rows(), 1.0, None, &mut self.recv);
        }
        if let Some(e) = &c.overlay {
            let shoot_e: Vec<[f32; 4]> = c
                .sent
                .iter()
                .enumerate()
                .map(|(p, x)| {
                    let s = self.d.share(p);
                    [x[0] as f32 * s, x[1] as f32 * s, x[2] as f32 * s, 0.0]
                })
                .collect();
            add_ends(e, nb, &shoot_e[..], -1.0, None, &mut self.recv);
        }
        silence_absent(s.absent_mask(), nb, &mut self.recv);
        self.bal.ends_gathered += [s.overlay.as_ref().map(|o| &o.gather), c.overlay.as_ref()]
            .iter()
            .flatten()
            .map(|e| e.other.len() as u64)
            .sum::<u64>();
    }

    /// Gathers what patches shoot (`packed`) over frame 0's links into
    /// `recv`, window by window.
    fn gather_base(&mut self, present: Option<&[bool]>) -> Result<(), DistributeError> {
        let (d, nb) = (self.d, self.d.nb);
        let (shoot, recv) = (self.packed.rows(), &mut self.recv);
        // Resident ends are one window, split over the workers; streamed
        // windows are each one worker's, unless fewer are held at once
        // than there are workers (few windows, or a budget with room for
        // few): then a window's patches are split too.
        let own = d.own_receivers();
        let parallel = match d.v.links {
            crate::archive::Links::Resident(_) => true,
            crate::archive::Links::Streamed(s, _) => {
                s.windows_in_flight().min(s.windows_meeting(&own)) < rayon::current_num_threads()
            }
        };
        // This process's receivers only (all of them without a team); the
        // team's other members send theirs.
        let mine = &mut recv[own.start * nb..own.end * nb];
        d.v.links.for_each_window_par(Columns::GATHER, d.v.patch_count(), own, mine, nb, |w, out| {
            gather(&w, nb, present, shoot, out, parallel);
            Ok::<(), DistributeError>(())
        })?;
        d.share_received(recv);
        Ok(())
    }

    /// The full gather: frame 0's links, the frame's overlay, and what
    /// non-diffuse senders send along their ends.
    fn gather_full(&mut self) -> Result<(), DistributeError> {
        let (d, s, nb) = (self.d, self.s, self.d.nb);
        let v = &d.v;
        let present = s.absent_mask();
        let started = std::time::Instant::now();
        let exchanging = d.exchange_totals().1;
        self.gather_base(present)?;
        {
            // The gather's own time: without the team's exchange.
            use std::sync::atomic::Ordering::Relaxed;
            let exchange = d.exchange_totals().1 - exchanging;
            let gather = (started.elapsed().as_secs_f64() - exchange).max(0.0);
            d.gather_ns.fetch_add((gather * 1e9) as u64, Relaxed);
            d.gather_ends.fetch_add(d.own_ends(), Relaxed);
        }
        // Directional light is shot once, the step after the table step
        // that made it.
        let nd_phi = d.nd.as_ref().zip(self.glossy.as_ref()).filter(|(_, g)| g.unsent).map(|(x, g)| (x, &g.phi[..]));
        if let Some(o) = &s.overlay {
            add_ends(&o.gather, nb, self.packed.rows(), 1.0, nd_phi.map(|(x, phi)| x.senders(phi)), &mut self.recv);
        }
        if let Some((x, phi)) = nd_phi {
            x.gather_corrections(nb, d.use_buckets, phi, &mut self.recv);
            silence_absent(present, nb, &mut self.recv);
        }
        self.bal.ends_gathered += (v.link_end_count() + s.overlay.as_ref().map_or(0, |o| o.gather.other.len())) as u64;
        Ok(())
    }

    /// Light that arrived at patch `p`'s rings in wide buckets, spread
    /// onto it (§3.4): computed where it is used, not kept.
    #[inline]
    fn spread_onto(d: &Distributor<'_>, recv: &[[f32; 3]], p: usize) -> [f32; 3] {
        match &d.rings {
            Some(rings) if d.use_buckets => rings.spread_onto(recv, d.nb, p),
            _ => [0.0; 3],
        }
    }

    /// Adds what this step sent and received to the totals a sparse jump
    /// of the next frame starts from.
    fn add_to_carry(&mut self) {
        if !self.carrying {
            return;
        }
        let nb = self.d.nb;
        fn add<const L: usize>((t, x): (&mut [[f64; 3]], &[[f32; L]])) {
            for (t, x) in t.iter_mut().zip(x) {
                for c in 0..3 {
                    t[c] += x[c] as f64;
                }
            }
        }
        self.sent_total.par_chunks_mut(BLOCK).zip(self.send.par_chunks(BLOCK)).for_each(add);
        self.received_total.par_chunks_mut(BLOCK * nb).zip(self.recv.par_chunks(BLOCK * nb)).for_each(add);
    }

    /// Non-diffuse patches add what arrived this step to what waits, and
    /// when it is time (see [`Glossy`]) reflect all of it along each
    /// direction through their tables (Figure 9) into the per-ray power the
    /// next step shoots. Called after [`Self::reflect`], whose residual
    /// (the diffuse power still to send) it weighs what waits against.
    fn reflect_directional(&mut self) {
        let (Some(x), Some(g)) = (self.d.nd.as_ref(), self.glossy.as_mut()) else { return };
        let nb = self.d.nb;
        let shoot = self.packed.rows();
        for (p, t) in g.shot.iter_mut().enumerate() {
            let s = shoot.row(p);
            for c in 0..3 {
                t[c] += s[c];
            }
        }
        for (k, &q) in x.patches.iter().enumerate() {
            let arrived = &self.recv[q as usize * nb..(q as usize + 1) * nb];
            let bound = x.reflect_bound(k);
            for c in 0..3 {
                let a: f32 = arrived.iter().map(|r| r[c]).sum();
                g.waiting += (a.abs() * bound[c]) as f64;
            }
        }
        let table_step = !self.d.opts.defer_glossy || g.waiting >= self.residual_total;
        if !table_step {
            return;
        }
        g.waiting = 0.0;
        let overlay_ends = overlay_ends(self.s);
        let totals = x.step(&g.shot[..], &g.phi, &overlay_ends, &mut g.phi_next);
        std::mem::swap(&mut g.phi, &mut g.phi_next);
        g.shot.fill([0.0; 4]);
        g.unsent = true;
        self.bal.table_steps += 1;
        // Absent non-diffuse patches keep nothing to send: `step` walks
        // their frame 0 ends too, and what it finds there is not light of
        // this frame (the senders counted those ends as escaped,
        // `absent_ends`).
        let present = self.s.absent_mask();
        if let Some(present) = present {
            for (k, &q) in x.patches.iter().enumerate() {
                if !present[q as usize] {
                    g.phi[k * x.n..(k + 1) * x.n].fill([0.0; 4]);
                }
            }
        }
        let n = x.n;
        g.radiance.par_chunks_mut(n).zip(g.phi.par_chunks(n)).enumerate().for_each(|(k, (t, p))| {
            let to_l = x.ray_to_radiance(k);
            for (t, p) in t.iter_mut().zip(p) {
                for c in 0..3 {
                    t[c] += p[c] * to_l;
                }
            }
        });
        for (k, t) in totals.iter().enumerate() {
            if present.is_some_and(|p| !p[x.patches[k] as usize]) {
                g.pending[k] = [0.0; 3];
                continue;
            }
            g.pending[k] = t.reflected;
            for c in 0..3 {
                self.bal.absorbed[c] -= t.reflected[c];
                self.residual_total += t.reflected[c].abs();
            }
        }
    }

    /// Every patch reflects `ρ` of what it received (direct and spread) as
    /// new unshot power and absorbs the rest: `f(x + δ) = f(x) − δ + K·δ`.
    /// When `recording`, the step's secant pair (the change of the
    /// residual, and what was reflected) goes straight into Anderson's
    /// history.
    fn reflect(&mut self, recording: bool) -> Result<(), DistributeError> {
        let (d, nb, n) = (self.d, self.d.nb, self.unshot.len());
        let (recv, send) = (&self.recv, &self.send);
        let spill = d.spill.as_deref();
        let fail = |e| scratch_error(spill, e);
        // Per block of patches, its part of the pair's two vectors, and of
        // the totals.
        let slot = match recording {
            true => self.anderson.slot(n).map_err(fail)?,
            false => None,
        };
        type Pair<'a> = Option<(BlockMut<'a, [Half; 3]>, BlockMut<'a, [Half; 3]>)>;
        let pairs: Vec<Pair<'_>> = match slot {
            Some((df, kdx)) => df.blocks_mut(BLOCK).into_iter().zip(kdx.blocks_mut(BLOCK)).map(Some).collect(),
            None => (0..n.div_ceil(BLOCK)).map(|_| None).collect(),
        };
        let totals: Vec<_> =
            self.total_direct.blocks_mut(BLOCK).into_iter().zip(self.total_spread.blocks_mut(BLOCK)).collect();
        let sums: Result<Vec<([f64; 3], f64)>, std::io::Error> = (totals, pairs, self.unshot.par_chunks_mut(BLOCK))
            .into_par_iter()
            .enumerate()
            .map_init(Buffers::default, |b, (block, ((mut td, mut ts), mut pair, un))| {
                let (mut absorbed, mut residual) = ([0.0f64; 3], 0.0f64);
                {
                    let (tdv, tsv) = (td.open(true, &mut b.direct)?, ts.open(true, &mut b.spread)?);
                    let mut out = match pair.as_mut() {
                        Some((df, kdx)) => Some((df.open(false, &mut b.df)?, kdx.open(false, &mut b.kdx)?)),
                        None => None,
                    };
                    for i in 0..tdv.len() {
                        let p = block * BLOCK + i;
                        let (rho, spread) = (d.rho(p), Self::spread_onto(d, recv, p));
                        for c in 0..3 {
                            let direct = recv[p * nb][c];
                            let r = direct + spread[c];
                            tdv[i][c] += direct;
                            tsv[i][c] += spread[c];
                            let reflected = r * rho[c];
                            if let Some((df, kdx)) = out.as_mut() {
                                df[i][c] = to_half(reflected - send[p][c]);
                                kdx[i][c] = to_half(reflected);
                            }
                            un[i][c] = un[i][c] - send[p][c] + reflected;
                            absorbed[c] += (r - reflected) as f64;
                            residual += un[i][c].abs() as f64;
                        }
                    }
                }
                td.close(&b.direct)?;
                ts.close(&b.spread)?;
                if let Some((df, kdx)) = &pair {
                    df.close(&b.df)?;
                    kdx.close(&b.kdx)?;
                }
                Ok((absorbed, residual))
            })
            .collect();
        for (a, r) in &sums.map_err(fail)? {
            for c in 0..3 {
                self.bal.absorbed[c] += a[c];
            }
            self.residual_total += r;
        }
        Ok(())
    }

    /// Per patch, the radiance of the emitted light reflected once,
    /// `ρ·G(E)` over the area as in [`Self::finish`]: one gather of the
    /// emitted power over the frame's links (frame 0's, the overlay; the
    /// non-diffuse senders' directional light is not emission), spread
    /// over the rings like any other step's.
    fn first_bounce(&mut self) -> Result<Vec<[f32; 3]>, DistributeError> {
        let (d, s, nb) = (self.d, self.s, self.d.nb);
        let v = &d.v;
        let present = s.absent_mask();
        self.packed.blocks_mut().enumerate().for_each(|(block, out)| {
            for (i, sh) in out.chunks_exact_mut(3).enumerate() {
                let p = block * BLOCK + i;
                let (e, k) = (s.emitted_power(p), d.share(p));
                sh.copy_from_slice(&[e[0] * k, e[1] * k, e[2] * k]);
            }
        });
        self.gather_base(present)?;
        if let Some(o) = &s.overlay {
            add_ends(&o.gather, nb, self.packed.rows(), 1.0, None, &mut self.recv);
        }
        self.first_bounce_directional();
        let (inv_pi, recv) = (1.0 / std::f32::consts::PI, &self.recv);
        Ok((0..v.patch_count())
            .into_par_iter()
            .map(|p| {
                let (area_eff, rho) = (d.area_eff(p), d.rho(p));
                let kd = if area_eff > 0.0 { inv_pi / area_eff } else { 0.0 };
                let ks = if v.patch_area[p] > 0.0 { inv_pi / v.patch_area[p] } else { 0.0 };
                let spread = Self::spread_onto(d, recv, p);
                [0, 1, 2].map(|c| rho[c] * (recv[p * nb][c] * kd + spread[c] * ks))
            })
            .collect())
    }

    /// The directional part of [`Self::first_bounce`]: non-diffuse
    /// patches reflect the emitted light (in `packed`, with nothing
    /// directional arriving) through their tables into `phi_next`, the
    /// per-ray power of their direct highlights. Called after the loop,
    /// when `phi` and `phi_next` are spare.
    fn first_bounce_directional(&mut self) {
        let (Some(x), Some(g)) = (self.d.nd.as_ref(), self.glossy.as_mut()) else { return };
        let overlay_ends = overlay_ends(self.s);
        g.phi.fill([0.0; 4]);
        x.step(self.packed.rows(), &g.phi, &overlay_ends, &mut g.phi_next);
        if let Some(present) = self.s.absent_mask() {
            for (k, &q) in x.patches.iter().enumerate() {
                if !present[q as usize] {
                    g.phi_next[k * x.n..(k + 1) * x.n].fill([0.0; 4]);
                }
            }
        }
    }

    /// The frame's solution: radiance from the received totals, the
    /// balance with what is left unshot, and what the next frame's warm
    /// start reuses.
    pub fn finish(mut self, frame: u32) -> Result<Solution, DistributeError> {
        let (d, s) = (self.d, self.s);
        let mut bal = self.bal;
        for u in &self.unshot {
            for c in 0..3 {
                bal.residual[c] += u[c] as f64;
            }
        }
        if let Some(g) = &self.glossy {
            for p in &g.pending {
                for c in 0..3 {
                    bal.residual[c] += p[c];
                }
            }
        }
        bal.converged = self.residual_total <= d.opts.tolerance * s.emitted_total();
        // The solution is made in the room the loop's vectors leave, each
        // freed once nothing below reads it (`memory.rs` counts the loop's
        // vectors, not these beside them). A still's secant pairs steer no
        // later frame.
        self.send = Vec::new();
        let history = std::mem::replace(&mut self.anderson, Anderson::new(0));
        let history = if d.v.sequence.is_some() { history } else { Anderson::new(0) };
        // The first bounce first, in the loop's gather buffers, which are
        // then freed; then received power and the residual, which free
        // the unshot power; the radiance last: the solution is made in the
        // room the loop's vectors leave, never beside all of them. The
        // totals are read a block at a time (back from the scratch file
        // when spilled).
        let direct = match d.opts.split_direct {
            true => Some(self.first_bounce()?),
            false => None,
        };
        // The first bounce's highlights are in `phi_next`: the gather's
        // buffers are done.
        (self.packed, self.recv) = (PackedRgb::default(), Vec::new());
        let fail = |e| scratch_error(d.spill.as_deref(), e);
        let totals = (&self.total_direct, &self.total_spread);
        let (received, residual) = totals::received_and_residual(&self.unshot, totals).map_err(fail)?;
        self.unshot = Vec::new();
        let totals = (&self.total_direct, &self.total_spread);
        let radiance = totals::radiance(d, s, totals).map_err(fail)?;
        (self.total_direct, self.total_spread) = (PatchVec::Memory(Vec::new()), PatchVec::Memory(Vec::new()));
        let directional = d.nd.as_ref().zip(self.glossy.as_mut()).map(|(x, g)| {
            // `first_bounce` left the highlights' per-ray power in phi_next.
            let direct = match direct {
                Some(_) => (0..x.patches.len())
                    .flat_map(|k| {
                        let to_l = x.ray_to_radiance(k);
                        g.phi_next[k * x.n..(k + 1) * x.n].iter().map(move |t| [t[0] * to_l, t[1] * to_l, t[2] * to_l])
                    })
                    .collect(),
                None => Vec::new(),
            };
            DirectionalRadiance {
                patches: x.patches.clone(),
                directions: x.n,
                radiance: std::mem::take(&mut g.radiance),
                direct,
            }
        });
        let carry = self.carrying.then(|| {
            std::sync::Arc::new(Carry {
                distributor: d.id,
                frame,
                chain: self.warm.carry().map_or(0, |c| c.chain + 1),
                sent: self.sent_total,
                received: self.received_total,
                emitted: s.emitted_powers(),
                overlay: s.overlay.as_ref().map(|o| o.gather.clone()),
            })
        });
        check_finite(frame, &radiance, &received, &bal, direct.as_deref(), directional.as_ref())?;
        Ok(Solution {
            radiance,
            received,
            residual,
            balance: bal,
            delta_s: s.delta_s,
            directional,
            direct,
            surface_emission: s.surface_emission.clone(),
            surface_reflectance: d.surface_reflectance.clone(),
            surface_specular: d.surface_specular.clone(),
            history,
            carry,
            frame,
        })
    }
}

/// One worker's buffers for the blocks of spilled vectors.
#[derive(Default)]
struct Buffers {
    direct: Vec<[f32; 3]>,
    spread: Vec<[f32; 3]>,
    df: Vec<[Half; 3]>,
    kdx: Vec<[Half; 3]>,
}

/// The RGB lanes of a four-lane row.
#[inline]
fn rgb(x: [f32; 4]) -> [f32; 3] {
    [x[0], x[1], x[2]]
}

/// The frame's overlay ends of patch `q` as `(other, weight, direction)`,
/// for the non-diffuse step's in-buffers.
fn overlay_ends<'f>(s: &'f FrameSetup<'_>) -> impl Fn(usize, &mut dyn FnMut(u32, f32, u32)) + Sync + 'f {
    let all_ends = s.overlay.as_ref().and_then(|o| o.all.as_ref());
    move |q, add| {
        if let Some(o) = all_ends {
            for e in o.run(q, 1, 0) {
                add(o.other[e], o.weight[e], o.direction[e]);
            }
        }
    }
}

/// Refuses a result with a NaN or infinity anywhere (issue of forged or
/// out-of-range archives: never an image of NaN).
fn check_finite(
    frame: u32,
    radiance: &[[f32; 3]],
    received: &[[f32; 3]],
    bal: &EnergyBalance,
    direct: Option<&[[f32; 3]]>,
    directional: Option<&DirectionalRadiance>,
) -> Result<(), DistributeError> {
    let first_bad = |v: &[[f32; 3]]| v.iter().position(|x| !x.iter().all(|c| c.is_finite()));
    let fail = |what: String| Err(DistributeError::NotFinite { frame, what });
    if let Some(p) = first_bad(radiance) {
        return fail(format!("radiance {:?} of patch {p}", radiance[p]));
    }
    if let Some(p) = first_bad(received) {
        return fail(format!("power {:?} received by patch {p}", received[p]));
    }
    if let Some(p) = direct.and_then(first_bad) {
        return fail(format!("direct radiance of patch {p}"));
    }
    if let Some(k) = directional.and_then(|d| first_bad(&d.radiance).or_else(|| first_bad(&d.direct))) {
        return fail(format!("directional radiance entry {k}"));
    }
    let totals = [bal.emitted, bal.absorbed, bal.back_faces, bal.escaped, bal.residual];
    if !totals.iter().flatten().all(|x| x.is_finite()) {
        return fail(format!(
            "energy balance: emitted {:?} W, absorbed {:?} W, back faces {:?} W, escaped {:?} W",
            bal.emitted, bal.absorbed, bal.back_faces, bal.escaped
        ));
    }
    Ok(())
}
