//! The contents' rules (§7, steps 5 and 6), run in order by
//! [`validate_contents`]: each named check below, then those of the other
//! files of this module, so that later code can index without bounds
//! surprises. This file holds the first: the build record and the section
//! counts it implies, the camera, the materials and the surfaces.

use super::geometry::{check_adjacency, check_directions, check_patches, check_primitives};
use super::link_ends::check_link_ends;
use super::reflectance::validate_reflectance;
use super::sequence::check_sequence;
use super::shading::validate_shading;
use super::views::InetView;
use super::{bad, camera_geometry, check, count, finite};
use crate::archive::layout::{self, CameraRecord};
use crate::archive::{ArchiveError, ArchiveMeta};
use crate::limits::MAX_RADIANCE;

/// Checks counts and every stored index, so that later code can index
/// without bounds surprises; `version_read` is the header's (rules that
/// depend on it).
pub(super) fn validate_contents(v: &InetView<'_>, meta: &ArchiveMeta, version_read: u32) -> Result<(), ArchiveError> {
    check_counts(v, meta)?;
    check_camera(v.camera)?;
    check_materials(v)?;
    check_surfaces(v)?;
    check_primitives(v, version_read)?;
    check_directions(v)?;
    check_patches(v)?;
    check_adjacency(v)?;
    check_link_ends(v)?;
    if let Some(r) = &v.reflectance {
        validate_reflectance(v, r)?;
    }
    if let Some(sh) = &v.shading {
        validate_shading(v, sh)?;
    }
    if let Some(s) = &v.sequence {
        check_sequence(v, s)?;
    }
    Ok(())
}

/// `BILD`'s own rules (a direction set its frequency gives, buckets, ray
/// spacing) and the record count of every section it implies, `META`'s
/// names included; `PBAK` within `PHIT`.
fn check_counts(v: &InetView<'_>, meta: &ArchiveMeta) -> Result<(), ArchiveError> {
    let b = v.build;
    let (p, nv, nd) = (b.patch_count as usize, b.vertex_count as usize, b.direction_count as usize);
    count("SURF", v.surfaces.len(), b.surface_count as usize)?;
    count("MATL", v.materials.len(), b.material_count as usize)?;
    count("PRIM", v.primitives.len(), b.primitive_count as usize)?;
    count("DIRS", v.directions.len(), nd)?;
    let f = b.frequency as u64;
    let expected_dirs = match b.direction_set {
        0 if (1..=crate::limits::MAX_FREQUENCY as u64).contains(&f) => 10 * f * f + 2,
        1 if (1..=100).contains(&f) => 6 * f * f,
        _ => u64::MAX,
    };
    check(nd as u64 == expected_dirs, || {
        format!("BILD: direction set {} with frequency {f} does not give {nd} directions", b.direction_set)
    })?;
    check(b.max_bucket <= layout::MAX_BUCKET, || format!("BILD: max bucket {} out of range", b.max_bucket))?;
    for (name, n) in [
        ("PCEN", v.patch_centre.len()),
        ("PNRM", v.patch_normal.len()),
        ("PARE", v.patch_area.len()),
        ("PPRM", v.patch_primitive.len()),
        ("PCOR", v.patch_corners.len()),
        ("PHIT", v.patch_hits.len()),
        ("PEXP", v.patch_expected_hits.len()),
    ] {
        count(name, n, p)?;
    }
    if let Some(back) = v.patch_back_hits {
        count("PBAK", back.len(), p)?;
        if let Some(i) = back.iter().zip(v.patch_hits).position(|(b, h)| b > h) {
            return Err(bad(format!(
                "PBAK[{i}]: {} back-face rays, more than its {} PHIT rays",
                back[i], v.patch_hits[i]
            )));
        }
    }
    count("VPOS", v.vertex_position.len(), nv)?;
    count("ADJO", v.adjacency_offsets.len(), p + 1)?;
    count("LOFF", v.link_offsets.len(), p + 1)?;
    count("META surface names", meta.surface_names.len(), v.surfaces.len())?;
    count("META material names", meta.material_names.len(), v.materials.len())?;
    check(b.ray_spacing_m.is_finite() && b.ray_spacing_m >= crate::limits::MIN_RAY_SPACING, || {
        format!("BILD: ray spacing {:e} m below {:e} m", b.ray_spacing_m, crate::limits::MIN_RAY_SPACING)
    })?;
    Ok(())
}

/// `CAMR`: a camera rays can be made from, a field of view and an image
/// size in range.
fn check_camera(c: &CameraRecord) -> Result<(), ArchiveError> {
    check(camera_geometry(c), || "CAMR: position, look_at or up non-finite, beyond ±1e9 m or degenerate".into())?;
    check(c.fov_y_deg > 0.0 && c.fov_y_deg < 180.0, || format!("CAMR: field of view {}", c.fov_y_deg))?;
    check((1..=16384).contains(&c.width) && (1..=16384).contains(&c.height), || {
        "CAMR: image size out of range".into()
    })?;
    Ok(())
}

/// `MATL`: known models, finite parameters, reflectances that conserve
/// energy.
fn check_materials(v: &InetView<'_>) -> Result<(), ArchiveError> {
    for (i, m) in v.materials.iter().enumerate() {
        use layout::model::{BROAD_SPECULAR, DIFFUSE, ROUGH_CONDUCTOR};
        check([DIFFUSE, ROUGH_CONDUCTOR, BROAD_SPECULAR].contains(&m.model), || {
            format!("MATL[{i}]: unknown model {}", m.model)
        })?;
        check(finite(&m.params), || format!("MATL[{i}]: non-finite parameter"))?;
        check(m.params[..6].iter().all(|r| (0.0..=1.0).contains(r)), || {
            format!("MATL[{i}]: reflectance outside [0, 1]")
        })?;
        let (kd, ks) = ([m.params[0], m.params[1], m.params[2]], [m.params[3], m.params[4], m.params[5]]);
        check(crate::limits::conserves_energy(kd, ks), || format!("MATL[{i}]: reflectance + specular above 1"))?;
    }
    Ok(())
}

/// `SURF`: materials and primitives in range, emission bounded, and the
/// reflectance sections present when a used material needs them.
fn check_surfaces(v: &InetView<'_>) -> Result<(), ArchiveError> {
    for (i, s) in v.surfaces.iter().enumerate() {
        check((s.material as usize) < v.materials.len(), || {
            format!("SURF[{i}]: material {} out of range", s.material)
        })?;
        check(s.emission.iter().all(|e| (0.0..=MAX_RADIANCE).contains(e)), || {
            format!("SURF[{i}]: emission {:?} outside [0, {MAX_RADIANCE:e}]", s.emission)
        })?;
        check(s.first_primitive as u64 + s.primitive_count as u64 <= v.primitives.len() as u64, || {
            format!("SURF[{i}]: primitives out of range")
        })?;
    }
    // A material no surface's primitives use needs no tables (§5.14).
    for (i, s) in v.surfaces.iter().enumerate() {
        check(
            v.materials[s.material as usize].model == layout::model::DIFFUSE
                || s.primitive_count == 0
                || v.reflectance.is_some(),
            || format!("SURF[{i}]: a non-diffuse material needs the reflectance sections"),
        )?;
    }
    Ok(())
}
