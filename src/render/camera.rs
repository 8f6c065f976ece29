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

    /// Ray through image point `(x, y)` in pixel units (`(0, 0)` is the top
    /// left corner of the image): origin and unit direction.
    pub fn ray(&self, x: f32, y: f32) -> (Vec3, Vec3) {
        let aspect = self.width as f32 / self.height as f32;
        let sx = (2.0 * x / self.width as f32 - 1.0) * aspect * self.tan_half_fov;
        let sy = (1.0 - 2.0 * y / self.height as f32) * self.tan_half_fov;
        (self.origin, (self.forward + sx * self.right + sy * self.up).normalize())
    }
}
