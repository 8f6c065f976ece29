//! Keyframed rigid motion of surfaces (issue #5, paper §2).
//!
//! A moving surface's geometry at frame `f` is its base geometry (after its
//! static `transform`) moved by the keyframed transform at `f`:
//! `p' = pivot + translate + R·(scale ⊙ (p − pivot))`, with `R` from
//! `rotate_deg = [rx, ry, rz]` as `Rz·Ry·Rx`. Between keyframes translation
//! and scale interpolate linearly and rotation spherically (slerp of the
//! keyframes' quaternions), or hold the earlier keyframe; before the first
//! and after the last keyframe the nearest one holds.

use glam::{Mat3, Quat, Vec3};

use super::texture::Shading;
use crate::geometry::{Primitive, PrimitiveKind};

/// How values between keyframes are found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Interpolation {
    /// Linear translation and scale, spherical-linear rotation.
    Linear,
    /// The earlier keyframe's value until the next keyframe.
    Hold,
}

/// One keyframe.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Keyframe {
    /// Frame number (0-based).
    pub frame: u32,
    /// Translation (m).
    pub translate: Vec3,
    /// Rotation as `Rz·Ry·Rx` (quaternion).
    pub rotation: Quat,
    /// Per-axis scale.
    pub scale: Vec3,
}

/// A surface's motion: keyframes in strictly increasing frame order.
#[derive(Debug, Clone, PartialEq)]
pub struct Motion {
    /// Point rotation and scale are about.
    pub pivot: Vec3,
    /// Between-keyframe rule.
    pub interpolation: Interpolation,
    /// At least one keyframe, frames strictly increasing.
    pub keyframes: Vec<Keyframe>,
}

/// Sequence length and rate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Animation {
    /// Number of frames (≥ 1).
    pub frames: u32,
    /// Frames per second (> 0).
    pub fps: f32,
}

/// Quaternion of the rotation `Rz·Ry·Rx` by the given angles in degrees.
pub fn rotation_from_degrees(r: Vec3) -> Quat {
    Quat::from_rotation_z(r.z.to_radians())
        * Quat::from_rotation_y(r.y.to_radians())
        * Quat::from_rotation_x(r.x.to_radians())
}

impl Motion {
    /// The transform at `frame`: (rotation, scale, translation).
    pub fn at(&self, frame: u32) -> (Quat, Vec3, Vec3) {
        let k = &self.keyframes;
        let i = k.partition_point(|kf| kf.frame <= frame);
        let pick = |kf: &Keyframe| (kf.rotation, kf.scale, kf.translate);
        if i == 0 {
            return pick(&k[0]);
        }
        let a = &k[i - 1];
        if i == k.len() || a.frame == frame || self.interpolation == Interpolation::Hold {
            return pick(a);
        }
        let b = &k[i];
        let t = (frame - a.frame) as f32 / (b.frame - a.frame) as f32;
        (a.rotation.slerp(b.rotation, t), a.scale.lerp(b.scale, t), a.translate.lerp(b.translate, t))
    }

    /// `primitives` moved to `frame`. Mirroring scales keep fronts outward.
    pub fn apply(&self, frame: u32, primitives: &[Primitive]) -> Vec<Primitive> {
        let (r, s, t) = self.at(frame);
        let mirrored = s.x * s.y * s.z < 0.0;
        primitives
            .iter()
            .map(|p| {
                let q = p.p.map(|v| self.pivot + t + r * (s * (v - self.pivot)));
                match (p.kind, mirrored) {
                    (PrimitiveKind::Quad, false) => Primitive::quad(q),
                    (PrimitiveKind::Quad, true) => Primitive::quad([q[3], q[2], q[1], q[0]]),
                    (PrimitiveKind::Triangle, false) => Primitive::triangle(q[0], q[1], q[2]),
                    (PrimitiveKind::Triangle, true) => Primitive::triangle(q[0], q[2], q[1]),
                }
            })
            .collect()
    }

    /// The shading detail of `primitives` (`moved`: them placed by
    /// [`Self::apply`] at `frame`) moved with them: corners in the order
    /// `apply` gives them, normals by the transform's inverse transpose
    /// and expressed in each moved primitive's own frame. Empty for none.
    pub fn apply_shading(
        &self,
        frame: u32,
        primitives: &[Primitive],
        moved: &[Primitive],
        shading: &[Shading],
    ) -> Vec<Shading> {
        if shading.len() != primitives.len() {
            return Vec::new();
        }
        let (r, s, _) = self.at(frame);
        let normal_map = (Mat3::from_quat(r) * Mat3::from_diagonal(s)).inverse().transpose();
        let mirrored = s.x * s.y * s.z < 0.0;
        primitives
            .iter()
            .zip(moved)
            .zip(shading)
            .map(|((p, q), sh)| {
                let [x, y, z] = p.own_frame();
                let world = sh.normal.map(|n| match n == Vec3::ZERO {
                    true => n,
                    // A zero scale has no inverse: the face normal then.
                    false => (normal_map * (x * n.x + y * n.y + z * n.z)).normalize_or_zero(),
                });
                let order = |c: [Vec3; 4]| match (p.kind, mirrored) {
                    (PrimitiveKind::Quad, true) => [c[3], c[2], c[1], c[0]],
                    (PrimitiveKind::Triangle, true) => [c[0], c[2], c[1], c[1]],
                    _ => c,
                };
                let uv = order(sh.uv.map(|u| u.extend(0.0))).map(|u| u.truncate());
                Shading { uv, normal: Shading::to_local(q, order(world)), ..*sh }
            })
            .collect()
    }

    /// A direction (the grain) moved to `frame`: rotated and scaled, renormalised.
    pub fn apply_direction(&self, frame: u32, d: Vec3) -> Vec3 {
        let (r, s, _) = self.at(frame);
        (r * (s * d)).normalize_or(d)
    }

    /// Whether frames `a` and `b` give bitwise the same transform (so one
    /// temporal instance can serve both).
    pub fn same_transform(&self, a: u32, b: u32) -> bool {
        let (ra, sa, ta) = self.at(a);
        let (rb, sb, tb) = self.at(b);
        ra.to_array() == rb.to_array() && sa.to_array() == sb.to_array() && ta.to_array() == tb.to_array()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolates_and_holds() {
        let kf = |frame, x: f32, ry: f32| Keyframe {
            frame,
            translate: Vec3::new(x, 0.0, 0.0),
            rotation: rotation_from_degrees(Vec3::new(0.0, ry, 0.0)),
            scale: Vec3::ONE,
        };
        let mut m = Motion {
            pivot: Vec3::ZERO,
            interpolation: Interpolation::Linear,
            keyframes: vec![kf(2, 0.0, 0.0), kf(6, 4.0, 90.0)],
        };
        assert_eq!(m.at(0).2.x, 0.0, "holds before the first keyframe");
        assert!((m.at(4).2.x - 2.0).abs() < 1e-6);
        let half = m.at(4).0 * Vec3::X;
        assert!((half - Vec3::new(45f32.to_radians().cos(), 0.0, -45f32.to_radians().sin())).length() < 1e-5, "{half}");
        assert_eq!(m.at(9).2.x, 4.0, "holds after the last keyframe");
        assert!(m.same_transform(0, 2) && !m.same_transform(2, 3));
        m.interpolation = Interpolation::Hold;
        assert_eq!(m.at(5).2.x, 0.0);
    }

    #[test]
    fn shading_follows_a_mirroring_stretching_motion() {
        // uv = the base corner's (x, z); normals leaning 30° along +x.
        let base = [
            Primitive::quad([Vec3::ZERO, Vec3::X, Vec3::new(1.0, 0.0, -1.0), Vec3::NEG_Z]),
            Primitive::triangle(Vec3::ZERO, Vec3::X, Vec3::NEG_Z),
        ];
        let lean = Vec3::new(0.5, 0.75f32.sqrt(), 0.0);
        let shading: Vec<Shading> = base
            .iter()
            .map(|p| Shading {
                uv: p.p.map(|c| glam::Vec2::new(c.x, c.z)),
                normal: Shading::to_local(p, [lean; 4]),
                ..Shading::FLAT
            })
            .collect();
        let r = rotation_from_degrees(Vec3::new(0.0, 40.0, 0.0));
        let scale = Vec3::new(-2.0, 1.0, 0.5);
        let m = Motion {
            pivot: Vec3::ZERO,
            interpolation: Interpolation::Linear,
            keyframes: vec![Keyframe { frame: 0, translate: Vec3::Y, rotation: r, scale }],
        };
        let moved = m.apply(0, &base);
        let placed = m.apply_shading(0, &base, &moved, &shading);
        let linear = Mat3::from_quat(r) * Mat3::from_diagonal(scale);
        let want_normal = (linear.inverse().transpose() * lean).normalize();
        for (q, sh) in moved.iter().zip(&placed) {
            let [x, y, z] = q.own_frame();
            for k in 0..q.corner_count() {
                // Corner k came from the base corner whose (x, z) is its uv.
                let from = linear.inverse() * (q.p[k] - Vec3::Y);
                let uv = glam::Vec2::new(from.x, from.z);
                assert!((uv - sh.uv[k]).length() < 1e-5, "corner {k}: {uv} vs {}", sh.uv[k]);
                let n = sh.normal[k];
                assert!(((x * n.x + y * n.y + z * n.z) - want_normal).length() < 1e-5, "corner {k}");
            }
        }
    }
}

/// A camera keyframe: where the eye is and what it looks at.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraKey {
    /// Frame number.
    pub frame: u32,
    /// Eye position (m).
    pub position: Vec3,
    /// Point looked at (m).
    pub look_at: Vec3,
    /// Up vector (the camera's own for TOML keys; a glTF camera node's as
    /// it turns).
    pub up: Vec3,
}

/// An emission keyframe of a surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EmissionKey {
    /// Frame number.
    pub frame: u32,
    /// Emitted radiance (W·sr⁻¹·m⁻², RGB).
    pub emission: Vec3,
}

/// Linear interpolation over keys sorted by frame, holding outside them.
pub fn interpolate<T: Copy>(
    keys: &[T],
    frame: u32,
    frame_of: impl Fn(&T) -> u32,
    lerp: impl Fn(T, T, f32) -> T,
) -> Option<T> {
    let i = keys.partition_point(|k| frame_of(k) <= frame);
    match (i, keys.len()) {
        (_, 0) => None,
        (0, _) => Some(keys[0]),
        (i, n) if i == n => Some(keys[n - 1]),
        (i, _) => {
            let (a, b) = (keys[i - 1], keys[i]);
            let t = (frame - frame_of(&a)) as f32 / (frame_of(&b) - frame_of(&a)) as f32;
            Some(lerp(a, b, t))
        }
    }
}
