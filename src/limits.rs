//! Limits every stage agrees on: what the scene reader accepts, what the
//! build makes, what the archive format allows (`format-spec/archive.md`)
//! and what the readers check. One home, so that a scene that parses also
//! builds, and an archive a build writes also opens.

/// Largest geodesic subdivision frequency (10f² + 2 = 64 002 directions).
pub const MAX_FREQUENCY: u32 = 80;

/// Widest bucket of §3.4 (a 4-ring of a grid holds 41 patches).
pub const MAX_BUCKET: u32 = 4;

/// Largest emitted radiance (W·sr⁻¹·m⁻² per band; the sun's disc is about
/// 2·10⁷): bounds every power the distribution sums, so that it stays finite.
pub const MAX_RADIANCE: f32 = 1e9;

/// How far `k_d + k_s` may exceed 1 in a band (rounding of f32 sums:
/// glTF's and OBJ's conversions land a few ulps above 1).
pub const REFLECTANCE_SLACK: f32 = 1e-6;

/// Whether a material with diffuse reflectance `kd` and specular colour
/// `ks` conserves energy: `k_d + k_s ≤ 1 +` [`REFLECTANCE_SLACK`] in every
/// band. The one rule of the scene reader, `render --set` and the archive
/// reader, so that what one accepts the others do too (issue 42, §8).
pub fn conserves_energy(kd: [f32; 3], ks: [f32; 3]) -> bool {
    (0..3).all(|c| kd[c] + ks[c] <= 1.0 + REFLECTANCE_SLACK)
}

/// Largest patch area (m²; a square 10 000 km on a side): with
/// [`MAX_RADIANCE`], a patch's emitted power stays far inside f32.
pub const MAX_PATCH_AREA: f32 = 1e14;

/// Smallest non-zero patch area (m²; the scene reader's smallest
/// primitive, 10⁻¹² of a 1 mm square): the distribution divides by a
/// patch's area, and 1/(π·A) of a denormal area is infinite (issue 42, §1).
pub const MIN_PATCH_AREA: f32 = 1e-18;

/// Smallest ray spacing (m): a patch's expected hits are at most
/// A·N/δ² (§7), so A·H/PEXP, the least area the distribution divides by,
/// is at least H·δ²/N; a tiny δ lifts that bound until any exposure
/// passes (a spacing of 10⁻²⁰ made infinite light, issue 42, §1).
pub const MIN_RAY_SPACING: f32 = 1e-6;

/// Largest coordinate magnitude (m) of a camera, primitive corner or
/// vertex: ray arithmetic with it stays finite in f32.
pub const MAX_COORDINATE: f32 = 1e9;

/// Whether rays can be made from a camera at `position` looking at
/// `look_at` with `up`: points within ±[`MAX_COORDINATE`] and at least
/// 10⁻⁶ m apart, and |f̂ × up| ≥ 10⁻⁶ for the unit view direction f̂ (a
/// tiny `up` is as bad as a parallel one). Computed in f64 from the f32 values, so that the
/// scene reader (every frame's camera) and the archive reader agree.
pub fn camera_is_usable(position: [f32; 3], look_at: [f32; 3], up: [f32; 3]) -> bool {
    let within = |v: &[f32; 3]| v.iter().all(|x| x.abs() <= MAX_COORDINATE);
    if !(within(&position) && within(&look_at) && within(&up)) {
        return false;
    }
    let f: [f64; 3] = std::array::from_fn(|i| look_at[i] as f64 - position[i] as f64);
    let u: [f64; 3] = std::array::from_fn(|i| up[i] as f64);
    let cross = [f[1] * u[2] - f[2] * u[1], f[2] * u[0] - f[0] * u[2], f[0] * u[1] - f[1] * u[0]];
    let len = |x: &[f64; 3]| (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt();
    // At least 1 µm between position and look_at: a shorter view vector's
    // squares underflow in f32 and its direction is NaN (found by fuzzing).
    len(&f) >= 1e-6 && len(&cross) >= 1e-6 * len(&f)
}

/// Largest side of a texture, in texels: the archive's `TXHD` rule
/// (format §5.15), which the glTF and OBJ importers apply to every image
/// they decode, so that a texture a scene accepts is one its build can
/// write (a 1 × 20 000 texture passed import and failed the build's end,
/// issue 42, §7).
pub const MAX_TEXTURE_SIDE: u32 = 16384;

/// Most texels an importer decodes in one texture (an 8192² image): its
/// memory, not the format, sets this bound.
pub const MAX_TEXTURE_TEXELS: u64 = 1 << 26;

/// Why an image of `width × height` texels cannot be a scene's texture
/// (`None` when it can): each side in 1..=[`MAX_TEXTURE_SIDE`], at most
/// [`MAX_TEXTURE_TEXELS`] in all. The importers' one rule, checked from
/// the image's header before it is decoded.
pub fn texture_size_problem(width: u32, height: u32) -> Option<String> {
    let side = 1..=MAX_TEXTURE_SIDE;
    if !(side.contains(&width) && side.contains(&height)) {
        return Some(format!("{width} × {height} texels, each side must be in 1..={MAX_TEXTURE_SIDE}"));
    }
    if width as u64 * height as u64 > MAX_TEXTURE_TEXELS {
        return Some(format!(
            "{width} × {height} texels, more than the {MAX_TEXTURE_TEXELS} (8192²) a texture may hold"
        ));
    }
    None
}

/// Largest scene-side file read whole (a TOML scene or camera file, an OBJ,
/// an MTL, a texture, a glTF file, its buffers and images), in bytes.
pub const MAX_INPUT_FILE: u64 = 8 << 30;

/// Opens `path` for reading if it is a regular file of at most `max_len`
/// bytes, and returns it with its length; anything else (a FIFO, a
/// character or block device such as `/dev/zero`, a directory, a socket)
/// is refused without blocking and without reading: the file is checked
/// with `stat` before it is opened, opened non-blocking (a FIFO put in
/// its place in between does not hang the open) and checked again. One
/// rule for every path a user gives (scene files, meshes, textures,
/// camera files, archives, images), so that none can hang a run or grow
/// a read without bound. The error says what the file is; callers name it.
pub fn open_regular(path: &std::path::Path, max_len: u64) -> std::io::Result<(std::fs::File, u64)> {
    use std::os::unix::fs::OpenOptionsExt;
    let refuse = |meta: &std::fs::Metadata| -> std::io::Result<u64> {
        use std::os::unix::fs::FileTypeExt;
        let t = meta.file_type();
        let kind = if t.is_file() {
            if meta.len() > max_len {
                return Err(std::io::Error::other(format!(
                    "is {} bytes, more than the {max_len} read at most",
                    meta.len()
                )));
            }
            return Ok(meta.len());
        } else if t.is_dir() {
            "a directory"
        } else if t.is_fifo() {
            "a FIFO (named pipe)"
        } else if t.is_char_device() {
            "a character device"
        } else if t.is_block_device() {
            "a block device"
        } else if t.is_socket() {
            "a socket"
        } else {
            "not a file"
        };
        Err(std::io::Error::other(format!("is {kind}, not a regular file")))
    };
    refuse(&std::fs::metadata(path)?)?;
    let file = std::fs::OpenOptions::new().read(true).custom_flags(libc::O_NONBLOCK).open(path)?;
    let len = refuse(&file.metadata()?)?;
    Ok((file, len))
}

/// Reads the whole of `path` through [`open_regular`]: at most `max_len`
/// bytes, even if the file grows while it is read.
pub fn read_regular(path: &std::path::Path, max_len: u64) -> std::io::Result<Vec<u8>> {
    use std::io::Read;
    let (file, len) = open_regular(path, max_len)?;
    let mut bytes = Vec::with_capacity(len as usize);
    file.take(max_len.saturating_add(1)).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max_len {
        return Err(std::io::Error::other(format!("grew past the {max_len} bytes read at most while read")));
    }
    Ok(bytes)
}

/// [`read_regular`] as UTF-8 text (an `InvalidData` error when it is not).
pub fn read_regular_text(path: &std::path::Path, max_len: u64) -> std::io::Result<String> {
    String::from_utf8(read_regular(path, max_len)?)
        .map_err(|_| std::io::Error::new(std::io::ErrorKind::InvalidData, "stream did not contain valid UTF-8"))
}
