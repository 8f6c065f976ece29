//! Per-frame setup: what one frame of a sequence changes in the
//! per-archive state of a [`Distributor`] — which patches are present,
//! what they emit, the frame's overlay of link changes and the linked
//! weights that follow.

use std::borrow::Cow;

use super::overlay::Overlay;
use super::{DistributeError, Distributor};
use crate::archive::ArchiveError;
use crate::archive::presence::FramePresence;

/// One frame's view of the archive, made before its first iteration.
pub(super) struct FrameSetup<'d> {
    /// Which patches are present (`None` for a still: all of them).
    pub presence: Option<FramePresence>,
    /// Emitted radiance per surface (keyed emission applied).
    pub surface_emission: Vec<[f32; 3]>,
    /// Each patch's surface (the distributor's), and its area: what a
    /// patch emits is its surface's, so nothing per patch is kept for it.
    patch_surface: super::PatchSurfaces<'d>,
    patch_area: &'d [f32],
    /// The frame's link changes against frame 0 (sequences only).
    pub overlay: Option<Overlay>,
    /// Per patch, the summed weight of its link ends in this frame
    /// (frame 0's, borrowed, unless the frame changes them).
    pub linked: Cow<'d, [f64]>,
    /// Per non-diffuse patch and direction, the rays that reach a facing
    /// patch in this frame (borrowed unless the frame changes them).
    pub linked_dir: Cow<'d, [f32]>,
    /// The power patches emit ([`Self::emitted_power`]) summed per band.
    pub emitted: [f64; 3],
    /// Seconds spent decoding and applying the delta (0 for stills).
    pub delta_s: f64,
}

impl FrameSetup<'_> {
    /// The emitted power summed over bands.
    pub fn emitted_total(&self) -> f64 {
        self.emitted.iter().sum()
    }

    /// Emitted radiance of patch `p` (zero for absent patches).
    #[inline]
    pub fn emit(&self, p: usize) -> [f32; 3] {
        match self.presence.as_ref().is_some_and(|f| !f.patch(p)) {
            true => [0.0; 3],
            false => self.surface_emission[self.patch_surface.of(p)],
        }
    }

    /// Power patch `p` emits, `π·L_e·A_p` (the first unshot power).
    #[inline]
    pub fn emitted_power(&self, p: usize) -> [f32; 4] {
        let (e, k) = (self.emit(p), std::f32::consts::PI * self.patch_area[p]);
        [e[0] * k, e[1] * k, e[2] * k, 0.0]
    }

    /// [`Self::emitted_power`] of every patch, as a vector.
    pub fn emitted_powers(&self) -> Vec<[f32; 4]> {
        (0..self.patch_surface.len()).map(|p| self.emitted_power(p)).collect()
    }

    /// Per patch, whether it is present; `None` when all are.
    pub fn absent_mask(&self) -> Option<&[bool]> {
        self.presence.as_ref().and_then(FramePresence::absent_mask)
    }
}

impl<'a> Distributor<'a> {
    /// Checks `frame` against the archive and sets it up.
    pub(super) fn setup(&self, frame: u32) -> Result<FrameSetup<'_>, DistributeError> {
        let v = &self.v;
        let mut surface_emission = self.surface_emission.clone();
        let t_delta = std::time::Instant::now();
        let (overlay, presence) = match &v.sequence {
            Some(s) => {
                if frame >= s.frames() {
                    return Err(DistributeError::FrameOutOfRange { frame, frames: s.frames() });
                }
                let presence = v.presence(frame);
                let keyed = v.keyed_emission(frame);
                if let Some(keyed) = keyed {
                    for (s, e) in surface_emission.iter_mut().enumerate() {
                        if !self.emission_fixed.get(s).copied().unwrap_or(false) {
                            *e = keyed[s];
                        }
                    }
                }
                let (_, overlay) =
                    v.frame_links_with(frame, |r| Overlay::new(self.nb, r, &presence, self.nd.is_some()))?;
                (Some(overlay), Some(presence))
            }
            None if frame == 0 => (None, None),
            None => return Err(DistributeError::NotASequence { frame }),
        };
        let mut linked = Cow::Borrowed(&self.linked[..]);
        if let Some(o) = &overlay {
            let linked = linked.to_mut();
            for (l, d) in linked.iter_mut().zip(&o.linked) {
                *l += d;
            }
            self.absent_ends(frame, |q, w, _| linked[q] -= w as f64);
            // Records were checked one by one (`frame_links`); their sums too.
            for (q, &l) in linked.iter().enumerate() {
                let h = v.patch_hits[q] as f64;
                if !(l >= -1e-3 && l <= h * (1.0 + 1e-6) + 1e-3) {
                    return Err(DistributeError::Archive(ArchiveError::corrupt(format!(
                        "DELT frame {frame}: patch {q}'s links carry {l} rays, outside 0..={h} (its PHIT)"
                    ))));
                }
            }
        }
        let delta_s = if overlay.is_some() { t_delta.elapsed().as_secs_f64() } else { 0.0 };
        let linked_dir = self.linked_directions(frame, overlay.as_ref());
        let mut setup = FrameSetup {
            presence,
            surface_emission,
            patch_surface: self.patch_surface,
            patch_area: v.patch_area,
            overlay,
            linked,
            linked_dir,
            emitted: [0.0; 3],
            delta_s,
        };
        for p in 0..v.patch_count() {
            let u = setup.emitted_power(p);
            for c in 0..3 {
                setup.emitted[c] += u[c] as f64;
            }
        }
        Ok(setup)
    }

    /// Per non-diffuse patch and direction, the rays that reach a facing
    /// patch at `frame`: frame 0's, changed by the overlay and less the
    /// ends to patches absent from the frame.
    fn linked_directions(&self, frame: u32, overlay: Option<&Overlay>) -> Cow<'_, [f32]> {
        match (&self.nd, overlay.and_then(|o| o.all.as_ref())) {
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
                Cow::Owned(l)
            }
            (Some(x), None) => Cow::Borrowed(&x.linked[..]),
            _ => Cow::Borrowed(&[][..]),
        }
    }

    /// Calls `out(q, w, d)` for every frame 0 link end of a patch `q` whose
    /// other patch is absent from `frame`: `w` rays leaving `q` along
    /// direction `d` that no longer link (§5.13: a link with an end at an
    /// absent patch is not a link of the frame).
    pub(super) fn absent_ends(&self, frame: u32, mut out: impl FnMut(usize, f32, u32)) {
        for (k, &(_, last)) in self.leaving.iter().enumerate() {
            if frame > last {
                let (other, weight, direction) = self.leaving_rows.ends(k);
                for ((&q, &w), &d) in other.iter().zip(weight).zip(direction) {
                    out(q as usize, w, d ^ 1);
                }
            }
        }
    }
}
