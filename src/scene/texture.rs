//! Base-colour textures of imported scenes (glTF, OBJ + MTL): their mean
//! albedo over a surface, which is what the I-net uses, and the texels and
//! per-primitive coordinates the render multiplies each image sample's
//! reflected light by ([`TextureImage`], [`Shading`]).

use glam::{Vec2, Vec3};

use crate::geometry::Primitive;

/// How texture coordinates outside `[0, 1]` are brought back in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Wrap {
    /// The edge texel repeats.
    Clamp,
    /// The texture tiles.
    Repeat,
    /// The texture tiles, every other copy mirrored.
    Mirror,
}

/// A base-colour texture as the archive keeps it for the render: 8-bit
/// sRGB texels, `width × height`, RGB, row-major from the top row.
#[derive(Debug, Clone, PartialEq)]
pub struct TextureImage {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// How coordinates outside `[0, 1]` wrap, along u and v.
    pub wrap: [Wrap; 2],
    /// Whether a sample takes the nearest texel (else bilinear between
    /// texel centres).
    pub nearest: bool,
    /// `3 × width × height` bytes.
    pub srgb: Vec<u8>,
}

/// Per-primitive shading detail of an imported mesh, for the render:
/// texture coordinates and shading normals at the corners, and a texture
/// whose texel, times `tint`, multiplies the light a sample reflects
/// diffusely. (The distribution uses each surface's mean albedo; `tint` is
/// one over the texture's mean over the surface, so the multiplier averages
/// 1 and the surface reflects as much light as the I-net gave it.)
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Shading {
    /// Texture coordinates at corners 0..4 (a triangle repeats corner 2).
    pub uv: [Vec2; 4],
    /// Unit shading normals at the corners, in the primitive's own frame
    /// ([`Primitive::own_frame`]: x along its first edge, z its face
    /// normal), so that they follow the primitive through rigid motion;
    /// zero where the mesh gives none (the face normal is used).
    pub normal: [Vec3; 4],
    /// Index into [`crate::scene::Scene::textures`] (`u32::MAX`: none).
    pub texture: u32,
    /// Multiplies the texel (linear RGB).
    pub tint: [f32; 3],
}

impl Shading {
    /// No texture, no normals: shades as the face.
    pub const FLAT: Shading =
        Shading { uv: [Vec2::ZERO; 4], normal: [Vec3::ZERO; 4], texture: u32::MAX, tint: [1.0; 3] };

    /// `world` normals at `p`'s corners in its own frame, each of unit
    /// length (a zero or non-finite one stays zero).
    pub fn to_local(p: &Primitive, world: [Vec3; 4]) -> [Vec3; 4] {
        let [x, y, z] = p.own_frame();
        world.map(|n| {
            let n = n.normalize_or_zero();
            if n == Vec3::ZERO { n } else { Vec3::new(n.dot(x), n.dot(y), n.dot(z)) }
        })
    }
}

/// Most texel bytes a scene keeps for the render (1 GiB): beyond it,
/// further textures enter as their surfaces' mean albedo only (said).
pub const MAX_TEXEL_BYTES: usize = 1 << 30;

/// An encoded image (PNG, JPEG, … by its bytes) decoded as a texture: its
/// size read from the header first and held to
/// [`crate::limits::texture_size_problem`] (the archive's side limit and the
/// importers' texel bound) before anything is decoded; the decoder limited
/// to that size. The glTF and OBJ importers' one way in, so that every
/// texture a scene keeps is one its build can write. The error says what
/// is wrong; callers name the image.
pub(in crate::scene) fn decode_image(bytes: &[u8]) -> Result<image::DynamicImage, String> {
    use crate::limits::{MAX_TEXTURE_SIDE, MAX_TEXTURE_TEXELS, texture_size_problem};
    let reader = || {
        image::ImageReader::new(std::io::Cursor::new(bytes))
            .with_guessed_format()
            .map_err(|e| format!("cannot read the image: {e}"))
    };
    let (width, height) = reader()?.into_dimensions().map_err(|e| format!("cannot read the image: {e}"))?;
    if let Some(problem) = texture_size_problem(width, height) {
        return Err(format!("cannot be a texture: {problem}"));
    }
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_TEXTURE_SIDE);
    limits.max_image_height = Some(MAX_TEXTURE_SIDE);
    // Eight bytes a texel: a 16-bit RGBA image at the texel bound.
    limits.max_alloc = Some(MAX_TEXTURE_TEXELS * 8);
    let mut reader = reader()?;
    reader.limits(limits);
    let image = reader.decode().map_err(|e| format!("cannot decode the image: {e}"))?;
    // The decoded size, in case a decoder's differs from its header's.
    match texture_size_problem(image.width(), image.height()) {
        Some(problem) => Err(format!("cannot be a texture: {problem}")),
        None => Ok(image),
    }
}

/// Linear value → sRGB-encoded byte (rounded).
pub fn linear_to_srgb_byte(v: f32) -> u8 {
    let v = if v.is_finite() { v.clamp(0.0, 1.0) } else { 0.0 };
    let e = if v <= 0.003_130_8 { 12.92 * v } else { 1.055 * v.powf(1.0 / 2.4) - 0.055 };
    (e * 255.0).round().clamp(0.0, 255.0) as u8
}

/// sRGB-encoded value in `[0, 1]` → linear.
pub fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.04045 { v / 12.92 } else { ((v + 0.055) / 1.055).powf(2.4) }
}

/// A texture's size and a reader of its linear RGB texels (row-major, top
/// row first): decoded one at a time, so a large texture is not copied.
pub struct Texture<'a> {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// Linear RGB of texel `y·width + x`.
    pub texel: &'a dyn Fn(usize) -> [f32; 3],
}

impl Texture<'_> {
    /// The area-weighted mean linear albedo over the texture triangles
    /// `uvs` (`areas` their world areas): each triangle sampled at the
    /// centroids of a regular grid of sub-triangles, about 64 per texel it
    /// covers (at least 16, at most 4 096), nearest texel. `[1, 1, 1]`
    /// for no area.
    pub fn mean_albedo(&self, wrap: (Wrap, Wrap), uvs: &[[Vec2; 3]], areas: impl Iterator<Item = f32>) -> [f32; 3] {
        let (w, h) = (self.width.max(1) as usize, self.height.max(1) as usize);
        let texels = (w * h) as f64;
        let fetch = |uv: Vec2| -> [f32; 3] {
            let x = wrap_index(uv.x, w, wrap.0);
            let y = wrap_index(uv.y, h, wrap.1);
            (self.texel)(y * w + x)
        };
        let mut sum = [0f64; 3];
        let mut total = 0f64;
        for (t, area) in uvs.iter().zip(areas) {
            if !(area > 0.0 && area.is_finite()) {
                continue;
            }
            let uv_area = ((t[1] - t[0]).perp_dot(t[2] - t[0]) / 2.0).abs() as f64;
            // m² sub-triangles, each sampled at its centroid (m even: texel
            // edges at half the texture fall on grid lines).
            let n = if uv_area.is_finite() { (64.0 * uv_area * texels).clamp(16.0, 4096.0) } else { 16.0 };
            let m = ((n.sqrt().ceil() as usize).div_ceil(2) * 2).max(2);
            let mut acc = [0f64; 3];
            let mut sample = |a: f32, b: f32| {
                let c = fetch(t[0] + (t[1] - t[0]) * a + (t[2] - t[0]) * b);
                for i in 0..3 {
                    acc[i] += c[i] as f64;
                }
            };
            let mf = m as f32;
            for i in 0..m {
                for j in 0..m - i {
                    sample((i as f32 + 1.0 / 3.0) / mf, (j as f32 + 1.0 / 3.0) / mf);
                    if i + j + 1 < m {
                        sample((i as f32 + 2.0 / 3.0) / mf, (j as f32 + 2.0 / 3.0) / mf);
                    }
                }
            }
            for i in 0..3 {
                sum[i] += acc[i] / (m * m) as f64 * area as f64;
            }
            total += area as f64;
        }
        if total <= 0.0 {
            return [1.0; 3];
        }
        sum.map(|s| (s / total) as f32)
    }
}

/// The texel column (or row) of coordinate `u` in a texture `n` wide.
fn wrap_index(u: f32, n: usize, mode: Wrap) -> usize {
    let x = if u.is_finite() { u } else { 0.0 };
    let t = match mode {
        Wrap::Clamp => x.clamp(0.0, 1.0),
        Wrap::Repeat => x - x.floor(),
        Wrap::Mirror => {
            let f = x.rem_euclid(2.0);
            if f > 1.0 { 2.0 - f } else { f }
        }
    };
    ((t * n as f32) as usize).min(n - 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrapping_modes() {
        assert_eq!(wrap_index(1.25, 4, Wrap::Repeat), 1);
        assert_eq!(wrap_index(-0.25, 4, Wrap::Repeat), 3);
        assert_eq!(wrap_index(1.25, 4, Wrap::Clamp), 3);
        assert_eq!(wrap_index(1.25, 4, Wrap::Mirror), 3);
        assert_eq!(wrap_index(f32::NAN, 4, Wrap::Repeat), 0);
    }

    #[test]
    fn the_mean_of_a_checker_is_exact_over_a_split_square() {
        // 2 × 2 texels 0, 1, 1, 0 (one channel): mean 0.5 over the square
        // cut on its diagonal, and 0 or 1 over a single texel.
        let v = [0.0, 1.0, 1.0, 0.0];
        let fetch = |i: usize| [v[i]; 3];
        let t = Texture { width: 2, height: 2, texel: &fetch };
        let (a, b, c, d) = (Vec2::ZERO, Vec2::X, Vec2::ONE, Vec2::Y);
        let square = [[a, b, c], [a, c, d]];
        let mean = t.mean_albedo((Wrap::Repeat, Wrap::Repeat), &square, [1.0, 1.0].into_iter());
        assert!((mean[0] - 0.5).abs() < 1e-6, "{mean:?}");
        let texel = [[Vec2::new(0.5, 0.0), Vec2::new(1.0, 0.0), Vec2::new(0.5, 0.5)]];
        assert_eq!(t.mean_albedo((Wrap::Clamp, Wrap::Clamp), &texel, [1.0].into_iter())[0], 1.0);
    }
}
