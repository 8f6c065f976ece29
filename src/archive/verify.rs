//! `illumnet verify`: checks an archive beyond what opening it checks.
//!
//! Opening validates every section before use (format-spec §7: checksums,
//! counts, indices, the invariants that keep results finite). What it
//! cannot afford on every open, `verify` does once, reading the link ends
//! a window at a time so that an archive far larger than memory is
//! verified in bounded memory:
//!
//! - every link end joins two patches that face each other along its
//!   direction (the sender's front towards it, the receiver's against it);
//! - every link is stored at both its ends, with the same weight and
//!   opposite directions (a sum of 64-bit hashes of every end against the
//!   same sum over their mirror images: equal when, and with overwhelming
//!   probability only when, the ends pair up);
//! - every frame of a sequence decodes, and its records apply to frame 0's
//!   links without leaving a weight negative or a patch over its hit count;
//! - every prototype table is reciprocal where both entries of a pair are
//!   kept: `T(i→o)/(cos θ_o·Ω_o) = T(o→i)/(cos θ_i·Ω_i)` (format-spec
//!   §5.14; opening checks that rows conserve energy).
//!
//! Findings name the section and record; the first [`MAX_FINDINGS`] of
//! each kind are listed, and all are counted.

use std::ops::Range;
use std::path::Path;
use std::time::Instant;

use rayon::prelude::*;

use super::layout::kind;
use super::links::Columns;
use super::{Archive, ArchiveError};

/// Findings listed per kind (all are counted).
pub const MAX_FINDINGS: usize = 20;

/// Link ends per window read while verifying (40 MB of columns at most).
const WINDOW_ENDS: usize = 1 << 22;

/// Patches a task checks at a time.
const PATCH_RUN: usize = 2048;

/// Below this cosine a planar patch does not face a direction (rounding
/// of a normal computed from corners may put a grazing end just under 0).
const PLANAR_FACING: f32 = -1e-4;

/// Below this cosine a grouped patch (several small triangles whose
/// normals differ by up to 60° from one another, §5.5) cannot face a
/// direction along which one of its triangles faces.
const GROUPED_FACING: f32 = -0.9;

/// What one run of patches gave: its first findings (link end, words),
/// how many it found, and its ends' and their mirrors' hash sums.
type RunCheck = (Vec<(u64, String)>, usize, u64, u64);

/// One thing wrong with an archive.
#[derive(Debug, Clone, PartialEq)]
pub struct Finding {
    /// The section it is in (its tag), or a name for a whole-file check.
    pub section: String,
    /// The record (link end, frame, …) within it, when there is one.
    pub record: Option<u64>,
    /// What is wrong, in words.
    pub what: String,
}

/// What `verify` found, and what it read.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Verification {
    /// Findings listed (at most [`MAX_FINDINGS`] of each kind).
    pub findings: Vec<Finding>,
    /// Findings in all, listed or not.
    pub finding_count: u64,
    /// The archive's size in bytes.
    pub bytes: u64,
    /// Patches, link ends and frames checked.
    pub patches: u64,
    /// Link ends checked.
    pub link_ends: u64,
    /// Frames decoded and checked (a still has one).
    pub frames: u32,
    /// Seconds it took, opening included.
    pub seconds: f64,
}

impl Verification {
    /// Whether nothing was found.
    pub fn sound(&self) -> bool {
        self.finding_count == 0
    }

    fn add(&mut self, kind_count: &mut usize, section: &str, record: Option<u64>, what: String) {
        self.finding_count += 1;
        *kind_count += 1;
        if *kind_count <= MAX_FINDINGS {
            self.findings.push(Finding { section: section.into(), record, what });
        }
    }
}

/// One 64-bit hash of a link end as seen from `from`: the commutative sum
/// of these over every end equals the sum over their mirror images when
/// each link is stored at both its ends.
fn end_hash(from: u32, to: u32, pair: u32, outgoing: bool, weight: f32) -> u64 {
    let mix = |mut z: u64| {
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    };
    let a = mix(((from as u64) << 32) | to as u64);
    mix(a ^ (((pair as u64) << 33) | ((outgoing as u64) << 32) | weight.to_bits() as u64))
}

/// Verifies the archive at `path`. An archive that does not open (a
/// checksum, a count, an index: format-spec §7) gives that error as its
/// one finding; an I/O error reading it is returned as an error.
pub fn verify(path: &Path) -> Result<Verification, ArchiveError> {
    let started = Instant::now();
    let mut out = Verification { bytes: std::fs::metadata(path).map(|m| m.len()).unwrap_or(0), ..Default::default() };
    let archive = match Archive::open_streamed(path, WINDOW_ENDS) {
        Ok(a) => a,
        Err(e @ ArchiveError::Io { .. }) => return Err(e),
        Err(e) => {
            let mut n = 0;
            out.add(&mut n, "file", None, format!("does not open: {e}"));
            out.seconds = started.elapsed().as_secs_f64();
            return Ok(out);
        }
    };
    let v = archive.view();
    out.patches = v.patch_count() as u64;
    let normal: Vec<glam::Vec3> = v.patch_normal.iter().map(|&n| glam::Vec3::from(n)).collect();
    let grouped: Vec<bool> =
        v.patch_primitive.iter().map(|&p| v.primitives[p as usize].kind == kind::GROUPED_TRIANGLE).collect();
    let dirs: Vec<glam::Vec3> = v.directions.iter().map(|d| glam::Vec3::from(d.direction)).collect();
    let (mut facing, mut sum_ends, mut sum_mirrors) = (0usize, 0u64, 0u64);
    let offsets = v.link_offsets;
    let columns = Columns::ALL;
    v.links.for_each_window(columns, v.patch_count(), |w| {
        // In parallel over runs of patches; hashes add in any order, and
        // the findings are merged in patch order.
        let runs: Vec<Range<usize>> =
            w.patches.clone().step_by(PATCH_RUN).map(|a| a..(a + PATCH_RUN).min(w.patches.end)).collect();
        let parts: Vec<RunCheck> = runs
            .into_par_iter()
            .map(|run| {
                let (mut found, mut count, mut ends, mut mirrors) = (Vec::new(), 0usize, 0u64, 0u64);
                for p in run {
                    debug_assert_eq!(w.row(p), w.local(offsets[p] as usize..offsets[p + 1] as usize));
                    for (i, q, _) in w.ends_of(p) {
                        let (d, weight) = (w.direction[i], w.weight.get(i));
                        let dir = dirs[d as usize];
                        let (cp, cq) = (normal[p].dot(dir), normal[q as usize].dot(dir));
                        let least = |x: usize| if grouped[x] { GROUPED_FACING } else { PLANAR_FACING };
                        if cp < least(p) || -cq < least(q as usize) {
                            count += 1;
                            if found.len() < MAX_FINDINGS {
                                found.push((
                                    (w.first_end + i) as u64,
                                    format!(
                                        "link end of patch {p} to patch {q} along direction {d}: the patches do \
                                         not face each other along it (cosines {cp:.3} and {cq:.3})"
                                    ),
                                ));
                            }
                        }
                        ends = ends.wrapping_add(end_hash(p as u32, q, d / 2, d % 2 == 0, weight));
                        mirrors = mirrors.wrapping_add(end_hash(q, p as u32, d / 2, d % 2 == 1, weight));
                    }
                }
                (found, count, ends, mirrors)
            })
            .collect();
        for (found, count, ends, mirrors) in parts {
            sum_ends = sum_ends.wrapping_add(ends);
            sum_mirrors = sum_mirrors.wrapping_add(mirrors);
            let unlisted = count - found.len();
            for (record, what) in found {
                out.add(&mut facing, "LDIR", Some(record), what);
            }
            out.finding_count += unlisted as u64;
            facing += unlisted;
        }
        Ok::<(), ArchiveError>(())
    })?;
    out.link_ends = v.link_end_count() as u64;
    if sum_ends != sum_mirrors {
        let mut n = 0;
        out.add(
            &mut n,
            "LOTH",
            None,
            "link ends do not pair up: some link is not stored at both its ends with the same weight and \
             opposite directions"
                .into(),
        );
    }
    if let Some(r) = v.reflectance {
        let mut tables = 0;
        for (t, table) in r.prototypes.iter().enumerate() {
            let (listed, count) = unreciprocal(&r, t, &dirs, v.directions);
            out.finding_count += count - listed.len() as u64;
            tables += (count as usize).saturating_sub(listed.len());
            for (entry, i, o, what) in listed {
                out.add(
                    &mut tables,
                    "PFAC",
                    Some(table.first_factor + entry),
                    format!("table {t}: T({i}→{o}) and T({o}→{i}) are not reciprocal ({what})"),
                );
            }
        }
    }
    let frames = v.sequence.map_or(1, |s| s.frames());
    let mut bad_frames = 0;
    for f in 1..frames {
        if let Err(e) = v.frame_links(f) {
            out.add(&mut bad_frames, "DELT", Some(f as u64), format!("frame {f}: {e}"));
        }
    }
    out.frames = frames;
    out.seconds = started.elapsed().as_secs_f64();
    Ok(out)
}

/// A pair of table entries that breaks reciprocity: the factor's index
/// within the table, i, o, and the two values in words.
type Unreciprocal = (u64, usize, usize, String);

/// Relative difference above which two entries of a table are not
/// reciprocal: tables are built exactly reciprocal up to f32 rounding
/// (measured 10⁻⁷, `reflectance::prototype`).
const RECIPROCITY: f64 = 1e-3;

/// Entries of table `t` whose reverse entry breaks reciprocity,
/// `T(i→o)/(cos θ_o·Ω_o) = T(o→i)/(cos θ_i·Ω_i)` per band, where both
/// are kept (a threshold may drop one of a pair): the first
/// [`MAX_FINDINGS`] as `(factor within the table, i, o, the two values)`,
/// and how many pairs break it in all.
fn unreciprocal(
    r: &super::ReflectanceView<'_>,
    t: usize,
    dirs: &[glam::Vec3],
    records: &[super::layout::DirectionRecord],
) -> (Vec<Unreciprocal>, u64) {
    let bands = r.prototypes[t].bands as usize;
    let scale = |d: usize| dirs[d].y as f64 * records[d].solid_angle_sr as f64;
    let row_start = |i: usize| r.rows[r.prototypes[t].first_row as usize + i] as u64;
    // Rows in parallel, merged in row order.
    let rows: Vec<(Vec<Unreciprocal>, u64)> = (0..dirs.len())
        .into_par_iter()
        .map(|i| {
            let (mut found, mut count) = (Vec::new(), 0u64);
            let (outs, factors) = r.row(t, i);
            for (k, &o) in outs.iter().enumerate() {
                let o = o as usize;
                if o <= i || scale(i) <= 0.0 || scale(o) <= 0.0 {
                    continue;
                }
                let (back, back_factors) = r.row(t, o);
                let at = match back.windows(2).all(|w| w[0] < w[1]) {
                    true => back.binary_search(&(i as u32)).ok(),
                    false => back.iter().position(|&x| x as usize == i),
                };
                let Some(j) = at else { continue };
                for c in 0..bands {
                    let a = factors[k * bands + c] as f64 / scale(o);
                    let b = back_factors[j * bands + c] as f64 / scale(i);
                    if (a - b).abs() > RECIPROCITY * a.abs().max(b.abs()) {
                        count += 1;
                        if found.len() < MAX_FINDINGS {
                            let entry = row_start(i) * bands as u64 + (k * bands + c) as u64;
                            found.push((entry, i, o, format!("{a:.4e} and {b:.4e}")));
                        }
                        break;
                    }
                }
            }
            (found, count)
        })
        .collect();
    let (mut out, mut count) = (Vec::new(), 0u64);
    for (found, n) in rows {
        count += n;
        out.extend(found.into_iter().take(MAX_FINDINGS - out.len().min(MAX_FINDINGS)));
    }
    (out, count)
}
