//! A frame's changes to frame 0's links, as signed link ends (§5.13): the
//! overlay the distribution gathers on top of frame 0's CSR.

use std::sync::Arc;

use crate::archive::layout::DeltaRecord;
use crate::archive::presence::FramePresence;

/// Link ends as CSR by owner patch, each owner's ends split into one run
/// per bucket (`offsets[q·B + k]..offsets[q·B + k + 1]`, B buckets).
#[derive(Debug, Default, PartialEq)]
pub(super) struct Ends {
    /// Per owner and bucket, where its run starts.
    pub(super) offsets: Vec<u32>,
    /// Other patches, each below `patches` (asserted in [`Ends::new`]).
    pub(super) other: Vec<u32>,
    /// Rays merged into the end (negative: removed).
    pub(super) weight: Vec<f32>,
    /// The end's outgoing direction.
    pub(super) direction: Vec<u32>,
    /// Patches in the archive.
    pub(super) patches: usize,
}

impl Ends {
    /// The ends of `records` (both ends of each) that `keep(owner, other)`.
    pub(super) fn new(n: usize, buckets: usize, records: &[DeltaRecord], keep: impl Fn(u32, u32) -> bool) -> Self {
        let slot = |me: u32, k: u8| me as usize * buckets + if buckets > 1 { k as usize } else { 0 };
        let ends = |d: &DeltaRecord| [(d.a, d.b, d.bucket_a, 2 * d.pair), (d.b, d.a, d.bucket_b, 2 * d.pair + 1)];
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

    /// Patch `q`'s ends of bucket `k`.
    pub(super) fn run(&self, q: usize, buckets: usize, k: usize) -> std::ops::Range<usize> {
        self.offsets[q * buckets + k] as usize..self.offsets[q * buckets + k + 1] as usize
    }
}

/// What a frame changes in frame 0's links: link ends added (positive
/// weights) or removed (negative).
pub(super) struct Overlay {
    /// Every end between two present patches, by owner (one bucket run
    /// each): what non-diffuse patches send and receive along. Built only
    /// for archives with non-diffuse patches.
    pub(super) all: Option<Ends>,
    /// The ends between two patches present in the frame, by owner and
    /// bucket: what the gather adds. Ends that touch an absent patch are
    /// left out: absent patches receive nothing and so send nothing,
    /// where adding frame 0's ends and subtracting them again would leave
    /// rounding residue.
    pub(super) gather: Arc<Ends>,
    /// Per patch, the change of its summed link weight.
    pub(super) linked: Vec<f64>,
}

impl Overlay {
    /// The overlay of a frame's delta `records` for the patches `present`
    /// then, its gather ends bucketed by `buckets` (and, for archives with
    /// non-diffuse patches, all its ends in one run per owner).
    pub(super) fn new(buckets: usize, records: &[DeltaRecord], present: &FramePresence, nondiffuse: bool) -> Self {
        // Links with an end at an absent patch are not links of the frame
        // (§5.13): files before version 6 list frame 0's such links as
        // removals, later files leave them out; both are skipped here, and
        // frame 0's links to patches absent from the frame are taken off
        // the linked weights by `Distributor::absent_ends`.
        let n = present.patches.len();
        let both = |me: u32, them: u32| present.link(me, them);
        let mut linked = vec![0.0f64; n];
        for d in records.iter().filter(|d| both(d.a, d.b)) {
            linked[d.a as usize] += d.count as f64;
            linked[d.b as usize] += d.count as f64;
        }
        let gather = Arc::new(Ends::new(n, buckets, records, both));
        let all = nondiffuse.then(|| Ends::new(n, 1, records, both));
        Self { all, gather, linked }
    }
}
