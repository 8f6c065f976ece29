//! `KHR_lights_punctual` lamps as small area emitters of the same power:
//! the I-net carries light between surfaces, so a lamp must be one.
//!
//! * Intensity is in candela (lm/sr); it becomes radiant intensity
//!   `I = colour × intensity / 683` W/sr (683 lm/W, the photometric constant).
//! * A **point** light becomes an icosahedron of circumradius `r` emitting
//!   `L = 4·I / A` from its outward faces (`A` its area): a convex emitter's
//!   mean projected area is `A/4`, so it sends `I` on average in every
//!   direction and `4π·I` in all.
//! * A **spot** light becomes a square of the disc's area `π r²` facing the
//!   light's −Z axis, emitting the cone's power: `2π(1 − cos θ)·I` with `θ`
//!   the mean of the inner and outer cone angles (the light is full inside
//!   the inner cone and fades to nothing at the outer), so
//!   `L = 2(1 − cos θ)·I / A`. Its falloff is Lambertian, not the cone's
//!   (said in the notes): the energy balance is right, the spot's shape is
//!   not.
//! * Directional lights have no place in a closed energy balance; they are
//!   said and left out.

use std::path::Path;

use glam::{Mat4, Vec3};
use gltf::khr_lights_punctual::Kind;

use crate::geometry::Primitive;
use crate::scene::SceneError;
use crate::scene::error::error;
use crate::scene::import::Notes;

/// Lumens per watt at 555 nm: candela → W/sr.
pub const LUMENS_PER_WATT: f32 = 683.0;

/// A lamp's stand-in: its primitives and their emitted radiance.
pub(super) type Emitter = (Vec<Primitive>, [f32; 3]);

/// The emitter standing in for `lamp` placed by `world`, or `None` for a
/// light that cannot be one.
pub(super) fn emitter(
    path: &Path,
    at: &str,
    lamp: &gltf::khr_lights_punctual::Light<'_>,
    radius: f32,
    world: Mat4,
    notes: &mut Notes,
) -> Result<Option<Emitter>, SceneError> {
    let name = lamp.name().map_or_else(|| format!("light {}", lamp.index()), |n| format!("light `{n}`"));
    let intensity = lamp.intensity();
    if !(intensity.is_finite() && intensity >= 0.0) {
        return Err(error(path, format!("{at}/intensity"), "must be a finite number ≥ 0"));
    }
    let colour = lamp.color();
    if !colour.iter().all(|c| c.is_finite() && *c >= 0.0) {
        return Err(error(path, format!("{at}/color"), "each component must be finite and ≥ 0"));
    }
    if !(radius.is_finite() && radius > 0.0) {
        return Err(error(path, at, format!("the lamp radius {radius} m must be positive")));
    }
    if lamp.range().is_some() {
        notes.add(format!("{name}: its range is ignored (light falls off with distance alone)"));
    }
    let centre = world.transform_point3(Vec3::ZERO);
    let i = colour.map(|c| c * intensity / LUMENS_PER_WATT);
    let (primitives, area, per_area) = match lamp.kind() {
        Kind::Directional => {
            notes.add(format!("{name}: directional lights are not supported and were left out"));
            return Ok(None);
        }
        Kind::Point => {
            let prims = icosahedron(centre, radius);
            let area: f32 = prims.iter().map(Primitive::area).sum();
            (prims, area, 4.0)
        }
        Kind::Spot { inner_cone_angle, outer_cone_angle } => {
            notes.add(format!(
                "{name}: a spot light's cone (outer angle {:.1}°) is approximated by a Lambertian square facing its \
                 axis, of the cone's power",
                outer_cone_angle.to_degrees()
            ));
            let theta = ((inner_cone_angle + outer_cone_angle) / 2.0).clamp(0.0, std::f32::consts::FRAC_PI_2);
            let axis = world.transform_vector3(Vec3::NEG_Z).normalize_or_zero();
            if axis == Vec3::ZERO {
                return Err(error(path, at, "the spot light's node has a degenerate transform"));
            }
            let side = radius * std::f32::consts::PI.sqrt();
            let q = square(centre, axis, side);
            let area = q.area();
            (vec![q], area, 2.0 * (1.0 - theta.cos()))
        }
    };
    let within = centre.is_finite() && centre.abs().max_element() <= crate::limits::MAX_COORDINATE;
    if !within || area.is_nan() || area <= 0.0 {
        return Err(error(path, at, "the lamp's node places it beyond ±1e9 m"));
    }
    let radiance = i.map(|x| per_area * x / area);
    if radiance.iter().any(|&l| l > crate::limits::MAX_RADIANCE) {
        notes.add(format!("{name}: its radiance is above 1e9 W·sr⁻¹·m⁻² and was clamped there"));
    }
    let radiance = radiance.map(|l| l.min(crate::limits::MAX_RADIANCE));
    Ok(Some((primitives, radiance)))
}

/// The 20 outward faces of an icosahedron of circumradius `r` about `c`.
fn icosahedron(c: Vec3, r: f32) -> Vec<Primitive> {
    let phi = (1.0 + 5f32.sqrt()) / 2.0;
    let mut v = Vec::with_capacity(12);
    for a in [-1.0f32, 1.0] {
        for b in [-phi, phi] {
            v.push(Vec3::new(0.0, a, b));
            v.push(Vec3::new(a, b, 0.0));
            v.push(Vec3::new(b, 0.0, a));
        }
    }
    let edge = |a: Vec3, b: Vec3| ((a - b).length() - 2.0).abs() < 1e-4;
    let mut faces = Vec::with_capacity(20);
    for i in 0..12 {
        for j in i + 1..12 {
            for k in j + 1..12 {
                if edge(v[i], v[j]) && edge(v[j], v[k]) && edge(v[i], v[k]) {
                    let (a, b, d) = (v[i], v[j], v[k]);
                    let (b, d) = if (b - a).cross(d - a).dot(a + b + d) > 0.0 { (b, d) } else { (d, b) };
                    let s = r / v[0].length();
                    faces.push(Primitive::triangle(c + a * s, c + b * s, c + d * s));
                }
            }
        }
    }
    faces
}

/// A square of side `side` centred on `c`, facing `n`.
fn square(c: Vec3, n: Vec3, side: f32) -> Primitive {
    let (t, b) = n.any_orthonormal_pair();
    let h = side / 2.0;
    // t × b = n: counter-clockwise seen from the front.
    Primitive::quad([c - t * h - b * h, c + t * h - b * h, c + t * h + b * h, c - t * h + b * h])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn icosahedron_faces_outwards_with_its_area() {
        let c = Vec3::new(1.0, 2.0, 3.0);
        let f = icosahedron(c, 0.5);
        assert_eq!(f.len(), 20);
        for p in &f {
            let mid = (p.p[0] + p.p[1] + p.p[2]) / 3.0;
            assert!(p.normal().dot(mid - c) > 0.0);
            assert!(p.p[..3].iter().all(|v| ((*v - c).length() - 0.5).abs() < 1e-5));
        }
        // Area of a regular icosahedron of circumradius R: 20·(√3/4)·a², a = R / sin(2π/5).
        let a = 0.5 / (2.0 * std::f32::consts::PI / 5.0).sin();
        let want = 5.0 * 3f32.sqrt() * a * a;
        let got: f32 = f.iter().map(Primitive::area).sum();
        assert!((got - want).abs() < 1e-4 * want, "{got} vs {want}");
    }

    #[test]
    fn square_faces_its_axis() {
        let n = Vec3::new(0.0, -1.0, 0.0);
        let q = square(Vec3::ZERO, n, 2.0);
        assert!((q.normal() - n).length() < 1e-6);
        assert!((q.area() - 4.0).abs() < 1e-5);
    }
}
