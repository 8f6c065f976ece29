//! The pinhole camera: image right is `forward × up`, rows run top to bottom.

use glam::Vec3;

use crate::archive::layout::CameraRecord;

/// A pinhole camera ready to generate primary rays.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PinholeCamera {
    origin: Vec3,
    forward: Vec3,
    right: Vec3,
    up: Vec3,
    tan_half_fov: f32,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
}

impl PinholeCamera {
    /// The camera stored in an archive.
    pub fn from_record(c: &CameraRecord) -> Self {
        let origin = Vec3::from(c.position);
        let forward = (Vec3::from(c.look_at) - origin).normalize();
        let right = forward.cross(Vec3::from(c.up)).normalize();
        let up = right.cross(forward);
        Self {
            origin,
            forward,
            right,
            up,
            tan_half_fov: (c.fov_y_deg.to_radians() * 0.5).tan(),
            width: c.width,
            height: c.height,
        }
    }

    /// The image point `(x, y)` (pixel units) a world point projects to, or
    /// `None` when it is not in front of the camera.
    pub fn project(&self, p: Vec3) -> Option<(f32, f32)> {
        let d = p - self.origin;
        let z = d.dot(self.forward);
        if z <= 1e-6 {
            return None;
        }
        let aspect = self.width as f32 / self.height as f32;
        let sx = d.dot(self.right) / (z * aspect * self.tan_half_fov);
        let sy = d.dot(self.up) / (z * self.tan_half_fov);
        Some(((sx + 1.0) * 0.5 * self.width as f32, (1.0 - sy) * 0.5 * self.height as f32))
    }

    /// Ray through image point `(x, y)` in pixel units (`(0, 0)` is the top
    /// left corner of the image): origin and unit direction.
    pub fn ray(&self, x: f32, y: f32) -> (Vec3, Vec3) {
        let aspect = self.width as f32 / self.height as f32;
        let sx = (2.0 * x / self.width as f32 - 1.0) * aspect * self.tan_half_fov;
        let sy = (1.0 - 2.0 * y / self.height as f32) * self.tan_half_fov;
        (self.origin, (self.forward + sx * self.right + sy * self.up).normalize())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn projection_inverts_rays() {
        let c = PinholeCamera::from_record(&CameraRecord {
            position: [0.3, 1.0, -2.0],
            look_at: [0.5, 0.8, 1.0],
            up: [0.0, 1.0, 0.0],
            fov_y_deg: 50.0,
            width: 64,
            height: 48,
        });
        for (x, y) in [(0.5, 0.5), (10.25, 40.0), (63.0, 1.0)] {
            let (o, d) = c.ray(x, y);
            let (px, py) = c.project(o + 3.7 * d).unwrap();
            assert!((px - x).abs() < 1e-3 && (py - y).abs() < 1e-3, "({x}, {y}) -> ({px}, {py})");
        }
        assert!(c.project(Vec3::new(0.3, 1.0, -3.0)).is_none(), "behind the camera");
    }
}
