//! Temporal instances (§2): a still surface is one instance present in
//! every frame; a moving surface is one instance per run of frames with the
//! same transform, its primitives placed for those frames. Builds trace
//! every instance once, so a sequence costs its moving surfaces' runs, not
//! its frames.

use crate::archive::presence::FrameSpan;
use crate::geometry::Primitive;
use crate::scene::Scene;
use crate::scene::texture::Shading;

use super::BuildError;

/// A primitive set present over a range of frames: a permanent surface
/// (all frames) or one temporal instance of a moving surface (§2).
#[derive(Debug, Clone, PartialEq)]
pub struct Instance {
    /// Surface index.
    pub surface: u32,
    /// The frames it is present in.
    pub frames: FrameSpan,
    /// The surface's primitives placed for those frames.
    pub primitives: Vec<Primitive>,
    /// The surface's grain placed for those frames.
    pub grain: Option<glam::Vec3>,
    /// The surface's shading detail placed with the primitives (empty for
    /// none).
    pub shading: Vec<Shading>,
}

/// The instances of `scene`: each still surface once; each moving surface
/// once per run of consecutive frames with bitwise the same transform.
pub fn instances(scene: &Scene) -> Vec<Instance> {
    let last = scene.frame_count() - 1;
    let mut out = Vec::new();
    for (s, surf) in scene.surfaces.iter().enumerate() {
        match &surf.motion {
            None => out.push(Instance {
                surface: s as u32,
                frames: FrameSpan { first: 0, last },
                primitives: surf.primitives.clone(),
                grain: surf.grain,
                shading: surf.shading.clone(),
            }),
            Some(m) => {
                let mut f0 = 0;
                for f in 1..=last + 1 {
                    if f == last + 1 || !m.same_transform(f0, f) {
                        let primitives = m.apply(f0, &surf.primitives);
                        out.push(Instance {
                            surface: s as u32,
                            frames: FrameSpan { first: f0, last: f - 1 },
                            shading: m.apply_shading(f0, &surf.primitives, &primitives, &surf.shading),
                            primitives,
                            grain: surf.grain.map(|g| m.apply_direction(f0, g)),
                        });
                        f0 = f;
                    }
                }
            }
        }
    }
    out
}

/// Checks the instances' placed primitives: motion is applied after
/// parsing checked the base geometry, so a keyframe can still make a
/// primitive degenerate or move it beyond what an archive holds.
pub(super) fn check_placed(scene: &Scene, instances: &[Instance]) -> Result<(), BuildError> {
    for inst in instances {
        for p in &inst.primitives {
            if !(p.p.iter().all(|v| v.is_finite()) && p.area() > 0.0) {
                return Err(BuildError::Failed(format!(
                    "surface `{}` at frames {}..={}: keyframed motion makes a primitive degenerate or infinite (a scale through 0?)",
                    scene.surfaces[inst.surface as usize].name, inst.frames.first, inst.frames.last
                )));
            }
            if !p.p.iter().all(|v| v.abs().max_element() <= crate::limits::MAX_COORDINATE) {
                return Err(BuildError::Failed(format!(
                    "surface `{}` at frames {}..={}: keyframed motion moves a corner beyond ±{:e} m, the most an \
                     archive holds",
                    scene.surfaces[inst.surface as usize].name,
                    inst.frames.first,
                    inst.frames.last,
                    crate::limits::MAX_COORDINATE
                )));
            }
        }
    }
    Ok(())
}
