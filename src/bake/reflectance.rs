//! The build's share of general reflectance (§3.6): which patches are not
//! diffuse, their orientations and actual-to-prototype maps, and the
//! prototype tables of their materials (from the prototype library when it
//! holds them), assembled into the archive's reflectance sections.

use std::collections::HashMap;

use glam::Vec3;
use rayon::prelude::*;

use super::settings::BuildSettings;
use super::setup::Setup;
use crate::archive::ReflectanceContents;
use crate::archive::layout::{NonDiffusePatchRecord, OrientationRecord, PrototypeRecord, table_model};
use crate::geodesic::DirectionSet;
use crate::geometry::Primitive;
use crate::patch::Patches;
use crate::progress::Progress;
use crate::reflectance::library::Library;
use crate::reflectance::{Frame, Lobe, MapMethod, OrientationMap, PrototypeTable, TableModel, prototype};
use crate::scene::Scene;

/// Per primitive: the non-diffuse material's lobe, or `None`.
pub fn primitive_lobes(scene: &Scene, prim_surface: &[u32]) -> Vec<Option<Lobe>> {
    prim_surface
        .iter()
        .map(|&s| scene.materials[scene.surfaces[s as usize].material as usize].model.lobe().map(|(_, l)| l))
        .collect()
}

/// Per patch, its index among the non-diffuse patches (`u32::MAX`: diffuse).
pub fn nondiffuse_index(patches: &Patches, lobes: &[Option<Lobe>]) -> Vec<u32> {
    let mut next = 0u32;
    patches
        .primitive
        .iter()
        .map(|&p| match lobes[p as usize] {
            Some(_) => {
                next += 1;
                next - 1
            }
            None => u32::MAX,
        })
        .collect()
}

/// What tabulating took.
#[derive(Debug, Clone, Default)]
pub struct ReflectanceStats {
    /// Tables used.
    pub tables: usize,
    /// Tables read from the library instead of built.
    pub tables_cached: usize,
    /// Seconds spent on tables (building or reading).
    pub table_s: f64,
    /// Distinct orientations (one map each).
    pub orientations: usize,
    /// Seconds spent on maps.
    pub map_s: f64,
    /// Problems with the library that did not stop the build.
    pub warnings: Vec<String>,
}

/// Everything needed to assemble the reflectance sections.
pub struct Input<'a> {
    /// The direction set.
    pub dirs: &'a DirectionSet,
    /// All primitives.
    pub prims: &'a [Primitive],
    /// Per primitive, its grain (the instance's, or `None`: its first edge).
    pub grain: &'a [Option<Vec3>],
    /// Per primitive, its lobe when non-diffuse.
    pub lobes: &'a [Option<Lobe>],
    /// The patches.
    pub patches: &'a Patches,
    /// Per non-diffuse patch and pair, rays crossing it (from tracing).
    pub nd_hits: Vec<u32>,
    /// Of those, rays whose light meets a back face.
    pub nd_backs: Vec<u32>,
    /// Library to read and store tables in.
    pub library: Option<&'a Library>,
    /// How maps are made.
    pub map_method: MapMethod,
    /// Table threshold.
    pub threshold: f64,
}

/// The reflectance sections of the patches of `setup` (`lobes` per
/// primitive, `nd_hits` and `nd_backs` from tracing) with the tables of
/// the prototype library `settings` name, if any: [`assemble`]'s.
pub(super) fn sections(
    settings: &BuildSettings,
    setup: &Setup,
    lobes: &[Option<Lobe>],
    nd_hits: Vec<u32>,
    nd_backs: Vec<u32>,
    progress: &dyn Progress,
) -> Result<(Option<ReflectanceContents>, ReflectanceStats), String> {
    let library = settings.prototype_library.as_ref().map(Library::new);
    assemble(
        Input {
            dirs: &setup.dirs,
            prims: &setup.prims,
            grain: &setup.prim_grain,
            lobes,
            patches: &setup.patches,
            nd_hits,
            nd_backs,
            library: library.as_ref(),
            map_method: settings.map_method,
            threshold: settings.table_threshold,
        },
        progress,
    )
}

/// Assembles the reflectance sections; `None` when every patch is diffuse.
pub fn assemble(
    input: Input<'_>,
    progress: &dyn Progress,
) -> Result<(Option<ReflectanceContents>, ReflectanceStats), String> {
    let mut stats = ReflectanceStats::default();
    if input.lobes.iter().all(Option::is_none) {
        return Ok((None, stats));
    }
    let n = input.dirs.len();
    let (lobes, lobe_index) = distinct_lobes(input.lobes);
    let (frames, orientation) = distinct_orientations(&input);
    let tables = prototype_tables(&input, &lobes, &mut stats, progress);
    let maps = orientation_maps(&input, &frames, &mut stats, progress);

    let mut out = ReflectanceContents::default();
    for (l, t) in lobes.iter().zip(&tables) {
        if t.offsets.len() != n + 1 {
            return Err("prototype table does not match the direction set".into());
        }
        out.prototypes.push(PrototypeRecord {
            model: table_model::GGX,
            bands: t.bands as u32,
            alpha_u: l.alpha_u,
            alpha_v: l.alpha_v,
            ior: l.ior.unwrap_or([0.0; 3]),
            threshold: input.threshold as f32,
            first_row: out.rows.len() as u64,
            first_entry: out.outgoing.len() as u64,
            entry_count: t.outgoing.len() as u64,
            first_factor: out.factors.len() as u64,
        });
        out.rows.extend_from_slice(&t.offsets);
        out.outgoing.extend_from_slice(&t.outgoing);
        out.factors.extend_from_slice(&t.factors);
    }
    for (f, m) in frames.iter().zip(&maps) {
        let s = m.stats(&input.dirs.directions, f);
        let v = |x: [f64; 3]| x.map(|c| c as f32);
        out.orientations.push(OrientationRecord {
            normal: v(f.n),
            grain: v(f.t),
            error_mean_rad: s.mean_rad as f32,
            error_max_rad: s.max_rad as f32,
        });
        out.maps.extend_from_slice(&m.to_prototype);
    }
    for (q, &prim) in input.patches.primitive.iter().enumerate() {
        let prim = prim as usize;
        if input.lobes[prim].is_some() {
            out.patches.push(NonDiffusePatchRecord {
                patch: q as u32,
                prototype: lobe_index[prim],
                orientation: orientation[prim],
                reserved: 0,
            });
        }
    }
    out.hits = input.nd_hits;
    out.back_hits = input.nd_backs;
    Ok((Some(out), stats))
}

/// The distinct lobes of `lobes` (per primitive), in primitive order
/// (deterministic), and per primitive its lobe's index among them
/// (`u32::MAX`: diffuse).
fn distinct_lobes(lobes: &[Option<Lobe>]) -> (Vec<Lobe>, Vec<u32>) {
    let mut distinct: Vec<Lobe> = Vec::new();
    let lobe_index: Vec<u32> = lobes
        .iter()
        .map(|l| match l {
            None => u32::MAX,
            Some(l) => match distinct.iter().position(|x| x == l) {
                Some(i) => i as u32,
                None => {
                    distinct.push(*l);
                    distinct.len() as u32 - 1
                }
            },
        })
        .collect();
    (distinct, lobe_index)
}

/// The distinct orientations of the non-diffuse primitives, in primitive
/// order, and per primitive its orientation's index among them
/// (`u32::MAX`: diffuse).
fn distinct_orientations(input: &Input<'_>) -> (Vec<Frame>, Vec<u32>) {
    let mut frames: Vec<Frame> = Vec::new();
    let mut keys: HashMap<[i64; 6], u32> = HashMap::new();
    let orientation: Vec<u32> = input
        .prims
        .iter()
        .zip(input.lobes)
        .zip(input.grain)
        .map(|((p, l), g)| {
            let Some(l) = l else {
                return u32::MAX;
            };
            // An isotropic lobe does not care about the grain: take the one
            // closest to the prototype's (+x), so that surfaces facing +y get
            // the identity map and others the least rotation.
            let grain = match l.alpha_u == l.alpha_v {
                true => Vec3::X,
                false => g.unwrap_or(p.p[1] - p.p[0]),
            };
            let f = Frame::new(p.normal().to_array(), grain.to_array());
            let q = |x: f64| (x * 1e5).round() as i64;
            let key = [q(f.n[0]), q(f.n[1]), q(f.n[2]), q(f.t[0]), q(f.t[1]), q(f.t[2])];
            *keys.entry(key).or_insert_with(|| {
                frames.push(f);
                frames.len() as u32 - 1
            })
        })
        .collect();
    (frames, orientation)
}

/// The prototype table of each of `lobes`, read from the library when it
/// holds it, else built (and stored there); counted in `stats`.
fn prototype_tables(
    input: &Input<'_>,
    lobes: &[Lobe],
    stats: &mut ReflectanceStats,
    progress: &dyn Progress,
) -> Vec<PrototypeTable> {
    let t0 = std::time::Instant::now();
    progress.start("prototype reflectance tables", lobes.len() as u64);
    let mut tables = Vec::with_capacity(lobes.len());
    for l in lobes {
        let model = TableModel::Ggx(*l);
        let (dirs, omega) = (&input.dirs.directions, &input.dirs.solid_angle);
        let table = match input.library {
            Some(lib) => {
                let found = lib.get_or_build(model, dirs, omega, input.threshold);
                stats.tables_cached += found.built.is_none() as usize;
                stats.warnings.extend(found.warning);
                found.table
            }
            None => prototype::build(model, dirs, omega, input.threshold).0,
        };
        tables.push(table);
        progress.advance(1);
    }
    progress.finish();
    stats.tables = tables.len();
    stats.table_s = t0.elapsed().as_secs_f64();
    tables
}

/// The actual-to-prototype map of each of `frames`, made in parallel;
/// counted in `stats`.
fn orientation_maps(
    input: &Input<'_>,
    frames: &[Frame],
    stats: &mut ReflectanceStats,
    progress: &dyn Progress,
) -> Vec<OrientationMap> {
    let t1 = std::time::Instant::now();
    progress.start("actual-to-prototype maps", frames.len() as u64);
    let maps: Vec<OrientationMap> = frames
        .par_iter()
        .map(|f| {
            let m = OrientationMap::new(&input.dirs.directions, &input.dirs.neighbours, f, input.map_method);
            progress.advance(1);
            m
        })
        .collect();
    progress.finish();
    stats.orientations = frames.len();
    stats.map_s = t1.elapsed().as_secs_f64();
    maps
}
