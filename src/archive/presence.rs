//! The frame-presence rules of sequence archives (§5.13), in one place.
//!
//! A sequence holds every primitive once per run of frames it keeps one
//! transform: an *instance*, present over an inclusive frame span. Every
//! stage asks the same questions of it: is this primitive (or patch)
//! present at frame k, which primitives are temporal (present in only some
//! frames), is a link a link of frame k (both its ends present). The
//! build asks them of the instances it traces, the distribution and the
//! renderer of an archive's `INST` section; this module answers for both,
//! so the rules are written once.

use super::layout::InstanceRecord;

/// An inclusive range of frames, `first..=last`: the frames an instance
/// (and so each of its primitives and patches) is present in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct FrameSpan {
    /// First frame present.
    pub first: u32,
    /// Last frame present (inclusive).
    pub last: u32,
}

impl FrameSpan {
    /// Every frame of a sequence of `frames` frames (a permanent surface).
    pub fn all(frames: u32) -> Self {
        Self { first: 0, last: frames.saturating_sub(1) }
    }

    /// Whether `frame` lies in the span.
    #[inline]
    pub fn contains(self, frame: u32) -> bool {
        self.first <= frame && frame <= self.last
    }

    /// Whether the span leaves out some frame of a `frames`-frame sequence:
    /// the primitives of such an instance are *temporal*.
    pub fn is_temporal(self, frames: u32) -> bool {
        self.first > 0 || self.last.saturating_add(1) < frames
    }
}

impl InstanceRecord {
    /// The frames the instance is present in.
    pub fn span(&self) -> FrameSpan {
        FrameSpan { first: self.frame_first, last: self.frame_last }
    }

    /// Its primitives, `first..first + count`.
    pub fn primitive_range(&self) -> std::ops::Range<usize> {
        let first = self.first_primitive as usize;
        first..first + self.primitive_count as usize
    }
}

/// Per primitive, the frame span of the instance it belongs to (`INST`
/// covers every primitive exactly once; validated on open).
pub fn primitive_spans(instances: &[InstanceRecord], primitives: usize) -> Vec<FrameSpan> {
    let mut out = vec![FrameSpan::all(1); primitives];
    for i in instances {
        out[i.primitive_range()].fill(i.span());
    }
    out
}

/// Which patches and primitives of an archive are present at one frame,
/// and so which links are links of that frame. A still archive has every
/// patch present at its only frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FramePresence {
    /// The frame.
    pub frame: u32,
    /// Per primitive: present at the frame.
    pub primitives: Vec<bool>,
    /// Per patch: present at the frame.
    pub patches: Vec<bool>,
    /// Whether some patch is absent (false for every frame of a still).
    pub any_absent: bool,
}

impl FramePresence {
    /// Presence at `frame` for primitives of `spans`, patches on
    /// `patch_primitive`.
    pub fn new(frame: u32, spans: &[FrameSpan], patch_primitive: &[u32]) -> Self {
        let primitives: Vec<bool> = spans.iter().map(|s| s.contains(frame)).collect();
        let patches: Vec<bool> = patch_primitive.iter().map(|&p| primitives[p as usize]).collect();
        let any_absent = patches.iter().any(|&p| !p);
        Self { frame, primitives, patches, any_absent }
    }

    /// Whether patch `p` is present.
    #[inline]
    pub fn patch(&self, p: usize) -> bool {
        self.patches[p]
    }

    /// Whether a link between patches `a` and `b` is a link of the frame:
    /// a link with an end at an absent patch is not (§5.13, step 2).
    #[inline]
    pub fn link(&self, a: u32, b: u32) -> bool {
        self.patches[a as usize] && self.patches[b as usize]
    }

    /// The per-patch presence, or `None` when every patch is present (the
    /// distribution's kernels then skip the test).
    pub fn absent_mask(&self) -> Option<&[bool]> {
        self.any_absent.then_some(&self.patches[..])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spans_and_presence_follow_the_instances() {
        let frames = 5;
        let inst = |first_primitive, primitive_count, frame_first, frame_last| InstanceRecord {
            first_primitive,
            primitive_count,
            frame_first,
            frame_last,
            ..Default::default()
        };
        // A permanent primitive, then one moving surface as two instances.
        let instances = [inst(0, 1, 0, 4), inst(1, 2, 0, 1), inst(3, 2, 2, 4)];
        let spans = primitive_spans(&instances, 5);
        assert_eq!(spans[0], FrameSpan::all(frames));
        assert!(!spans[0].is_temporal(frames));
        assert!(spans[1].is_temporal(frames) && spans[4].is_temporal(frames));
        assert!(spans[2].contains(1) && !spans[2].contains(2));
        // Patches: two on the permanent primitive, one on each other.
        let patch_primitive = [0, 0, 1, 2, 3, 4];
        let at1 = FramePresence::new(1, &spans, &patch_primitive);
        assert_eq!(at1.patches, [true, true, true, true, false, false]);
        assert!(at1.link(0, 3) && !at1.link(0, 4) && !at1.link(5, 1));
        assert_eq!(at1.absent_mask().map(<[bool]>::len), Some(6));
        let still = FramePresence::new(0, &[FrameSpan::all(1)], &[0, 0]);
        assert!(still.absent_mask().is_none());
    }
}
