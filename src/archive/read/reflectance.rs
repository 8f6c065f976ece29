//! The reflectance sections' rules (§5.14): prototype tables, orientation
//! maps, the non-diffuse patches and their ray counts.

use super::views::{InetView, ReflectanceView};
use super::{bad, check, csr, finite};
use crate::archive::ArchiveError;
use crate::archive::layout;

/// §5.14: tables well formed and energy-conserving, maps bijections,
/// exactly the non-diffuse patches listed.
pub(super) fn validate_reflectance(v: &InetView<'_>, r: &ReflectanceView<'_>) -> Result<(), ArchiveError> {
    let n = v.directions.len();
    let (mut row, mut entry, mut factor) = (0u64, 0u64, 0u64);
    for (t, p) in r.prototypes.iter().enumerate() {
        check(finite(&[p.alpha_u, p.alpha_v, p.threshold]) && finite(&p.ior), || {
            format!("PTAB[{t}]: non-finite parameter")
        })?;
        check(p.ior.iter().all(|&x| x >= 0.0) && p.alpha_u >= 0.0 && p.alpha_v >= 0.0, || {
            format!("PTAB[{t}]: negative roughness or index of refraction")
        })?;
        check(p.model <= layout::table_model::GGX && (p.bands == 1 || p.bands == 3), || {
            format!("PTAB[{t}]: unknown model {} or bands {}", p.model, p.bands)
        })?;
        check(p.first_row == row && p.first_entry == entry && p.first_factor == factor, || {
            format!("PTAB[{t}]: tables not contiguous")
        })?;
        row += n as u64 + 1;
        entry = entry.checked_add(p.entry_count).ok_or_else(|| bad(format!("PTAB[{t}]: entry count overflows")))?;
        factor = p
            .entry_count
            .checked_mul(p.bands as u64)
            .and_then(|x| x.checked_add(factor))
            .ok_or_else(|| bad(format!("PTAB[{t}]: factor count overflows")))?;
        check(
            row <= r.rows.len() as u64 && entry <= r.outgoing.len() as u64 && factor <= r.factors.len() as u64,
            || format!("PTAB[{t}]: rows or entries outside PROW/PODR/PFAC"),
        )?;
        let rows = &r.rows[p.first_row as usize..row as usize];
        csr(&format!("PROW (table {t})"), rows.iter().map(|&x| x as u64), p.entry_count as usize)?;
    }
    check(row == r.rows.len() as u64 && entry == r.outgoing.len() as u64 && factor == r.factors.len() as u64, || {
        "PROW/PODR/PFAC hold more than the tables".into()
    })?;
    check(r.outgoing.iter().all(|&o| (o as usize) < n), || "PODR: direction out of range".into())?;
    for t in 0..r.prototypes.len() {
        for i in 0..n {
            check(r.row(t, i).0.windows(2).all(|w| w[0] < w[1]), || format!("PTAB[{t}]: row {i} not ascending"))?;
        }
    }
    check(r.factors.iter().all(|f| f.is_finite() && *f >= 0.0), || "PFAC: factor negative or non-finite".into())?;
    // No table returns more than it receives.
    for t in 0..r.prototypes.len() {
        let k = r.prototypes[t].bands as usize;
        for i in 0..n {
            let (_, f) = r.row(t, i);
            let mut sum = [0.0f64; 3];
            for e in f.chunks_exact(k) {
                for c in 0..k {
                    sum[c] += e[c] as f64;
                }
            }
            check(sum.iter().all(|&x| x <= 1.0 + 1e-4), || {
                format!("PTAB[{t}]: row {i} reflects more than it receives")
            })?;
        }
    }
    check(r.maps.len() == r.orientations.len() * n, || "OMAP: not one map of N entries per orientation".into())?;
    let mut seen = vec![0u32; n];
    for o in 0..r.orientations.len() {
        for &d in r.map(o) {
            check((d as usize) < n && seen[d as usize] != o as u32 + 1, || format!("OMAP[{o}]: not a bijection"))?;
            seen[d as usize] = o as u32 + 1;
        }
    }
    check(r.patches.windows(2).all(|w| w[0].patch < w[1].patch), || "NDPA: patches not ascending".into())?;
    let nd_patch = |q: usize| {
        let m =
            &v.materials[v.surfaces[v.primitives[v.patch_primitive[q] as usize].surface as usize].material as usize];
        m.model != layout::model::DIFFUSE
    };
    for (k, e) in r.patches.iter().enumerate() {
        check((e.patch as usize) < v.patch_centre.len() && nd_patch(e.patch as usize), || {
            format!("NDPA[{k}]: patch {} out of range or diffuse", e.patch)
        })?;
        check((e.prototype as usize) < r.prototypes.len() && (e.orientation as usize) < r.orientations.len(), || {
            format!("NDPA[{k}]: prototype or orientation out of range")
        })?;
        check(r.prototypes[e.prototype as usize].model == layout::table_model::GGX, || {
            format!("NDPA[{k}]: prototype is not a GGX lobe")
        })?;
    }
    let listed = (0..v.patch_centre.len()).filter(|&q| nd_patch(q)).count();
    check(listed == r.patches.len(), || format!("NDPA: {} patches listed, {listed} are non-diffuse", r.patches.len()))?;
    check(r.hits.len() == r.patches.len() * (n / 2), || "NDHC: not N/2 counts per non-diffuse patch".into())?;
    if let Some(back) = r.back_hits {
        check(back.len() == r.hits.len(), || format!("NDBK: {} records, expected {}", back.len(), r.hits.len()))?;
        check(back.iter().zip(r.hits).all(|(b, h)| b <= h), || "NDBK: more back-face rays than NDHC rays".into())?;
    }
    Ok(())
}
