//! Writing images: linear OpenEXR and sRGB-encoded PNG, each written to a
//! temporary file and renamed into place.

use std::io::BufWriter;
use std::path::Path;

use image::{ImageFormat, RgbImage};

use super::Image;

/// The sRGB transfer function (IEC 61966-2-1) of a linear value in `[0, 1]`.
pub fn srgb_encode(linear: f32) -> f32 {
    let x = linear.clamp(0.0, 1.0);
    if x <= 0.003_130_8 { 12.92 * x } else { 1.055 * x.powf(1.0 / 2.4) - 0.055 }
}

/// How linear radiance becomes display values for an 8-bit PNG (after the
/// exposure; sRGB encoding follows).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ToneMap {
    /// Clamped at 1: exact below it, highlights burn out.
    #[default]
    Clamp,
    /// Reinhard's `x / (1 + x)`: everything compressed, nothing clipped.
    Reinhard,
    /// The ACES filmic curve (Narkowicz's fit to the reference rendering
    /// transform): a toe and a soft shoulder, film-like contrast.
    Aces,
}

impl ToneMap {
    /// The display value in `[0, 1]` of linear value `x` (≥ 0).
    pub fn apply(self, x: f32) -> f32 {
        let x = x.max(0.0);
        match self {
            ToneMap::Clamp => x.min(1.0),
            ToneMap::Reinhard => x / (1.0 + x),
            ToneMap::Aces => ((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14)).clamp(0.0, 1.0),
        }
    }
}

/// Text recorded in an image file: (key, value) pairs, e.g. the archive
/// and the settings that made it (PNG `iTXt` chunks, UTF-8; EXR string
/// attributes, where a character beyond Latin-1 becomes `?`). Keys are
/// ASCII words of 1 to 79 characters.
pub type Metadata<'m> = &'m [(String, String)];

type WriteResult = Result<(), Box<dyn std::error::Error + Send + Sync>>;

fn save_atomic(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<&mut std::fs::File>) -> WriteResult,
) -> Result<(), String> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let err = |e: &dyn std::fmt::Display| format!("cannot write {}: {e}", path.display());
    // `-o out/frame_%04d.png` into a directory that does not exist yet.
    std::fs::create_dir_all(dir).map_err(|e| format!("cannot create directory {}: {e}", dir.display()))?;
    crate::scratch::write_atomic(path, |w| {
        // The encoders' own wording hides the cause ("Format error decoding
        // OpenExr" for a full disk): report the innermost error.
        write(w).map_err(|e| {
            let mut cause: &dyn std::error::Error = e.as_ref();
            while let Some(inner) = cause.source() {
                cause = inner;
            }
            std::io::Error::other(cause.to_string())
        })
    })
    .map_err(|e| err(&e))
}

/// Writes linear radiance as a 32-bit float RGB OpenEXR file.
pub fn write_exr(image: &Image, path: &Path) -> Result<(), String> {
    write_exr_with(image, path, &[])
}

/// [`write_exr`], recording `metadata` as string attributes of the file.
pub fn write_exr_with(image: &Image, path: &Path, metadata: Metadata<'_>) -> Result<(), String> {
    use exr::prelude::{AttributeValue, Image as ExrImage, SpecificChannels, Text, Vec2, WritableImage};
    let (w, h) = (image.width as usize, image.height as usize);
    if image.pixels.len() != w * h {
        return Err("image size mismatch".into());
    }
    let channels = SpecificChannels::rgb(|Vec2(x, y): Vec2<usize>| {
        let p = image.pixels[y * w + x];
        (p[0], p[1], p[2])
    });
    let mut exr = ExrImage::from_channels((w, h), channels);
    // Blocks in increasing order, whichever thread compressed them first:
    // the same image gives the same bytes.
    exr.layer_data.encoding.line_order = exr::meta::attribute::LineOrder::Increasing;
    for (key, value) in metadata {
        // OpenEXR text is Latin-1: a path in another script keeps its shape.
        let latin1 = |t: &str| -> String { t.chars().map(|c| if (c as u32) < 256 { c } else { '?' }).collect() };
        let (Some(k), Some(v)) = (Text::new_or_none(latin1(key)), Text::new_or_none(latin1(value))) else {
            return Err(format!("metadata `{key}` cannot be stored in OpenEXR"));
        };
        exr.layer_data.attributes.other.insert(k, AttributeValue::Text(v));
    }
    save_atomic(path, |wr| Ok(exr.write().to_buffered(wr)?))
}

/// Writes an 8-bit sRGB PNG: radiance times `exposure`, clamped to `[0, 1]`,
/// sRGB-encoded.
pub fn write_png(image: &Image, path: &Path, exposure: f32) -> Result<(), String> {
    write_png_with(image, path, exposure, ToneMap::Clamp, &[])
}

/// Writes an 8-bit sRGB PNG: radiance times `exposure`, through `tone`,
/// sRGB-encoded; `metadata` as `tEXt` chunks.
pub fn write_png_with(
    image: &Image,
    path: &Path,
    exposure: f32,
    tone: ToneMap,
    metadata: Metadata<'_>,
) -> Result<(), String> {
    let data = srgb8_tone(image, exposure, tone);
    if data.len() != image.width as usize * image.height as usize * 3 {
        return Err("image size mismatch".into());
    }
    save_atomic(path, |w| {
        let mut enc = png::Encoder::new(w, image.width, image.height);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
        // fdeflate: the fan room's 60 frames took 0.7 s less to write
        // (of a 11 s render) than at the default level, for files a third
        // larger (3.1 against 2.3 MB).
        enc.set_compression(png::Compression::Fast);
        for (key, value) in metadata {
            enc.add_itxt_chunk(key.clone(), value.clone())?;
        }
        let mut writer = enc.write_header()?;
        writer.write_image_data(&data)?;
        writer.finish()?;
        Ok(())
    })
}

/// The text an image written by [`write_png_with`] or [`write_exr_with`]
/// records (chosen by the extension: `.exr` or else PNG), after decoding
/// the whole image: a truncated or damaged file is an error, so what a
/// killed writer or a full disk left is never taken for a finished frame.
pub fn read_metadata(path: &Path) -> Result<Vec<(String, String)>, String> {
    let is_exr = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("exr"));
    if is_exr {
        read_exr(path)?;
        let meta = exr::meta::MetaData::read_from_file(path, false).map_err(|e| format!("{}: {e}", path.display()))?;
        let header = meta.headers.first().ok_or_else(|| format!("{}: no header", path.display()))?;
        let mut text = Vec::new();
        for (k, v) in &header.own_attributes.other {
            if let exr::prelude::AttributeValue::Text(v) = v {
                text.push((k.to_string(), v.to_string()));
            }
        }
        return Ok(text);
    }
    let file = std::fs::File::open(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let err = |e: &dyn std::fmt::Display| format!("{}: {e}", path.display());
    let mut reader = png::Decoder::new(std::io::BufReader::new(file)).read_info().map_err(|e| err(&e))?;
    let mut buf = vec![0; reader.output_buffer_size().ok_or_else(|| err(&"image too large"))?];
    reader.next_frame(&mut buf).map_err(|e| err(&e))?;
    // Text after the image data is read with the end of the file.
    reader.finish().map_err(|e| err(&e))?;
    let info = reader.info();
    let mut text: Vec<(String, String)> =
        info.uncompressed_latin1_text.iter().map(|t| (t.keyword.clone(), t.text.clone())).collect();
    for t in &info.utf8_text {
        text.push((t.keyword.clone(), t.get_text().map_err(|e| err(&e))?));
    }
    Ok(text)
}

/// Reads an OpenEXR file as linear RGB (for comparisons with references).
pub fn read_exr(path: &Path) -> Result<Image, String> {
    // A regular file only, bounded (`limits::open_regular`): a FIFO or a
    // device given as an image is refused, never waited on or read
    // without end.
    let bytes = crate::limits::read_regular(path, crate::limits::MAX_INPUT_FILE)
        .map_err(|e| format!("{}: cannot read: {e}", path.display()))?;
    let img = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| format!("{}: {e}", path.display()))?
        .decode()
        .map_err(|e| format!("{}: {e}", path.display()))?
        .into_rgb32f();
    let (width, height) = img.dimensions();
    let pixels = img.into_raw().chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    Ok(Image { width, height, pixels })
}

/// Relative L2 error ‖a − ref‖ / ‖ref‖ over the RGB values of pixels whose
/// reference is below `1.0` in every channel (emitters seen directly are
/// left out), the measure used against path-traced references.
pub fn relative_l2(image: &Image, reference: &Image) -> Result<f64, String> {
    relative_l2_below(image, reference, 1.0)
}

/// [`relative_l2`] over the pixels whose reference is below `limit` in
/// every channel (a bright highlight is judged with a limit above it, the
/// emitter's radiance below it).
pub fn relative_l2_below(image: &Image, reference: &Image, limit: f32) -> Result<f64, String> {
    if (image.width, image.height) != (reference.width, reference.height) {
        return Err(format!(
            "image is {}×{}, reference {}×{}",
            image.width, image.height, reference.width, reference.height
        ));
    }
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (a, r) in image.pixels.iter().zip(&reference.pixels) {
        if r.iter().all(|&x| x < limit) {
            for c in 0..3 {
                let d = (a[c] - r[c]) as f64;
                num += d * d;
                den += (r[c] as f64).powi(2);
            }
        }
    }
    Ok((num / den.max(f64::MIN_POSITIVE)).sqrt())
}

/// Error measures of an image against a reference, on linear radiance, over
/// the pixels whose reference is below `1.0` in every channel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageError {
    /// ‖a − ref‖₂ / ‖ref‖₂ (the measure of [`relative_l2`]).
    pub relative_l2: f64,
    /// Mean of (a − ref)² / mean of ref².
    pub relative_mse: f64,
    /// Mean |a − ref|.
    pub mean_abs: f64,
    /// Pixels compared.
    pub pixels: u64,
}

/// Computes [`ImageError`] and, per pixel, the relative error
/// `|a − ref| / (ref + 0.01)` of the luminance (0 where the pixel is excluded).
pub fn compare(image: &Image, reference: &Image) -> Result<(ImageError, Vec<f32>), String> {
    compare_below(image, reference, 1.0)
}

/// [`compare`] over the pixels whose reference is below `limit` in every
/// channel.
pub fn compare_below(image: &Image, reference: &Image, limit: f32) -> Result<(ImageError, Vec<f32>), String> {
    let rel = relative_l2_below(image, reference, limit)?;
    let lum = |c: &[f32; 3]| 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2];
    let (mut sq, mut ref_sq, mut abs, mut n) = (0.0f64, 0.0f64, 0.0f64, 0u64);
    let mut map = Vec::with_capacity(image.pixels.len());
    for (a, r) in image.pixels.iter().zip(&reference.pixels) {
        if r.iter().all(|&x| x < limit) {
            for c in 0..3 {
                let d = (a[c] - r[c]) as f64;
                sq += d * d;
                ref_sq += (r[c] as f64).powi(2);
                abs += d.abs();
            }
            n += 1;
            map.push((lum(a) - lum(r)).abs() / (lum(r) + 0.01));
        } else {
            map.push(0.0);
        }
    }
    let values = (3 * n).max(1) as f64;
    let err = ImageError {
        relative_l2: rel,
        relative_mse: sq / ref_sq.max(f64::MIN_POSITIVE),
        mean_abs: abs / values,
        pixels: n,
    };
    Ok((err, map))
}

/// Writes a per-pixel error map as a PNG: black at 0, through red and
/// yellow, to white at `full_scale` and above.
pub fn write_heatmap(width: u32, height: u32, values: &[f32], full_scale: f32, path: &Path) -> Result<(), String> {
    let data: Vec<u8> = values
        .iter()
        .flat_map(|&v| {
            let t = (v / full_scale).clamp(0.0, 1.0) * 3.0;
            [t.min(1.0), (t - 1.0).clamp(0.0, 1.0), (t - 2.0).clamp(0.0, 1.0)].map(|c| (c * 255.0 + 0.5) as u8)
        })
        .collect();
    let img = RgbImage::from_raw(width, height, data).ok_or("image size mismatch")?;
    save_atomic(path, |w| Ok(img.write_to(w, ImageFormat::Png)?))
}

/// 8-bit sRGB pixels of `image` (radiance × `exposure`, clamped).
fn srgb8(image: &Image, exposure: f32) -> Vec<u8> {
    let thresholds = srgb8_thresholds();
    image.pixels.iter().flatten().map(|&v| srgb8_of(thresholds, v * exposure)).collect()
}

/// [`srgb8`] through a tone map (the clamp is the plain encoding).
fn srgb8_tone(image: &Image, exposure: f32, tone: ToneMap) -> Vec<u8> {
    if tone == ToneMap::Clamp {
        return srgb8(image, exposure);
    }
    let thresholds = srgb8_thresholds();
    image.pixels.iter().flatten().map(|&v| srgb8_of(thresholds, tone.apply(v * exposure))).collect()
}

/// The 8-bit sRGB code of a linear value: `(srgb_encode(x)·255 + 0.5)` truncated.
fn srgb8_exact(x: f32) -> u8 {
    (srgb_encode(x) * 255.0 + 0.5) as u8
}

/// [`srgb8_exact`] by search among the 255 linear values where the code
/// steps up (a `powf` per channel was most of the time spent writing a
/// frame). The code is a non-decreasing function of `x`, so the thresholds
/// reproduce it exactly (tested at the steps and on a dense sample; an
/// ignored test checks every `f32` of `[0, 1]`).
fn srgb8_of(thresholds: &[f32; 255], x: f32) -> u8 {
    // NaN gives 0, as `as u8` of NaN does.
    if x.is_nan() {
        return 0;
    }
    thresholds.partition_point(|&t| t <= x) as u8
}

/// `thresholds[k]`: the least `f32` whose code is above `k`.
fn srgb8_thresholds() -> &'static [f32; 255] {
    static T: std::sync::OnceLock<[f32; 255]> = std::sync::OnceLock::new();
    T.get_or_init(|| {
        std::array::from_fn(|k| {
            // Bisect over the bit patterns of non-negative floats (ordered
            // as integers) for the first one whose code exceeds k.
            let (mut lo, mut hi) = (0u32, 1.0f32.to_bits() + 1);
            while lo < hi {
                let mid = lo + (hi - lo) / 2;
                if srgb8_exact(f32::from_bits(mid)) as usize > k { hi = mid } else { lo = mid + 1 }
            }
            f32::from_bits(lo)
        })
    })
}

/// Writes frames as an animated GIF (looping, `fps` frames per second),
/// for previews: GIF has 256 colours per frame, so use EXR or PNG frames for
/// anything else.
pub fn write_gif(frames: &[Image], fps: f32, exposure: f32, path: &Path) -> Result<(), String> {
    use image::codecs::gif::{GifEncoder, Repeat};
    use image::{Delay, Frame, RgbaImage};
    let delay = Delay::from_saturating_duration(std::time::Duration::from_secs_f32(1.0 / fps.max(0.01)));
    save_atomic(path, |w| {
        let mut enc = GifEncoder::new_with_speed(w, 10);
        enc.set_repeat(Repeat::Infinite)?;
        for f in frames {
            let rgb = srgb8(f, exposure);
            let rgba: Vec<u8> = rgb.chunks_exact(3).flat_map(|c| [c[0], c[1], c[2], 255]).collect();
            let img = RgbaImage::from_raw(f.width, f.height, rgba).expect("sizes match");
            enc.encode_frame(Frame::from_parts(img, 0, 0, delay))?;
        }
        Ok(())
    })
}

/// Writes frames side by side as a contact sheet PNG, `columns` per row.
pub fn write_contact_sheet(frames: &[Image], columns: u32, exposure: f32, path: &Path) -> Result<(), String> {
    let Some(first) = frames.first() else { return Err("no frames for the contact sheet".into()) };
    let (w, h) = (first.width, first.height);
    let columns = columns.clamp(1, frames.len() as u32);
    let rows = (frames.len() as u32).div_ceil(columns);
    let mut sheet = RgbImage::new(w * columns, h * rows);
    for (i, f) in frames.iter().enumerate() {
        let rgb = srgb8(f, exposure);
        let (x0, y0) = ((i as u32 % columns) * w, (i as u32 / columns) * h);
        for y in 0..h {
            for x in 0..w {
                let k = ((y * w + x) * 3) as usize;
                sheet.put_pixel(x0 + x, y0 + y, image::Rgb([rgb[k], rgb[k + 1], rgb[k + 2]]));
            }
        }
    }
    save_atomic(path, |wr| Ok(sheet.write_to(wr, ImageFormat::Png)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tone_maps_are_monotone_bounded_and_named_right() {
        for t in [ToneMap::Clamp, ToneMap::Reinhard, ToneMap::Aces] {
            let mut last = -1.0;
            for i in 0..=2000 {
                let y = t.apply(i as f32 * 0.01);
                assert!((0.0..=1.0).contains(&y) && y >= last, "{t:?} at {}", i as f32 * 0.01);
                last = y;
            }
            assert_eq!(t.apply(f32::NAN), 0.0);
        }
        assert_eq!(ToneMap::Reinhard.apply(1.0), 0.5);
        assert_eq!(ToneMap::Clamp.apply(0.25), 0.25);
        // Narkowicz's fit: 0.8 at 1, nearly linear near 0 (slope 0.03/0.14).
        assert!((ToneMap::Aces.apply(1.0) - 0.8038).abs() < 1e-3);
        assert!(ToneMap::Aces.apply(20.0) > 0.99);
    }

    #[test]
    fn metadata_is_stored_in_png_and_exr() {
        let dir = tempfile::tempdir().unwrap();
        let image = Image { width: 3, height: 2, pixels: vec![[0.25, 0.5, 2.0]; 6] };
        let meta = vec![
            ("illumnet.archive".to_string(), "box.inet".to_string()),
            ("illumnet.set".to_string(), "Würfel.emission=1,1,1 立方体".to_string()),
        ];
        let png_path = dir.path().join("a.png");
        write_png_with(&image, &png_path, 1.0, ToneMap::Reinhard, &meta).unwrap();
        let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&png_path).unwrap()));
        let mut reader = decoder.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        reader.next_frame(&mut buf).unwrap();
        let text = &reader.info().utf8_text;
        let get = |k: &str| text.iter().find(|t| t.keyword == k).map(|t| t.get_text().unwrap());
        assert_eq!(get("illumnet.archive").as_deref(), Some("box.inet"));
        assert_eq!(get("illumnet.set").as_deref(), Some("Würfel.emission=1,1,1 立方体"));
        // Reinhard: 2 → 2/3 → sRGB code 213, not clipped at 255.
        assert_eq!(&buf[..3], &[srgb8_exact(0.2), srgb8_exact(1.0 / 3.0), srgb8_exact(2.0 / 3.0)]);
        let exr_path = dir.path().join("a.exr");
        write_exr_with(&image, &exr_path, &meta).unwrap();
        let back = read_exr(&exr_path).unwrap();
        assert_eq!(back, image);
        let meta_read = exr::meta::MetaData::read_from_file(&exr_path, false).unwrap();
        let attr = &meta_read.headers[0].own_attributes.other;
        let key = exr::prelude::Text::new_or_panic("illumnet.archive");
        assert!(matches!(attr.get(&key), Some(exr::prelude::AttributeValue::Text(t)) if t == "box.inet"));
        let key = exr::prelude::Text::new_or_panic("illumnet.set");
        assert!(
            matches!(attr.get(&key), Some(exr::prelude::AttributeValue::Text(t)) if t == "Würfel.emission=1,1,1 ???"),
            "{:?}",
            attr.get(&key)
        );
    }

    #[test]
    fn srgb8_by_thresholds_equals_the_formula() {
        // At each step, on both sides, and on a dense sample of bit patterns
        // (every 64th float of [0, 1], about 16 M values), plus values
        // outside [0, 1]. (Every float of [0, 1]: the ignored test below.)
        let t = srgb8_thresholds();
        for (k, &x) in t.iter().enumerate() {
            let below = f32::from_bits(x.to_bits() - 1);
            assert_eq!((srgb8_of(t, below), srgb8_of(t, x)), (srgb8_exact(below), srgb8_exact(x)), "step {k}");
            assert_eq!(srgb8_exact(x) as usize, k + 1, "step {k}");
        }
        for bits in (0..=1.0f32.to_bits()).step_by(64) {
            let x = f32::from_bits(bits);
            assert_eq!(srgb8_of(t, x), srgb8_exact(x), "{x}");
        }
        for x in [-1.0, -0.0, 1.5, f32::INFINITY, f32::NEG_INFINITY, f32::NAN, 1e-40] {
            assert_eq!(srgb8_of(t, x), srgb8_exact(x), "{x}");
        }
    }

    #[test]
    #[ignore = "every float of [0, 1]: about 5 s; run with --ignored"]
    fn srgb8_by_thresholds_equals_the_formula_everywhere() {
        let t = srgb8_thresholds();
        let differ = (0..=1.0f32.to_bits())
            .filter(|&b| {
                let x = f32::from_bits(b);
                srgb8_of(t, x) != srgb8_exact(x)
            })
            .count();
        assert_eq!(differ, 0);
    }
}
