//! What bounds the distribution's gather on a given archive: reading the
//! link-end stream from wherever it lives (L3 or DRAM), or the reads of
//! per-patch state at the ends' other patches. The archive's ends are
//! decoded to 32-bit ids (format 9's rows: `LOTH` + `LCNT`, 5 bytes an
//! end; format 10 stores 16-bit ids in runs, 3 bytes), and timed in
//! passes on 1 and 2 threads:
//!
//! - the stream alone (summing both columns, a chunk of each at a time);
//! - a gather like the distribution's (four partial sums of count ×
//!   state), as it is, with the other-patch ids masked into the first 2¹⁴
//!   patches (256 KiB of state, in the core's cache), with the stream
//!   prefetched 4 KiB ahead (x86-64), and with both;
//! - the masked gather over the first rows holding ~14 M ends (70 MB,
//!   which stay in a large L3), repeated to the same count of ends;
//! - the same gather over the ends re-laid in memory in blocks of
//!   (receiver chunk, sender chunk) with 16-bit ids local to the sender
//!   chunk (issue 11, item 4's layout, tried before it goes into the
//!   format), per receiver in runs, or sorted by sender with each end's
//!   receiver beside it;
//! - the distribution's loop over rows, asking for the state of the end
//!   0, 16, 32 or 64 ends ahead (software prefetch);
//! - the loop over rows with smaller per-patch state: 12 bytes (RGB in
//!   f32) and 8 bytes (a bound on what a smaller state's locality gives).
//!
//! Numbers for the notebook (`docs/notebook/2026-12-04-what-bounds-the-gather.md`
//! and the gather entries after it):
//!
//! ```text
//! cargo run --release --example gather_bounds -- ARCHIVE.inet [--blockings B] [--blocked-only] [--row-runs]
//! ```
//!
//! `--blockings 16x1024,13x1024,…` sets the (sender-chunk bits × receivers
//! a chunk) layouts tried (default `15x1024,16x1024,16x4096`);
//! `--blocked-only` times, on two threads, only the row gather and those
//! layouts; `--row-runs` times them with the ends left in row order (each
//! receiver's ends together, in runs by sender chunk, as the archive
//! stores them) and gathered in the same 2-D order, so that only the
//! stream's order differs from the blocked layout's.

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
    let usage = || -> ! {
        eprintln!("usage: gather_bounds ARCHIVE.inet [--blockings BITSxRECEIVERS,...] [--blocked-only] [--row-runs]");
        std::process::exit(2);
    };
    let mut args = std::env::args().skip(1);
    let (mut path, mut blockings, mut only, mut row_runs) = (None, BLOCKINGS.to_vec(), false, false);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--blocked-only" => only = true,
            "--row-runs" => row_runs = true,
            "--blockings" => {
                let list = args.next().unwrap_or_else(|| usage());
                blockings = list
                    .split(',')
                    .map(|x| {
                        let (b, r) = x.split_once('x').unwrap_or_else(|| usage());
                        match (b.parse::<u32>(), r.parse::<usize>()) {
                            (Ok(b @ 1..=16), Ok(r @ 1..=65_536)) => (b, r),
                            _ => usage(),
                        }
                    })
                    .collect();
            }
            _ if path.is_none() && !a.starts_with('-') => path = Some(a),
            _ => usage(),
        }
    }
    let Some(path) = path else { usage() };
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
    let decoded = links.window().other_ids();
    let (other, count, offsets) = (&decoded[..], links.weight.counts(), v.link_offsets);
    let patches = offsets.len() - 1;
    let shoot: Vec<[f32; 4]> = (0..patches).map(|i| [i as f32 * 1e-6, 1.0, 2.0, 0.0]).collect();
    let mut recv = vec![[0f32; 4]; patches];
    let mut recv2 = vec![[0f32; 4]; patches];
    let shoot3: Vec<[f32; 3]> = shoot.iter().map(|s| [s[0], s[1], s[2]]).collect();
    let shoot2: Vec<[f32; 2]> = shoot.iter().map(|s| [s[0], s[1]]).collect();
    let (mut recv3, mut recv2n) = (vec![[0f32; 3]; patches], vec![[0f32; 2]; patches]);
    // Every row's ends sorted by the other patch (ids and counts).
    // (Not with --blocked-only, which must fit archives of 2·10⁹ ends: 10
    // bytes an end less.)
    let (mut sorted_other, mut sorted_count) =
        if only { (Vec::new(), Vec::new()) } else { (other.to_vec(), count.to_vec()) };
    for q in (0..patches).filter(|_| !only) {
        let row = offsets[q] as usize..offsets[q + 1] as usize;
        let mut pairs: Vec<(u32, u8)> =
            other[row.clone()].iter().copied().zip(count[row.clone()].iter().copied()).collect();
        pairs.sort_unstable();
        for (i, (o, c)) in pairs.into_iter().enumerate() {
            sorted_other[row.start + i] = o;
            sorted_count[row.start + i] = c;
        }
    }
    let t = Instant::now();
    let row_layouts: Vec<RowRuns> = blockings
        .iter()
        .filter(|_| row_runs)
        .map(|&(bits, chunk)| RowRuns::new(offsets, other, count, bits, chunk))
        .collect();
    let blocked: std::collections::HashMap<(u32, usize), Blocked> = blockings
        .iter()
        .filter(|_| !row_runs)
        .map(|&(bits, chunk)| ((bits, chunk), Blocked::new(offsets, other, count, bits, chunk, false)))
        .collect();
    let scatter: Vec<Blocked> = SCATTERS
        .iter()
        .filter(|_| !only)
        .map(|&(bits, chunk)| Blocked::new(offsets, other, count, bits, chunk, true))
        .collect();
    eprintln!("blocked layouts made in {:.1} s", t.elapsed().as_secs_f64());
    for &(bits, chunk) in blockings.iter().filter(|_| !row_runs) {
        let b = &blocked[&(bits, chunk)];
        let runs = b.counts.iter().filter(|&&n| n > 0).count();
        println!(
            "blocked 2^{bits} x {chunk}: {:.1} blocks a receiver chunk, {:.1} runs a receiver, {:.1} ends a run",
            b.blocks.len() as f64 / (b.block_start.len() - 1) as f64,
            runs as f64 / patches as f64,
            b.ids.len() as f64 / runs as f64
        );
    }
    let ends = (other.len() * PASSES) as f64;
    println!(
        "{path}: {patches} patches, {} link ends ({:.1} ends a patch)",
        other.len(),
        other.len() as f64 / patches as f64
    );
    // The first rows holding ~14 M ends, and how often to repeat them.
    let sub = offsets.partition_point(|&o| o < 14_000_000).min(patches);
    let reps = (other.len() / (offsets[sub] as usize).max(1)).max(1);
    for threads in if only { vec![2] } else { vec![1, 2] } {
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
                ("gather", u32::MAX, Prefetch::No),
                ("gather, ids masked", MASK, Prefetch::No),
                ("gather, stream prefetched", u32::MAX, Prefetch::T0),
                ("gather, stream prefetched non-temporally", u32::MAX, Prefetch::Nta),
                ("gather, masked and prefetched", MASK, Prefetch::T0),
            ];
            let masks: Vec<(String, u32, Prefetch)> = (15..=19)
                .map(|k| {
                    (
                        format!("gather, ids masked into 2^{k} ({} KiB)", (16u64 << k) >> 10),
                        (1u32 << k) - 1,
                        Prefetch::No,
                    )
                })
                .collect();
            let variants = variants.into_iter().map(|(w, m, p)| (w.to_string(), m, p)).chain(masks);
            for (what, mask, prefetch) in variants.filter(|v| !only || v.0 == "gather") {
                line(&what, timed(ends, || gather(offsets, other, count, &shoot, mask, prefetch, &mut recv)));
            }
            if !only {
                let t = Instant::now();
                for _ in 0..PASSES * reps {
                    gather(&offsets[..sub + 1], other, count, &shoot, MASK, Prefetch::No, &mut recv[..sub]);
                }
                let n = offsets[sub] as f64 * (PASSES * reps) as f64;
                line(&format!("gather, masked, first {sub} patches x{reps}"), n / t.elapsed().as_secs_f64());
                line(
                    "gather, rows, the blocked kernel",
                    timed(ends, || rows(offsets, other, count, &shoot, &mut recv2)),
                );
                // The same loop with each row's ends sorted by the other
                // patch: the order the state is read in within a row.
                line(
                    "gather, rows sorted by other patch",
                    timed(ends, || rows(offsets, &sorted_other, &sorted_count, &shoot, &mut recv2)),
                );
                // Smaller per-patch state, the same loop: RGB in 12 bytes (what
                // the distribution could store), and 8 bytes (the size of RGB
                // in f16 with padding; two f32 read here, a bound on locality).
                line("gather, rows, 12-byte state", timed(ends, || rows(offsets, other, count, &shoot3, &mut recv3)));
                line(
                    "gather, rows, 8-byte state (locality bound)",
                    timed(ends, || rows(offsets, other, count, &shoot2, &mut recv2n)),
                );
                for ahead in [0, 16, 32, 64] {
                    line(
                        &format!("gather, state prefetched {ahead} ends ahead"),
                        timed(ends, || rows_prefetched(offsets, other, count, &shoot, ahead, &mut recv2)),
                    );
                }
            }
            for b in &row_layouts {
                let t = Instant::now();
                for _ in 0..PASSES {
                    b.gather(&shoot, &mut recv2);
                }
                let rate = ends / t.elapsed().as_secs_f64();
                gather(offsets, other, count, &shoot, u32::MAX, Prefetch::No, &mut recv);
                let err = max_relative_error(&recv, &recv2);
                let what = format!(
                    "row runs 2^{} x {} ({:.1} runs a receiver, rel {err:.1e})",
                    b.bits,
                    b.chunk,
                    b.runs.len() as f64 / patches as f64
                );
                line(&what, rate);
            }
            for &(bits, chunk) in blockings.iter().filter(|_| !row_runs) {
                let b = &blocked[&(bits, chunk)];
                let t = Instant::now();
                for _ in 0..PASSES {
                    b.gather(&shoot, &mut recv2);
                }
                let rate = ends / t.elapsed().as_secs_f64();
                gather(offsets, other, count, &shoot, u32::MAX, Prefetch::No, &mut recv);
                let err = max_relative_error(&recv, &recv2);
                line(&format!("blocked 2^{bits} x {chunk} ({:.2} B/end, rel {err:.1e})", b.bytes_per_end()), rate);
            }
            for b in &scatter {
                let t = Instant::now();
                for _ in 0..PASSES {
                    b.gather(&shoot, &mut recv2);
                }
                let rate = ends / t.elapsed().as_secs_f64();
                let err = max_relative_error(&recv, &recv2);
                let what =
                    format!("by sender 2^{} x {} ({:.2} B/end, rel {err:.1e})", b.bits, b.chunk, b.bytes_per_end());
                line(&what, rate);
            }
        });
    }
}

/// The blocked kernel's loop over rows of u32 ids, over per-patch state
/// of `N` floats.
fn rows<const N: usize>(offsets: &[u64], other: &[u32], count: &[u8], shoot: &[[f32; N]], recv: &mut [[f32; N]]) {
    recv.par_chunks_mut(BLOCK).enumerate().for_each(|(block, out)| {
        for (i, r) in out.iter_mut().enumerate() {
            let q = block * BLOCK + i;
            let row = offsets[q] as usize..offsets[q + 1] as usize;
            let (o, w) = (&other[row.clone()], &count[row]);
            let mut acc = [[0f32; N]; 4];
            for (o4, w4) in o.chunks(4).zip(w.chunks(4)) {
                for (j, (&o, &w)) in o4.iter().zip(w4).enumerate() {
                    let s = shoot[o as usize];
                    for c in 0..N {
                        acc[j][c] += w as f32 * s[c];
                    }
                }
            }
            *r = std::array::from_fn(|c| (acc[0][c] + acc[1][c]) + (acc[2][c] + acc[3][c]));
        }
    });
}

/// The distribution's gather over rows (unchecked state reads, four
/// partial sums), asking for the state of the end `ahead` ends on.
fn rows_prefetched(
    offsets: &[u64],
    other: &[u32],
    count: &[u8],
    shoot: &[[f32; 4]],
    ahead: usize,
    recv: &mut [[f32; 4]],
) {
    let last = shoot.len() - 1;
    recv.par_chunks_mut(BLOCK).enumerate().for_each(|(block, out)| {
        let hi = offsets[block * BLOCK + out.len()] as usize;
        for (i, r) in out.iter_mut().enumerate() {
            let q = block * BLOCK + i;
            let row = offsets[q] as usize..offsets[q + 1] as usize;
            let (o, w) = (&other[row.clone()], &count[row.clone()]);
            let mut acc = [[0f32; 4]; 4];
            let (o4, w4) = (o.chunks_exact(4), w.chunks_exact(4));
            let (o_rest, w_rest) = (o4.remainder(), w4.remainder());
            for (k, (o, w)) in o4.zip(w4).enumerate() {
                if ahead > 0 {
                    let at = row.start + 4 * k + ahead;
                    if at + 4 <= hi {
                        for &p in &other[at..at + 4] {
                            prefetch(&shoot[(p as usize).min(last)]);
                        }
                    }
                }
                for j in 0..4 {
                    let s = shoot[(o[j] as usize).min(last)];
                    let wj = w[j] as f32;
                    for c in 0..4 {
                        acc[j][c] += wj * s[c];
                    }
                }
            }
            for (j, (&o, &w)) in o_rest.iter().zip(w_rest).enumerate() {
                let s = shoot[(o as usize).min(last)];
                for c in 0..4 {
                    acc[j][c] += w as f32 * s[c];
                }
            }
            *r = [0, 1, 2, 3].map(|c| (acc[0][c] + acc[1][c]) + (acc[2][c] + acc[3][c]));
        }
    });
}

#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn prefetch(x: &[f32; 4]) {
    use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
    // SAFETY: a prefetch is a hint that reads no memory and faults on no
    // address.
    unsafe { _mm_prefetch::<_MM_HINT_T0>((x as *const [f32; 4]).cast()) }
}

#[cfg(not(target_arch = "x86_64"))]
fn prefetch(_: &[f32; 4]) {}

/// Sender-chunk bits and receiver-chunk sizes tried.
const BLOCKINGS: [(u32, usize); 3] = [(15, 1024), (16, 1024), (16, 4096)];

/// Sender-chunk bits and receiver-chunk sizes tried with ends sorted by sender.
const SCATTERS: [(u32, usize); 2] = [(16, 2048), (16, 4096)];

/// The link ends re-laid in blocks of (receiver chunk, sender chunk):
/// within a receiver chunk, per sender chunk, each receiver's ends with
/// 16-bit ids local to the sender chunk.
struct Blocked {
    bits: u32,
    chunk: usize,
    patches: usize,
    /// Per receiver chunk, its blocks `block_start[c]..block_start[c + 1]`.
    block_start: Vec<usize>,
    /// Per block: sender chunk, first count index, first end.
    blocks: Vec<(u32, usize, usize)>,
    /// Per block, per receiver of the chunk, its ends in the block (empty
    /// when sorted by sender).
    counts: Vec<u16>,
    /// Per end, its receiver within the chunk (when sorted by sender).
    recv: Vec<u16>,
    ids: Vec<u16>,
    weights: Vec<u8>,
}

impl Blocked {
    fn new(offsets: &[u64], other: &[u32], count: &[u8], bits: u32, chunk: usize, by_sender: bool) -> Self {
        let patches = offsets.len() - 1;
        let chunks = patches.div_ceil(chunk);
        let parts: Vec<_> = (0..chunks)
            .into_par_iter()
            .map(|c| {
                let (lo, hi) = (c * chunk, ((c + 1) * chunk).min(patches));
                let mut e: Vec<(u32, u32, u32)> = Vec::new();
                for q in lo..hi {
                    let row = offsets[q] as usize..offsets[q + 1] as usize;
                    for (k, &o) in row.clone().zip(&other[row]) {
                        e.push((o >> bits, if by_sender { o } else { (q - lo) as u32 }, k as u32));
                    }
                }
                e.sort_unstable();
                let mut blocks = Vec::new();
                let mut counts = Vec::new();
                let mut recv = Vec::new();
                let (mut ids, mut weights) = (Vec::with_capacity(e.len()), Vec::with_capacity(e.len()));
                let owner = |k: u32| offsets.partition_point(|&o| o <= k as u64) - 1 - lo;
                for run in e.chunk_by(|a, b| a.0 == b.0) {
                    blocks.push((run[0].0, counts.len(), ids.len()));
                    let mut n = vec![0u16; chunk];
                    for &(_, r, k) in run {
                        if by_sender {
                            recv.push(owner(k) as u16);
                        } else {
                            n[r as usize] += 1;
                        }
                        ids.push((other[k as usize] & ((1 << bits) - 1)) as u16);
                        weights.push(count[k as usize]);
                    }
                    if !by_sender {
                        counts.extend_from_slice(&n);
                    }
                }
                (blocks, counts, recv, ids, weights)
            })
            .collect();
        let mut b = Blocked {
            bits,
            chunk,
            patches,
            block_start: vec![0],
            blocks: Vec::new(),
            counts: Vec::new(),
            recv: Vec::new(),
            ids: Vec::new(),
            weights: Vec::new(),
        };
        // Reserved whole, so that the copy holds one part beside the
        // result, not a doubled vector (2·10⁹ ends: 6 GB).
        b.ids.reserve_exact(parts.iter().map(|p| p.3.len()).sum());
        b.weights.reserve_exact(parts.iter().map(|p| p.4.len()).sum());
        b.counts.reserve_exact(parts.iter().map(|p| p.1.len()).sum());
        b.recv.reserve_exact(parts.iter().map(|p| p.2.len()).sum());
        for (blocks, counts, recv, ids, weights) in parts {
            let (c0, e0) = (b.counts.len(), b.ids.len());
            b.blocks.extend(blocks.into_iter().map(|(s, c, e)| (s, c + c0, e + e0)));
            b.block_start.push(b.blocks.len());
            b.counts.extend(counts);
            b.recv.extend(recv);
            b.ids.extend(ids);
            b.weights.extend(weights);
        }
        b
    }

    fn bytes_per_end(&self) -> f64 {
        (self.ids.len() * 3 + self.recv.len() * 2 + self.counts.len() * 2 + self.blocks.len() * 16) as f64
            / self.ids.len() as f64
    }

    fn gather(&self, shoot: &[[f32; 4]], recv: &mut [[f32; 4]]) {
        recv[..self.patches].par_chunks_mut(self.chunk).enumerate().for_each(|(c, out)| {
            for r in out.iter_mut() {
                *r = [0.0; 4];
            }
            let blocks = self.block_start[c]..self.block_start[c + 1];
            if !self.recv.is_empty() {
                for i in blocks {
                    let (s, _, e0) = self.blocks[i];
                    let e1 = self.blocks.get(i + 1).map_or(self.ids.len(), |b| b.2);
                    let base = (s as usize) << self.bits;
                    let slice = &shoot[base..(base + (1 << self.bits)).min(shoot.len())];
                    for ((&o, &w), &r) in self.ids[e0..e1].iter().zip(&self.weights[e0..e1]).zip(&self.recv[e0..e1]) {
                        let s = slice[o as usize];
                        let a = &mut out[r as usize];
                        for c in 0..4 {
                            a[c] += w as f32 * s[c];
                        }
                    }
                }
                return;
            }
            for &(s, c0, e0) in &self.blocks[blocks] {
                let base = (s as usize) << self.bits;
                let slice = &shoot[base..(base + (1 << self.bits)).min(shoot.len())];
                let mut e = e0;
                for (r, &n) in out.iter_mut().zip(&self.counts[c0..c0 + self.chunk]) {
                    let n = n as usize;
                    if n == 0 {
                        continue;
                    }
                    let (o, w) = (&self.ids[e..e + n], &self.weights[e..e + n]);
                    e += n;
                    let mut acc = [[0f32; 4]; 4];
                    for (o4, w4) in o.chunks(4).zip(w.chunks(4)) {
                        for (j, (&o, &w)) in o4.iter().zip(w4).enumerate() {
                            let s = slice[o as usize];
                            for c in 0..4 {
                                acc[j][c] += w as f32 * s[c];
                            }
                        }
                    }
                    for c in 0..4 {
                        r[c] += (acc[0][c] + acc[1][c]) + (acc[2][c] + acc[3][c]);
                    }
                }
            }
        });
    }
}

/// `ends / s` for `PASSES` calls of `pass`, each over `ends / PASSES`
/// link ends.
fn timed(ends: f64, mut pass: impl FnMut()) -> f64 {
    let t = Instant::now();
    for _ in 0..PASSES {
        pass();
    }
    ends / t.elapsed().as_secs_f64()
}

/// The largest relative difference of `b`'s RGB from `a`'s.
fn max_relative_error(a: &[[f32; 4]], b: &[[f32; 4]]) -> f64 {
    let rel = |x: f32, y: f32| ((x - y) as f64).abs() / (x as f64).abs().max(1e-30);
    a.iter().zip(b).flat_map(|(a, b)| (0..3).map(move |c| rel(a[c], b[c]))).fold(0.0, f64::max)
}

/// The link ends in row order (each receiver's ends together), each row
/// in runs by sender chunk of 2^bits patches with 16-bit ids local to it
/// (the archive's layout, with smaller chunks), gathered in blocks:
/// per receiver chunk, sender chunk by sender chunk, each receiver's run
/// of that chunk (so the stream is read out of order within a receiver
/// chunk, and the state from one slice at a time).
struct RowRuns {
    bits: u32,
    chunk: usize,
    patches: usize,
    ids: Vec<u16>,
    weights: Vec<u8>,
    /// Per run: sender chunk, ends.
    runs: Vec<(u32, u32)>,
    /// Per receiver, its first run (and one past the last).
    run_off: Vec<u32>,
    /// Per receiver, its first end.
    offsets: Vec<u64>,
}

impl RowRuns {
    fn new(offsets: &[u64], other: &[u32], count: &[u8], bits: u32, chunk: usize) -> Self {
        let patches = offsets.len() - 1;
        let parts: Vec<_> = (0..patches.div_ceil(chunk))
            .into_par_iter()
            .map(|c| {
                let (lo, hi) = (c * chunk, ((c + 1) * chunk).min(patches));
                let n = (offsets[hi] - offsets[lo]) as usize;
                let (mut ids, mut weights, mut runs, mut per) =
                    (Vec::with_capacity(n), Vec::with_capacity(n), Vec::new(), Vec::new());
                let mut e: Vec<(u32, u32)> = Vec::new();
                for q in lo..hi {
                    let row = offsets[q] as usize..offsets[q + 1] as usize;
                    e.clear();
                    e.extend(row.clone().map(|k| (other[k] >> bits, k as u32)));
                    e.sort_by_key(|x| x.0);
                    let first = runs.len();
                    for run in e.chunk_by(|a, b| a.0 == b.0) {
                        runs.push((run[0].0, run.len() as u32));
                        for &(_, k) in run {
                            ids.push((other[k as usize] & ((1 << bits) - 1)) as u16);
                            weights.push(count[k as usize]);
                        }
                    }
                    per.push((runs.len() - first) as u32);
                }
                (ids, weights, runs, per)
            })
            .collect();
        let mut b = RowRuns {
            bits,
            chunk,
            patches,
            ids: Vec::new(),
            weights: Vec::new(),
            runs: Vec::new(),
            run_off: vec![0],
            offsets: offsets.to_vec(),
        };
        b.ids.reserve_exact(parts.iter().map(|p| p.0.len()).sum());
        b.weights.reserve_exact(parts.iter().map(|p| p.1.len()).sum());
        for (ids, weights, runs, per) in parts {
            b.ids.extend(ids);
            b.weights.extend(weights);
            b.runs.extend(runs);
            for n in per {
                let last = *b.run_off.last().expect("one entry");
                b.run_off.push(last + n);
            }
        }
        b
    }

    fn gather(&self, shoot: &[[f32; 4]], recv: &mut [[f32; 4]]) {
        let slices = self.patches.div_ceil(1 << self.bits);
        recv[..self.patches].par_chunks_mut(self.chunk).enumerate().for_each(|(c, out)| {
            let lo = c * self.chunk;
            let mut cursor: Vec<(u32, usize)> =
                (lo..lo + out.len()).map(|q| (self.run_off[q], self.offsets[q] as usize)).collect();
            for r in out.iter_mut() {
                *r = [0.0; 4];
            }
            for s in 0..slices as u32 {
                let base = (s as usize) << self.bits;
                let slice = &shoot[base..(base + (1 << self.bits)).min(shoot.len())];
                for (i, (r, cur)) in out.iter_mut().zip(cursor.iter_mut()).enumerate() {
                    let q = lo + i;
                    if cur.0 == self.run_off[q + 1] || self.runs[cur.0 as usize].0 != s {
                        continue;
                    }
                    let n = self.runs[cur.0 as usize].1 as usize;
                    let (o, w) = (&self.ids[cur.1..cur.1 + n], &self.weights[cur.1..cur.1 + n]);
                    *cur = (cur.0 + 1, cur.1 + n);
                    let mut acc = [[0f32; 4]; 4];
                    for (o4, w4) in o.chunks(4).zip(w.chunks(4)) {
                        for (j, (&o, &w)) in o4.iter().zip(w4).enumerate() {
                            let s = slice[o as usize];
                            for c in 0..4 {
                                acc[j][c] += w as f32 * s[c];
                            }
                        }
                    }
                    for c in 0..4 {
                        r[c] += (acc[0][c] + acc[1][c]) + (acc[2][c] + acc[3][c]);
                    }
                }
            }
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
    prefetch: Prefetch,
    recv: &mut [[f32; 4]],
) {
    let last = shoot.len() - 1;
    recv.par_chunks_mut(BLOCK).enumerate().for_each(|(block, out)| {
        for (i, r) in out.iter_mut().enumerate() {
            let q = block * BLOCK + i;
            let row = offsets[q] as usize..offsets[q + 1] as usize;
            match prefetch {
                Prefetch::No => {}
                Prefetch::T0 => prefetch_ahead::<false>(other, count, row.clone()),
                Prefetch::Nta => prefetch_ahead::<true>(other, count, row.clone()),
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

/// Whether and how the gather asks for the stream ahead of use.
#[derive(Clone, Copy)]
enum Prefetch {
    No,
    /// Into every cache level (`_MM_HINT_T0`).
    T0,
    /// Non-temporal (`_MM_HINT_NTA`): kept out of the shared L3, so that
    /// the stream passing through does not evict the per-patch state.
    Nta,
}

/// Asks for the cache lines of both columns 1 024 ends past `row`
/// (non-temporally if `NTA`).
#[cfg(target_arch = "x86_64")]
fn prefetch_ahead<const NTA: bool>(other: &[u32], count: &[u8], row: std::ops::Range<usize>) {
    use std::arch::x86_64::{_MM_HINT_NTA, _MM_HINT_T0, _mm_prefetch};
    let ask = |p: *const i8| {
        // SAFETY: a prefetch is a hint that reads no memory and faults on
        // no address; the pointers are formed with wrapping arithmetic.
        unsafe { if NTA { _mm_prefetch::<_MM_HINT_NTA>(p) } else { _mm_prefetch::<_MM_HINT_T0>(p) } }
    };
    for k in row.step_by(16) {
        ask(other.as_ptr().wrapping_add(k + 1024).cast());
        if k % 64 == 0 {
            ask(count.as_ptr().wrapping_add(k + 1024).cast());
        }
    }
}

#[cfg(not(target_arch = "x86_64"))]
fn prefetch_ahead<const NTA: bool>(_: &[u32], _: &[u8], _: std::ops::Range<usize>) {}
