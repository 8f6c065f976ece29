//! Assembling the archive's contents from what the stages made: frame 0's
//! link table (merged in memory, or the spilled runs' merge to come), the
//! expected hits, the records of surfaces, materials, primitives and
//! directions, the patch columns, and a sequence's, the reflectance and
//! the shading sections ([`sequence`]).

use glam::Vec3;
use rayon::prelude::*;

use super::bundle::Bundle;
use super::links::{self, LinkTable};
use super::setup::Setup;
use super::spill::{Spill, SpilledLinks};
use super::{BuildError, BuildSettings, BuildStats, Instance, LinkRecord, Sequence, trace};
use crate::archive::deltas::{Block, SpillFile};
use crate::archive::layout::{
    self, AnimationRecord, BuildRecord, CameraRecord, DirectionRecord, InstanceRecord, MaterialRecord, PrimitiveRecord,
    SurfaceRecord,
};
use crate::archive::{ArchiveContents, ArchiveMeta, ReflectanceContents, SequenceContents};
use crate::geodesic::DirectionSet;
use crate::geometry::Primitive;
use crate::geometry::grid::CellOrder;
use crate::patch::{Patches, PrimitivePatches};
use crate::progress::Progress;
use crate::scene::texture::Shading;
use crate::scene::{ReflectanceModel, Scene};

/// Frame 0's links, as [`link_table`] leaves them.
pub(super) struct FrameLinks {
    /// The link-end table (only its offsets when the links were spilled).
    pub(super) table: LinkTable,
    /// The spilled runs, to merge as the archive is written.
    pub(super) spilled: Option<SpilledLinks>,
    /// The links as records, when kept for verification.
    pub(super) base: Option<Vec<LinkRecord>>,
}

/// Frame 0's links as the archive's link-end table, from the `bundles`
/// tracing kept: merged in memory ([`links::assemble`]), or, when a
/// bounded build's `spill` has spilled any, what was never spilled
/// spilled too and the runs merged as the archive is written (the table
/// then holds only `LOFF`, the runs come back as [`SpilledLinks`]). With
/// `keep_links`, also frame 0's links as records ([`Sequence::base`]).
pub(super) fn link_table(
    bundles: Vec<Bundle>,
    spill: Option<Spill>,
    patch_count: usize,
    max_bucket: u32,
    keep_links: bool,
    progress: &dyn Progress,
) -> Result<FrameLinks, BuildError> {
    let spilled_any = spill.as_ref().is_some_and(|s| s.run_count() > 0);
    let (table, spilled, bundles) = match spill {
        Some(sp) if spilled_any => {
            // What was never spilled goes too, in runs of consecutive pairs.
            let mut rest = bundles;
            let mut group: Vec<Bundle> = Vec::new();
            for b in rest.drain(..) {
                if group.last().is_some_and(|l| l.pair + 1 != b.pair) {
                    sp.spill(&mut group)?;
                }
                group.push(b);
            }
            sp.spill(&mut group)?;
            let (merge, offsets) = sp.finish(progress)?;
            let table =
                LinkTable { offsets, other: Vec::new(), weight: Vec::new(), direction: Vec::new(), bucket: Vec::new() };
            (table, Some(merge), Vec::new())
        }
        _ => (links::assemble(&bundles, patch_count, max_bucket), None, bundles),
    };
    crate::scratch::stop_point("links");
    let base = keep_links.then(|| {
        bundles
            .iter()
            .flat_map(|b| {
                (0..b.a.len()).map(move |i| LinkRecord {
                    pair: b.pair,
                    a: b.a[i],
                    b: b.b[i],
                    bucket_a: b.bucket_a[i],
                    bucket_b: b.bucket_b[i],
                    weight: b.w[i],
                })
            })
            .collect()
    });
    drop(bundles); // the link table now holds them
    Ok(FrameLinks { table, spilled, base })
}

/// What tracing and the stages after it made, for the archive's contents
/// and the [`Sequence`].
pub(super) struct Products {
    /// `H_p`: hits per patch.
    pub(super) hits: Vec<u32>,
    /// Per patch, of its `H_p` rays those whose light meets a back face.
    pub(super) backs: Vec<u32>,
    /// Frame 0's link-end table (only its offsets when the links were
    /// spilled).
    pub(super) table: LinkTable,
    /// Frame 0's links, when kept for verification.
    pub(super) base: Option<Vec<LinkRecord>>,
    /// A sequence's per-frame link changes, compressed as tracing left
    /// them, and the file the spilled ones went to.
    pub(super) deltas: Vec<Vec<Block>>,
    pub(super) spilled_deltas: Option<SpillFile>,
    /// The reflectance sections (`None`: every patch is diffuse).
    pub(super) reflectance: Option<ReflectanceContents>,
    /// Bounds the ray grids covered.
    pub(super) bounds: (Vec3, Vec3),
    /// Problems that did not stop the build.
    pub(super) warnings: Vec<String>,
}

/// The built [`Sequence`]: the archive's contents assembled from the
/// `setup` and what the stages after it made, with the build's `stats`.
pub(super) fn sequence(
    scene: &Scene,
    settings: &BuildSettings,
    setup: Setup,
    made: Products,
    stats: BuildStats,
) -> Result<Sequence, BuildError> {
    let expected = expected_hits(&setup.dirs, settings.ray_spacing, &setup.prims, &setup.patches);
    let patch_identity = patch_identity(&setup.patches.primitives, &setup.prim_surface, &setup.sort_key);
    let Setup { dirs, instances, prims, prim_surface, patches, .. } = setup;
    let table = made.table;
    let contents = ArchiveContents {
        build: build_record(scene, settings, &dirs, &patches, prims.len(), &stats),
        camera: camera_record(&scene.camera),
        surfaces: surface_records(scene, &instances),
        materials: material_records(scene),
        primitives: primitive_records(&prims, &patches, &prim_surface),
        directions: direction_records(&dirs),
        patch_centre: patches.centre,
        patch_normal: patches.normal,
        patch_area: patches.area,
        patch_primitive: patches.primitive,
        patch_corners: patches.corners,
        patch_hits: made.hits,
        patch_expected_hits: expected,
        patch_back_hits: made.backs,
        vertex_position: patches.vertex_position,
        grouped_triangles: patches.mesh_triangles,
        adjacency_offsets: patches.adjacency_offsets,
        adjacency: patches.adjacency,
        link_offsets: table.offsets,
        link_other: table.other,
        link_weight: table.weight,
        link_direction: table.direction,
        link_bucket: table.bucket,
        meta: ArchiveMeta {
            generator: format!("illumnet {}", env!("CARGO_PKG_VERSION")),
            scene: scene.name.clone(),
            surface_names: scene.surfaces.iter().map(|s| s.name.clone()).collect(),
            material_names: scene.materials.iter().map(|m| m.name.clone()).collect(),
        },
        sequence: sequence_sections(scene, &instances, made.deltas, made.spilled_deltas)?,
        reflectance: made.reflectance,
        shading: shading_contents(scene, &instances),
    };
    Ok(Sequence {
        contents,
        stats,
        frames: scene.frame_count(),
        instances,
        base: made.base,
        patch_identity,
        bounds: made.bounds,
        warnings: made.warnings,
    })
}

/// The build record (`BILD`, §5.1): the resolution and the counts of the
/// build.
fn build_record(
    scene: &Scene,
    settings: &BuildSettings,
    dirs: &DirectionSet,
    patches: &Patches,
    primitive_count: usize,
    stats: &BuildStats,
) -> BuildRecord {
    BuildRecord {
        frequency: dirs.frequency,
        direction_count: dirs.len() as u32,
        patch_count: patches.len() as u32,
        vertex_count: patches.vertex_position.len() as u32,
        primitive_count: primitive_count as u32,
        surface_count: scene.surfaces.len() as u32,
        material_count: scene.materials.len() as u32,
        link_merge: layout::merge::PATCH_PAIR_DIRECTION,
        direction_set: dirs.kind as u32,
        max_bucket: settings.max_bucket,
        ray_spacing_m: settings.ray_spacing,
        patch_size_m: settings.patch_size,
        ray_count: stats.rays,
        link_count: stats.links,
        link_end_count: stats.link_ends,
        hit_count: stats.hits,
        reserved1: [0; 6],
    }
}

/// Expected hits from geometry: a patch of area A and normal n is crossed
/// by A·|n·d_k|·density_k rays of pair k (both directions of the pair).
fn expected_hits(dirs: &DirectionSet, ray_spacing: f32, prims: &[Primitive], patches: &Patches) -> Vec<f32> {
    let densities: Vec<f64> = (0..dirs.len() as u32 / 2).map(|k| trace::layout(dirs, ray_spacing, k).density).collect();
    let coverage: Vec<f64> = prims
        .par_iter()
        .map(|p| {
            let n = p.normal().as_dvec3();
            densities
                .iter()
                .enumerate()
                .map(|(k, rho)| n.dot(glam::DVec3::from(dirs.directions[2 * k].map(f64::from))).abs() * rho)
                .sum()
        })
        .collect();
    // A grouped patch sums its triangles', each with its own normal.
    let mut expected = vec![0.0f64; patches.len()];
    for (pi, pp) in patches.primitives.iter().enumerate() {
        if pp.grouped() {
            expected[pp.first_patch as usize] += prims[pi].area() as f64 * coverage[pi];
        } else {
            for p in pp.first_patch..pp.first_patch + pp.grid.cell_count() {
                expected[p as usize] += patches.area[p as usize] as f64 * coverage[pi];
            }
        }
    }
    expected.into_iter().map(|e| e as f32).collect()
}

/// The surface records (`SURF`, §5.3): each surface's instances' primitives, which are
/// consecutive in instance order.
fn surface_records(scene: &Scene, instances: &[Instance]) -> Vec<SurfaceRecord> {
    let mut surfaces = Vec::with_capacity(scene.surfaces.len());
    let mut first = 0u32;
    for (si, s) in scene.surfaces.iter().enumerate() {
        let n = instances.iter().filter(|i| i.surface == si as u32).map(|i| i.primitives.len() as u32).sum::<u32>();
        surfaces.push(SurfaceRecord {
            material: s.material,
            first_primitive: first,
            primitive_count: n,
            reserved0: 0,
            emission: s.emission,
            reserved1: 0.0,
        });
        first += n;
    }
    surfaces
}

/// The material records (`MATL`, §5.4): model and parameters.
fn material_records(scene: &Scene) -> Vec<MaterialRecord> {
    scene
        .materials
        .iter()
        .map(|m| {
            let mut params = [0.0; 14];
            params[..3].copy_from_slice(&m.model.diffuse());
            if let Some((ks, lobe)) = m.model.lobe() {
                params[3..6].copy_from_slice(&ks);
                params[6] = lobe.alpha_u;
                params[7] = lobe.alpha_v;
                params[8..11].copy_from_slice(&lobe.ior.unwrap_or([0.0; 3]));
            }
            let model = match m.model {
                ReflectanceModel::Diffuse { .. } => layout::model::DIFFUSE,
                ReflectanceModel::RoughConductor { .. } => layout::model::ROUGH_CONDUCTOR,
                ReflectanceModel::BroadSpecular { .. } => layout::model::BROAD_SPECULAR,
            };
            MaterialRecord { model, reserved: 0, params }
        })
        .collect()
}

/// The primitive records (`PRIM`, §5.5): kind, surface, patch grid and where its patches
/// and vertices start, corners.
fn primitive_records(prims: &[Primitive], patches: &Patches, prim_surface: &[u32]) -> Vec<PrimitiveRecord> {
    prims
        .iter()
        .zip(&patches.primitives)
        .zip(prim_surface)
        .map(|((p, pp), &s)| PrimitiveRecord {
            kind: if pp.grouped() { layout::kind::GROUPED_TRIANGLE } else { p.kind as u32 },
            surface: s,
            grid_u: pp.grid.n_u,
            grid_v: pp.grid.n_v,
            first_patch: pp.first_patch,
            first_vertex: pp.first_vertex,
            cell_order: match pp.grid.order {
                CellOrder::Rows => layout::cell_order::ROWS,
                CellOrder::Tiles => layout::cell_order::TILES,
            },
            reserved: 0,
            corners: p.p.map(|v| v.to_array()),
        })
        .collect()
}

/// The direction records (`DIRS`, §5.6): direction, Voronoi cell, neighbours.
fn direction_records(dirs: &DirectionSet) -> Vec<DirectionRecord> {
    dirs.directions
        .iter()
        .zip(&dirs.neighbours)
        .zip(&dirs.solid_angle)
        .map(|((d, n), &w)| DirectionRecord { direction: *d, solid_angle_sr: w as f32, neighbours: *n })
        .collect()
}

/// Per patch: (surface, primitive index within its surface, cell), from
/// the primitives' patches (`primitives`), surfaces and sort keys; indexed
/// by patch id, whatever order the patches are numbered in.
fn patch_identity(primitives: &[PrimitivePatches], prim_surface: &[u32], sort_key: &[u64]) -> Vec<(u32, u32, u32)> {
    let n_patches: usize = primitives.iter().map(|pp| pp.owned_patches() as usize).sum();
    let mut patch_identity = vec![(0, 0, 0); n_patches];
    for (pi, pp) in primitives.iter().enumerate() {
        for cell in 0..pp.owned_patches() {
            patch_identity[(pp.first_patch + cell) as usize] =
                (prim_surface[pi], (sort_key[pi] & 0xffff_ffff) as u32, cell);
        }
    }
    patch_identity
}

/// The shading sections (§5.15) for the archive's primitives, instance by
/// instance: each primitive's surface's shading detail (texture
/// coordinates, normals in the primitive's own frame and texture, which
/// rigid motion leaves as they are), and the scene's textures; `None` when
/// no surface has any.
fn shading_contents(scene: &Scene, instances: &[Instance]) -> Option<crate::archive::ShadingContents> {
    use crate::archive::layout::{ShadingRecord, TextureRecord, shading_flags};
    use crate::scene::texture::Wrap;
    if scene.surfaces.iter().all(|s| s.shading.is_empty()) {
        return None;
    }
    let mut primitives = Vec::with_capacity(instances.iter().map(|i| i.primitives.len()).sum());
    // What the format allows (§5.15): finite coordinates within ±10⁶, a
    // tint in [0, 10⁶], normal components within ±1.
    let clean = |x: f32, bound: f32| if x.is_finite() { x.clamp(-bound, bound) } else { 0.0 };
    for inst in instances {
        for i in 0..inst.primitives.len() {
            let sh = if inst.shading.len() == inst.primitives.len() { inst.shading[i] } else { Shading::FLAT };
            let has_normals = sh.normal.iter().any(|n| *n != glam::Vec3::ZERO);
            let has_texture = (sh.texture as usize) < scene.textures.len();
            primitives.push(ShadingRecord {
                flags: if has_normals { shading_flags::NORMALS } else { 0 }
                    | if has_texture { shading_flags::TEXTURE } else { 0 },
                texture: if has_texture { sh.texture } else { u32::MAX },
                tint: if has_texture { sh.tint.map(|t| clean(t, 1e6).max(0.0)) } else { [1.0; 3] },
                reserved: 0,
                normals: sh.normal.map(|n| n.to_array().map(|c| clean(c, 1.0))),
                uvs: sh.uv.map(|u| u.to_array().map(|c| clean(c, 1e6))),
            });
        }
    }
    let mut textures = Vec::with_capacity(scene.textures.len());
    let mut texels = Vec::with_capacity(scene.textures.iter().map(|t| t.srgb.len()).sum());
    for t in &scene.textures {
        let wrap = t.wrap.map(|w| match w {
            Wrap::Clamp => 0,
            Wrap::Repeat => 1,
            Wrap::Mirror => 2,
        });
        textures.push(TextureRecord {
            width: t.width,
            height: t.height,
            wrap,
            first_byte: texels.len() as u64,
            filter: u32::from(t.nearest),
            reserved: 0,
        });
        texels.extend_from_slice(&t.srgb);
    }
    Some(crate::archive::ShadingContents { primitives, textures, texels })
}

/// The animation sections for an animated scene: instances and, per frame,
/// the link changes relative to frame 0 (so that any frame is reached by
/// decoding one entry; see `format-spec/archive.md` §5.13), assembled from
/// the blocks tracing compressed.
fn sequence_sections(
    scene: &Scene,
    instances: &[Instance],
    blocks: Vec<Vec<crate::archive::deltas::Block>>,
    spilled: Option<crate::archive::deltas::SpillFile>,
) -> Result<Option<SequenceContents>, BuildError> {
    let Some(anim) = scene.animation.filter(|_| scene.is_animated()) else {
        return Ok(None);
    };
    let mut first = 0;
    let records = instances
        .iter()
        .map(|i| {
            let r = InstanceRecord {
                surface: i.surface,
                first_primitive: first,
                primitive_count: i.primitives.len() as u32,
                frame_first: i.frames.first,
                frame_last: i.frames.last,
                reserved: [0; 3],
            };
            first += i.primitives.len() as u32;
            r
        })
        .collect();
    let deltas = crate::archive::deltas::EncodedDeltas::from_blocks(anim.frames as usize, blocks, spilled)
        .map_err(|e| BuildError::Scratch(format!("cannot read back the spilled per-frame link changes: {e}")))?;
    let cameras = match scene.camera_keys.is_empty() {
        true => Vec::new(),
        false => (0..anim.frames).map(|f| camera_record(&scene.camera_at(f))).collect(),
    };
    let emissions = match scene.surfaces.iter().all(|s| s.emission_keys.is_empty()) {
        true => Vec::new(),
        false => (0..anim.frames).flat_map(|f| scene.surfaces.iter().map(move |s| s.emission_at(f))).collect(),
    };
    Ok(Some(SequenceContents {
        record: AnimationRecord {
            frames: anim.frames,
            fps: anim.fps,
            instance_count: instances.len() as u32,
            reserved: [0; 5],
        },
        instances: records,
        deltas,
        cameras,
        emissions,
    }))
}

fn camera_record(c: &crate::scene::Camera) -> CameraRecord {
    CameraRecord {
        position: c.position.to_array(),
        look_at: c.look_at.to_array(),
        up: c.up.to_array(),
        fov_y_deg: c.fov_y_deg,
        width: c.width,
        height: c.height,
    }
}
