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
}

/// Bytes of one patch's share of the rings a bucketed gather spreads light
/// over: ring k holds at most 2k² + 2k + 1 patches (a member and a weight
/// each) and an offset per patch.
fn ring_bytes(buckets: u64) -> u64 {
    (1..buckets).map(|k| 8 + 8 * (2 * k * k + 2 * k + 1)).sum()
}

/// Heap bytes a distribution of `s` holds at its peak (a frame being
/// solved while the previous frame's solution is kept).
pub fn state_bytes(s: &StateShape) -> u64 {
    let (p, nb, depth) = (s.patches, s.buckets.max(1), s.anderson_depth);
    // Distributor: rho, emit (12 each), share, area_eff, surface (4 each),
    // linked (8), in_base (1), rings; non-diffuse index per patch (4). (The
    // gather's runs are the archive's, `LRUN`, counted with it.)
    let distributor = p * (12 + 12 + 4 + 4 + 4 + 8 + 1 + 4) + p * ring_bytes(nb);
    // Frame setup: emit (12), emitted power (16), linked (8), presence (2).
    let setup = p * (12 + 16 + 8 + 2);
    // Iteration: seven [f32; 4] vectors, the gather's packed RGB (12),
    // received per bucket, Anderson's secant pairs, the warm guess, and a
    // sequence's running totals.
    let carry = if s.sequence { 24 + 24 * nb } else { 0 };
    let iteration = p * (7 * 16 + 12 + 16 * nb + 32 * depth + 16 + carry);
    // A solution: radiance, received, first bounce (12 each), residual (4),
    // and the carried totals plus emitted power. Its secant pairs are the
    // iteration's, moved into it (`step.rs`), so they are counted once
    // above; a sequence keeps the previous frame's besides (its solution's,
    // cloned into the next iteration as the warm start's).
    let solution = p * (40 + if s.sequence { carry + 16 } else { 0 });
    let previous_pairs = if s.sequence { p * 32 * depth } else { 0 };
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
    // transposed tables.
    let glossy = s.nondiffuse_slots * (2 * 16 + 12 + 4 + 4 + 12 + 2 * 2 * 12) + s.nondiffuse_ends * 12 + s.table_bytes;
    // A sequence keeps the previous frame's solution while it solves the
    // next (warm starts); a still has one frame, one solution.
    let solutions = if s.sequence { 2 } else { 1 };
    distributor + setup + iteration + solutions * solution + previous_pairs + overlay + glossy
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_estimate_grows_with_every_part_of_the_shape() {
        let base = StateShape { patches: 1000, buckets: 1, anderson_depth: 5, ..Default::default() };
        let b = state_bytes(&base);
        assert!(b > 1000 * 400 && b < 1000 * 2000, "{b} bytes for 1000 patches");
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
