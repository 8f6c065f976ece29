//! Link-end weights as stored since version 7 (§5.10): one byte per end
//! (`LCNT`), the number of parallel rays merged into the link, and the
//! rare weight that is not a whole number in 1..=255 kept apart (`LCNX`,
//! ascending by end, its `LCNT` byte 0).
//!
//! Builds merge a few rays per link (the Cornell box at default settings:
//! 76% of ends carry 1 ray, none more than 6), so one byte holds nearly
//! every weight exactly: the gather's stream is 5 bytes per end (`LOTH` +
//! `LCNT`) instead of 8, and, where no weight escapes, its sums are those
//! of the f32 weights bit for bit (a byte converts to the same f32).
//! Escapes are added by a separate, sparse pass (in another order than a
//! sum over f32 weights would take).

use std::ops::Range;

use super::ArchiveError;
use super::layout::WeightEscape;

/// The weights of a run of link ends: `counts[i]` is end `first_end + i`'s
/// ray count, or 0 when its weight is the escape with that end.
#[derive(Clone, Copy, Debug)]
pub struct Weights<'a> {
    counts: &'a [u8],
    escapes: &'a [WeightEscape],
    first_end: u64,
}

impl<'a> Weights<'a> {
    /// The weights of ends `first_end ..` given by `counts` and the escapes
    /// among them, which must be validated (each a zero of `counts`, every
    /// zero one of them; [`check`]). `escapes` may hold others too.
    pub fn new(counts: &'a [u8], escapes: &'a [WeightEscape], first_end: u64) -> Self {
        let end = first_end + counts.len() as u64;
        let a = escapes.partition_point(|x| x.end < first_end);
        let b = a + escapes[a..].partition_point(|x| x.end < end);
        Self { counts, escapes: &escapes[a..b], first_end }
    }

    /// The weights of all E ends, `counts` being `LCNT` and `escapes` all
    /// of `LCNX` (not narrowed, so that validation sees every record).
    pub fn whole(counts: &'a [u8], escapes: &'a [WeightEscape]) -> Self {
        Self { counts, escapes, first_end: 0 }
    }

    /// No weights (a column not read).
    pub fn empty() -> Self {
        Self { counts: &[], escapes: &[], first_end: 0 }
    }

    /// Ends covered.
    pub fn len(&self) -> usize {
        self.counts.len()
    }

    /// True when no ends are covered.
    pub fn is_empty(&self) -> bool {
        self.counts.is_empty()
    }

    /// The one-byte counts (0 where an escape holds the weight).
    pub fn counts(&self) -> &'a [u8] {
        self.counts
    }

    /// The escapes among these ends, ascending.
    pub fn escapes(&self) -> &'a [WeightEscape] {
        self.escapes
    }

    /// The index of the first end.
    pub fn first_end(&self) -> u64 {
        self.first_end
    }

    /// The weight of the `i`-th end covered.
    #[inline]
    pub fn get(&self, i: usize) -> f32 {
        match self.counts[i] {
            0 => {
                let e = self.first_end + i as u64;
                let k = self.escapes.partition_point(|x| x.end < e);
                // Validated: every zero count has its escape.
                self.escapes.get(k).filter(|x| x.end == e).map_or(0.0, |x| x.weight)
            }
            c => c as f32,
        }
    }

    /// The weights of the covered ends `range` (local indices).
    pub fn slice(&self, range: Range<usize>) -> Self {
        Self::new(&self.counts[range.clone()], self.escapes, self.first_end + range.start as u64)
    }

    /// Every weight, in order.
    pub fn iter(&self) -> impl Iterator<Item = f32> + '_ {
        (0..self.counts.len()).map(|i| self.get(i))
    }

    /// Every weight as f32 (for the few rows that are revisited).
    pub fn to_vec(&self) -> Vec<f32> {
        self.iter().collect()
    }
}

/// Appends the one-byte form of `weights`, the weights of ends
/// `first_end ..`, to `counts`, and their escapes to `escapes`.
pub fn encode(weights: &[f32], first_end: u64, counts: &mut Vec<u8>, escapes: &mut Vec<WeightEscape>) {
    counts.reserve(weights.len());
    for (i, &w) in weights.iter().enumerate() {
        let c = w as u8;
        // `as` saturates and truncates: only a whole number in 1..=255
        // comes back as itself.
        if c != 0 && c as f32 == w {
            counts.push(c);
        } else {
            counts.push(0);
            escapes.push(WeightEscape { end: first_end + i as u64, weight: w, reserved: 0 });
        }
    }
}

/// Checks the weights of ends `first_end ..` (`counts`) against `escapes`
/// (those of the whole archive, from the one at index `*next` on, which
/// this advances past the ones it consumed): every zero count has the
/// next escape, at its end; escapes are ascending, finite, ≥ 0, reserved
/// zero, and not whole numbers in 1..=255 (those belong in `LCNT`).
pub fn check(counts: &[u8], first_end: u64, escapes: &[WeightEscape], next: &mut usize) -> Result<(), String> {
    for (i, _) in counts.iter().enumerate().filter(|(_, c)| **c == 0) {
        let e = first_end + i as u64;
        let Some(x) = escapes.get(*next) else {
            return Err(format!("LCNT: end {e} has count 0 but LCNX has no entry for it"));
        };
        if x.end != e {
            return Err(format!(
                "LCNX[{}]: end {} where end {e} (count 0 in LCNT) was expected (ascending, one per zero count)",
                *next, x.end
            ));
        }
        let c = x.weight as u8;
        if !x.weight.is_finite() || x.weight < 0.0 || x.reserved != 0 || (c != 0 && c as f32 == x.weight) {
            return Err(format!(
                "LCNX[{}]: weight {} of end {e} is negative, non-finite or belongs in LCNT (or reserved not zero)",
                *next, x.weight
            ));
        }
        *next += 1;
    }
    Ok(())
}

/// Relative slack on sums of f32 ray counts (exact integers below 2²⁴;
/// larger sums round).
const SUM_SLACK: f64 = 1e-6;

/// Folds link-end weights into per-patch sums and checks each finished
/// patch's sum against its hit count `PHIT[p]` (each ray line crossing a
/// patch makes at most one link end there). Fed weights in end order, in
/// any slicing.
pub(super) struct WeightSums<'a> {
    offsets: &'a [u64],
    hits: &'a [u32],
    /// The patch whose ends come next.
    patch: usize,
    /// The end that comes next.
    end: usize,
    sum: f64,
}

impl<'a> WeightSums<'a> {
    /// Sums over the rows `offsets` (validated CSR) of patches with `hits`.
    pub(super) fn new(offsets: &'a [u64], hits: &'a [u32]) -> Self {
        Self { offsets, hits, patch: 0, end: 0, sum: 0.0 }
    }

    /// Adds the next `weights` (ends `self.end ..`).
    pub(super) fn add(&mut self, weights: Weights<'_>) -> Result<(), ArchiveError> {
        let mut i = 0;
        while i < weights.len() {
            self.finish_empty()?;
            let row_end = self.offsets[self.patch + 1] as usize;
            let take = (row_end - self.end).min(weights.len() - i);
            self.sum += weights.slice(i..i + take).iter().map(|w| w as f64).sum::<f64>();
            self.end += take;
            i += take;
        }
        self.finish_empty()
    }

    /// Closes every patch whose row is complete.
    fn finish_empty(&mut self) -> Result<(), ArchiveError> {
        while self.patch + 1 < self.offsets.len() && self.offsets[self.patch + 1] as usize == self.end {
            let h = self.hits[self.patch] as f64;
            if self.sum > h * (1.0 + SUM_SLACK) {
                return Err(ArchiveError::corrupt(format!(
                    "LCNT: patch {}'s link ends carry {} rays, more than the {h} that cross it (PHIT)",
                    self.patch, self.sum
                )));
            }
            self.sum = 0.0;
            self.patch += 1;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encoding_keeps_every_weight_and_escapes_only_the_rest() {
        let w = [1.0f32, 255.0, 256.0, 0.0, 3.5, 7.0, 1e9, 2.0];
        let (mut counts, mut escapes) = (Vec::new(), Vec::new());
        encode(&w[..4], 100, &mut counts, &mut escapes);
        encode(&w[4..], 104, &mut counts, &mut escapes);
        assert_eq!(counts, [1, 255, 0, 0, 0, 7, 0, 2]);
        assert_eq!(escapes.iter().map(|x| x.end).collect::<Vec<_>>(), [102, 103, 104, 106]);
        let all = Weights::new(&counts, &escapes, 100);
        assert_eq!(all.to_vec(), w);
        // A slice sees its own escapes only.
        let s = all.slice(3..6);
        assert_eq!(s.to_vec(), &w[3..6]);
        assert_eq!(s.escapes().len(), 2);
        let mut next = 0;
        check(&counts, 100, &escapes, &mut next).unwrap();
        assert_eq!(next, escapes.len());
        // A zero without its escape, an escape that belongs in LCNT, an
        // escape out of order: each refused.
        let mut next = 0;
        assert!(check(&counts, 100, &escapes[1..], &mut next).is_err());
        let mut bad = escapes.clone();
        bad[0].weight = 9.0;
        assert!(check(&counts, 100, &bad, &mut 0).unwrap_err().contains("belongs in LCNT"));
        bad = escapes.clone();
        bad.swap(0, 1);
        assert!(check(&counts, 100, &bad, &mut 0).is_err());
        bad = escapes;
        bad[3].weight = f32::NAN;
        assert!(check(&counts, 100, &bad, &mut 0).is_err());
    }
}
