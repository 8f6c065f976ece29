//! `illumnet inspect ARCHIVE`: an archive validated and described — its
//! header, build settings, camera, materials and surfaces (emitters with
//! their power), sequence, reflectance tables and sections, as text or JSON.

use std::path::Path;

use anyhow::Result;
use illumnet::archive::{self, Archive, tag_name};
use illumnet::geometry;

use crate::cli::common::opened;

/// What `inspect` says of one surface: its primitives, patches, area and
/// emitted power (π·L·area per channel, W) at frame 0 (in a sequence, only
/// the instances present then: the others are the same surface at other
/// frames).
fn surface_summary(
    v: &archive::InetView<'_>,
    sf: &archive::layout::SurfaceRecord,
    present: &[bool],
) -> (u64, u64, f64, [f64; 3]) {
    let first = sf.first_primitive as usize;
    let range = first..first + sf.primitive_count as usize;
    let prims: Vec<&archive::layout::PrimitiveRecord> =
        range.filter(|&i| present.get(i).copied().unwrap_or(false)).map(|i| &v.primitives[i]).collect();
    // A group of grouped triangles (consecutive, one patch) counts once.
    let patches: u64 = prims
        .iter()
        .enumerate()
        .map(|(i, p)| match p.kind {
            archive::layout::kind::GROUPED_TRIANGLE => {
                u64::from(i == 0 || prims[i - 1].kind != p.kind || prims[i - 1].first_patch != p.first_patch)
            }
            _ => (p.grid_u as u64) * (p.grid_v as u64),
        })
        .sum();
    let primitives = prims.len() as u64;
    let area: f64 = prims
        .iter()
        .map(|p| {
            let kind = if p.kind == 0 { geometry::PrimitiveKind::Quad } else { geometry::PrimitiveKind::Triangle };
            geometry::Primitive { kind, p: p.corners.map(glam::Vec3::from) }.area() as f64
        })
        .sum();
    (primitives, patches, area, sf.emission.map(|e| std::f64::consts::PI * e as f64 * area))
}

/// The scene-format name of a material model code.
fn model_name(m: u32) -> &'static str {
    match m {
        archive::layout::model::DIFFUSE => "diffuse",
        archive::layout::model::ROUGH_CONDUCTOR => "rough_conductor",
        archive::layout::model::BROAD_SPECULAR => "broad_specular",
        _ => "unknown",
    }
}

/// Most materials and surfaces the text `inspect` lists one by one.
const LIST_LIMIT: usize = 24;

/// Prints what `inspect` says of the archive at `path`: as JSON, or as
/// text.
pub fn inspect(path: &Path, json: bool) -> Result<()> {
    // Inspecting reads no link end after validation: streamed, it holds a
    // chunk of them at a time whatever the archive's size.
    let archive = opened(path, Archive::open_streamed(path, archive::CHUNK_ENDS))?;
    let v = archive.view();
    if json {
        return print_json(&archive, &v);
    }
    print_header(path, &archive, &v);
    print_materials_and_surfaces(archive.meta(), &v);
    if let Some(s) = v.sequence {
        let changes: u64 = s.index.iter().map(|i| i.count).sum();
        let stored: u64 = s.index.iter().map(|i| i.stored_length).sum();
        println!(
            "  sequence: {} frames at {} fps, {} temporal instances, {} link changes against frame 0 ({:.1} MB zstd)",
            s.frames(),
            s.record.fps,
            s.instances.len(),
            changes,
            stored as f64 / 1e6
        );
    }
    print_reflectance(&v);
    print_sections(&archive);
    Ok(())
}

/// `inspect --json`: everything the text says, and every section's and
/// surface's details.
fn print_json(archive: &Archive, v: &archive::InetView<'_>) -> Result<()> {
    let h = archive.header();
    let b = v.build;
    let meta = archive.meta();
    let sections: Vec<serde_json::Value> = archive
        .sections()
        .iter()
        .map(|e| {
            serde_json::json!({
                "tag": tag_name(e.tag),
                "offset": e.offset,
                "stored_length": e.stored_length,
                "length": e.length,
                "count": e.count,
                "record_size": e.record_size,
                "compression": match e.compression { 0 => "none", 1 => "zstd", _ => "unknown" },
                "checksum": format!("{:016x}", e.checksum),
            })
        })
        .collect();
    let mut emitted_w = 0.0f64;
    let present = v.presence(0).primitives;
    let details: Vec<serde_json::Value> = v
        .surfaces
        .iter()
        .enumerate()
        .map(|(i, sf)| {
            let (primitives, patches, area, watts) = surface_summary(v, sf, &present);
            emitted_w += watts.iter().sum::<f64>();
            serde_json::json!({
                "name": meta.surface_names.get(i),
                "material": sf.material,
                "primitives": primitives,
                "patches": patches,
                "area_m2": area,
                "emission": sf.emission,
                "power_w": watts,
            })
        })
        .collect();
    let out = serde_json::json!({
        "format_version": h.version_write,
        "version_read": h.version_read,
        "file_length": h.file_length,
        "generator": meta.generator,
        "scene": meta.scene,
        "frequency": b.frequency,
        "directions": b.direction_count,
        "patches": b.patch_count,
        "vertices": b.vertex_count,
        "primitives": b.primitive_count,
        "surfaces": meta.surface_names,
        "materials": meta.material_names,
        "ray_spacing_m": b.ray_spacing_m,
        "patch_size_m": b.patch_size_m,
        "rays": b.ray_count,
        "hits": b.hit_count,
        "links": b.link_end_count / 2,
        "links_unmerged": b.link_count,
        "link_ends": b.link_end_count,
        "frames": v.sequence.map_or(1, |s| s.frames()),
        "instances": v.sequence.map_or(0, |s| s.instances.len()),
        "prototype_tables": v.reflectance.map_or(0, |r| r.prototypes.len()),
        "orientations": v.reflectance.map_or(0, |r| r.orientations.len()),
        "nondiffuse_patches": v.reflectance.map_or(0, |r| r.patches.len()),
        "sections": sections,
        "camera": {
            "position": v.camera.position,
            "look_at": v.camera.look_at,
            "up": v.camera.up,
            "fov_y_deg": v.camera.fov_y_deg,
            "width": v.camera.width,
            "height": v.camera.height,
        },
        "material_models": v.materials.iter().map(|m| model_name(m.model)).collect::<Vec<_>>(),
        "surface_details": details,
        "emitted_w": emitted_w,
    });
    println!("{}", serde_json::to_string_pretty(&out)?);
    Ok(())
}

/// The text's first lines: the format, the generator and scene, the build's
/// counts and the camera.
fn print_header(path: &Path, archive: &Archive, v: &archive::InetView<'_>) {
    let h = archive.header();
    let b = v.build;
    let meta = archive.meta();
    println!(
        "{}: illumnet archive, format version {} (readable by version {}+)",
        path.display(),
        h.version_write,
        h.version_read
    );
    println!("  written by {}, scene `{}`, {} bytes", meta.generator, meta.scene, h.file_length);
    println!(
        "  {} directions (f = {}), {} patches, {} vertices, {} primitives, {} surfaces, {} materials",
        b.direction_count,
        b.frequency,
        b.patch_count,
        b.vertex_count,
        b.primitive_count,
        b.surface_count,
        b.material_count
    );
    println!(
        "  {} rays at δ = {} m, {} hits, {} links ({} before merging parallel rays), {} link ends",
        b.ray_count,
        b.ray_spacing_m,
        b.hit_count,
        b.link_end_count / 2,
        b.link_count,
        b.link_end_count
    );
    let c = v.camera;
    println!(
        "  camera: at {:?} looking at {:?}, up {:?}, {}° vertical field of view, {} × {} pixels",
        c.position, c.look_at, c.up, c.fov_y_deg, c.width, c.height
    );
}

/// The materials and the surfaces (each with its material, primitives and
/// patches at frame 0; emitters with their power), the first
/// [`LIST_LIMIT`] of each, and the emitters' total power.
fn print_materials_and_surfaces(meta: &archive::ArchiveMeta, v: &archive::InetView<'_>) {
    let name_or = |names: &[String], i: usize| names.get(i).cloned().unwrap_or_else(|| format!("#{i}"));
    println!("  materials:");
    for (i, m) in v.materials.iter().enumerate().take(LIST_LIMIT) {
        println!("    {}: {}", name_or(&meta.material_names, i), model_name(m.model));
    }
    if v.materials.len() > LIST_LIMIT {
        println!("    … and {} more (--json lists all)", v.materials.len() - LIST_LIMIT);
    }
    let at_frame_0 = if v.sequence.is_some() { " at frame 0" } else { "" };
    println!("  surfaces (material, primitives, patches{at_frame_0}; emitters with their power, π·L·area):");
    let (mut emitters, mut power) = (0usize, [0.0f64; 3]);
    let present = v.presence(0).primitives;
    for (i, sf) in v.surfaces.iter().enumerate() {
        let (primitives, patches, area, watts) = surface_summary(v, sf, &present);
        let emits = sf.emission.iter().any(|&e| e > 0.0);
        if emits {
            emitters += 1;
            (0..3).for_each(|k| power[k] += watts[k]);
        }
        if i < LIST_LIMIT {
            let light = if emits {
                format!(", emits {:?} W·sr⁻¹·m⁻² over {area:.4} m²: {:.3} W", sf.emission, watts.iter().sum::<f64>())
            } else {
                String::new()
            };
            println!(
                "    {}: {}, {} primitive{}, {patches} patches{light}",
                name_or(&meta.surface_names, i),
                name_or(&meta.material_names, sf.material as usize),
                primitives,
                if primitives == 1 { "" } else { "s" },
            );
        }
    }
    if v.surfaces.len() > LIST_LIMIT {
        println!("    … and {} more (--json lists all)", v.surfaces.len() - LIST_LIMIT);
    }
    println!(
        "  emitters: {emitters} surface{} emitting {:.3} W in all at frame 0 ({:.3}, {:.3}, {:.3} W per channel)",
        if emitters == 1 { "" } else { "s" },
        power.iter().sum::<f64>(),
        power[0],
        power[1],
        power[2]
    );
}

/// The reflectance tables of non-diffuse patches, if any: their count and
/// orientations' map error, then every prototype table.
fn print_reflectance(v: &archive::InetView<'_>) {
    let b = v.build;
    if let Some(r) = v.reflectance {
        let (mean, max) = r.orientations.iter().fold((0.0f64, 0.0f32), |(m, x), o| {
            (m + o.error_mean_rad as f64 / r.orientations.len() as f64, x.max(o.error_max_rad))
        });
        println!(
            "  reflectance: {} non-diffuse patches, {} orientation{} (map error mean {:.2}°, max {:.2}°)",
            r.patches.len(),
            r.orientations.len(),
            if r.orientations.len() == 1 { "" } else { "s" },
            mean.to_degrees(),
            max.to_degrees()
        );
        for (t, p) in r.prototypes.iter().enumerate() {
            let model = if p.model == archive::layout::table_model::GGX { "GGX lobe" } else { "Lambertian" };
            let ior = if p.ior == [0.0; 3] { "Fresnel 1".to_string() } else { format!("ior {:?}", p.ior) };
            println!(
                "    table {t}: {model}, α = ({}, {}), {ior}, {} band{}, {} entries ({:.1} per direction), threshold {}",
                p.alpha_u,
                p.alpha_v,
                p.bands,
                if p.bands == 1 { "" } else { "s" },
                p.entry_count,
                p.entry_count as f64 / b.direction_count as f64,
                p.threshold
            );
        }
    }
}

/// The section table.
fn print_sections(archive: &Archive) {
    println!("  sections:");
    println!(
        "    {:4}  {:>12}  {:>12}  {:>12}  {:>6}  {:4}  checksum",
        "tag", "offset", "stored", "records", "size", "comp"
    );
    for e in archive.sections() {
        println!(
            "    {:4}  {:>12}  {:>12}  {:>12}  {:>6}  {:4}  {:016x}",
            tag_name(e.tag),
            e.offset,
            e.stored_length,
            e.count,
            e.record_size,
            if e.compression == 1 { "zstd" } else { "none" },
            e.checksum
        );
    }
}
