//! Pictures that explain an archive and its solution: per-patch quantities
//! (link ends, hit counts, bucket use, the patch grid, what the
//! distribution left unshot) and per-pixel error against a reference,
//! drawn from the camera in false colour with a colour bar beneath.
//!
//! Patches are coloured flat (no interpolation: the grid shows), a pixel is
//! the box-filtered mean of its samples' colours, back faces and misses are
//! black. Continuous quantities use the viridis map (perceptually uniform,
//! readable in grey), linear or logarithmic as the quantity spreads; patch
//! ids use a categorical palette. Colours are made in sRGB and stored
//! linear, so that writing the image as PNG gives them back exactly.

use crate::archive::{ArchiveError, Columns, InetView};

use super::{Image, SamplePatches};

/// What a false-colour picture shows per patch.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quantity {
    /// Link ends per patch (log scale): where links are dense or sparse.
    Links,
    /// `H_p / E[H_p]`, the rays that reached a patch over those its area
    /// should catch (0..2): below 1 where the patch is hidden or
    /// under-sampled.
    Hits,
    /// The share of a patch's link-end rays that arrive in wide buckets
    /// (spread over rings of neighbours, §3.4): 0..1.
    Buckets,
    /// Every patch its own colour: the patch grid and grouped triangles.
    Patches,
    /// Power the distribution left unshot at a patch over the power it
    /// received (log scale): where it has not converged.
    Residual,
}

/// How values map to the colour bar.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scale {
    /// Value at the bar's left end (dark).
    pub min: f32,
    /// Value at its right end (bright).
    pub max: f32,
    /// Logarithmic between them.
    pub log: bool,
}

impl Scale {
    /// The scale spanning `values` (finite ones; positive ones for a log
    /// scale).
    pub fn spanning(values: &[f32], log: bool) -> Self {
        let usable = |x: &&f32| x.is_finite() && (!log || **x > 0.0);
        let min = values.iter().filter(usable).copied().fold(f32::INFINITY, f32::min);
        let max = values.iter().filter(usable).copied().fold(f32::NEG_INFINITY, f32::max);
        if min > max {
            return Self { min: if log { 1.0 } else { 0.0 }, max: if log { 10.0 } else { 1.0 }, log };
        }
        Self { min, max: if max > min { max } else { min + min.abs().max(1.0) }, log }
    }

    /// Where `x` lies on the bar, in [0, 1].
    pub fn position(&self, x: f32) -> f32 {
        let t = match self.log {
            true => (x.max(self.min).ln() - self.min.ln()) / (self.max.ln() - self.min.ln()),
            false => (x - self.min) / (self.max - self.min),
        };
        if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.0 }
    }
}

/// `q` for every patch of `v` (`residual`: the solution's unshot power
/// over received power, per patch, for [`Quantity::Residual`]).
pub fn patch_values(v: &InetView<'_>, q: Quantity, residual: Option<&[f32]>) -> Result<Vec<f32>, ArchiveError> {
    let n = v.patch_count();
    Ok(match q {
        Quantity::Links => (0..n).map(|p| (v.link_offsets[p + 1] - v.link_offsets[p]) as f32).collect(),
        Quantity::Hits => (0..n)
            .map(|p| {
                let e = v.patch_expected_hits[p];
                if e > 0.0 { v.patch_hits[p] as f32 / e } else { 0.0 }
            })
            .collect(),
        Quantity::Patches => (0..n).map(|p| p as f32).collect(),
        Quantity::Residual => residual.map_or_else(|| vec![0.0; n], <[f32]>::to_vec),
        Quantity::Buckets => {
            let mut share = vec![0.0f32; n];
            if v.build.max_bucket > 0 {
                let columns = Columns { weight: true, ..Default::default() };
                v.links.for_each_window(columns, n, |w| {
                    for p in w.patches.clone() {
                        let (mut wide, mut all) = (0.0f64, 0.0f64);
                        for run in w.runs_of(p) {
                            let rays: f64 = w.weight.slice(run.ends()).iter().map(f64::from).sum();
                            all += rays;
                            if run.bucket() != 0 {
                                wide += rays;
                            }
                        }
                        share[p] = if all > 0.0 { (wide / all) as f32 } else { 0.0 };
                    }
                    Ok::<(), ArchiveError>(())
                })?;
            }
            share
        }
    })
}

/// The scale a quantity is drawn on, from its values.
pub fn scale_of(q: Quantity, values: &[f32]) -> Scale {
    match q {
        Quantity::Links | Quantity::Residual => Scale::spanning(values, true),
        Quantity::Hits => Scale { min: 0.0, max: 2.0, log: false },
        Quantity::Buckets => Scale { min: 0.0, max: 1.0, log: false },
        Quantity::Patches => Scale { min: 0.0, max: values.len().max(1) as f32, log: false },
    }
}

/// The picture of per-patch `values` on `scale` as `samples` see them,
/// with a colour bar beneath (categorical colours, no bar, for
/// [`Quantity::Patches`]).
pub fn picture(samples: &SamplePatches, values: &[f32], q: Quantity, scale: &Scale) -> Image {
    let colour_of = |p: u32| -> [f32; 3] {
        if p == u32::MAX || p as usize >= values.len() {
            return [0.0; 3];
        }
        match q {
            Quantity::Patches => {
                // Neighbouring ids get unrelated colours.
                let h = (p as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15) >> 40;
                linear(colorous::TABLEAU10[(h % 10) as usize])
            }
            _ => gradient(scale.position(values[p as usize])),
        }
    };
    let per = samples.per_pixel.max(1) as usize;
    let pixels = samples
        .patches
        .chunks(per)
        .map(|s| {
            let mut sum = [0.0f32; 3];
            for &p in s {
                let c = colour_of(p);
                for k in 0..3 {
                    sum[k] += c[k];
                }
            }
            sum.map(|x| x / per as f32)
        })
        .collect();
    let image = Image { width: samples.width, height: samples.height, pixels };
    if q == Quantity::Patches { image } else { with_colour_bar(image, scale) }
}

/// Per-pixel relative error of `image` against `reference` in luminance,
/// `|a − r| / (r + 0.01)`, from 0 to `full_scale`, with a colour bar; pixels
/// whose reference is `limit` or more in a channel (emitters) are black.
pub fn error_picture(image: &Image, reference: &Image, full_scale: f32, limit: f32) -> Result<Image, String> {
    if (image.width, image.height) != (reference.width, reference.height) {
        return Err(format!(
            "the image is {}×{} but the reference {}×{}",
            image.width, image.height, reference.width, reference.height
        ));
    }
    let lum = |c: &[f32; 3]| 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2];
    let scale = Scale { min: 0.0, max: full_scale, log: false };
    let pixels = image
        .pixels
        .iter()
        .zip(&reference.pixels)
        .map(|(a, r)| match r.iter().all(|&x| x < limit) {
            true => gradient(scale.position((lum(a) - lum(r)).abs() / (lum(r) + 0.01))),
            false => [0.0; 3],
        })
        .collect();
    Ok(with_colour_bar(Image { width: image.width, height: image.height, pixels }, &scale))
}

/// Viridis at `t` ∈ [0, 1], linear RGB.
fn gradient(t: f32) -> [f32; 3] {
    linear(colorous::VIRIDIS.eval_continuous(t as f64))
}

fn linear(c: colorous::Color) -> [f32; 3] {
    [c.r, c.g, c.b].map(|u| {
        let x = u as f32 / 255.0;
        if x <= 0.040_45 { x / 12.92 } else { ((x + 0.055) / 1.055).powf(2.4) }
    })
}

/// Height of the strip under the picture: a gap, the bar, its labels.
const BAR_STRIP: u32 = 30;

/// `image` with a strip beneath: the gradient from the scale's minimum
/// (left) to its maximum (right), labelled at both ends.
fn with_colour_bar(mut image: Image, scale: &Scale) -> Image {
    let (w, h) = (image.width, image.height);
    image.pixels.resize((w * (h + BAR_STRIP)) as usize, [0.0; 3]);
    image.height = h + BAR_STRIP;
    let margin = (w / 20).max(2);
    let span = w.saturating_sub(2 * margin).max(1);
    for y in h + 4..h + 14 {
        for x in margin..(margin + span).min(w) {
            image.pixels[(y * w + x) as usize] = gradient((x - margin) as f32 / span.saturating_sub(1).max(1) as f32);
        }
    }
    let label = |v: f32| match v.abs() {
        a if a != 0.0 && !(1e-2..1e5).contains(&a) => format!("{v:.1e}"),
        a if a >= 100.0 => format!("{v:.0}"),
        a if a >= 1.0 || a == 0.0 => format!("{v:.2}"),
        _ => format!("{v:.3}"),
    };
    let (lo, hi) = (label(scale.min), label(scale.max));
    let white = [1.0; 3];
    draw_text(&mut image, margin, h + 18, &lo, white);
    let hi_w = text_width(&hi);
    draw_text(&mut image, (margin + span).saturating_sub(hi_w), h + 18, &hi, white);
    if scale.log {
        let log = "log";
        draw_text(&mut image, (w.saturating_sub(text_width(log))) / 2, h + 18, log, white);
    }
    image
}

/// Glyphs 3 pixels wide and 5 high, drawn at twice that size: digits and
/// what numbers need.
fn glyph(c: char) -> [u8; 5] {
    match c {
        '0' => [0b111, 0b101, 0b101, 0b101, 0b111],
        '1' => [0b010, 0b110, 0b010, 0b010, 0b111],
        '2' => [0b111, 0b001, 0b111, 0b100, 0b111],
        '3' => [0b111, 0b001, 0b111, 0b001, 0b111],
        '4' => [0b101, 0b101, 0b111, 0b001, 0b001],
        '5' => [0b111, 0b100, 0b111, 0b001, 0b111],
        '6' => [0b111, 0b100, 0b111, 0b101, 0b111],
        '7' => [0b111, 0b001, 0b010, 0b010, 0b010],
        '8' => [0b111, 0b101, 0b111, 0b101, 0b111],
        '9' => [0b111, 0b101, 0b111, 0b001, 0b111],
        '.' => [0b000, 0b000, 0b000, 0b000, 0b010],
        '-' => [0b000, 0b000, 0b111, 0b000, 0b000],
        'e' => [0b000, 0b111, 0b111, 0b100, 0b111],
        'l' => [0b100, 0b100, 0b100, 0b100, 0b111],
        'o' => [0b000, 0b111, 0b101, 0b101, 0b111],
        'g' => [0b111, 0b101, 0b111, 0b001, 0b110],
        _ => [0; 5],
    }
}

fn text_width(text: &str) -> u32 {
    text.chars().count() as u32 * 8
}

fn draw_text(image: &mut Image, x0: u32, y0: u32, text: &str, colour: [f32; 3]) {
    for (i, c) in text.chars().enumerate() {
        for (row, bits) in glyph(c).iter().enumerate() {
            for col in 0..3 {
                if bits >> (2 - col) & 1 == 1 {
                    for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let (x, y) = (x0 + i as u32 * 8 + col * 2 + dx, y0 + row as u32 * 2 + dy);
                        if x < image.width && y < image.height {
                            image.pixels[(y * image.width + x) as usize] = colour;
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scales_place_values_and_survive_degenerate_input() {
        let lin = Scale::spanning(&[2.0, 4.0, f32::NAN, 6.0], false);
        assert_eq!((lin.min, lin.max), (2.0, 6.0));
        assert_eq!(lin.position(4.0), 0.5);
        assert_eq!(lin.position(100.0), 1.0);
        let log = Scale::spanning(&[0.0, 1.0, 100.0], true);
        assert_eq!((log.min, log.max), (1.0, 100.0));
        assert!((log.position(10.0) - 0.5).abs() < 1e-6);
        assert_eq!(log.position(0.0), 0.0);
        let flat = Scale::spanning(&[3.0, 3.0], false);
        assert!(flat.max > flat.min);
        let none = Scale::spanning(&[], true);
        assert!(none.min > 0.0 && none.max > none.min);
    }

    #[test]
    fn pictures_colour_patches_flat_and_add_a_bar() {
        // Two pixels of two samples: patch 0 and 1 (values 0 and 1), then
        // patch 1 and nothing.
        let samples = SamplePatches { width: 2, height: 1, per_pixel: 2, patches: vec![0, 1, 1, u32::MAX] };
        let scale = Scale { min: 0.0, max: 1.0, log: false };
        let img = picture(&samples, &[0.0, 1.0], Quantity::Buckets, &scale);
        assert_eq!((img.width, img.height), (2, 1 + BAR_STRIP));
        let (lo, hi) = (gradient(0.0), gradient(1.0));
        for k in 0..3 {
            assert!((img.pixels[0][k] - 0.5 * (lo[k] + hi[k])).abs() < 1e-6);
            assert!((img.pixels[1][k] - 0.5 * hi[k]).abs() < 1e-6);
        }
        // The bar runs dark to bright.
        let lum = |c: [f32; 3]| c[0] + c[1] + c[2];
        assert!(lum(gradient(1.0)) > 4.0 * lum(gradient(0.0)));
        let ids = picture(&samples, &[0.0, 1.0], Quantity::Patches, &scale);
        assert_eq!(ids.height, 1, "patch ids take no bar");
    }
}
