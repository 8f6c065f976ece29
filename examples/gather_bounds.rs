//! What bounds the distribution's gather on a given archive: reading the
//! link-end stream (`LOTH` + `LCNT`, 5 bytes an end) from wherever it
//! lives (L3 or DRAM), or the reads of per-patch state at the ends' other
//! patches. Passes over the mapped archive's link ends, on 1 and 2
//! threads:
//!
//! - the stream alone (summing both columns, a chunk of each at a time);
//! - a gather like the distribution's (four partial sums of count ×
//!   state), as it is, with the other-patch ids masked into the first 2¹⁴
//!   patches (256 KiB of state, in the core's cache), with the stream
//!   prefetched 4 KiB ahead (x86-64), and with both;
//! - the masked gather over the first rows holding ~14 M ends (70 MB,
//!   which stay in a large L3), repeated to the same count of ends.
//!
//! Numbers for `docs/PERFORMANCE.md`:
//!
//! ```text
//! cargo run --release --example gather_bounds -- ARCHIVE.inet
//! ```

use std::time::Instant;

use illumnet::archive::Archive;
use rayon::prelude::*;

/// Patches per parallel task, as the distribution's.
const BLOCK: usize = 512;
/// Passes over all link ends per measurement.
const PASSES: usize = 3;
/// Ids masked into the first 2¹⁴ patches.
const MASK: u32 = (1 << 14) - 1;

fn main() {
    let Some(path) = std::env::args().nth(1) else {
        eprintln!("usage: gather_bounds ARCHIVE.inet");
        std::process::exit(2);
    };
    let archive = match Archive::open(std::path::Path::new(&path)) {
        Ok(a) => a,
        Err(e) => {
            eprintln!("gather_bounds: {path}: {e}");
            std::process::exit(1);
        }
    };
    let v = archive.view();
    let Some(links) = v.links.resident() else {
        eprintln!("gather_bounds: {path}: the link ends are not resident");
        std::process::exit(1);
    };
    let (other, count, offsets) = (links.other.ids(), links.weight.counts(), v.link_offsets);
    let patches = offsets.len() - 1;
    let shoot: Vec<[f32; 4]> = (0..patches).map(|i| [i as f32 * 1e-6, 1.0, 2.0, 0.0]).collect();
    let mut recv = vec![[0f32; 4]; patches];
    let ends = (other.len() * PASSES) as f64;
    println!(
        "{path}: {patches} patches, {} link ends ({:.1} ends a patch)",
        other.len(),
        other.len() as f64 / patches as f64
    );
    // The first rows holding ~14 M ends, and how often to repeat them.
    let sub = offsets.partition_point(|&o| o < 14_000_000).min(patches);
    let reps = (other.len() / (offsets[sub] as usize).max(1)).max(1);
    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a thread pool");
        pool.install(|| {
            let t = Instant::now();
            let mut sum = 0u64;
            for _ in 0..PASSES {
                let chunk = 1 << 16;
                let pass: u64 = other
                    .par_chunks(chunk)
                    .zip(count.par_chunks(chunk))
                    .map(|(o, w)| {
                        let a = o.iter().fold(0u32, |a, &x| a.wrapping_add(x));
                        let b = w.iter().fold(0u32, |a, &x| a.wrapping_add(x as u32));
                        a.wrapping_add(b) as u64
                    })
                    .sum();
                sum = sum.wrapping_add(pass);
            }
            let s = t.elapsed().as_secs_f64();
            let line = |what: &str, rate: f64| println!("{threads} thread(s): {what:<44} {:>6.0} M ends/s", rate / 1e6);
            line(&format!("stream only ({:.1} GB/s; {sum})", ends * 5.0 / s / 1e9), ends / s);
            let variants = [
                ("gather", u32::MAX, false),
                ("gather, ids masked", MASK, false),
                ("gather, stream prefetched", u32::MAX, true),
            ];
            for (what, mask, prefetch) in variants.into_iter().chain([("gather, masked and prefetched", MASK, true)]) {
                let t = Instant::now();
                for _ in 0..PASSES {
                    gather(offsets, other, count, &shoot, mask, prefetch, &mut recv);
                }
                line(what, ends / t.elapsed().as_secs_f64());
            }
            let t = Instant::now();
            for _ in 0..PASSES * reps {
                gather(&offsets[..sub + 1], other, count, &shoot, MASK, false, &mut recv[..sub]);
            }
            let n = offsets[sub] as f64 * (PASSES * reps) as f64;
            line(&format!("gather, masked, first {sub} patches x{reps}"), n / t.elapsed().as_secs_f64());
        });
    }
}

/// `recv[q] = Σ count·shoot[other & mask]` over each patch's ends (rows
/// `offsets[q]..offsets[q + 1]`), optionally prefetching the stream.
fn gather(
    offsets: &[u64],
    other: &[u32],
    count: &[u8],
    shoot: &[[f32; 4]],
    mask: u32,
    prefetch: bool,
    recv: &mut [[f32; 4]],
) {
    let last = shoot.len() - 1;
    recv.par_chunks_mut(BLOCK).enumerate().for_each(|(block, out)| {
        for (i, r) in out.iter_mut().enumerate() {
            let q = block * BLOCK + i;
            let row = offsets[q] as usize..offsets[q + 1] as usize;
            if prefetch {
                prefetch_ahead(other, count, row.clone());
            }
            let (o, w) = (&other[row.clone()], &count[row]);
            let mut acc = [[0f32; 4]; 4];
            for (o4, w4) in o.chunks(4).zip(w.chunks(4)) {
                for (j, (&o, &w)) in o4.iter().zip(w4).enumerate() {
                    let s = shoot[((o & mask) as usize).min(last)];
                    for c in 0..4 {
                        acc[j][c] += w as f32 * s[c];
                    }
                }
            }
            *r = [0, 1, 2, 3].map(|c| (acc[0][c] + acc[1][c]) + (acc[2][c] + acc[3][c]));
        }
    });
}

/// Asks for the cache lines of both columns 1 024 ends past `row`.
#[cfg(target_arch = "x86_64")]
fn prefetch_ahead(other: &[u32], count: &[u8], row: std::ops::Range<usize>) {
    use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
    for k in row.step_by(16) {
        // SAFETY: a prefetch is a hint that reads no memory and faults on
        // no address; the pointers are formed with wrapping arithmetic.
        unsafe {
            _mm_prefetch::<_MM_HINT_T0>(other.as_ptr().wrapping_add(k + 1024).cast());
            if k % 64 == 0 {
                _mm_prefetch::<_MM_HINT_T0>(count.as_ptr().wrapping_add(k + 1024).cast());
            }
        }
    }
}

#[cfg(not(target_arch = "x86_64"))]
fn prefetch_ahead(_: &[u32], _: &[u8], _: std::ops::Range<usize>) {}
