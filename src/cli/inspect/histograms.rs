//! `inspect --histograms`: how an archive's links, hit counts, buckets and
//! frame changes are distributed, in text (with bars) or JSON. Read in
//! bounded memory: link ends a window at a time.

use std::path::Path;

use anyhow::Result;
use illumnet::archive::{self, Archive, ArchiveError, Columns};

use crate::cli::common::opened;

/// A histogram: a name, the unit of what it counts, and bins.
struct Histogram {
    key: &'static str,
    title: String,
    bins: Vec<Bin>,
}

/// `count` values in `[from, to)` (`to` absent: and above).
struct Bin {
    from: f64,
    to: Option<f64>,
    count: u64,
}

/// Bins of powers of two: 0, [1, 2), [2, 4), … up to the largest value.
fn log2_bins(values: impl Iterator<Item = u64>) -> Vec<Bin> {
    let mut counts: Vec<u64> = Vec::new();
    for v in values {
        let k = if v == 0 { 0 } else { 64 - v.leading_zeros() as usize };
        if counts.len() <= k {
            counts.resize(k + 1, 0);
        }
        counts[k] += 1;
    }
    counts
        .iter()
        .enumerate()
        .map(|(k, &count)| match k {
            0 => Bin { from: 0.0, to: Some(1.0), count },
            k => Bin { from: (1u64 << (k - 1)) as f64, to: Some((1u64 << k) as f64), count },
        })
        .collect()
}

/// Bins of width `width` from 0 to `top`, then one for `top` and above.
fn linear_bins(values: impl Iterator<Item = f64>, width: f64, top: f64) -> Vec<Bin> {
    let n = (top / width).round() as usize;
    let mut counts = vec![0u64; n + 1];
    for v in values {
        let k = if v.is_finite() && v >= 0.0 { ((v / width) as usize).min(n) } else { n };
        counts[k] += 1;
    }
    counts
        .iter()
        .enumerate()
        .map(|(k, &count)| Bin { from: k as f64 * width, to: (k < n).then(|| (k + 1) as f64 * width), count })
        .collect()
}

/// Bins of lengths by powers of two of metres, from `2^lo` (and below).
fn length_bins(counts: &[u64], lo: i32) -> Vec<Bin> {
    counts
        .iter()
        .enumerate()
        .map(|(k, &count)| Bin {
            from: if k == 0 { 0.0 } else { 2f64.powi(lo + k as i32 - 1) },
            to: Some(2f64.powi(lo + k as i32)),
            count,
        })
        .collect()
}

/// Shortest length bin's upper end: 2^-10 m, about a millimetre.
const LENGTH_LO: i32 = -10;

/// Prints `inspect --histograms` of the archive at `path` (text or
/// JSON), and draws them as charts in `charts` if given.
pub fn inspect_histograms(path: &Path, json: bool, charts: Option<&Path>) -> Result<()> {
    let archive = opened(path, Archive::open_streamed(path, archive::CHUNK_ENDS))?;
    let hists = histograms_of(&archive.view())?;
    if let Some(dir) = charts {
        draw_charts(dir, &hists)?;
    }
    print_histograms(&hists, json)
}

/// Every histogram of an archive: per patch (link ends, hits), over its
/// link ends in one pass (lengths, directions, buckets), and of its
/// glossy patches and sequence if it has them.
fn histograms_of(v: &archive::InetView<'_>) -> Result<Vec<Histogram>> {
    let n = v.patch_count();
    let mut hists = vec![
        Histogram {
            key: "link_ends_per_patch",
            title: format!("link ends per patch ({n} patches)"),
            bins: log2_bins((0..n).map(|p| v.link_offsets[p + 1] - v.link_offsets[p])),
        },
        Histogram {
            key: "hits_over_expected",
            title: "rays that crossed a patch over those its area and orientation expect, H_p / E[H_p] (patches)"
                .into(),
            bins: linear_bins(
                (0..n).map(|p| {
                    let e = v.patch_expected_hits[p] as f64;
                    if e > 0.0 { v.patch_hits[p] as f64 / e } else { 0.0 }
                }),
                0.1,
                2.0,
            ),
        },
    ];
    // One pass over the link ends: lengths, directions, buckets.
    let mut lengths = [0u64; 24];
    let mut per_direction = vec![0u64; v.directions.len()];
    let mut per_bucket: Vec<u64> = Vec::new();
    let columns = Columns { other: true, direction: true, ..Default::default() };
    v.links.for_each_window(columns, n, |w| {
        for p in w.patches.clone() {
            let c = glam::Vec3::from(v.patch_centre[p]);
            for (e, q, b) in w.ends_of(p) {
                let q = q as usize;
                let d = c.distance(glam::Vec3::from(v.patch_centre[q.min(n - 1)])) as f64;
                let k = if d > 0.0 { (d.log2().floor() as i32 - LENGTH_LO + 1).clamp(0, 23) as usize } else { 0 };
                lengths[k] += 1;
                if let Some(slot) = w.direction.get(e).and_then(|&dir| per_direction.get_mut(dir as usize)) {
                    *slot += 1;
                }
                if per_bucket.len() <= b as usize {
                    per_bucket.resize(b as usize + 1, 0);
                }
                per_bucket[b as usize] += 1;
            }
        }
        Ok::<(), ArchiveError>(())
    })?;
    let last = lengths.iter().rposition(|&c| c > 0).unwrap_or(0);
    hists.push(Histogram {
        key: "link_length_m",
        title: "link lengths, between patch centres (metres; link ends)".into(),
        bins: length_bins(&lengths[..=last], LENGTH_LO),
    });
    hists.push(Histogram {
        key: "link_ends_per_direction",
        title: format!("link ends per direction ({} directions)", v.directions.len()),
        bins: log2_bins(per_direction.iter().copied()),
    });
    if !per_bucket.is_empty() {
        hists.push(Histogram {
            key: "link_ends_per_bucket",
            title: "link ends by bucket (0: the patch itself; k: spread over k rings of neighbours)".into(),
            bins: per_bucket
                .iter()
                .enumerate()
                .map(|(k, &count)| Bin { from: k as f64, to: Some(k as f64 + 1.0), count })
                .collect(),
        });
    }
    if let Some(r) = v.reflectance {
        hists.push(Histogram {
            key: "rays_per_glossy_patch_direction",
            title: format!(
                "rays per non-diffuse patch and direction pair ({} patches × {} pairs; NDHC)",
                r.patches.len(),
                v.directions.len() / 2
            ),
            bins: log2_bins(r.hits.iter().map(|&h| h as u64)),
        });
    }
    if let Some(s) = v.sequence {
        hists.push(Histogram {
            key: "delta_records_per_frame",
            title: format!("changes to frame 0's links per frame ({} frames)", s.index.len()),
            bins: log2_bins(s.index.iter().map(|d| d.count)),
        });
    }
    Ok(hists)
}

/// Draws every histogram as a PNG bar chart in `dir`.
fn draw_charts(dir: &Path, hists: &[Histogram]) -> Result<()> {
    let charts: Vec<super::charts::Chart<'_>> = hists
        .iter()
        .map(|h| super::charts::Chart {
            key: h.key,
            title: &h.title,
            counts_what: counted(h.key),
            bins_what: binned(h.key),
            labels: h.bins.iter().map(|b| number_label(b.from)).collect(),
            counts: h.bins.iter().map(|b| b.count).collect(),
        })
        .collect();
    for p in super::charts::write_charts(dir, &charts)? {
        eprintln!("wrote chart {}", p.display());
    }
    Ok(())
}

/// Prints the histograms, as JSON or as text with bars.
fn print_histograms(hists: &[Histogram], json: bool) -> Result<()> {
    if json {
        let out: serde_json::Map<String, serde_json::Value> = hists
            .iter()
            .map(|h| {
                let bins: Vec<serde_json::Value> = h
                    .bins
                    .iter()
                    .map(|b| serde_json::json!({ "from": b.from, "to": b.to, "count": b.count }))
                    .collect();
                (h.key.to_string(), serde_json::json!({ "title": h.title, "bins": bins }))
            })
            .collect();
        println!("{}", serde_json::to_string_pretty(&serde_json::json!({ "histograms": out }))?);
        return Ok(());
    }
    for h in hists {
        println!("{}", h.title);
        let most = h.bins.iter().map(|b| b.count).max().unwrap_or(0).max(1);
        for b in &h.bins {
            let bar = "#".repeat(((b.count as f64 / most as f64) * 40.0).ceil() as usize);
            println!("  {:>20} {:>12}  {bar}", range_label(b), b.count);
        }
        println!();
    }
    Ok(())
}

/// What a histogram's bins measure (the chart's x axis).
fn binned(key: &str) -> &'static str {
    match key {
        "link_ends_per_patch" => "link ends of a patch",
        "hits_over_expected" => "hits H_p over their expected number",
        "link_length_m" => "link length between patch centres (m)",
        "link_ends_per_direction" => "link ends along a direction",
        "link_ends_per_bucket" => "bucket",
        "rays_per_glossy_patch_direction" => "rays of a glossy patch along a direction pair",
        "delta_records_per_frame" => "link changes in a frame",
        _ => "value",
    }
}

/// What a histogram's bins count.
fn counted(key: &str) -> &'static str {
    match key {
        "link_ends_per_patch" | "hits_over_expected" => "patches",
        "link_ends_per_direction" => "directions",
        "rays_per_glossy_patch_direction" => "(patch, direction pair)s",
        "delta_records_per_frame" => "frames",
        _ => "link ends",
    }
}

/// A bin bound, short.
fn number_label(x: f64) -> String {
    match x {
        x if x.fract() == 0.0 && x.abs() < 1e15 => format!("{x:.0}"),
        x if x.abs() < 1e-3 => format!("{x:.1e}"),
        x => format!("{x:.4}").trim_end_matches('0').to_string(),
    }
}

/// A bin's range in words: `A – B`, or `A and above`.
fn range_label(b: &Bin) -> String {
    let label = number_label;
    match b.to {
        Some(t) => format!("{} – {}", label(b.from), label(t)),
        None => format!("{} and above", label(b.from)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bins_hold_their_values() {
        let b = log2_bins([0u64, 1, 2, 3, 4, 9].into_iter());
        let counts: Vec<u64> = b.iter().map(|b| b.count).collect();
        assert_eq!(counts, [1, 1, 2, 1, 1]);
        assert_eq!((b[4].from, b[4].to), (8.0, Some(16.0)));
        let l = linear_bins([0.05, 0.95, 1.0, 2.5, f64::NAN].into_iter(), 0.5, 2.0);
        let counts: Vec<u64> = l.iter().map(|b| b.count).collect();
        assert_eq!(counts, [1, 1, 1, 0, 2]);
        assert_eq!(l[4].to, None);
    }
}
