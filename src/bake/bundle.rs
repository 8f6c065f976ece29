//! The record tracing hands on: one direction pair's links, merged
//! ([`Bundle`]), and the counts of tracing ([`BundleStats`]).
//!
//! It sits below the files that make and take bundles: `trace` makes them,
//! `spill` writes them as sorted runs and `links` turns them into the link
//! table, so that none of those needs another's file for the type.

/// Links of one direction pair, merged: `a` faces along the pair's first
/// direction `d`, `b` faces back along `−d`, `w` parallel rays with the same
/// buckets joined them. Sorted by `(a, b, bucket_a, bucket_b)`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Bundle {
    /// Index `k` of the pair (directions `2k` and `2k+1`).
    pub pair: u32,
    /// Patch that sends along `d`.
    pub a: Vec<u32>,
    /// Patch that sends along `−d`.
    pub b: Vec<u32>,
    /// Number of rays merged into the link.
    pub w: Vec<u32>,
    /// Bucket of the end at `a` (light received by `a` over this link).
    pub bucket_a: Vec<u8>,
    /// Bucket of the end at `b`.
    pub bucket_b: Vec<u8>,
}

/// Counts from tracing.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BundleStats {
    /// Ray lines traced.
    pub rays: u64,
    /// Hits on surfaces.
    pub hits: u64,
    /// Links before merging.
    pub links: u64,
}
