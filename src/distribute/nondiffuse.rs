//! Non-diffuse patches in the distribution (§3.6.2, Figure 9).
//!
//! A diffuse patch sends the same share of its power along every link end.
//! A non-diffuse patch `q` instead keeps an **in-buffer** per direction: the
//! power that arrived over its link ends, sorted by the direction `i` it came
//! from (the end's `LDIR`). Each iteration:
//!
//! 1. light from direction `i` goes through the orientation's
//!    actual-to-prototype map to prototype row `map[i]`, whose factors
//!    scatter it into a **scratch** area indexed by prototype direction;
//! 2. scratch entry `p` divided by `cos θ_p Ω_p` (its prototype direction's
//!    weight in the table) is proportional to the radiance leaving along
//!    `p`; actual outgoing direction `o` takes that of `map[o]`. (Taking the
//!    power `scratch[map[o]]` itself would carry the prototype direction's
//!    `cos θ Ω` over to a direction a few degrees away: near the horizon
//!    that is a 40% error.)
//! 3. it leaves along the rays of direction `o` that cross `q` (`n_o` of
//!    them, from `NDHC`), each carrying `φ_o = k_s · R_map[o]`: the radiance
//!    times the étendue of one ray. Rays of `o` that reach no facing patch
//!    lose theirs.
//!
//! Energy is conserved exactly per patch and per incoming direction, as
//! `U_p/H_p` does for diffuse patches, whatever the ray counts: light from
//! direction `i` is scaled on entry by
//! `c_i = a_i / Σ_o n_o·T(map[i]→map[o])/w_map[o]` (`w_p = cos θ_p Ω_p`),
//! the row's albedo over what its outgoing radiance would carry on this
//! patch's actual rays. One exception bounds it: when the patch has fewer
//! rays than one in the direction of the row's peak (`T/w` largest), `c_i`
//! is held at `a_i / max_p T/w`, so no ray and no radiance exceeds what
//! arrived and the missing rays' share is lost (a small glossy patch whose
//! rays miss its lobe; a forged `NDHC`). The scale depends on the patch and
//! the direction only, never on the light, so the step is linear (warm starts, which send
//! a guess and then signed corrections, rely on that; a per-step
//! normalisation by the reflected light's own shape was not, and broke them).
//!
//! The diffuse part `k_d` of a broad-specular patch takes the ordinary
//! diffuse path (with buckets). Light a non-diffuse patch sends reaches its
//! receivers through a **correction list**: the link ends whose other patch
//! is non-diffuse, found once per archive, each adding `w · φ` to the
//! receiver; the main gather sees those senders' diffuse share only.
//! When it reflects is the iteration's choice (`step.rs`): the step is
//! linear in what arrives, so light may wait at a patch over several
//! diffuse steps and be reflected in one table step.
//!
//! A scene that is all diffuse never builds any of this.

use rayon::prelude::*;

use super::kernels::{
    BATCH, BLOCK, DirectionalSenders, LANES, Lanes, StateRows, TableColumns, gather_table_columns, scatter_table_rows,
};
use crate::archive::{ArchiveError, Columns, InetView, LinkRows, ReflectanceView};

/// Per-archive state of the non-diffuse patches.
pub(super) struct NonDiffuse<'a> {
    r: ReflectanceView<'a>,
    /// Directions in the set.
    pub n: usize,
    /// Per patch, its non-diffuse index (`u32::MAX`: diffuse).
    pub nd_of: Vec<u32>,
    /// Non-diffuse index → patch.
    pub patches: Vec<u32>,
    /// `k_s` per non-diffuse patch.
    ks: Vec<[f32; 3]>,
    /// Prototype → actual direction, per orientation.
    inverse: Vec<u32>,
    /// Per non-diffuse patch and direction: `n_o`, the rays of `o` leaving
    /// the patch (−1 for directions behind it).
    rays: Vec<f32>,
    /// Per prototype direction, `1 / (cos θ_p Ω_p)` (0 below the prototype surface).
    inv_weight: Vec<f32>,
    /// Per table and prototype row, its albedo (the row sum) per band.
    albedo: Vec<Vec<[f32; 3]>>,
    /// Per non-diffuse patch, the radiance one unit of per-ray power stands
    /// for: a ray carries the étendue `π·A_p/E[H_p]` of its patch (as for
    /// diffuse radiance).
    to_radiance: Vec<f32>,
    /// Per non-diffuse patch, `k_s` times the largest albedo of its
    /// table's rows, per band: what it reflects into directions of a unit
    /// of arriving power, at most.
    bound: Vec<[f32; 3]>,
    /// Per non-diffuse patch and actual incoming direction, `c_i` per band
    /// (module docs), `scale_bands` values each: 1 when every table has one
    /// band (its `c_i` is the same in the three), else 3.
    in_scale: Vec<f32>,
    scale_bands: usize,
    /// Link ends whose other patch is non-diffuse.
    corrections: Corrections,
    /// Rays of each direction leaving each non-diffuse patch that reach a
    /// facing patch (frame 0's links).
    pub linked: Vec<f32>,
    /// Rays of each direction leaving each non-diffuse patch whose light
    /// meets a back face (`NDBK`; empty for files without it).
    pub back_rays: Vec<f32>,
    /// Frame 0's link ends of each non-diffuse patch, walked every step.
    rows: LinkRows,
    /// Each table by outgoing direction.
    columns: Vec<TableColumns>,
    /// Runs of at most [`BATCH`] consecutive non-diffuse patches with the
    /// same table and orientation: `(first, len)`.
    batches: Vec<(usize, usize)>,
}

/// Visits a patch's extra link ends (a frame's overlay) as `(other, weight, direction)`.
pub(super) type ExtraEnds<'f> = dyn Fn(usize, &mut dyn FnMut(u32, f32, u32)) + Sync + 'f;

/// What one reflection step produced, per band.
#[derive(Default, Clone, Copy)]
pub(super) struct StepTotals {
    /// Power reflected into directions (sent next iteration).
    pub reflected: [f64; 3],
}

impl<'a> NonDiffuse<'a> {
    /// Prepares the reflectance sections of `v`, with `ks` per surface
    /// (`None` for an archive without them).
    pub fn new(v: &InetView<'a>, ks_of_surface: &[[f32; 3]]) -> Result<Option<Self>, ArchiveError> {
        let Some(r) = v.reflectance else { return Ok(None) };
        let n = v.directions.len();
        let np = v.patch_count();
        let mut nd_of = vec![u32::MAX; np];
        for (k, e) in r.patches.iter().enumerate() {
            nd_of[e.patch as usize] = k as u32;
        }
        let patches: Vec<u32> = r.patches.iter().map(|e| e.patch).collect();
        let surface = |q: u32| v.primitives[v.patch_primitive[q as usize] as usize].surface as usize;
        let ks: Vec<[f32; 3]> = patches.iter().map(|&q| ks_of_surface[surface(q)]).collect();
        let mut inverse = vec![0u32; r.orientations.len() * n];
        for o in 0..r.orientations.len() {
            for (a, &p) in r.map(o).iter().enumerate() {
                inverse[o * n + p as usize] = a as u32;
            }
        }
        let (rays, back_rays) = leaving_rays(v, &r, &patches);
        let inv_weight = prototype_inverse_weights(v);
        let corrections = Corrections::new(v, &nd_of)?;
        let rows = v.link_rows(&patches)?;
        let mut linked = vec![0.0f32; patches.len() * n];
        for k in 0..patches.len() {
            let (_, w, d) = rows.ends(k);
            for (&w, &d) in w.iter().zip(d) {
                linked[k * n + d as usize] += w;
            }
        }
        let albedo = row_albedos(&r, n);
        let batches = table_batches(&r);
        let columns = (0..r.prototypes.len())
            .map(|t| TableColumns::new(n, r.prototypes[t].bands as usize, &|i| r.row(t, i)))
            .collect();
        let scale_bands = r.prototypes.iter().map(|p| p.bands as usize).max().unwrap_or(1).clamp(1, 3);
        let in_scale = incoming_scales(&r, n, scale_bands, &batches, &inverse, &rays, &inv_weight, &albedo);
        let to_radiance = patches
            .iter()
            .map(|&q| {
                let a = v.patch_area[q as usize];
                if a > 0.0 { v.patch_expected_hits[q as usize] / (std::f32::consts::PI * a) } else { 0.0 }
            })
            .collect();
        let bound = r
            .patches
            .iter()
            .zip(&ks)
            .map(|(rec, ks): (_, &[f32; 3])| {
                let most =
                    albedo[rec.prototype as usize].iter().fold([0.0f32; 3], |m, a| [0, 1, 2].map(|c| m[c].max(a[c])));
                [0, 1, 2].map(|c| ks[c].abs() * most[c])
            })
            .collect();
        Ok(Some(Self {
            r,
            n,
            nd_of,
            patches,
            ks,
            inverse,
            rays,
            inv_weight,
            albedo,
            to_radiance,
            bound,
            in_scale,
            scale_bands,
            corrections,
            linked,
            back_rays,
            rows,
            columns,
            batches,
        }))
    }

    /// Index into the per-ray directional power (`phi`) of non-diffuse patch
    /// `k` sending along direction `d`.
    #[inline]
    pub fn slot(&self, k: u32, d: u32) -> usize {
        k as usize * self.n + d as usize
    }

    /// The non-diffuse senders with per-ray power `phi`, as the link-end
    /// gather ([`super::kernels::add_ends`]) reads them.
    pub fn senders<'s>(&'s self, phi: &'s [[f32; 4]]) -> DirectionalSenders<'s> {
        DirectionalSenders { nd_of: &self.nd_of, directions: self.n, phi }
    }

    /// Patch `k`'s radiance per unit of per-ray power.
    #[inline]
    pub fn ray_to_radiance(&self, k: usize) -> f32 {
        self.to_radiance[k]
    }

    /// Patch `k`'s bound on the power it reflects into directions per unit
    /// of arriving power, per band.
    #[inline]
    pub fn reflect_bound(&self, k: usize) -> [f32; 3] {
        self.bound[k]
    }

    /// Adds what non-diffuse senders send along their directions to `recv`
    /// (bucketed as the main gather, `nb` buckets per patch).
    pub fn gather_corrections(&self, nb: usize, use_buckets: bool, phi: &[[f32; 4]], recv: &mut [[f32; 3]]) {
        recv.par_chunks_mut(BLOCK * nb).enumerate().for_each(|(block, out)| {
            let first = block * BLOCK;
            for (i, r) in out.chunks_exact_mut(nb).enumerate() {
                let q = first + i;
                let corr = &self.corrections;
                for e in corr.offsets[q] as usize..corr.offsets[q + 1] as usize {
                    let s = phi[corr.slot[e] as usize];
                    let w = corr.weight[e];
                    let slot = &mut r[if use_buckets { corr.bucket[e] as usize } else { 0 }];
                    for c in 0..3 {
                        slot[c] += w * s[c];
                    }
                }
            }
        });
    }

    /// One reflection step for every non-diffuse patch: in-buffers from what
    /// arrives this iteration (`shoot`: diffuse share per patch, `phi`:
    /// directional power per ray, `extra`: the frame's overlay ends of each
    /// patch as `(other, weight, direction)`), through map and table, into
    /// `phi_next`. Returns the power each patch reflected into directions.
    ///
    /// Patches sharing a table and an orientation go through the table
    /// [`BATCH`] at a time: each table entry read is applied to all of them,
    /// so the table (megabytes) streams from memory once per batch instead
    /// of once per patch, and the inner loop is 24 independent lanes.
    pub fn step<S: StateRows + Sync>(
        &self,
        shoot: S,
        phi: &[[f32; 4]],
        extra: &ExtraEnds<'_>,
        phi_next: &mut [[f32; 4]],
    ) -> Vec<StepTotals> {
        let n = self.n;
        // Split the output by batch.
        let mut outs: Vec<(usize, &mut [[f32; 4]])> = Vec::with_capacity(self.batches.len());
        let mut rest = phi_next;
        for &(first, len) in &self.batches {
            let (head, tail) = rest.split_at_mut(len * n);
            outs.push((first, head));
            rest = tail;
        }
        let totals: Vec<Vec<StepTotals>> = outs
            .into_par_iter()
            .map_init(
                || (vec![[0.0f32; LANES]; n], vec![[0.0f32; LANES]; n], vec![[0.0f32; LANES]; n]),
                |(inbuf, scratch, proto), (first, out)| {
                    let len = out.len() / n;
                    for lane in inbuf.iter_mut() {
                        *lane = [0.0; LANES];
                    }
                    for b in 0..len {
                        let q = self.patches[first + b] as usize;
                        let mut add = |other: u32, w: f32, d: u32| {
                            let mut s = shoot.row(other as usize);
                            let j = self.nd_of[other as usize];
                            if j != u32::MAX {
                                let p = phi[self.slot(j, d ^ 1)];
                                for c in 0..4 {
                                    s[c] += p[c];
                                }
                            }
                            let slot = &mut inbuf[d as usize][3 * b..3 * b + 3];
                            for c in 0..3 {
                                slot[c] += w * s[c];
                            }
                        };
                        let (o, w, d) = self.rows.ends(first + b);
                        for e in 0..o.len() {
                            add(o[e], w[e], d[e]);
                        }
                        extra(q, &mut add);
                    }
                    let reflected = self.scale_incoming(first, len, inbuf);
                    self.scatter(first, inbuf, proto, scratch);
                    (0..len)
                        .map(|b| {
                            self.emit(first + b, b, scratch, &mut out[b * n..(b + 1) * n]);
                            StepTotals { reflected: reflected[b] }
                        })
                        .collect()
                },
            )
            .collect();
        totals.into_iter().flatten().collect()
    }

    /// In-buffers of a batch → map → table → scratch (prototype
    /// directions). While at most half the incoming directions have light
    /// (the emitters' first bounce), each adds its row of the table times
    /// its light to the scratch area and unlit rows are skipped; else each
    /// output direction gathers its column of the table over the light
    /// put in prototype order (`proto`): 20-30% faster on the glossy
    /// floor's table steps, where nearly every row is lit.
    fn scatter(&self, first: usize, inbuf: &[Lanes], proto: &mut [Lanes], scratch: &mut [Lanes]) {
        let rec = self.r.patches[first];
        let (t, orient) = (rec.prototype as usize, rec.orientation as usize);
        let bands = self.r.prototypes[t].bands as usize;
        let map = self.r.map(orient);
        let lit = inbuf.iter().filter(|l| l.iter().any(|&x| x != 0.0)).count();
        if 2 * lit > inbuf.len() {
            // The map is a bijection (validated when the archive opens).
            for (i, l) in inbuf.iter().enumerate() {
                proto[map[i] as usize] = *l;
            }
            gather_table_columns(&self.columns[t], proto, scratch);
            return;
        }
        for s in scratch.iter_mut() {
            *s = [0.0; LANES];
        }
        let rows = |i: usize| self.r.row(t, map[i] as usize);
        scatter_table_rows(bands, inbuf, scratch, &rows);
    }
}

/// The correction list: link ends whose other patch is non-diffuse, CSR
/// by receiving patch, each with its weight, the slot of the sender's
/// per-ray power it reads (the antipode of the receiver's direction) and
/// its bucket.
struct Corrections {
    offsets: Vec<u64>,
    weight: Vec<f32>,
    slot: Vec<u32>,
    bucket: Vec<u8>,
}

impl Corrections {
    /// One scan over `v`'s link ends, `nd_of` the non-diffuse index of
    /// each patch (`u32::MAX`: diffuse).
    fn new(v: &InetView<'_>, nd_of: &[u32]) -> Result<Self, ArchiveError> {
        let n = v.directions.len();
        let np = v.patch_count();
        let mut offsets = Vec::with_capacity(np + 1);
        let (mut weight, mut slot, mut bucket_of) = (Vec::new(), Vec::new(), Vec::new());
        offsets.push(0u64);
        v.links.for_each_window(Columns::ALL, np, |w| {
            for q in w.patches.clone() {
                for (e, other, bucket) in w.ends_of(q) {
                    let k = nd_of[other as usize];
                    if k != u32::MAX {
                        weight.push(w.weight.get(e));
                        // The sender sends along the antipode of the receiver's direction.
                        slot.push(k * n as u32 + (w.direction[e] ^ 1));
                        bucket_of.push(bucket);
                    }
                }
                offsets.push(weight.len() as u64);
            }
            Ok::<(), ArchiveError>(())
        })?;
        Ok(Self { offsets, weight, slot, bucket: bucket_of })
    }
}

/// Per non-diffuse patch and direction, `n_o`: the rays of `o` leaving the
/// patch (−1 for directions behind it); and the rays whose light meets a
/// back face (`NDBK`; empty for files without it).
fn leaving_rays(v: &InetView<'_>, r: &ReflectanceView<'_>, patches: &[u32]) -> (Vec<f32>, Vec<f32>) {
    let n = v.directions.len();
    let mut rays = vec![-1.0f32; patches.len() * n];
    let mut back_rays = vec![0.0f32; if r.back_hits.is_some() { patches.len() * n } else { 0 }];
    for (k, &q) in patches.iter().enumerate() {
        let nq = v.patch_normal[q as usize];
        let hits = r.pair_hits(k);
        let backs = r.back_hits.map(|b| &b[k * (n / 2)..(k + 1) * (n / 2)]);
        for (o, d) in v.directions.iter().enumerate() {
            let cos = nq[0] * d.direction[0] + nq[1] * d.direction[1] + nq[2] * d.direction[2];
            if cos > 0.0 {
                rays[k * n + o] = hits[o / 2] as f32;
                if let Some(b) = backs {
                    back_rays[k * n + o] = b[o / 2] as f32;
                }
            }
        }
    }
    (rays, back_rays)
}

/// Per prototype direction, `1 / (cos θ_p Ω_p)` (0 below the prototype
/// surface, whose normal is +y).
fn prototype_inverse_weights(v: &InetView<'_>) -> Vec<f32> {
    v.directions
        .iter()
        .map(|d| {
            let w = d.direction[1] * d.solid_angle_sr;
            if d.direction[1] > 0.0 && w > 0.0 { 1.0 / w } else { 0.0 }
        })
        .collect()
}

/// Per table and prototype row, its albedo (the row sum) per band (a
/// one-band table's in all three).
fn row_albedos(r: &ReflectanceView<'_>, n: usize) -> Vec<Vec<[f32; 3]>> {
    (0..r.prototypes.len())
        .map(|t| {
            let bands = r.prototypes[t].bands as usize;
            (0..n)
                .map(|i| {
                    let (_, f) = r.row(t, i);
                    let mut a = [0.0f32; 3];
                    for e in f.chunks_exact(bands) {
                        for c in 0..3 {
                            a[c] += e[c.min(bands - 1)];
                        }
                    }
                    a
                })
                .collect()
        })
        .collect()
}

/// Runs of at most [`BATCH`] consecutive non-diffuse patches with the
/// same table and orientation: `(first, len)`.
fn table_batches(r: &ReflectanceView<'_>) -> Vec<(usize, usize)> {
    let mut batches = Vec::new();
    let mut k = 0;
    while k < r.patches.len() {
        let key = |j: usize| (r.patches[j].prototype, r.patches[j].orientation);
        let mut len = 1;
        while k + len < r.patches.len() && len < BATCH && key(k + len) == key(k) {
            len += 1;
        }
        batches.push((k, len));
        k += len;
    }
    batches
}

/// `c_i` of every non-diffuse patch and incoming direction (module docs):
/// the row's albedo over `Σ_o n_o·T(map[i]→map[o])/w_map[o]`, a batch of patches at a
/// time (one pass over the table per batch, 8 lanes); `bands_out` values
/// each (those of the first bands: one suffices where every table has one).
#[allow(clippy::too_many_arguments)]
fn incoming_scales(
    r: &ReflectanceView<'_>,
    n: usize,
    bands_out: usize,
    batches: &[(usize, usize)],
    inverse: &[u32],
    rays: &[f32],
    inv_weight: &[f32],
    albedo: &[Vec<[f32; 3]>],
) -> Vec<f32> {
    let mut out = vec![0.0f32; r.patches.len() * n * bands_out];
    let mut slices: Vec<(usize, usize, &mut [f32])> = Vec::with_capacity(batches.len());
    let mut rest = &mut out[..];
    for &(first, len) in batches {
        let (head, tail) = rest.split_at_mut(len * n * bands_out);
        slices.push((first, len, head));
        rest = tail;
    }
    slices.into_par_iter().for_each(|(first, len, out)| {
        let rec = r.patches[first];
        let (t, orient) = (rec.prototype as usize, rec.orientation as usize);
        let bands = r.prototypes[t].bands as usize;
        let (map, inv) = (r.map(orient), &inverse[orient * n..(orient + 1) * n]);
        // g[p][b] = n_o / w_p of patch b for the actual o = inv[p] (0 behind);
        // h[p][b] = 1 / w_p for a direction in front of patch b (0 behind).
        let front = |b: usize, p: usize| b < len && rays[(first + b) * n + inv[p] as usize] >= 0.0;
        let g: Vec<[f32; BATCH]> = (0..n)
            .map(|p| {
                let o = inv[p] as usize;
                std::array::from_fn(|b| if front(b, p) { rays[(first + b) * n + o] * inv_weight[p] } else { 0.0 })
            })
            .collect();
        let h: Vec<[f32; BATCH]> =
            (0..n).map(|p| std::array::from_fn(|b| if front(b, p) { inv_weight[p] } else { 0.0 })).collect();
        for i in 0..n {
            if (0..len).all(|b| rays[(first + b) * n + i] < 0.0) {
                continue; // light never arrives from behind
            }
            let (outs, f) = r.row(t, map[i] as usize);
            let a = albedo[t][map[i] as usize];
            // `peak`: the largest radiance factor T/w over the directions in
            // front. One ray there would carry all `a`; with fewer rays than
            // that (`sent < peak`), the scale is held at `a / peak` so that no
            // ray and no radiance the eye sees exceeds what arrived, and
            // light the missing rays would have carried is lost. Every
            // direction with a ray has `sent ≥ peak` unless the peak's own
            // direction has none: a patch whose rays miss its lobe, which a
            // small glossy patch can meet and a forged `NDHC` can force.
            let (mut sent, mut peak) = ([[0.0f32; BATCH]; 3], [[0.0f32; BATCH]; 3]);
            for (e, &p) in outs.iter().enumerate() {
                let (gp, hp) = (&g[p as usize], &h[p as usize]);
                for c in 0..bands {
                    let fe = f[e * bands + c];
                    for b in 0..BATCH {
                        sent[c][b] += fe * gp[b];
                        peak[c][b] = peak[c][b].max(fe * hp[b]);
                    }
                }
            }
            for b in 0..len {
                for (c, x) in out[(b * n + i) * bands_out..][..bands_out].iter_mut().enumerate() {
                    let s = sent[c.min(bands - 1)][b].max(peak[c.min(bands - 1)][b]);
                    *x = if s > 0.0 { a[c] / s } else { 0.0 };
                }
            }
        }
    });
    out
}

impl NonDiffuse<'_> {
    /// The power each patch of a batch reflects (`k_s`·albedo·light, per
    /// band), then the in-buffers scaled by `c_i` (module docs).
    fn scale_incoming(&self, first: usize, len: usize, inbuf: &mut [Lanes]) -> [[f64; 3]; BATCH] {
        let n = self.n;
        let rec = self.r.patches[first];
        let (t, map) = (rec.prototype as usize, self.r.map(rec.orientation as usize));
        let mut reflected = [[0.0f64; 3]; BATCH];
        for (i, light) in inbuf.iter_mut().enumerate() {
            if light.iter().all(|&l| l == 0.0) {
                continue;
            }
            let a = self.albedo[t][map[i] as usize];
            for b in 0..len {
                let sb = self.scale_bands;
                let (ks, scale) = (self.ks[first + b], &self.in_scale[((first + b) * n + i) * sb..][..sb]);
                for c in 0..3 {
                    let l = &mut light[3 * b + c];
                    reflected[b][c] += (ks[c] * a[c] * *l) as f64;
                    *l *= scale[c.min(sb - 1)];
                }
            }
        }
        reflected
    }

    /// Scratch lane `b` → map back → per-ray power of non-diffuse patch `k`.
    fn emit(&self, k: usize, b: usize, scratch: &[Lanes], out: &mut [[f32; 4]]) {
        let n = self.n;
        let orient = self.r.patches[k].orientation as usize;
        let ks = self.ks[k];
        let inv = &self.inverse[orient * n..(orient + 1) * n];
        let rays = &self.rays[k * n..(k + 1) * n];
        out.fill([0.0; 4]);
        for (p, s) in scratch.iter().enumerate() {
            let o = inv[p] as usize;
            // Directions in front with no ray crossing this patch still
            // carry radiance (seen by the eye); they just send nothing.
            if rays[o] >= 0.0 {
                let iw = self.inv_weight[p];
                for c in 0..3 {
                    out[o][c] = ks[c] * s[3 * b + c] * iw;
                }
            }
        }
    }
}
