//! The build's setup: the direction set, and the instances' primitives cut
//! into patches ([`Setup`]), small triangles of still, diffuse meshes
//! grouped into patches of several first. What it makes is what tracing
//! and the archive's sections are made from.

use super::BuildError;
use super::instances::Instance;
use super::settings::{BuildSettings, ray_space_divisions};
use crate::archive::presence::FrameSpan;
use crate::geodesic::{DirectionSet, DirectionSetKind};
use crate::geometry::Primitive;
use crate::patch::{CutSize, Patches};
use crate::scene::{ReflectanceModel, Scene};

/// The direction set `settings` asks for: the geodesic set of its
/// frequency, or the ray-space baseline with about as many directions.
pub(super) fn directions(settings: &BuildSettings) -> Result<DirectionSet, String> {
    match settings.direction_set {
        DirectionSetKind::Geodesic => DirectionSet::new(settings.frequency),
        DirectionSetKind::RaySpace => crate::geodesic::ray_space(ray_space_divisions(settings.frequency)),
    }
}

/// What the setup made: the directions, the primitives of every instance
/// as columns (in instance order, each instance's primitives in build
/// order), and their patches.
pub(super) struct Setup {
    /// The direction set.
    pub(super) dirs: DirectionSet,
    /// The instances, their primitives reordered group by group where
    /// small triangles were grouped.
    pub(super) instances: Vec<Instance>,
    /// All primitives: every instance's, in instance order.
    pub(super) prims: Vec<Primitive>,
    /// Per primitive, its instance's grain.
    pub(super) prim_grain: Vec<Option<glam::Vec3>>,
    /// Per primitive, its surface.
    pub(super) prim_surface: Vec<u32>,
    /// Per primitive, the frames it is present in.
    pub(super) active: Vec<FrameSpan>,
    /// Per primitive, `surface << 32 | index within the surface`: the
    /// build-independent tie-break of hits at equal distance, and the
    /// patches' identities.
    pub(super) sort_key: Vec<u64>,
    /// The patches cut from the primitives.
    pub(super) patches: Patches,
}

impl Setup {
    /// Cuts `instances` (of `scene`, checked) into patches as `settings`
    /// say, with `dirs` kept for the stages after; refused before cutting
    /// when `refuse_cut` (under a budget) refuses the primitives' count
    /// and what cutting them would make.
    pub(super) fn new(
        scene: &Scene,
        settings: &BuildSettings,
        dirs: DirectionSet,
        mut instances: Vec<Instance>,
        refuse_cut: Option<&dyn Fn(usize, CutSize) -> Result<(), BuildError>>,
    ) -> Result<Self, BuildError> {
        let triangle_group = group_mesh_triangles(scene, settings, &mut instances);
        // Columns of exactly the primitives' count: a mesh of 10⁶ triangles
        // must not hold twice its columns while they grow.
        let n_prims: usize = instances.iter().map(|i| i.primitives.len()).sum();
        let mut prims: Vec<Primitive> = Vec::with_capacity(n_prims);
        let mut prim_grain = Vec::with_capacity(n_prims);
        let mut prim_surface = Vec::with_capacity(n_prims);
        let mut active = Vec::with_capacity(n_prims);
        let mut sort_key = Vec::with_capacity(n_prims);
        for inst in &instances {
            for (i, p) in inst.primitives.iter().enumerate() {
                prims.push(*p);
                prim_grain.push(inst.grain);
                prim_surface.push(inst.surface);
                active.push(inst.frames);
                sort_key.push(((inst.surface as u64) << 32) | i as u64);
            }
        }
        // Adjacency may cross primitive edges only within one instance: two
        // instances of a surface are never present in the same frame.
        let prim_instance: Vec<u32> = instances
            .iter()
            .enumerate()
            .flat_map(|(i, inst)| std::iter::repeat_n(i as u32, inst.primitives.len()))
            .collect();
        // Under a budget, a cut it cannot hold is refused before it is made.
        if let Some(refuse) = refuse_cut {
            let (size, order) = (settings.patch_size, settings.cell_order);
            refuse(prims.len(), crate::patch::cut_size(&prims, &prim_instance, &triangle_group, size, order)?)?;
        }
        let patches = cut_patches(scene, settings, &prims, &prim_instance, &triangle_group)?;
        Ok(Self { dirs, instances, prims, prim_grain, prim_surface, active, sort_key, patches })
    }
}

/// Small triangles of still, diffuse surfaces become patches of several
/// (patch::mesh), their instance's primitives (and shading) reordered
/// group by group. Returns every primitive's group, in the new order
/// ([`crate::patch::mesh::UNGROUPED`] for the others).
fn group_mesh_triangles(scene: &Scene, settings: &BuildSettings, instances: &mut [Instance]) -> Vec<u32> {
    let mut triangle_group = Vec::with_capacity(instances.iter().map(|i| i.primitives.len()).sum());
    for inst in instances {
        let surface = &scene.surfaces[inst.surface as usize];
        let diffuse = matches!(scene.materials[surface.material as usize].model, ReflectanceModel::Diffuse { .. });
        if settings.group_triangles && surface.motion.is_none() && !surface.moved && diffuse {
            let g = crate::patch::mesh::group_triangles(&inst.primitives, settings.patch_size);
            inst.primitives = g.order.iter().map(|&i| inst.primitives[i as usize]).collect();
            if inst.shading.len() == g.order.len() {
                inst.shading = g.order.iter().map(|&i| inst.shading[i as usize]).collect();
            }
            triangle_group.extend_from_slice(&g.group);
        } else {
            triangle_group.extend(std::iter::repeat_n(crate::patch::mesh::UNGROUPED, inst.primitives.len()));
        }
    }
    triangle_group
}

/// The patches of `prims` (adjacency within each `prim_instance`, small
/// triangles grouped as `triangle_group` says), numbered along a Morton
/// curve for still scenes; refused when a patch is larger than an archive
/// holds.
fn cut_patches(
    scene: &Scene,
    settings: &BuildSettings,
    prims: &[Primitive],
    prim_instance: &[u32],
    triangle_group: &[u32],
) -> Result<Patches, BuildError> {
    let mut patches =
        Patches::with_groups(prims, prim_instance, triangle_group, settings.patch_size, settings.cell_order)?;
    // A spatial patch order for still scenes. Sequences keep primitive
    // order (an instance's patches stay together, and frames are compared
    // by patch id), and so do the stills compared with them: a frame of a
    // sequence (moved surfaces), or one built on a sequence's ray grid.
    let still = scene.animation.is_none()
        && settings.grid_bounds.is_none()
        && scene.surfaces.iter().all(|s| s.motion.is_none() && !s.moved);
    if settings.patch_order == crate::patch::order::PatchOrder::Spatial && still {
        patches.renumber(&crate::patch::order::spatial_order(prims, &patches));
    }
    if let Some(p) = patches.area.iter().position(|&a| a > crate::limits::MAX_PATCH_AREA) {
        return Err(format!(
            "patch {p} has an area of {:e} m², above the {:e} an archive holds: use a smaller --patch-size",
            patches.area[p],
            crate::limits::MAX_PATCH_AREA
        )
        .into());
    }
    Ok(patches)
}
