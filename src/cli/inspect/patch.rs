//! `illumnet inspect --patch N`: one patch of an archive explained — its
//! surface and geometry, its hit counts against their expectation, its
//! neighbours, and where its link ends lead (grouped by the patch at their
//! other end, heaviest first).

use std::path::Path;

use anyhow::Result;
use illumnet::archive::{self, Archive};

use crate::cli::common::opened;
use crate::cli::exit::BadInput;

/// Link ends `inspect --patch` lists one by one (by other patch, heaviest first).
const PATCH_LIST: usize = 12;

/// Prints what `inspect --patch N` says of patch `p` of the archive at
/// `path` (text or JSON).
pub fn inspect_patch(path: &Path, p: u32, json: bool) -> Result<()> {
    let archive = opened(path, Archive::open_streamed(path, archive::CHUNK_ENDS))?;
    let v = archive.view();
    let meta = archive.meta();
    let n = v.patch_count();
    if p as usize >= n {
        return Err(BadInput(format!("--patch {p}: the archive has patches 0..{n}")).into());
    }
    let i = p as usize;
    let prim = v.patch_primitive[i];
    let r = &v.primitives[prim as usize];
    let surface = r.surface as usize;
    let material = v.surfaces[surface].material as usize;
    let name = |names: &[String], k: usize| names.get(k).cloned().unwrap_or_else(|| format!("#{k}"));
    let kind = match r.kind {
        archive::layout::kind::QUAD => "quad",
        archive::layout::kind::TRIANGLE => "triangle",
        _ => "grouped triangles",
    };
    // Grouped patches: the triangles of the group (consecutive primitives).
    let triangles =
        v.primitives[prim as usize..].iter().take_while(|q| q.kind == r.kind && q.first_patch == r.first_patch).count();
    let adjacent = &v.adjacency[v.adjacency_offsets[i] as usize..v.adjacency_offsets[i + 1] as usize];
    let rows = v.link_rows(&[p])?;
    let (other, weight, direction) = rows.ends(0);
    // Ends by the patch at their other end.
    let mut by_other: std::collections::BTreeMap<u32, (f64, u32)> = std::collections::BTreeMap::new();
    for (&q, &w) in other.iter().zip(weight) {
        let e = by_other.entry(q).or_default();
        e.0 += w as f64;
        e.1 += 1;
    }
    let mut ranked: Vec<(u32, f64, u32)> = by_other.iter().map(|(&q, &(w, k))| (q, w, k)).collect();
    ranked.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
    let total: f64 = weight.iter().map(|&w| w as f64).sum();
    let mut directions: Vec<u32> = direction.to_vec();
    directions.sort_unstable();
    directions.dedup();
    let surface_of = |q: u32| v.primitives[v.patch_primitive[q as usize] as usize].surface as usize;
    let (hits, expected) = (v.patch_hits[i], v.patch_expected_hits[i]);
    let back = v.patch_back_hits.map(|b| b[i]);
    if json {
        let top: Vec<serde_json::Value> = ranked
            .iter()
            .take(PATCH_LIST)
            .map(|&(q, w, k)| {
                serde_json::json!({ "patch": q, "surface": name(&meta.surface_names, surface_of(q)), "ends": k, "rays": w })
            })
            .collect();
        let out = serde_json::json!({
            "patch": p,
            "surface": name(&meta.surface_names, surface),
            "material": name(&meta.material_names, material),
            "primitive": prim,
            "kind": kind,
            "triangles": if r.kind == archive::layout::kind::GROUPED_TRIANGLE { triangles } else { 0 },
            "centre": v.patch_centre[i],
            "normal": v.patch_normal[i],
            "area_m2": v.patch_area[i],
            "hits": hits,
            "expected_hits": expected,
            "back_face_rays": back,
            "adjacent": adjacent,
            "link_ends": other.len(),
            "rays": total,
            "directions": directions.len(),
            "other_patches": ranked.len(),
            "heaviest": top,
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    println!("{} patch {p} of {n}", path.display());
    println!(
        "  surface {} ({}), primitive {prim} ({kind}{})",
        name(&meta.surface_names, surface),
        name(&meta.material_names, material),
        if r.kind == archive::layout::kind::GROUPED_TRIANGLE {
            format!(", {triangles} of them")
        } else {
            String::new()
        }
    );
    println!("  centre {:?} m, normal {:?}, area {:.4e} m²", v.patch_centre[i], v.patch_normal[i], v.patch_area[i]);
    println!(
        "  crossed by {hits} rays (H_p), {expected:.1} expected from its area and orientation ({:.0}%)",
        if expected > 0.0 { 100.0 * hits as f64 / expected as f64 } else { 0.0 }
    );
    if let Some(back) = back {
        println!(
            "  of them, {total:.0} link, {back} meet a back face (absorbed there) and {:.0} leave the scene",
            (hits as f64 - total - back as f64).max(0.0)
        );
    }
    println!("  {} adjacent patches: {adjacent:?}", adjacent.len());
    println!(
        "  {} link ends carrying {total:.0} rays, along {} of {} directions, to {} patches; heaviest:",
        other.len(),
        directions.len(),
        v.directions.len(),
        ranked.len()
    );
    for &(q, w, k) in ranked.iter().take(PATCH_LIST) {
        println!(
            "    patch {q} ({}): {k} end{}, {w:.0} rays ({:.1}%)",
            name(&meta.surface_names, surface_of(q)),
            if k == 1 { "" } else { "s" },
            100.0 * w / total.max(1.0)
        );
    }
    if ranked.len() > PATCH_LIST {
        println!("    … and {} more patches", ranked.len() - PATCH_LIST);
    }
    Ok(())
}
