//! A tracer's reusable scratch: the buffers one chunk of pairs walks its
//! rays in ([`Scratch`], lent from a pool by [`ScratchLease`]) and the
//! per-patch hit counts a worker adds up before it adds them to the shared
//! totals ([`HitCounts`]).

use std::sync::atomic::{AtomicU64, Ordering};

use super::{LinkKey, RayHitRecord};
use crate::archive::deltas::BlockCompressor;
use crate::archive::layout::DeltaRecord;

/// Scratch space of one chunk of pairs (reused through a pool).
#[derive(Default)]
pub(super) struct Scratch {
    pub(super) hits: Vec<RayHitRecord>,
    /// A band's hits as the scan conversion finds them (`raster.rs`):
    /// `slots_per_ray` a ray ([`super::SLOTS`]), their count per ray, and
    /// a ray's hits past its slots as `(ray in the band, hit)`.
    pub(super) slots: Vec<RayHitRecord>,
    pub(super) slot_count: Vec<u8>,
    pub(super) slots_per_ray: usize,
    pub(super) overflow: Vec<(u32, RayHitRecord)>,
    /// Where each rasterised primitive falls on the current pair's grid,
    /// and the projections of those a band's rows may meet.
    pub(super) extents: Vec<super::raster::Extent>,
    pub(super) projected: Vec<super::raster::Projected>,
    pub(super) keys: Vec<LinkKey>,
    /// The keys' sort's second buffer (`sort.rs`).
    pub(super) sort_buffer: Vec<LinkKey>,
    /// The keys packed in words and their sort's second half (`sort.rs`;
    /// used instead of `sort_buffer` when a build's keys fit 64 bits).
    pub(super) words: Vec<u64>,
    pub(super) frame_links: Vec<LinkKey>,
    pub(super) prev_links: Vec<LinkKey>,
    pub(super) change_frames: Vec<u32>,
    /// Per frame, the current pair's changes at that frame (per ray, unmerged).
    pub(super) changes: Vec<Vec<DeltaRecord>>,
    /// The current pair's changes relative to frame 0 at the previous frame,
    /// and the next frame's.
    pub(super) cumulative: Vec<DeltaRecord>,
    pub(super) next: Vec<DeltaRecord>,
    /// Per frame, the chunk's changes relative to frame 0, in pair order.
    pub(super) chunk: Vec<Vec<DeltaRecord>>,
    pub(super) compressor: Option<BlockCompressor>,
    pub(super) counts: HitCounts,
    /// Per temporal ray: indices of its permanent hits, of its temporal hits
    /// by first frame, of the temporal hits present at the current change
    /// frame, and of all hits present there (each ascending in ray order
    /// but `by_first`).
    pub(super) permanent: Vec<u32>,
    pub(super) by_first: Vec<u32>,
    pub(super) active: Vec<u32>,
    pub(super) walk: Vec<u32>,
    /// Bytes of the per-pair buffers above reported to a bounded build's
    /// count ([`Scratch::grown`]).
    pub(super) reported: u64,
}

impl Scratch {
    /// Bytes the per-pair buffers have grown by since last asked (they
    /// grow with a pair's rays and links, and are kept for the next pair).
    pub(super) fn grown(&mut self) -> u64 {
        fn cap<T>(v: &Vec<T>) -> u64 {
            (v.capacity() * size_of::<T>()) as u64
        }
        let frames: u64 = self.changes.iter().map(cap).sum();
        let bytes = cap(&self.hits)
            + cap(&self.slots)
            + cap(&self.slot_count)
            + cap(&self.overflow)
            + cap(&self.extents)
            + cap(&self.projected)
            + cap(&self.keys)
            + cap(&self.sort_buffer)
            + cap(&self.words)
            + cap(&self.frame_links)
            + cap(&self.prev_links)
            + cap(&self.change_frames)
            + frames
            + cap(&self.cumulative)
            + cap(&self.next)
            + cap(&self.permanent)
            + cap(&self.by_first)
            + cap(&self.active)
            + cap(&self.walk);
        let grown = bytes.saturating_sub(self.reported);
        self.reported = self.reported.max(bytes);
        grown
    }
}

/// Hits per patch counted by one worker and added to the shared totals when
/// its chunk is done: one atomic addition per patch touched instead of one
/// per hit (two workers adding to the same patches' counters hit by hit
/// spent a quarter of the walks in contended atomics).
#[derive(Default)]
pub(super) struct LocalCounts {
    count: Vec<u64>,
    touched: Vec<u32>,
}

impl LocalCounts {
    #[inline]
    pub(super) fn add(&mut self, patch: u32) {
        let c = &mut self.count[patch as usize];
        if *c == 0 {
            self.touched.push(patch);
        }
        *c += 1;
    }

    pub(super) fn flush(&mut self, totals: &[AtomicU64]) {
        for &p in &self.touched {
            totals[p as usize].fetch_add(std::mem::take(&mut self.count[p as usize]), Ordering::Relaxed);
        }
        self.touched.clear();
    }
}

/// A worker's per-patch counts: hits (`H_p`) and, of those, rays whose
/// light meets a back face.
#[derive(Default)]
pub(super) struct HitCounts {
    pub(super) hits: LocalCounts,
    pub(super) backs: LocalCounts,
}

impl HitCounts {
    /// Counts for `patches` patches: 24 bytes a patch, all told (a bounded
    /// build counts them so, `fixed_build_bytes`).
    pub(super) fn resize(&mut self, patches: usize) {
        for c in [&mut self.hits, &mut self.backs] {
            c.count.resize(patches, 0);
            c.touched.reserve_exact(patches.saturating_sub(c.touched.len()));
        }
    }
}

/// A [`Scratch`] borrowed from a pool, returned when dropped.
pub(super) struct ScratchLease<'p> {
    pool: &'p std::sync::Mutex<Vec<Scratch>>,
    scratch: Option<Scratch>,
}

impl<'p> ScratchLease<'p> {
    pub(super) fn take(pool: &'p std::sync::Mutex<Vec<Scratch>>) -> Self {
        let scratch = pool.lock().map(|mut p| p.pop()).unwrap_or_default().unwrap_or_default();
        Self { pool, scratch: Some(scratch) }
    }
}

impl std::ops::Deref for ScratchLease<'_> {
    type Target = Scratch;
    fn deref(&self) -> &Scratch {
        self.scratch.as_ref().expect("held until dropped")
    }
}

impl std::ops::DerefMut for ScratchLease<'_> {
    fn deref_mut(&mut self) -> &mut Scratch {
        self.scratch.as_mut().expect("held until dropped")
    }
}

impl Drop for ScratchLease<'_> {
    fn drop(&mut self) {
        if let (Ok(mut p), Some(s)) = (self.pool.lock(), self.scratch.take()) {
            p.push(s);
        }
    }
}
