//! Surface detail the I-net does not carry, applied per image sample: the
//! base-colour texture that multiplies the light a textured surface
//! reflects (its interpolated I-net radiance and its diffuse direct light;
//! not emission, nor the per-sample glossy highlights), and the shading
//! normal interpolated from a mesh's vertex normals that direct light is
//! computed with (the archive's shading sections, §5.15 of the format).
//! The distribution gave each surface its mean albedo; the texel times the
//! record's tint (one over that mean) redistributes the same light across
//! the surface.

use glam::{Vec2, Vec3};

use crate::archive::layout::{ShadingRecord, TextureRecord, shading_flags};
use crate::archive::{InetView, ShadingView};
use crate::geometry::{Primitive, PrimitiveKind};

/// Per primitive, what shades its samples beyond the patches' light.
pub(crate) struct SurfaceDetail<'a> {
    shading: Option<ShadingView<'a>>,
    /// Per primitive, its own frame (x, y, z = face normal) in world space,
    /// whether it is a quad or a triangle, and whether its texture applies
    /// (not on emitters, which show their own radiance).
    frames: Vec<([Vec3; 3], PrimitiveKind, bool)>,
    /// sRGB byte → linear.
    linear: [f32; 256],
}

impl<'a> SurfaceDetail<'a> {
    /// The detail of `v`'s primitives (`prims`, their corners as the frame
    /// places them).
    pub(crate) fn new(v: &InetView<'a>, prims: &[Primitive]) -> Self {
        let shading = v.shading;
        let frames = match shading {
            Some(_) => prims
                .iter()
                .zip(v.primitives)
                .map(|(p, r)| {
                    let emits = v.surfaces.get(r.surface as usize).is_some_and(|s| s.emission.iter().any(|&e| e > 0.0));
                    (p.own_frame(), p.kind, !emits)
                })
                .collect(),
            None => Vec::new(),
        };
        let mut linear = [0.0f32; 256];
        for (b, l) in linear.iter_mut().enumerate() {
            let c = b as f32 / 255.0;
            *l = if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) };
        }
        Self { shading, frames, linear }
    }

    fn record(&self, prim: u32) -> Option<&ShadingRecord> {
        self.shading.and_then(|s| s.primitives.get(prim as usize))
    }

    /// What multiplies the diffusely reflected light of a sample at surface
    /// coordinates `uv` of primitive `prim`: its texel (bilinear) times
    /// the tint, or 1.
    #[inline]
    pub(crate) fn albedo_scale(&self, prim: u32, uv: Vec2) -> Vec3 {
        let (Some(r), Some(s)) = (self.record(prim), self.shading) else { return Vec3::ONE };
        if r.flags & shading_flags::TEXTURE == 0 {
            return Vec3::ONE;
        }
        let (Some(t), Some(&(_, kind, true))) = (s.textures.get(r.texture as usize), self.frames.get(prim as usize))
        else {
            return Vec3::ONE;
        };
        let w = corner_weights(kind, uv);
        let mut st = Vec2::ZERO;
        for k in 0..4 {
            st += w[k] * Vec2::from(r.uvs[k]);
        }
        self.bilinear(t, s.texels, st) * Vec3::from(r.tint)
    }

    /// The unit shading normal at `uv` of primitive `prim` (`face`: its
    /// face normal, returned where the mesh gives none or the interpolated
    /// normal turns to the back).
    #[inline]
    pub(crate) fn normal(&self, prim: u32, uv: Vec2, face: Vec3) -> Vec3 {
        let Some(r) = self.record(prim) else { return face };
        if r.flags & shading_flags::NORMALS == 0 {
            return face;
        }
        let Some(&([x, y, z], kind, _)) = self.frames.get(prim as usize) else { return face };
        let w = corner_weights(kind, uv);
        let mut n = Vec3::ZERO;
        for k in 0..4 {
            let c = Vec3::from(r.normals[k]);
            if c == Vec3::ZERO {
                // A corner without a normal takes the face's.
                n += w[k] * Vec3::Z;
            } else {
                n += w[k] * c;
            }
        }
        let world = (x * n.x + y * n.y + z * n.z).normalize_or_zero();
        if world.dot(face) > 1e-3 { world } else { face }
    }

    /// Whether any primitive has detail (else every scale is 1 and every
    /// normal the face's).
    pub(crate) fn any(&self) -> bool {
        self.shading.is_some()
    }

    /// Texture `t` at coordinates `st` (bilinear between texel centres).
    fn bilinear(&self, t: &TextureRecord, texels: &[u8], st: Vec2) -> Vec3 {
        let (w, h) = (t.width.max(1) as usize, t.height.max(1) as usize);
        let x = st.x * w as f32 - 0.5;
        let y = st.y * h as f32 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let fetch = |i: f32, j: f32| -> Vec3 {
            let (i, j) = (wrap(i as i64, w, t.wrap[0]), wrap(j as i64, h, t.wrap[1]));
            let at = t.first_byte as usize + 3 * (j * w + i);
            match texels.get(at..at + 3) {
                Some(b) => {
                    Vec3::new(self.linear[b[0] as usize], self.linear[b[1] as usize], self.linear[b[2] as usize])
                }
                None => Vec3::ONE,
            }
        };
        if !(x0.is_finite() && y0.is_finite()) {
            return fetch(0.0, 0.0);
        }
        if t.filter == 1 {
            // Nearest: the texel whose square holds st.
            return fetch((st.x * w as f32).floor(), (st.y * h as f32).floor());
        }
        let top = fetch(x0, y0) * (1.0 - fx) + fetch(x0 + 1.0, y0) * fx;
        let bottom = fetch(x0, y0 + 1.0) * (1.0 - fx) + fetch(x0 + 1.0, y0 + 1.0) * fx;
        top * (1.0 - fy) + bottom * fy
    }
}

/// Texel index `i` of a row (or column) `n` long under wrap mode `mode`
/// (0 clamp, 1 repeat, 2 mirrored repeat, as `TXHD`).
fn wrap(i: i64, n: usize, mode: u32) -> usize {
    let n = n as i64;
    let k = match mode {
        1 => i.rem_euclid(n),
        2 => {
            let p = i.rem_euclid(2 * n);
            if p >= n { 2 * n - 1 - p } else { p }
        }
        _ => i.clamp(0, n - 1),
    };
    k as usize
}

/// Interpolation weights of corners 0..4 at surface coordinates `uv`:
/// bilinear on quads, barycentric on triangles (corner 3 unused).
#[inline]
fn corner_weights(kind: PrimitiveKind, uv: Vec2) -> [f32; 4] {
    let (u, v) = (uv.x, uv.y);
    match kind {
        PrimitiveKind::Quad => [(1.0 - u) * (1.0 - v), u * (1.0 - v), u * v, (1.0 - u) * v],
        PrimitiveKind::Triangle => [1.0 - u - v, u, v, 0.0],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_modes_of_texel_indices() {
        // Clamp, repeat, mirrored repeat over a row of 4.
        assert_eq!([-1, 0, 3, 4, 9].map(|i| wrap(i, 4, 0)), [0, 0, 3, 3, 3]);
        assert_eq!([-1, 0, 3, 4, 9].map(|i| wrap(i, 4, 1)), [3, 0, 3, 0, 1]);
        assert_eq!([-1, 0, 3, 4, 7, 8].map(|i| wrap(i, 4, 2)), [0, 0, 3, 3, 0, 0]);
    }

    #[test]
    fn corner_weights_interpolate_and_sum_to_one() {
        let q = corner_weights(PrimitiveKind::Quad, Vec2::new(0.25, 0.5));
        assert_eq!(q, [0.375, 0.125, 0.125, 0.375]);
        let t = corner_weights(PrimitiveKind::Triangle, Vec2::new(0.25, 0.5));
        assert_eq!(t, [0.25, 0.25, 0.5, 0.0]);
    }
}
