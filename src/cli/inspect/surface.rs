//! `illumnet inspect --surface NAME`: one surface of an archive explained —
//! its material and emission, its primitives and patches, how well rays
//! cover them (H_p over its expectation), and which surfaces its links
//! exchange light with. Link rows are read a block of patches at a time.

use std::path::Path;

use anyhow::Result;
use illumnet::archive::{self, Archive};

use crate::cli::common::opened;
use crate::cli::exit::BadInput;

/// Patches whose link rows are read at once.
const BLOCK: usize = 4096;
/// Surfaces listed as exchange partners, heaviest first.
const PARTNERS: usize = 12;

/// What a surface's link ends carry: rays by the surface at their other
/// end, link ends, patches without any, and the rays along links shorter
/// than `near` metres (centre to centre).
pub struct Exchange {
    /// Rays (link weights) by surface index.
    pub to: Vec<f64>,
    /// Link ends of the surface's patches.
    pub ends: u64,
    /// The surface's patches without a link end.
    pub unlinked: usize,
    /// Rays along links shorter than `near`, by surface index.
    pub near: Vec<f64>,
}

/// The [`Exchange`] of the surface whose patches are `patches`, read
/// [`BLOCK`] patches at a time.
pub fn exchange(v: &archive::InetView<'_>, patches: &[u32], near: f32) -> Result<Exchange> {
    let surface_of = |p: usize| v.primitives[v.patch_primitive[p] as usize].surface as usize;
    let mut x = Exchange { to: vec![0.0; v.surfaces.len()], ends: 0, unlinked: 0, near: vec![0.0; v.surfaces.len()] };
    for block in patches.chunks(BLOCK) {
        let rows = v.link_rows(block)?;
        for (k, &p) in block.iter().enumerate() {
            let (other, weight, _) = rows.ends(k);
            x.ends += other.len() as u64;
            x.unlinked += other.is_empty() as usize;
            let c = glam::Vec3::from(v.patch_centre[p as usize]);
            for (&q, &w) in other.iter().zip(weight) {
                let t = surface_of(q as usize);
                x.to[t] += w as f64;
                if near > 0.0 && c.distance(glam::Vec3::from(v.patch_centre[q as usize])) < near {
                    x.near[t] += w as f64;
                }
            }
        }
    }
    Ok(x)
}

/// Warnings for emitters that send most of their rays to surfaces within
/// two patch sizes: a lamp facing a nearby surface lights that surface
/// first (often a lamp placed the wrong way round, or against a wall).
pub fn facing_nearby(v: &archive::InetView<'_>, names: &[String], patch_size: f32) -> Result<Vec<String>> {
    let surface_of = |p: usize| v.primitives[v.patch_primitive[p] as usize].surface as usize;
    let emitters: Vec<usize> =
        (0..v.surfaces.len()).filter(|&s| v.surfaces[s].emission.iter().any(|&e| e > 0.0)).collect();
    if emitters.is_empty() {
        return Ok(Vec::new());
    }
    let mut is_emitter = vec![false; v.surfaces.len()];
    for &s in &emitters {
        is_emitter[s] = true;
    }
    let mut patches_of: Vec<Vec<u32>> = vec![Vec::new(); v.surfaces.len()];
    for p in 0..v.patch_count() {
        let s = surface_of(p);
        if is_emitter[s] {
            patches_of[s].push(p as u32);
        }
    }
    let near = 2.0 * patch_size;
    let mut out = Vec::new();
    for &s in &emitters {
        let x = exchange(v, &patches_of[s], near)?;
        let total: f64 = x.to.iter().sum();
        let close: f64 = x.near.iter().sum();
        if total > 0.0 && close > 0.5 * total {
            let mut by: Vec<(usize, f64)> = x.near.iter().copied().enumerate().filter(|&(_, w)| w > 0.0).collect();
            by.sort_by(|a, b| b.1.total_cmp(&a.1));
            let name = |k: usize| names.get(k).cloned().unwrap_or_else(|| format!("#{k}"));
            out.push(format!(
                "emitter `{}` sends {:.0}% of its linked rays to surfaces within {near:.3} m (mostly `{}`): \
                 is it facing a nearby surface? That surface is lit first",
                name(s),
                100.0 * close / total,
                name(by[0].0)
            ));
        }
    }
    Ok(out)
}

/// Prints what `inspect --surface NAME` says of the surface `name` of the
/// archive at `path` (text or JSON).
pub fn inspect_surface(path: &Path, name: &str, json: bool) -> Result<()> {
    let archive = opened(path, Archive::open_streamed(path, archive::CHUNK_ENDS))?;
    let v = archive.view();
    let meta = archive.meta();
    let names = &meta.surface_names;
    let Some(s) = names.iter().position(|n| n == name) else {
        let shown: Vec<&str> = names.iter().take(20).map(String::as_str).collect();
        let more = if names.len() > 20 { format!(", … {} more", names.len() - 20) } else { String::new() };
        return Err(BadInput(format!("--surface `{name}`: no such surface (known: {}{more})", shown.join(", "))).into());
    };
    let record = &v.surfaces[s];
    let material = meta.material_names.get(record.material as usize).cloned().unwrap_or_default();
    let surface_of = |p: usize| v.primitives[v.patch_primitive[p] as usize].surface as usize;
    // At frame 0: a sequence's other instances of the surface are the same
    // surface at other frames.
    let present = v.presence(0);
    let patches: Vec<u32> =
        (0..v.patch_count()).filter(|&p| surface_of(p) == s && present.patch(p)).map(|p| p as u32).collect();
    let first = record.first_primitive as usize;
    let primitives = (first..first + record.primitive_count as usize)
        .filter(|&i| present.primitives.get(i).copied().unwrap_or(false))
        .count();
    let area: f64 = patches.iter().map(|&p| v.patch_area[p as usize] as f64).sum();
    let hits: u64 = patches.iter().map(|&p| v.patch_hits[p as usize] as u64).sum();
    let expected: f64 = patches.iter().map(|&p| v.patch_expected_hits[p as usize] as f64).sum();
    let back: Option<u64> = v.patch_back_hits.map(|b| patches.iter().map(|&p| b[p as usize] as u64).sum());
    let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
    for &p in &patches {
        for (k, &c) in v.patch_centre[p as usize].iter().enumerate() {
            lo[k] = lo[k].min(c);
            hi[k] = hi[k].max(c);
        }
    }
    let x = exchange(&v, &patches, 0.0)?;
    let (to, ends, unlinked) = (x.to, x.ends, x.unlinked);
    let rays: f64 = to.iter().sum();
    let mut partners: Vec<(usize, f64)> = to.iter().copied().enumerate().filter(|&(_, w)| w > 0.0).collect();
    partners.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
    let power = std::f64::consts::PI * area * record.emission.iter().map(|&e| e as f64).sum::<f64>();
    let surface_name = |k: usize| names.get(k).cloned().unwrap_or_else(|| format!("#{k}"));
    if json {
        let top: Vec<serde_json::Value> = partners
            .iter()
            .take(PARTNERS)
            .map(|&(k, w)| serde_json::json!({ "surface": surface_name(k), "rays": w, "share": w / rays.max(1.0) }))
            .collect();
        let out = serde_json::json!({
            "surface": name,
            "index": s,
            "material": material,
            "emission": record.emission,
            "power_w": power,
            "primitives": primitives,
            "patches": patches.len(),
            "area_m2": area,
            "bounds_of_patch_centres": if patches.is_empty() { serde_json::Value::Null } else { serde_json::json!([lo, hi]) },
            "hits": hits,
            "expected_hits": expected,
            "patches_without_links": unlinked,
            "link_ends": ends,
            "rays": rays,
            "back_face_rays": back,
            "exchanges_with": top,
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    let at_frame_0 = if v.sequence.is_some() { ", at frame 0" } else { "" };
    println!("{} surface `{name}` (#{s} of {}{at_frame_0})", path.display(), v.surfaces.len());
    let plural = |n: usize, word: &str| format!("{n} {word}{}", if n == 1 { "" } else { "s" });
    println!(
        "  material {material}, {}, {}, {area:.4} m²",
        plural(primitives, "primitive"),
        plural(patches.len(), "patch").replace("patchs", "patches")
    );
    if record.emission.iter().any(|&e| e > 0.0) {
        println!("  emits {:?} W·sr⁻¹·m⁻²: {power:.4} W (π·L·area, summed over RGB)", record.emission);
    }
    if !patches.is_empty() {
        println!("  patch centres within {lo:?} .. {hi:?} m");
    }
    println!(
        "  crossed by {hits} rays (Σ H_p), {expected:.0} expected from area and orientation ({:.0}%)",
        if expected > 0.0 { 100.0 * hits as f64 / expected } else { 0.0 }
    );
    if unlinked > 0 {
        println!("  {unlinked} of its patches have no link end: no ray joined them to another patch");
    }
    if let Some(back) = back {
        println!(
            "  of its rays, {rays:.0} link, {back} meet a back face (absorbed there) and {:.0} leave the scene",
            (hits as f64 - rays - back as f64).max(0.0)
        );
    }
    println!("  {ends} link ends carrying {rays:.0} rays; light exchanged with:");
    for &(k, w) in partners.iter().take(PARTNERS) {
        println!("    {} : {w:.0} rays ({:.1}%)", surface_name(k), 100.0 * w / rays.max(1.0));
    }
    if partners.len() > PARTNERS {
        println!("    … and {} more surfaces", partners.len() - PARTNERS);
    }
    Ok(())
}
