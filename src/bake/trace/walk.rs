//! The walk along one ray: its hits in order, consecutive hits facing
//! each other emitted as links with the bucket of each end (§3.4), every
//! hit counted towards its patch's `H_p`; for a ray that meets temporal
//! instances, once more at every frame where its hits change, emitting the
//! changes of its links ([`Walk::ray`]).

use std::sync::atomic::{AtomicU32, Ordering};

use glam::Vec3;

use super::scratch::{HitCounts, Scratch};
use super::{LinkKey, RayHitRecord, TraceInput};
use crate::archive::layout::DeltaRecord;
use crate::archive::presence::FrameSpan;
use crate::patch::Patches;

/// Ring sizes of a square patch grid: patches within Manhattan distance `b`.
fn ring_size(b: u32) -> f64 {
    (2 * b * b + 2 * b + 1) as f64
}

/// The bucket (§3.4) of a link end: the widest ring of patches whose area
/// does not exceed the beam's footprint on the receiving patch. A ray stands
/// for a beam of cross-section `1/density` spreading over the direction's
/// solid angle `Ω`, so at distance `r` it covers about `(√(1/density) + r√Ω)²`,
/// divided by `|cos θ|` on the receiver; `width` is that beam width at the
/// receiver.
#[inline]
fn bucket_of_beam(width: f64, cos_receiver: f32, area_receiver: f32, max_bucket: u32) -> u8 {
    if max_bucket == 0 || area_receiver <= 0.0 {
        return 0;
    }
    // `ring_size(b) ≤ footprint / area`, multiplied out (no division).
    let footprint = width * width;
    let per_patch = (cos_receiver.abs() as f64).max(1e-3) * area_receiver as f64;
    let mut b = 0;
    while b < max_bucket && ring_size(b + 1) * per_patch <= footprint {
        b += 1;
    }
    b as u8
}

/// What a hit of one primitive has in common with its others: the
/// fields [`Walk::prepare`] fills, and what its patch is found from.
pub(super) struct Prepared<'a> {
    pub(super) active: FrameSpan,
    pub(super) cos: f32,
    pub(super) first_patch: u32,
    pub(super) grid: &'a crate::geometry::grid::PatchGrid,
}

/// Shared, read-only state of one bundle's walk along its rays.
pub(super) struct Walk<'a> {
    pub(super) input: &'a TraceInput<'a>,
    pub(super) patches: &'a Patches,
    pub(super) normals: &'a [Vec3],
    pub(super) dir: Vec3,
    pub(super) eps_t: f32,
    pub(super) max_bucket: u32,
    /// `√(1/density)` and `√Ω` of the layout (see [`bucket_of_beam`]).
    pub(super) beam_width: f64,
    pub(super) sqrt_solid_angle: f64,
    /// The bundle's direction pair, and the number of pairs.
    pub(super) pair: u32,
    pub(super) pairs: u32,
    /// Per patch, its index among non-diffuse patches (`u32::MAX`: diffuse).
    pub(super) nd_index: &'a [u32],
    /// Per non-diffuse patch and pair, rays crossing it.
    pub(super) nd_hits: &'a [AtomicU32],
    /// Per non-diffuse patch and pair, of those rays the ones whose light
    /// meets a back face.
    pub(super) nd_backs: &'a [AtomicU32],
    /// Per patch, the frames it is present in.
    pub(super) patch_active: &'a [FrameSpan],
}

impl Walk<'_> {
    /// Fills the per-hit fields the walks use (the scan converter fills
    /// them as it makes the hits, [`Walk::prepared`]).
    pub(super) fn prepare(&self, hits: &mut [RayHitRecord]) {
        for h in hits {
            let p = self.prepared(h.primitive);
            (h.active, h.cos, h.patch) = (p.active, p.cos, p.first_patch + p.grid.cell_at(h.uv));
        }
    }

    /// Orders two copies of one surface that meet the ray at one place
    /// facing apart (a two-sided sheet: glTF `doubleSided`) so that the one
    /// facing back up the ray comes first: each side then links to what
    /// faces it, and the copies never link to each other (the tie-break by
    /// primitive would otherwise put either first).
    fn order_sheets(&self, hits: &mut [RayHitRecord]) {
        let surface = |h: &RayHitRecord| self.input.sort_key[h.primitive as usize] >> 32;
        let normal = |h: &RayHitRecord| self.normals[h.primitive as usize];
        for i in 1..hits.len() {
            let (a, b) = (&hits[i - 1], &hits[i]);
            // Opposite normals: not two faces meeting at an edge the ray grazes.
            if a.cos > 0.0
                && b.cos < 0.0
                && b.t - a.t <= self.eps_t
                && surface(a) == surface(b)
                && normal(a).dot(normal(b)) < -0.999
            {
                hits.swap(i - 1, i);
            }
        }
    }

    /// Walks `hits`, the hits present in `frame` in ray order: consecutive
    /// hits facing each other become links (appended to `links`). Hits count
    /// towards `H_p` in the first frame they are present in. Returns hits
    /// counted.
    ///
    /// A counted hit whose light along its facing direction next meets a
    /// back face (the next hit down the ray faces the same way) also counts
    /// towards the patch's back-face rays (`PBAK`, `NDBK`), so that the
    /// energy balance can tell light absorbed by back faces from light that
    /// left the scene.
    fn frame<'h>(
        &self,
        hits: impl Iterator<Item = &'h RayHitRecord>,
        frame: u32,
        links: &mut Vec<LinkKey>,
        counts: &mut HitCounts,
    ) -> u64 {
        let mut counted = 0;
        let mut prev: Option<(u32, f32, u32, bool, f32)> = None; // (patch, t, primitive, faces +d, cos)
        let mut prev_counted = false;
        for h in hits {
            let lo = h.active.first;
            let cos = h.cos;
            if cos == 0.0 {
                continue;
            }
            let forward = cos > 0.0;
            if let Some((_, pt, pp, pf, _)) = prev {
                // One crossing reported twice (shared edge of coplanar
                // primitives): keep the first.
                if h.t - pt <= self.eps_t
                    && pf == forward
                    && pp != h.primitive
                    && self.normals[pp as usize] == self.normals[h.primitive as usize]
                {
                    continue;
                }
            }
            let patch = h.patch;
            let counts_here = frame == lo;
            if counts_here {
                counts.hits.add(patch);
                counted += 1;
                let nd = self.nd_index[patch as usize];
                if nd != u32::MAX {
                    self.nd_hits[nd as usize * self.pairs as usize + self.pair as usize]
                        .fetch_add(1, Ordering::Relaxed);
                }
            }
            // Back faces: a hit facing down the ray followed by another
            // facing down it sends its light into that one's back; a hit
            // facing back up the ray after one facing back up it likewise.
            if let Some((prev_patch, _, _, prev_forward, _)) = prev
                && prev_forward == forward
            {
                if forward && prev_counted {
                    self.add_back(prev_patch, counts);
                } else if !forward && counts_here {
                    self.add_back(patch, counts);
                }
            }
            // A link: the previous hit faces down the ray, this one faces back.
            // (Two triangles of one grouped patch can face each other at
            // grazing incidence; light a patch sends itself is no link.)
            if let (Some((prev_patch, pt, _, true, pcos)), false) = (prev, forward)
                && prev_patch != patch
            {
                // Buckets: each end's footprint from its own incidence.
                let r = h.t - pt;
                let area = &self.patches.area;
                let width = self.beam_width + r as f64 * self.sqrt_solid_angle;
                let ba = bucket_of_beam(width, pcos, area[prev_patch as usize], self.max_bucket);
                let bb = bucket_of_beam(width, cos, area[patch as usize], self.max_bucket);
                links.push((((prev_patch as u64) << 32) | patch as u64, ba, bb));
            }
            prev = Some((patch, h.t, h.primitive, forward, cos));
            prev_counted = counts_here;
        }
        counted
    }

    /// Counts one ray of `patch` (counted in this frame) that meets a back face.
    #[inline]
    fn add_back(&self, patch: u32, counts: &mut HitCounts) {
        counts.backs.add(patch);
        let nd = self.nd_index[patch as usize];
        if nd != u32::MAX {
            self.nd_backs[nd as usize * self.pairs as usize + self.pair as usize].fetch_add(1, Ordering::Relaxed);
        }
    }

    /// The fields [`Walk::prepare`] fills in a hit of `primitive`
    /// (`patch` from the hit's `uv`), computed once for all its hits.
    pub(super) fn prepared(&self, primitive: u32) -> Prepared<'_> {
        let p = primitive as usize;
        Prepared {
            active: self.input.active[p],
            cos: self.normals[p].dot(self.dir),
            first_patch: self.patches.primitives[p].first_patch,
            grid: &self.patches.primitives[p].grid,
        }
    }

    /// One ray, its hits prepared ([`Walk::prepare`]): frame 0's links go
    /// to `s.keys`; for rays that meet temporal instances, the changes at
    /// later frames go to `s.changes`.
    pub(super) fn ray(&self, pair: u32, hits: &mut [RayHitRecord], s: &mut Scratch) -> u64 {
        let last = self.input.frames - 1;
        self.order_sheets(hits);
        let all = FrameSpan::all(self.input.frames);
        let present_at = |f: u32| move |h: &&RayHitRecord| h.active.contains(f);
        let temporal = hits.iter().any(|h| h.active != all);
        if !temporal {
            // Every hit is present in every frame.
            return self.frame(hits.iter(), 0, &mut s.keys, &mut s.counts);
        }
        // The active hits change only where an instance appears or leaves.
        s.change_frames.clear();
        for h in hits.iter() {
            let FrameSpan { first: lo, last: hi } = h.active;
            if lo > 0 {
                s.change_frames.push(lo);
            }
            if hi < last {
                s.change_frames.push(hi + 1);
            }
        }
        s.change_frames.sort_unstable();
        s.change_frames.dedup();
        s.prev_links.clear();
        let mut counted = self.frame(hits.iter().filter(present_at(0)), 0, &mut s.prev_links, &mut s.counts);
        s.keys.extend_from_slice(&s.prev_links);
        s.prev_links.sort_unstable();
        // Each change frame walks only the hits present in it: the
        // permanent ones and the temporal ones whose frames it falls in
        // (about 4 of the 26 hits of a ray through the fan's disc), kept
        // as ray-ordered index lists rather than found by scanning all.
        s.permanent.clear();
        s.by_first.clear();
        for (i, h) in hits.iter().enumerate() {
            if h.active == all {
                s.permanent.push(i as u32);
            } else {
                s.by_first.push(i as u32);
            }
        }
        let hits = &*hits;
        s.by_first.sort_unstable_by_key(|&i| hits[i as usize].active.first);
        s.active.clear();
        let mut next = 0;
        for i in 0..s.change_frames.len() {
            let f = s.change_frames[i];
            s.active.retain(|&k| hits[k as usize].active.last >= f);
            while next < s.by_first.len() && hits[s.by_first[next] as usize].active.first <= f {
                let k = s.by_first[next];
                if hits[k as usize].active.last >= f {
                    s.active.push(k);
                }
                next += 1;
            }
            s.active.sort_unstable();
            s.walk.clear();
            merge_sorted(&s.permanent, &s.active, &mut s.walk);
            s.frame_links.clear();
            counted += self.frame(s.walk.iter().map(|&k| &hits[k as usize]), f, &mut s.frame_links, &mut s.counts);
            s.frame_links.sort_unstable();
            let out = &mut s.changes[f as usize];
            // A link with an end at a patch absent from f is removed by rule
            // (§5.13): the removal of the links of an instance that has just
            // left needs no record, and the running sums drop what such
            // patches still hold (`accumulate_changes`).
            let present = |p: u32| self.patch_active[p as usize].contains(f);
            diff(&s.prev_links, &s.frame_links, |key, count| {
                let (a, b) = ((key.0 >> 32) as u32, key.0 as u32);
                if present(a) && present(b) {
                    out.push(DeltaRecord { pair, a, b, count, bucket_a: key.1, bucket_b: key.2, reserved: 0 })
                }
            });
            std::mem::swap(&mut s.prev_links, &mut s.frame_links);
        }
        counted
    }
}

/// Appends the union of two ascending lists to `out`, ascending.
fn merge_sorted(a: &[u32], b: &[u32], out: &mut Vec<u32>) {
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        if a[i] < b[j] {
            out.push(a[i]);
            i += 1;
        } else {
            out.push(b[j]);
            j += 1;
        }
    }
    out.extend_from_slice(&a[i..]);
    out.extend_from_slice(&b[j..]);
}

/// Calls `out(key, ±n)` for the multiset difference `new − old` (both sorted).
fn diff(old: &[LinkKey], new: &[LinkKey], mut out: impl FnMut(LinkKey, i32)) {
    let (mut i, mut j) = (0, 0);
    while i < old.len() || j < new.len() {
        let next = match (old.get(i), new.get(j)) {
            (Some(a), Some(b)) => *a.min(b),
            (Some(a), None) => *a,
            (None, Some(b)) => *b,
            (None, None) => unreachable!(),
        };
        let mut n = 0i32;
        while old.get(i) == Some(&next) {
            n -= 1;
            i += 1;
        }
        while new.get(j) == Some(&next) {
            n += 1;
            j += 1;
        }
        if n != 0 {
            out(next, n);
        }
    }
}
