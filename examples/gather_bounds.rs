//! What bounds the distribution's gather on a given archive: the bytes of
//! the link-end stream (`LOTH` + `LCNT`, 5 an end) or the reads of
//! per-patch state at the ends' other patches. Three passes over the
//! mapped archive's link ends, each three times, on 1 and 2 threads:
//! the stream alone (summing its bytes), a gather as the distribution's
//! (four partial sums of count × state), and the same gather with the
//! other-patch ids masked into the first 2¹⁴ patches, whose 256 KiB of
//! state stay in the core's cache. If masking gains little, the state's
//! locality is not the limit; if the gather is near the stream-only rate,
//! the stream's bandwidth is. Numbers for `docs/PERFORMANCE.md`:
//!
//! ```text
//! cargo run --release --example gather_bounds -- ARCHIVE.inet
//! ```

use std::time::Instant;

use illumnet::archive::Archive;
use rayon::prelude::*;

/// Patches per parallel task, as the distribution's.
const BLOCK: usize = 512;

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
    const PASSES: usize = 3;
    let ends = (other.len() * PASSES) as f64;
    println!(
        "{path}: {patches} patches, {} link ends ({:.1} ends a patch)",
        other.len(),
        other.len() as f64 / patches as f64
    );
    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a thread pool");
        pool.install(|| {
            let t = Instant::now();
            let mut sum = 0u64;
            for _ in 0..PASSES {
                let ids: u64 = other.par_chunks(1 << 16).map(|c| c.iter().map(|&x| x as u64).sum::<u64>()).sum();
                let counts: u64 = count.par_chunks(1 << 16).map(|c| c.iter().map(|&x| x as u64).sum::<u64>()).sum();
                sum = sum.wrapping_add(ids + counts);
            }
            let s = t.elapsed().as_secs_f64();
            println!(
                "{threads} thread(s): stream only {:>6.0} M ends/s ({:.1} GB/s; checksum {sum})",
                ends / s / 1e6,
                ends * 5.0 / s / 1e9
            );
            for (what, mask) in [("gather", u32::MAX), ("gather, ids masked to 2^14 patches", (1 << 14) - 1)] {
                let t = Instant::now();
                for _ in 0..PASSES {
                    gather(offsets, other, count, &shoot, mask, &mut recv);
                }
                let s = t.elapsed().as_secs_f64();
                println!("{threads} thread(s): {what:<36} {:>6.0} M ends/s ({})", ends / s / 1e6, recv[patches / 2][0]);
            }
        });
    }
}

/// `recv[q] = Σ count·shoot[other & mask]` over each patch's ends.
fn gather(offsets: &[u64], other: &[u32], count: &[u8], shoot: &[[f32; 4]], mask: u32, recv: &mut [[f32; 4]]) {
    let last = shoot.len() - 1;
    recv.par_chunks_mut(BLOCK).enumerate().for_each(|(block, out)| {
        for (i, r) in out.iter_mut().enumerate() {
            let q = block * BLOCK + i;
            let row = offsets[q] as usize..offsets[q + 1] as usize;
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
