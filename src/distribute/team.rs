//! A distribution shared by several processes (`render --mpi`): each
//! *member* of a [`Team`] gathers light over the link ends of its own
//! contiguous range of receivers only, and after every gather the members
//! give each other what their receivers got. Everything else an iteration
//! does (shooting, spreading, reflecting, Anderson's mix, the energy
//! balance) is per patch and cheap next to the gather; every member does it
//! whole, over the same inputs, in the same block order, and so reaches
//! the same bits. That is what makes 1, 2 and 4 processes give one image:
//! no sum is ever split across members, and a receiver's row is summed
//! within one member in the order one process sums it.
//!
//! The link ends, the cost that grows to terabytes, are divided; the
//! per-patch state is not (each member holds all of it, `memory.rs`). The
//! exchange is the received light of every patch and bucket, 16 bytes
//! each, once per gather.
//!
//! The trait is the distribution's whole view of the transport: the
//! command line implements it with MPI (`cli/mpi.rs`, the `mpi` feature),
//! tests with threads.

use std::ops::Range;

/// Processes sharing one distribution, as the distribution sees them.
///
/// Every member calls the same methods in the same order (they are
/// collective: a member waits in each until all have called it). They are
/// called only from the thread that drives the iteration, never from the
/// gather's workers.
pub trait Team: Sync {
    /// This member's index, `0..size()`.
    fn rank(&self) -> usize;
    /// Members.
    fn size(&self) -> usize;
    /// All-gather: `parts[r]` is member `r`'s share of `data` (the parts
    /// are disjoint and ascending); each member gives its own share and
    /// receives everyone else's into `data`.
    fn share_f32(&self, data: &mut [f32], parts: &[Range<usize>]);
    /// [`Self::share_f32`] for `f64` values.
    fn share_f64(&self, data: &mut [f64], parts: &[Range<usize>]);
    /// Entry by entry, the largest of the members' values, on every member
    /// (an exact reduction whatever its order: used for flags).
    fn max_u8(&self, data: &mut [u8]);
    /// Member 0's `value`, on every member: for decisions that must be
    /// the same everywhere (whether a frame is skipped).
    fn leader_says(&self, value: bool) -> bool;
}

/// The receivers of each of `members` members: contiguous ranges of
/// patches, ascending, covering `0..n` (`n = link_offsets.len() − 1`),
/// each holding close to `1/members` of the link ends (`link_offsets` is
/// `LOFF`): the gather's cost is its ends.
pub fn receiver_ranges(link_offsets: &[u64], members: usize) -> Vec<Range<usize>> {
    let n = link_offsets.len().saturating_sub(1);
    let members = members.max(1);
    let total = link_offsets.last().copied().unwrap_or(0) as u128;
    let mut cuts: Vec<usize> = (0..=members)
        .map(|r| match r {
            0 => 0,
            r if r == members => n,
            r => {
                let target = (total * r as u128 / members as u128) as u64;
                link_offsets[..n].partition_point(|&o| o < target)
            }
        })
        .collect();
    // Monotone by construction; kept so if `LOFF` were not.
    for r in 1..cuts.len() {
        cuts[r] = cuts[r].max(cuts[r - 1]);
    }
    cuts.windows(2).map(|c| c[0]..c[1]).collect()
}

/// The ranges of `parts` scaled by `k` entries a patch.
pub(super) fn scaled(parts: &[Range<usize>], k: usize) -> Vec<Range<usize>> {
    parts.iter().map(|r| r.start * k..r.end * k).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_cover_every_patch_once_and_balance_the_ends() {
        // 10 patches; patch 3 has 100 ends, the rest 10 each.
        let mut offsets = vec![0u64];
        for p in 0..10 {
            let ends = if p == 3 { 100 } else { 10 };
            offsets.push(offsets[p] + ends);
        }
        for members in 1..=12 {
            let r = receiver_ranges(&offsets, members);
            assert_eq!(r.len(), members);
            assert_eq!(r[0].start, 0);
            assert_eq!(r[members - 1].end, 10);
            for w in r.windows(2) {
                assert_eq!(w[0].end, w[1].start);
            }
        }
        // Two members: the first patch at or past half the 190 ends is
        // the one after the heavy patch (130 ends before, 60 after; the
        // cut before it would leave 160 after).
        assert_eq!(receiver_ranges(&offsets, 2), vec![0..4, 4..10]);
        assert_eq!(receiver_ranges(&[0], 3), vec![0..0, 0..0, 0..0]);
    }
}
