//! What a distribution holds in memory, estimated from an archive's shape
//! before any of it is read, so that a memory budget can be checked before
//! work starts (`render --memory-budget`). The estimate counts every
//! per-patch vector of the distributor, the frame setup, the iteration,
//! the warm start and the solutions (a sequence keeps two: the previous
//! frame's and the current), field by field, and the frame overlays; it is
//! checked against measured peaks in `tests/budget.rs`.

/// The shape of a distribution, as far as memory goes.
#[derive(Clone, Copy, Debug, Default)]
pub struct StateShape {
    /// Patches.
    pub patches: u64,
    /// Buckets the gather sorts light into (`max_bucket + 1`, 1 without).
    pub buckets: u64,
    /// Secant pairs of the Anderson acceleration.
    pub anderson_depth: u64,
    /// Whether the archive is a sequence (warm starts keep totals).
    pub sequence: bool,
    /// Non-diffuse patches × directions: the per-ray state of glossy light.
    pub nondiffuse_slots: u64,
    /// Link ends of the non-diffuse patches, copied when streamed.
    pub nondiffuse_ends: u64,
    /// Bytes of the prototype tables' entries and factors: the distributor
    /// keeps each table transposed as well.
    pub table_bytes: u64,
    /// The most delta records a frame of the sequence has.
    pub max_delta_records: u64,
    /// Whether the secant pairs and received totals are kept in scratch
    /// files instead of memory (`Distributor::spill_in`).
    pub spill: bool,
}

/// Bytes of one patch's share of the rings a bucketed gather spreads light
/// over: ring k ≥ 2 holds at most 2k² + 2k + 1 patches (4 bytes a member;
/// the weights are computed from the rings' sizes) and an offset per patch
/// (4); the 1-ring is the archive's adjacency, counted with it.
fn ring_bytes(buckets: u64) -> u64 {
    (2..buckets).map(|k| 4 + 4 * (2 * k * k + 2 * k + 1)).sum()
}

/// Per patch: what the distributor keeps for the archive (linked (f64,
/// 8), in_base (1), the rings; the non-diffuse index (4) when there are
/// non-diffuse patches).
/// Surfaces, reflectance, emission, link shares, back-face shares and
/// effective areas are not kept per patch: they come from the surface
/// tables and the archive's patch columns where they are used. (The
/// gather's runs are the archive's, `LRUN`, counted with it.)
fn distributor_bytes(s: &StateShape) -> u64 {
    8 + 1 + if s.nondiffuse_slots > 0 { 4 } else { 0 } + ring_bytes(s.buckets.max(1))
}

/// Per patch: a frame's iteration: unshot, send and the two received
/// totals (RGB, 12 each; what the rings spread onto a patch is computed
/// where it is used, not kept), what it shoots (RGB packed, 12: the
/// gathers read it so),
/// received per bucket (RGB, 12 each), Anderson's secant pairs (two bfloat16
/// RGB vectors, 12 a pair; the step's change of the residual is written
/// straight into its pair, no vector of its own).
/// Spilled, the totals and the pairs are not in memory.
fn iteration_bytes(s: &StateShape) -> u64 {
    3 * 12 + 12 * s.buckets.max(1) + in_memory(s, spilled_patch_bytes(s))
}

/// `bytes` when the state is in memory, else nothing.
fn in_memory(s: &StateShape, bytes: u64) -> u64 {
    if s.spill { 0 } else { bytes }
}

/// Per patch: what a spilled iteration keeps in its scratch files instead
/// of memory: the two received totals (24) and the secant pairs (12 a
/// pair).
fn spilled_patch_bytes(s: &StateShape) -> u64 {
    24 + 12 * s.anderson_depth
}

/// Bytes the scratch files of a spilled distribution hold at most (a
/// sequence's previous frame keeps its pairs too; 0 unspilled).
pub fn spilled_bytes(s: &StateShape) -> u64 {
    let pairs = if s.sequence { 12 * s.anderson_depth } else { 0 };
    if s.spill { s.patches * (spilled_patch_bytes(s) + pairs) } else { 0 }
}

/// Per patch: a solution: radiance, received, first bounce (12 each),
/// residual (4).
const SOLUTION: u64 = 40;

/// Bytes a patch of the distribution's state holds at its peak, field by
/// field. A still's peak is its loop: its solution is made as the loop's
/// vectors are freed (`step.rs`, `finish`: send and the secant pairs
/// first, 12 + 12·depth in memory, before the first bounce, 12; the
/// gather's buffers before received and the residual, 16; the unshot
/// power before the radiance, 12). A sequence holds the frame's setup, its warm
/// start and the running totals, and the previous frame's solution with
/// its secant pairs, beside it: counted in full.
pub fn patch_bytes(s: &StateShape) -> u64 {
    let (nb, depth) = (s.buckets.max(1), s.anderson_depth);
    let (distributor, iteration) = (distributor_bytes(s), iteration_bytes(s));
    if !s.sequence {
        return distributor + iteration;
    }
    // A frame's linked weights (8) and presence (2); the warm guess (16);
    // the totals carried to the next frame (24, and 24 per bucket); a
    // solution carries them and its emitted power (16); the previous
    // frame's solution and secant pairs.
    let carry = 24 + 24 * nb;
    let solution = SOLUTION + carry + 16;
    distributor + (8 + 2) + iteration + 16 + carry + 2 * solution + in_memory(s, 12 * depth)
}

/// Bytes a patch of the distribution's state still holds once a still's
/// frame is solved (the distributor's and the solution's): the rest of
/// [`patch_bytes`] is free again for the renderer's vectors. A sequence's
/// next frame needs it all again: [`patch_bytes`].
pub fn kept_patch_bytes(s: &StateShape) -> u64 {
    match s.sequence {
        true => patch_bytes(s),
        false => distributor_bytes(s) + SOLUTION,
    }
}

/// Heap bytes a distribution of `s` holds at its peak (a frame being
/// solved while the previous frame's solution is kept).
pub fn state_bytes(s: &StateShape) -> u64 {
    let (p, nb) = (s.patches, s.buckets.max(1));
    // A frame's overlay (records, and the ends sorted per patch and
    // bucket), twice: the frame's and the one the warm start carries.
    let records = s.max_delta_records;
    // The overlay is made while the records are checked against frame 0
    // (`InetView::frame_links_with`): the check's two 24-byte ends per
    // removal, two 8-byte offsets per patch and the patches wanted (4) are
    // held beside it, and beside the overlay's cursor while it is built
    // (4 bytes per patch and bucket).
    let check = records * 2 * 24 + p * (20 + 4 * nb + 4);
    let overlay = if s.sequence { 2 * (records * (20 + 2 * 12 + 2 * 12) + p * (4 * nb + 4 + 8)) + check } else { 0 };
    // Glossy: per ray slot two [f32; 4] vectors and the running radiance
    // (12), rays, linked, incoming scale (at most 12); the directional
    // radiance of two solutions and its direct part; the copied ends; the
    // transposed tables; and per patch what it shot since the last table
    // step ([f32; 4], 16).
    let shot = if s.nondiffuse_slots > 0 { p * 16 } else { 0 };
    let glossy =
        s.nondiffuse_slots * (2 * 16 + 12 + 4 + 4 + 12 + 2 * 2 * 12) + s.nondiffuse_ends * 12 + s.table_bytes + shot;
    p * patch_bytes(s) + overlay + glossy
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_estimate_grows_with_every_part_of_the_shape() {
        let base = StateShape { patches: 1000, buckets: 1, anderson_depth: 5, ..Default::default() };
        let b = state_bytes(&base);
        assert!(b > 1000 * 120 && b < 1000 * 400, "{b} bytes for 1000 patches");
        // Spilled: the pairs and totals (24 + 60) leave memory, and the
        // finish (the solution made beside the loop's vectors) is the peak.
        let spilled = StateShape { spill: true, ..base };
        assert_eq!(spilled_bytes(&spilled), 1000 * 84);
        assert_eq!(spilled_bytes(&base), 0);
        let (plain, kept) = (patch_bytes(&base), patch_bytes(&spilled));
        assert!(kept < plain - 60 && kept <= 96, "{plain} → {kept} bytes a patch");
        for more in [
            StateShape { patches: 2000, ..base },
            StateShape { buckets: 4, ..base },
            StateShape { sequence: true, max_delta_records: 10, ..base },
            StateShape { nondiffuse_slots: 100, ..base },
            StateShape { table_bytes: 100, ..base },
        ] {
            assert!(state_bytes(&more) > b, "{more:?}");
        }
    }
}
