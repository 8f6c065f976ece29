//! Would a spatial patch order help the distribution's gather? Renumbers
//! an archive's patches by a Morton curve over centres: of primitives
//! within each surface (what format 10 allowed), of all primitives
//! (patches stay in their primitive's order: what builds of still scenes
//! do since format 11, `patch::order`), and of the patches themselves; re-lays the link ends' rows to match (u32 ids, each row
//! ordered by sender chunk), and times a row gather like the
//! distribution's over each order and the archive's, alternating, three
//! times each; it also prints how many sender chunks (2¹⁶ patches) a row
//! touches in each. Numbers for `docs/notebook/2026-12-05-block-layout-and-patch-order.md`:
//!
//! ```text
//! cargo run --release --example patch_order -- ARCHIVE.inet
//! ```

use std::time::Instant;

use illumnet::archive::Archive;
use rayon::prelude::*;

/// Patches per parallel task, as the distribution's.
const BLOCK: usize = 512;

fn main() {
    let Some(path) = std::env::args().nth(1) else {
        eprintln!("usage: patch_order ARCHIVE.inet");
        std::process::exit(2);
    };
    let archive = match Archive::open(std::path::Path::new(&path)) {
        Ok(a) => a,
        Err(e) => {
            eprintln!("patch_order: {path}: {e}");
            std::process::exit(1);
        }
    };
    let v = archive.view();
    let Some(links) = v.links.resident() else {
        eprintln!("patch_order: {path}: the link ends are not resident");
        std::process::exit(1);
    };
    let other = links.window().other_ids();
    let count = links.weight.counts();
    let offsets = v.link_offsets;
    let patches = offsets.len() - 1;
    let prims = v.primitives;

    // Primitives along a Morton curve over their centres.
    let centre: Vec<[f32; 3]> =
        prims.iter().map(|p| [0, 1, 2].map(|k| p.corners.iter().map(|c| c[k]).sum::<f32>() / 4.0)).collect();
    let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
    for c in &centre {
        for k in 0..3 {
            lo[k] = lo[k].min(c[k]);
            hi[k] = hi[k].max(c[k]);
        }
    }
    let extent = (0..3).map(|k| hi[k] - lo[k]).fold(1e-6f32, f32::max);
    let key = |c: &[f32; 3]| {
        let q = |k: usize| (((c[k] - lo[k]) / extent) * 1023.0) as u32;
        spread(q(0)) | spread(q(1)) << 1 | spread(q(2)) << 2
    };
    let mut order: Vec<usize> = (0..prims.len()).collect();
    order.sort_by_key(|&i| (key(&centre[i]), i));

    // The new id of every patch, and the rows in the new order.
    let first = |i: usize| prims[i].first_patch as usize;
    let end = |i: usize| prims.get(i + 1).map_or(patches, |p| p.first_patch as usize);
    let by_primitive: Vec<usize> = order.iter().flat_map(|&i| first(i)..end(i)).collect();
    // Primitives along the curve within each surface (surfaces keep their
    // ranges, as the format asks).
    let mut within: Vec<usize> = (0..prims.len()).collect();
    within.sort_by_key(|&i| (prims[i].surface, key(&centre[i]), i));
    let by_surface: Vec<usize> = within.iter().flat_map(|&i| first(i)..end(i)).collect();
    // Patches along a Morton curve over their own centres (a primitive
    // that spans rooms, a floor, is cut among them).
    let mut by_patch: Vec<usize> = (0..patches).collect();
    by_patch.sort_by_key(|&p| (key(&v.patch_centre[p]), p));
    let (primitive_rows, patch_rows) =
        (renumber(offsets, &other, count, &by_primitive), renumber(offsets, &other, count, &by_patch));
    let surface_rows = renumber(offsets, &other, count, &by_surface);
    println!(
        "{path}: {patches} patches, {} primitives; sender chunks a row: archive order {:.2}, Morton order within surfaces {:.2}, of primitives {:.2}, of patches {:.2}",
        prims.len(),
        chunks_a_row(offsets, &other),
        chunks_a_row(&surface_rows.0, &surface_rows.1),
        chunks_a_row(&primitive_rows.0, &primitive_rows.1),
        chunks_a_row(&patch_rows.0, &patch_rows.1)
    );

    let shoot: Vec<[f32; 4]> = (0..patches).map(|i| [i as f32 * 1e-6, 1.0, 2.0, 0.0]).collect();
    let mut recv = vec![[0f32; 4]; patches];
    let orders: [(&str, Rows<'_>); 4] = [
        ("archive order", Rows { offsets, other: &other, count }),
        (
            "Morton order within surfaces",
            Rows { offsets: &surface_rows.0, other: &surface_rows.1, count: &surface_rows.2 },
        ),
        (
            "Morton order of primitives",
            Rows { offsets: &primitive_rows.0, other: &primitive_rows.1, count: &primitive_rows.2 },
        ),
        ("Morton order of patches", Rows { offsets: &patch_rows.0, other: &patch_rows.1, count: &patch_rows.2 }),
    ];
    for _ in 0..3 {
        for (what, rows) in &orders {
            let t = Instant::now();
            for _ in 0..3 {
                gather(rows, &shoot, &mut recv);
            }
            println!("{what}: {:.0} M ends/s", 3.0 * other.len() as f64 / t.elapsed().as_secs_f64() / 1e6);
        }
    }
}

/// The rows renumbered so that patch `old_of[n]` becomes patch `n`: new
/// offsets, other patches (each row ordered by sender chunk) and counts.
fn renumber(offsets: &[u64], other: &[u32], count: &[u8], old_of: &[usize]) -> (Vec<u64>, Vec<u32>, Vec<u8>) {
    let patches = old_of.len();
    let mut new_id = vec![0u32; patches];
    for (n, &p) in old_of.iter().enumerate() {
        new_id[p] = n as u32;
    }
    let mut new_offsets = vec![0u64; patches + 1];
    let (mut new_other, mut new_count) = (Vec::with_capacity(other.len()), Vec::with_capacity(other.len()));
    let mut row = Vec::new();
    for (n, &p) in old_of.iter().enumerate() {
        let r = offsets[p] as usize..offsets[p + 1] as usize;
        row.clear();
        row.extend(other[r.clone()].iter().zip(&count[r]).map(|(&o, &w)| (new_id[o as usize], w)));
        row.sort_by_key(|e| e.0 >> 16);
        new_other.extend(row.iter().map(|e| e.0));
        new_count.extend(row.iter().map(|e| e.1));
        new_offsets[n + 1] = new_other.len() as u64;
    }
    (new_offsets, new_other, new_count)
}

/// The low 21 bits of `x`, two zero bits after each (a Morton code's axis).
fn spread(x: u32) -> u64 {
    let mut v = x as u64 & 0x1f_ffff;
    v = (v | v << 32) & 0x1f_0000_0000_ffff;
    v = (v | v << 16) & 0x1f_0000_ff00_00ff;
    v = (v | v << 8) & 0x100f_00f0_0f00_f00f;
    v = (v | v << 4) & 0x10c3_0c30_c30c_30c3;
    v = (v | v << 2) & 0x1249_2492_4924_9249;
    v
}

/// The mean count of sender chunks a row's ends fall in.
fn chunks_a_row(offsets: &[u64], other: &[u32]) -> f64 {
    let patches = offsets.len() - 1;
    let mut chunks = Vec::new();
    let mut n = 0;
    for q in 0..patches {
        chunks.clear();
        chunks.extend(other[offsets[q] as usize..offsets[q + 1] as usize].iter().map(|&o| o >> 16));
        chunks.sort_unstable();
        chunks.dedup();
        n += chunks.len();
    }
    n as f64 / patches as f64
}

/// Link ends in rows: patch `q`'s are `offsets[q]..offsets[q + 1]`.
struct Rows<'a> {
    offsets: &'a [u64],
    other: &'a [u32],
    count: &'a [u8],
}

/// `recv[q] = Σ count·shoot[other]` over each patch's row, in four partial
/// sums, as the distribution's gather.
fn gather(rows: &Rows<'_>, shoot: &[[f32; 4]], recv: &mut [[f32; 4]]) {
    let Rows { offsets, other, count } = *rows;
    recv.par_chunks_mut(BLOCK).enumerate().for_each(|(block, out)| {
        for (i, r) in out.iter_mut().enumerate() {
            let q = block * BLOCK + i;
            let row = offsets[q] as usize..offsets[q + 1] as usize;
            let mut acc = [[0f32; 4]; 4];
            for (o4, w4) in other[row.clone()].chunks(4).zip(count[row].chunks(4)) {
                for (j, (&o, &w)) in o4.iter().zip(w4).enumerate() {
                    let s = shoot[o as usize];
                    for c in 0..4 {
                        acc[j][c] += w as f32 * s[c];
                    }
                }
            }
            *r = [0, 1, 2, 3].map(|c| (acc[0][c] + acc[1][c]) + (acc[2][c] + acc[3][c]));
        }
    });
}
