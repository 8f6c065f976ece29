//! TOML scene text → [`Scene`], with errors that name file, line and field.

use std::fmt;
use std::ops::Range;
use std::path::{Path, PathBuf};

use glam::{Mat3, Vec3};
use serde::Deserialize;
use toml::Spanned;

use super::motion::{Animation, CameraKey, EmissionKey, Interpolation, Keyframe, Motion, rotation_from_degrees};
use super::{BuildHints, Camera, Material, ReflectanceModel, Scene, Surface};
use crate::geometry::{Primitive, PrimitiveKind};

/// A scene that could not be read: where, which field, and why.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneError {
    /// The scene file.
    pub file: PathBuf,
    /// 1-based line (0 when unknown, e.g. the file could not be read).
    pub line: usize,
    /// 1-based column (0 when unknown).
    pub column: usize,
    /// The offending field, e.g. `surface[3].quad` (empty when unknown).
    pub field: String,
    /// What is wrong.
    pub message: String,
    /// The file could not be read at all (an I/O failure, not a mistake
    /// in it): the CLI exits with its I/O code.
    pub unreadable: bool,
}

impl SceneError {
    pub(super) fn io(path: &Path, e: std::io::Error) -> Self {
        // Text that is not UTF-8 was read: a mistake in the file.
        let (message, unreadable) = match e.kind() {
            std::io::ErrorKind::InvalidData => ("is not UTF-8 text".to_string(), false),
            _ => (format!("cannot read: {e}"), true),
        };
        Self { file: path.into(), line: 0, column: 0, field: String::new(), message, unreadable }
    }
}

impl fmt::Display for SceneError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.display())?;
        if self.line > 0 {
            write!(f, ":{}:{}", self.line, self.column)?;
        }
        if !self.field.is_empty() {
            write!(f, ": field `{}`", self.field)?;
        }
        write!(f, ": {}", self.message)
    }
}

impl std::error::Error for SceneError {}

/// A TOML array of exactly `N` values: serde's fixed arrays take the first
/// `N` of a longer one without a word (`position = [1, 1, -2, 0]`).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Exact<T, const N: usize>([T; N]);

/// Three numbers: a point, a vector or an RGB triple.
type V3 = Exact<f32, 3>;

impl From<V3> for Vec3 {
    fn from(v: V3) -> Vec3 {
        Vec3::from(v.0)
    }
}

impl<T, const N: usize> std::ops::Deref for Exact<T, N> {
    type Target = [T; N];
    fn deref(&self) -> &[T; N] {
        &self.0
    }
}

impl<'de, T: Deserialize<'de>, const N: usize> Deserialize<'de> for Exact<T, N> {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let v = Vec::<T>::deserialize(d)?;
        let n = v.len();
        // Points and colours are lists of 3 numbers, quads of 4 corners.
        let expected = if N == 3 { format!("an array of length {N}") } else { format!("a list of {N} corners") };
        let a: [T; N] = v.try_into().map_err(|_| serde::de::Error::invalid_length(n, &expected.as_str()))?;
        Ok(Self(a))
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScene {
    camera: Option<Spanned<RawCamera>>,
    gltf: Option<Spanned<RawGltf>>,
    build: Option<Spanned<RawBuild>>,
    #[serde(default)]
    material: Vec<Spanned<RawMaterial>>,
    #[serde(default)]
    surface: Vec<Spanned<RawSurface>>,
    animation: Option<Spanned<RawAnimation>>,
}

/// `[gltf]`: a glTF file whose scene this one starts from.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawGltf {
    file: Spanned<String>,
    camera: Option<String>,
    light_radius: Option<Spanned<f32>>,
    fps: Option<Spanned<f32>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawAnimation {
    frames: Spanned<u32>,
    #[serde(default = "default_fps")]
    fps: Spanned<f32>,
}

fn default_fps() -> Spanned<f32> {
    Spanned::new(0..0, 24.0)
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawKeyframe {
    frame: u32,
    translate: Option<V3>,
    rotate_deg: Option<V3>,
    scale: Option<V3>,
}

/// `[camera]`: every field but `up` (default +Y) and `keyframes` is
/// required, except over a `[gltf]` scene, whose camera gives those left
/// out ([`camera_of`]).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCamera {
    position: Option<V3>,
    look_at: Option<V3>,
    up: Option<V3>,
    fov_y_deg: Option<Spanned<f32>>,
    width: Option<Spanned<u32>>,
    height: Option<Spanned<u32>>,
    keyframes: Option<Spanned<Vec<RawCameraKey>>>,
}

impl RawCamera {
    /// Whether the table gives a whole camera, needing none from a file.
    fn is_whole(&self) -> bool {
        self.position.is_some()
            && self.look_at.is_some()
            && self.fov_y_deg.is_some()
            && self.width.is_some()
            && self.height.is_some()
    }

    /// Whether the table says where the camera is or looks (so that a
    /// file camera's path no longer applies).
    fn places(&self) -> bool {
        self.position.is_some() || self.look_at.is_some() || self.up.is_some()
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCameraKey {
    frame: u32,
    position: V3,
    look_at: V3,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawEmissionKey {
    frame: u32,
    emission: V3,
}

/// Checks that keyed frames are in the sequence and strictly increasing.
fn check_key_frames(
    cx: &Ctx<'_>,
    frames: impl Iterator<Item = u32>,
    span: Range<usize>,
    field: &str,
    animation: &Option<Spanned<RawAnimation>>,
) -> Result<(), SceneError> {
    let Some(total) = animation.as_ref().map(|a| *a.get_ref().frames.get_ref()) else {
        return Err(cx.err(span, field, "keyframes need an [animation] table with `frames`"));
    };
    let mut prev: Option<u32> = None;
    for (i, f) in frames.enumerate() {
        if f >= total {
            return Err(cx.err(span, format!("{field}[{i}]"), format!("frame {f} is outside the sequence 0..{total}")));
        }
        if let Some(p) = prev
            && f <= p
        {
            return Err(cx.err(
                span,
                format!("{field}[{i}]"),
                format!("keyframes out of order: frame {f} follows frame {p}; list them by increasing frame"),
            ));
        }
        prev = Some(f);
    }
    Ok(())
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawBuild {
    patch_size: Option<Spanned<f32>>,
    frequency: Option<Spanned<u32>>,
    ray_spacing: Option<Spanned<f32>>,
    buckets: Option<Spanned<u32>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawMaterial {
    name: Spanned<String>,
    #[serde(rename = "type")]
    kind: Spanned<String>,
    reflectance: Option<Spanned<V3>>,
    specular: Option<Spanned<V3>>,
    alpha: Option<Spanned<f32>>,
    alpha_u: Option<Spanned<f32>>,
    alpha_v: Option<Spanned<f32>>,
    ior: Option<Spanned<Ior>>,
}

/// An index of refraction: one for all bands or one per band.
#[derive(Deserialize)]
#[serde(untagged)]
enum Ior {
    One(f32),
    Bands(V3),
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSurface {
    name: Spanned<String>,
    material: Spanned<String>,
    emission: Option<Spanned<V3>>,
    quad: Option<Spanned<Exact<V3, 4>>>,
    quads: Option<Spanned<Vec<Exact<V3, 4>>>>,
    #[serde(rename = "box")]
    cuboid: Option<Spanned<RawBox>>,
    mesh: Option<Spanned<String>>,
    transform: Option<Spanned<RawTransform>>,
    keyframes: Option<Spanned<Vec<RawKeyframe>>>,
    emission_keyframes: Option<Spanned<Vec<RawEmissionKey>>>,
    interpolation: Option<Spanned<String>>,
    pivot: Option<Spanned<V3>>,
    grain: Option<Spanned<V3>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawBox {
    min: V3,
    max: V3,
    #[serde(default)]
    inward: bool,
    #[serde(default)]
    omit: Vec<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTransform {
    scale: Option<V3>,
    rotate_deg: Option<V3>,
    translate: Option<V3>,
}

struct Ctx<'a> {
    text: &'a str,
    file: &'a Path,
}

impl Ctx<'_> {
    /// The text as `T`, a TOML error naming its line, column and field
    /// in plain words.
    fn deserialize<T: serde::de::DeserializeOwned>(&self) -> Result<T, SceneError> {
        toml::from_str(self.text).map_err(|e| {
            let span = e.span().unwrap_or(0..0);
            let field = field_at(self.text, span.start);
            let key = field.rsplit(['.', ']']).next().unwrap_or("").to_string();
            self.err(span, field, plain_message(e.message().trim(), &key))
        })
    }

    fn err(&self, span: Range<usize>, field: impl Into<String>, message: impl Into<String>) -> SceneError {
        let (line, column) = line_col(self.text, span.start);
        SceneError {
            file: self.file.into(),
            line,
            column,
            field: field.into(),
            message: message.into(),
            unreadable: false,
        }
    }
}

fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(text.len());
    let before = &text.as_bytes()[..offset];
    let line = before.iter().filter(|&&b| b == b'\n').count() + 1;
    let column = offset - before.iter().rposition(|&b| b == b'\n').map_or(0, |p| p + 1) + 1;
    (line, column)
}

/// The dotted path of the key whose value is at byte `offset` of `text`
/// (e.g. `surface[2].box.min`), from the table headers above it and the
/// keys on its line; empty when none is found. The TOML parser's errors
/// give a position only, and users look for a field.
fn field_at(text: &str, offset: usize) -> String {
    let offset = offset.min(text.len());
    let line_start = text[..offset].rfind('\n').map_or(0, |p| p + 1);
    // The table header in force, with the index of array tables.
    let mut header = String::new();
    let mut counts: Vec<(String, usize)> = Vec::new();
    // Brackets open at the start of each line (outside strings and
    // comments): a line inside a multi-line array is no table header.
    let mut depth = 0i32;
    // The line of the last key that began outside any bracket: the one a
    // value continued over several lines belongs to.
    let mut outer_start = 0..0;
    let mut at = 0;
    for raw in text[..line_start].split_inclusive('\n') {
        let (line, start) = (raw.trim(), at);
        at += raw.len();
        let open = depth;
        if open == 0
            && let Some((k, _)) = line.split_once('=')
            && !k.trim().is_empty()
            && k.trim().chars().all(|c| c.is_alphanumeric() || c == '_' || c == '-' || c == '.' || c == ' ')
        {
            outer_start = start..at;
        }
        for c in code_chars(line) {
            match c {
                '[' | '{' => depth += 1,
                ']' | '}' => depth -= 1,
                _ => {}
            }
        }
        if open > 0 {
            continue;
        }
        // A header line's own brackets balance.
        if line.starts_with('[') {
            depth = 0;
        }
        if let Some(name) = line.strip_prefix("[[").and_then(|l| l.split("]]").next()) {
            let name = name.trim().to_string();
            let n = match counts.iter_mut().find(|(k, _)| *k == name) {
                Some((_, n)) => {
                    *n += 1;
                    *n
                }
                None => {
                    counts.push((name.clone(), 0));
                    0
                }
            };
            header = format!("{name}[{n}]");
        } else if let Some(name) = line.strip_prefix('[').and_then(|l| l.split(']').next()) {
            header = name.trim().to_string();
        }
    }
    // Keys on the line up to the offset, nested by inline tables and
    // arrays (an inline table in an array is named by its index); if none
    // comes before it (a duplicate key is reported at the line's start),
    // the line's first key; if the line has none (a value continued from
    // the line above), the nearest key above.
    let keys = |segment: &str| {
        let mut p = KeyPath::default();
        p.feed(segment);
        p.path(None, false)
    };
    let line_end = text[offset..].find('\n').map_or(text.len(), |p| offset + p);
    // The error is in a table header itself (a table given twice).
    if depth <= 0
        && let Some(name) = text[line_start..line_end].trim().strip_prefix('[')
    {
        return name.trim_start_matches('[').split(']').next().unwrap_or("").trim().to_string();
    }
    // A key that starts at the offset (an unknown field is reported at
    // its key) names the field itself.
    let word: String =
        text[offset..].chars().take_while(|&c| c.is_alphanumeric() || c == '_' || c == '-' || c == '.').collect();
    let at_key = (!word.is_empty() && text[offset + word.len()..].trim_start().starts_with('=')).then_some(word);
    // An error about a whole inline table (a field it lacks) is reported
    // at its brace.
    let at_table = text[offset..].starts_with('{');
    let mut path = if depth > 0 && !outer_start.is_empty() {
        // Inside a value continued from above: the path from its key on,
        // line by line.
        let mut p = KeyPath::default();
        for line in text[outer_start.start..offset].split_inclusive('\n') {
            p.feed(line);
        }
        p.path(at_key.clone(), at_table)
    } else {
        let mut p = KeyPath::default();
        p.feed(&text[line_start..offset]);
        p.path(at_key.clone(), at_table)
    };
    if path.is_empty() {
        path = keys(&text[line_start..line_end]).into_iter().take(1).collect();
    }
    if path.is_empty() {
        path = text[..line_start]
            .lines()
            .rev()
            .take_while(|l| !l.trim_start().starts_with('['))
            .map(keys)
            .find(|k| !k.is_empty())
            .map(|k| k.into_iter().take(1).collect())
            .unwrap_or_default();
    }
    let tail = path.join(".");
    match (header.is_empty(), tail.is_empty()) {
        (true, _) => tail,
        (false, true) => header,
        (false, false) => format!("{header}.{tail}"),
    }
}

/// Where a position in TOML text lies among the inline tables and arrays
/// of a value, fed the text before it line by line.
#[derive(Default)]
struct KeyPath {
    /// Open inline tables (named by their key; empty: an array's element)
    /// and arrays (their key and the element at hand).
    open: Vec<(String, Option<usize>)>,
    /// The key whose value is being read.
    last: Option<String>,
    word: String,
}

impl KeyPath {
    fn feed(&mut self, line: &str) {
        for c in code_chars(line) {
            match c {
                // A dotted key (`camera.width`) is one path; a number's
                // dot never reaches a key (only a word before `=` does).
                c if c.is_alphanumeric() || c == '_' || c == '-' || c == '.' => self.word.push(c),
                '=' => {
                    if !self.word.is_empty() {
                        self.last = Some(std::mem::take(&mut self.word));
                    }
                }
                '{' | '[' => {
                    self.word.clear();
                    let key = self.last.take().unwrap_or_default();
                    self.open.push((key, (c == '[').then_some(0)));
                }
                '}' | ']' => {
                    self.word.clear();
                    self.open.pop();
                    self.last = None;
                }
                ',' => {
                    self.word.clear();
                    if let Some((_, Some(i))) = self.open.last_mut() {
                        *i += 1;
                    }
                }
                c if c.is_whitespace() => {}
                _ => self.word.clear(),
            }
        }
    }

    /// The keys down to the position (`key`: one that starts there;
    /// `at_table`: an inline table starts there): an array holding inline
    /// tables gives its element's index.
    fn path(&self, key: Option<String>, at_table: bool) -> Vec<String> {
        let mut out = Vec::new();
        for (i, (k, element)) in self.open.iter().enumerate() {
            let table_inside = self.open.get(i + 1).map_or(at_table, |n| n.1.is_none());
            match element {
                Some(e) if table_inside && !k.is_empty() => out.push(format!("{k}[{e}]")),
                _ if !k.is_empty() => out.push(k.clone()),
                _ => {}
            }
        }
        // A key that starts at the position after a dotted prefix
        // (`camera.` of `camera.fovv`) is named with it.
        let key = key.map(|k| if self.word.ends_with('.') { format!("{}{k}", self.word) } else { k });
        out.extend(key.or_else(|| self.last.clone()));
        out
    }
}

/// The characters of a TOML line outside strings (each string stands as
/// one `"`) up to a `#` comment.
fn code_chars(line: &str) -> impl Iterator<Item = char> + '_ {
    let (mut quote, mut escaped) = (None, false);
    line.chars()
        .filter_map(move |c| match (quote, c) {
            // A basic string's escape (`\"`, `\\`): the next character is
            // the string's.
            (Some('"'), _) if escaped => {
                escaped = false;
                None
            }
            (Some('"'), '\\') => {
                escaped = true;
                None
            }
            (Some(q), c) if c == q => {
                quote = None;
                None
            }
            (Some(_), _) => None,
            (None, '"' | '\'') => {
                quote = Some(c);
                Some('"')
            }
            _ => Some(c),
        })
        .take_while(|&c| c != '#')
}

/// The TOML parser's message in plain words: no Rust type names.
fn plain_message(message: &str, key: &str) -> String {
    if message == "duplicate key" {
        return if key.is_empty() { "a key is given twice".into() } else { format!("`{key}` is given twice") };
    }
    let words = |expected: &str| -> String {
        let e = expected.trim();
        match e {
            "u8" | "u16" | "u32" | "u64" | "usize" | "i32" | "i64" => "a whole number".into(),
            "f32" | "f64" => "a number".into(),
            "a sequence" => "a list in brackets, like [1, 2, 3]".into(),
            "a boolean" => "true or false".into(),
            "a string" => "a quoted string".into(),
            _ if e.starts_with("an array of length ") => {
                format!("a list of {} numbers, like [1, 2, 3]", e.trim_start_matches("an array of length "))
            }
            _ if e.starts_with("struct ") || e == "a map" || e.starts_with("a map") => "a table".into(),
            _ => e.to_string(),
        }
    };
    if let Some(rest) = message.strip_prefix("invalid length ")
        && let Some((got, expected)) = rest.split_once(", expected ")
    {
        return format!("expected {}, got {got} values", words(expected));
    }
    // A whole number out of its type's range.
    if let Some(rest) = message.strip_prefix("invalid value: integer ")
        && let Some((got, expected)) = rest.split_once(", expected ")
    {
        let range = match expected.trim() {
            "u8" => " from 0 to 255",
            "u16" => " from 0 to 65535",
            "u32" => " from 0 to 4294967295",
            "i32" => " from -2147483648 to 2147483647",
            _ => "",
        };
        let got = got.replace('`', "");
        if got.starts_with('-') && expected.trim().starts_with('u') {
            return format!("expected {}, not a negative one, got {got}", words(expected));
        }
        return format!("expected {}{range}, got {got}", words(expected));
    }
    if let Some(rest) = message.strip_prefix("invalid type: ")
        && let Some((got, expected)) = rest.split_once(", expected ")
    {
        let got = got
            .replace("floating point ", "")
            .replace("integer ", "")
            .replace("string ", "")
            .replace("boolean ", "")
            .replace('`', "");
        let got = match got.as_str() {
            "sequence" => "a list".to_string(),
            "map" => "a table".to_string(),
            other => other.to_string(),
        };
        return format!("expected {}, got {got}", words(expected));
    }
    message.to_string()
}

/// Finite and within ±[`crate::limits::MAX_COORDINATE`].
fn finite3(v: &[f32; 3]) -> bool {
    v.iter().all(|x| x.abs() <= crate::limits::MAX_COORDINATE)
}

pub(super) fn parse(text: &str, file: &Path, base_dir: &Path, name: String) -> Result<Scene, SceneError> {
    let cx = Ctx { text, file };
    let raw: RawScene = cx.deserialize()?;

    // A glTF file to start from: its materials and surfaces come first; this
    // file's override materials of the same name and add the rest.
    let imported = match &raw.gltf {
        None => None,
        Some(g) => {
            let (path, options) = gltf_source(&cx, g, &raw.animation, &raw.camera, base_dir)?;
            Some(super::gltf::import_unchecked(&path, &options).map_err(|e| at_gltf_file(&cx, g, &path, e))?)
        }
    };
    let (camera, camera_keys) = match (&raw.camera, &imported) {
        (Some(c), g) => camera_of(&cx, c, &raw.animation, g.as_ref().map(|g| (&g.camera, &g.camera_keys[..])), true)?,
        (None, Some(g)) => (g.camera, g.camera_keys.clone()),
        (None, None) => return Err(cx.err(0..0, "camera", "the scene has no [camera] table")),
    };

    // Build hints.
    let mut build = BuildHints::default();
    if let Some(b) = &raw.build {
        let b = b.get_ref();
        if let Some(p) = &b.patch_size {
            if !(p.get_ref().is_finite() && *p.get_ref() > 0.0) {
                return Err(cx.err(p.span(), "build.patch_size", "must be a positive length in metres"));
            }
            build.patch_size = Some(*p.get_ref());
        }
        if let Some(r) = &b.ray_spacing {
            if !(r.get_ref().is_finite() && *r.get_ref() >= crate::limits::MIN_RAY_SPACING) {
                return Err(cx.err(r.span(), "build.ray_spacing", "must be a length of at least 1e-6 metres"));
            }
            build.ray_spacing = Some(*r.get_ref());
        }
        if let Some(k) = &b.buckets {
            if *k.get_ref() > crate::limits::MAX_BUCKET {
                return Err(cx.err(k.span(), "build.buckets", format!("must be in 0..={}", crate::limits::MAX_BUCKET)));
            }
            build.buckets = Some(*k.get_ref());
        }
        if let Some(f) = &b.frequency {
            if !(1..=crate::limits::MAX_FREQUENCY).contains(f.get_ref()) {
                return Err(cx.err(
                    f.span(),
                    "build.frequency",
                    format!("must be in 1..={}", crate::limits::MAX_FREQUENCY),
                ));
            }
            build.frequency = Some(*f.get_ref());
        }
    }

    // Materials.
    let mut materials: Vec<Material> = imported.as_ref().map_or_else(Vec::new, |g| g.materials.clone());
    let from_gltf = materials.len();
    for (i, m) in raw.material.iter().enumerate() {
        let m = m.get_ref();
        let field = |f: &str| format!("material[{i}].{f}");
        if materials[from_gltf..].iter().any(|x| x.name == *m.name.get_ref()) {
            return Err(cx.err(
                m.name.span(),
                field("name"),
                format!("duplicate material name `{}`", m.name.get_ref()),
            ));
        }
        let unit_rgb = |v: &Option<Spanned<V3>>, key: &str, what: &str| -> Result<[f32; 3], SceneError> {
            let r = v.as_ref().ok_or_else(|| {
                cx.err(m.kind.span(), field(key), format!("a {} material needs `{key} = [r, g, b]`", m.kind.get_ref()))
            })?;
            if !r.get_ref().iter().all(|x| (0.0..=1.0).contains(x)) {
                return Err(cx.err(r.span(), field(key), format!("each component of {what} must be in [0, 1]")));
            }
            Ok(r.get_ref().0)
        };
        let lobe = || -> Result<crate::reflectance::Lobe, SceneError> {
            let check = |a: &Spanned<f32>, key: &str| {
                let x = *a.get_ref();
                if (0.01..=1.0).contains(&x) {
                    Ok(x)
                } else {
                    Err(cx.err(a.span(), field(key), "roughness must be in [0.01, 1]"))
                }
            };
            let (au, av) = match (&m.alpha, &m.alpha_u, &m.alpha_v) {
                (Some(a), None, None) => (check(a, "alpha")?, check(a, "alpha")?),
                (None, Some(u), Some(v)) => (check(u, "alpha_u")?, check(v, "alpha_v")?),
                (Some(a), _, _) => {
                    return Err(cx.err(a.span(), field("alpha"), "give `alpha` or `alpha_u` and `alpha_v`, not both"));
                }
                _ => {
                    return Err(cx.err(
                        m.kind.span(),
                        field("alpha"),
                        "a glossy material needs `alpha = a` (isotropic) or `alpha_u` and `alpha_v`",
                    ));
                }
            };
            let ior = match &m.ior {
                None => None,
                Some(i) => {
                    let v = match i.get_ref() {
                        Ior::One(x) => [*x; 3],
                        Ior::Bands(b) => b.0,
                    };
                    if !v.iter().all(|x| x.is_finite() && *x > 0.0) {
                        return Err(cx.err(i.span(), field("ior"), "an index of refraction must be positive"));
                    }
                    Some(v)
                }
            };
            Ok(crate::reflectance::Lobe { alpha_u: au, alpha_v: av, ior })
        };
        let unused = |present: bool, key: &str| -> Result<(), SceneError> {
            if present {
                Err(cx.err(m.kind.span(), field(key), format!("a {} material has no `{key}`", m.kind.get_ref())))
            } else {
                Ok(())
            }
        };
        let model = match m.kind.get_ref().as_str() {
            "diffuse" => {
                unused(m.specular.is_some(), "specular")?;
                unused(m.alpha.is_some() || m.alpha_u.is_some() || m.alpha_v.is_some(), "alpha")?;
                unused(m.ior.is_some(), "ior")?;
                ReflectanceModel::Diffuse { reflectance: unit_rgb(&m.reflectance, "reflectance", "a reflectance")? }
            }
            "rough_conductor" => {
                unused(m.reflectance.is_some(), "reflectance")?;
                ReflectanceModel::RoughConductor {
                    specular: unit_rgb(&m.specular, "specular", "a specular colour")?,
                    lobe: lobe()?,
                }
            }
            "broad_specular" => {
                let kd = unit_rgb(&m.reflectance, "reflectance", "a reflectance")?;
                let ks = unit_rgb(&m.specular, "specular", "a specular colour")?;
                if !crate::limits::conserves_energy(kd, ks) {
                    return Err(cx.err(
                        m.specular.as_ref().map_or(m.kind.span(), |s| s.span()),
                        field("specular"),
                        "reflectance + specular must not exceed 1 in any band (the surface would create energy)",
                    ));
                }
                ReflectanceModel::BroadSpecular { reflectance: kd, specular: ks, lobe: lobe()? }
            }
            other => {
                return Err(cx.err(
                    m.kind.span(),
                    field("type"),
                    format!("unknown material type `{other}` (known: diffuse, rough_conductor, broad_specular)"),
                ));
            }
        };
        match materials[..from_gltf].iter_mut().find(|x| x.name == *m.name.get_ref()) {
            Some(overridden) => overridden.model = model,
            None => materials.push(Material { name: m.name.get_ref().clone(), model }),
        }
    }

    // Surfaces.
    let mut surfaces: Vec<Surface> = imported.as_ref().map_or_else(Vec::new, |g| g.surfaces.clone());
    for (i, s) in raw.surface.iter().enumerate() {
        let sspan = s.span();
        let s = s.get_ref();
        let field = |f: &str| format!("surface[{i}].{f}");
        let name = s.name.get_ref().clone();
        if surfaces.iter().any(|x| x.name == name) {
            return Err(cx.err(s.name.span(), field("name"), format!("duplicate surface name `{name}`")));
        }
        let material = materials.iter().position(|m| m.name == *s.material.get_ref()).ok_or_else(|| {
            let known: Vec<&str> = materials.iter().map(|m| m.name.as_str()).collect();
            cx.err(
                s.material.span(),
                field("material"),
                format!("no material named `{}` (known: {})", s.material.get_ref(), known.join(", ")),
            )
        })? as u32;
        let emission = match &s.emission {
            Some(e) => {
                if !e.get_ref().iter().all(|x| (0.0..=crate::limits::MAX_RADIANCE).contains(x)) {
                    return Err(cx.err(e.span(), field("emission"), "each component must be in [0, 1e9] W·sr⁻¹·m⁻²"));
                }
                e.get_ref().0
            }
            None => [0.0; 3],
        };
        let given = [s.quad.is_some(), s.quads.is_some(), s.cuboid.is_some(), s.mesh.is_some()];
        if given.iter().filter(|&&g| g).count() != 1 {
            return Err(cx.err(sspan, field("quad"), "give exactly one of `quad`, `quads`, `box` or `mesh`"));
        }
        let mut prims: Vec<Primitive> = Vec::new();
        let mut geometry_span = sspan.clone();
        let mut geometry_field = field("quad");
        if let Some(q) = &s.quad {
            prims.push(Primitive::quad(q.get_ref().0.map(Vec3::from)));
            geometry_span = q.span();
        }
        if let Some(qs) = &s.quads {
            prims.extend(qs.get_ref().iter().map(|q| Primitive::quad(q.map(Vec3::from))));
            geometry_span = qs.span();
            geometry_field = field("quads");
        }
        if let Some(b) = &s.cuboid {
            geometry_span = b.span();
            geometry_field = field("box");
            prims.extend(box_quads(b.get_ref()).map_err(|m| cx.err(b.span(), field("box"), m))?);
        }
        if let Some(m) = &s.mesh {
            geometry_span = m.span();
            geometry_field = field("mesh");
            let path = base_dir.join(m.get_ref());
            // (A file that is not there is an I/O failure, still named at
            // its field.)
            prims.extend(load_obj(&path).map_err(|msg| SceneError {
                unreadable: std::fs::metadata(&path).is_err(),
                ..cx.err(m.span(), field("mesh"), msg)
            })?);
        }
        if let Some(t) = &s.transform {
            let m = transform_matrix(t.get_ref()).map_err(|msg| cx.err(t.span(), field("transform"), msg))?;
            let mirrored = m.0.determinant() < 0.0;
            for p in &mut prims {
                for v in &mut p.p {
                    *v = m.0 * *v + m.1;
                }
                if mirrored {
                    // A mirroring scale reverses the winding: restore the front side.
                    *p = match p.kind {
                        PrimitiveKind::Quad => Primitive::quad([p.p[3], p.p[2], p.p[1], p.p[0]]),
                        PrimitiveKind::Triangle => Primitive::triangle(p.p[0], p.p[2], p.p[1]),
                    };
                }
            }
        }
        for (k, p) in prims.iter().enumerate() {
            check_primitive(p).map_err(|msg| {
                cx.err(geometry_span.clone(), geometry_field.clone(), format!("primitive {k}: {msg}"))
            })?;
        }
        if prims.is_empty() {
            return Err(cx.err(geometry_span, geometry_field, "the surface has no primitives"));
        }
        let motion = parse_motion(&cx, s, &raw.animation, &field)?;
        let mut emission_keys = Vec::new();
        if let Some(keys) = &s.emission_keyframes {
            check_key_frames(
                &cx,
                keys.get_ref().iter().map(|k| k.frame),
                keys.span(),
                &field("emission_keyframes"),
                &raw.animation,
            )?;
            for k in keys.get_ref() {
                if !k.emission.iter().all(|x| (0.0..=crate::limits::MAX_RADIANCE).contains(x)) {
                    return Err(cx.err(
                        keys.span(),
                        field("emission_keyframes"),
                        "emission must be in [0, 1e9] W·sr⁻¹·m⁻²",
                    ));
                }
                emission_keys.push(EmissionKey { frame: k.frame, emission: Vec3::from(k.emission) });
            }
        }
        let grain = match &s.grain {
            None => None,
            Some(g) => {
                let v = Vec3::from(*g.get_ref());
                if !v.is_finite() || v.length() < 1e-6 {
                    return Err(cx.err(g.span(), field("grain"), "the grain must be a non-zero direction"));
                }
                // Local coordinates: the surface's transform applies.
                let v = match &s.transform {
                    Some(t) => transform_matrix(t.get_ref()).map(|m| m.0 * v).unwrap_or(v),
                    None => v,
                };
                Some(v.normalize())
            }
        };
        surfaces.push(Surface {
            name,
            material,
            emission,
            primitives: prims,
            motion,
            emission_keys,
            grain,
            moved: false,
            shading: Vec::new(),
        });
    }
    if surfaces.is_empty() {
        return Err(cx.err(0..0, "surface", "the scene has no surfaces"));
    }
    // Over a glTF scene, a material of this file overrides the glTF's of
    // its name, or is new for this file's surfaces: one that does neither
    // is a misspelt override, which would change nothing.
    if imported.is_some() {
        for (i, m) in raw.material.iter().enumerate() {
            let name = m.get_ref().name.get_ref();
            let at = materials.iter().position(|x| x.name == *name).expect("every material was added");
            if at >= from_gltf && !surfaces.iter().any(|s| s.material as usize == at) {
                let known: Vec<&str> = materials[..from_gltf].iter().map(|x| x.name.as_str()).collect();
                return Err(cx.err(
                    m.get_ref().name.span(),
                    format!("material[{i}].name"),
                    format!(
                        "`{name}` names no material of the glTF file ({}) and no surface uses it: a misspelt override?",
                        if known.is_empty() { "it has none".to_string() } else { known.join(", ") }
                    ),
                ));
            }
        }
    }
    let animation = match &raw.animation {
        None if imported.is_some() => imported.as_ref().and_then(|g| g.animation),
        Some(a) => {
            let (frames, fps) = (a.get_ref().frames.get_ref(), a.get_ref().fps.get_ref());
            if !(1..=100_000).contains(frames) {
                return Err(cx.err(a.get_ref().frames.span(), "animation.frames", "must be in 1..=100000"));
            }
            if !(fps.is_finite() && *fps > 0.0) {
                return Err(cx.err(a.get_ref().fps.span(), "animation.fps", "must be positive"));
            }
            Some(Animation { frames: *frames, fps: *fps })
        }
        None => None,
    };
    let (notes, textures) = imported.map_or_else(Default::default, |g| (g.notes, g.textures));
    let scene = Scene { name, materials, surfaces, camera, build, animation, camera_keys, notes, textures };
    Ok(scene)
}

/// The `[camera]` table (and its keyframes, which need `[animation]`),
/// checked: every frame's camera, between keys too, can make rays (the
/// archive reader's rule). Over a glTF scene (`file`: its camera and
/// keys) the fields the table leaves out are the file camera's: the width
/// alone sets the height by the file camera's aspect ratio (and the height
/// alone the width), `up` is the file's only with its position and
/// look_at, and the file camera's path stays unless the table places the
/// camera (`position`, `look_at` or `up`). `scene`: read from a scene
/// (else a camera file, read alone), for what a missing field's error
/// says.
fn camera_of(
    cx: &Ctx<'_>,
    raw: &Spanned<RawCamera>,
    animation: &Option<Spanned<RawAnimation>>,
    file: Option<(&Camera, &[CameraKey])>,
    scene: bool,
) -> Result<(Camera, Vec<CameraKey>), SceneError> {
    // Camera.
    let c = raw.get_ref();
    let cspan = raw.span();
    // Only without a file camera, which gives every field.
    let missing = |field: &str| {
        let why = format!(
            "missing field `{field}` (a [camera] needs position, look_at, fov_y_deg, width and height{})",
            match file {
                Some(_) => "",
                None if scene => "; over a [gltf] scene, the file's camera gives those left out",
                None => "; a camera file is read alone, so its [camera] gives them all",
            }
        );
        cx.err(cspan.clone(), format!("camera.{field}"), why)
    };
    let pick = |v: &Option<V3>, of_file: fn(&Camera) -> Vec3, field: &str| match (v, file) {
        (Some(v), _) => Ok(Vec3::from(*v)),
        (None, Some((f, _))) => Ok(of_file(f)),
        (None, None) if field == "up" => Ok(Vec3::Y),
        (None, None) => Err(missing(field)),
    };
    let position = pick(&c.position, |f| f.position, "position")?;
    let look_at = pick(&c.look_at, |f| f.look_at, "look_at")?;
    // The file's `up` goes with its view only: a table that says where
    // the camera is or looks has `up`'s default.
    let up = match (&c.up, c.position.is_some() || c.look_at.is_some()) {
        (None, true) => Vec3::Y,
        _ => pick(&c.up, |f| f.up, "up")?,
    };
    if !finite3(&position.to_array()) || !finite3(&look_at.to_array()) || !finite3(&up.to_array()) {
        return Err(cx.err(cspan, "camera", "position, look_at and up must be finite and within ±1e9 m"));
    }
    let forward = look_at - position;
    if forward.length() <= 0.0 || forward.normalize().cross(up).length() < 1e-6 {
        return Err(cx.err(
            cspan,
            "camera.up",
            "look_at must differ from position, and up must not be parallel to the view direction",
        ));
    }
    let fov = match (&c.fov_y_deg, file) {
        (Some(v), _) => {
            let fov = *v.get_ref();
            if !(fov > 0.0 && fov < 180.0) {
                return Err(cx.err(v.span(), "camera.fov_y_deg", format!("must be in (0, 180) degrees, got {fov}")));
            }
            fov
        }
        (None, Some((f, _))) => f.fov_y_deg,
        (None, None) => return Err(missing("fov_y_deg")),
    };
    for (v, f) in [(&c.width, "camera.width"), (&c.height, "camera.height")] {
        if let Some(v) = v
            && !(1..=16384).contains(v.get_ref())
        {
            return Err(cx.err(v.span(), f, format!("must be in 1..=16384 pixels, got {}", v.get_ref())));
        }
    }
    // One side given over a file camera: the other keeps its aspect ratio.
    let scaled = |n: u32, ratio: f64| ((n as f64 * ratio).round() as u32).clamp(1, 16384);
    let (width, height) = match (c.width.as_ref().map(|v| *v.get_ref()), c.height.as_ref().map(|v| *v.get_ref()), file)
    {
        (Some(w), Some(h), _) => (w, h),
        (Some(w), None, Some((f, _))) => (w, scaled(w, f.height as f64 / f.width as f64)),
        (None, Some(h), Some((f, _))) => (scaled(h, f.width as f64 / f.height as f64), h),
        (None, None, Some((f, _))) => (f.width, f.height),
        (None, _, None) => return Err(missing("width")),
        (_, None, None) => return Err(missing("height")),
    };
    let camera = Camera { position, look_at, up, fov_y_deg: fov, width, height };

    // A file camera's path, unless the table places the camera.
    let mut camera_keys = match (file, &c.keyframes) {
        (Some((_, keys)), None) if !c.places() => keys.to_vec(),
        _ => Vec::new(),
    };
    if let Some(keys) = &raw.get_ref().keyframes {
        check_key_frames(cx, keys.get_ref().iter().map(|k| k.frame), keys.span(), "camera.keyframes", animation)?;
        for k in keys.get_ref() {
            let (p, l) = (Vec3::from(k.position), Vec3::from(k.look_at));
            if !(finite3(&p.to_array()) && finite3(&l.to_array()))
                || (l - p).normalize_or_zero().cross(camera.up).length() < 1e-6
            {
                return Err(cx.err(
                    keys.span(),
                    "camera.keyframes",
                    "position and look_at must be finite (within ±1e9 m), distinct and not along `up`",
                ));
            }
            camera_keys.push(CameraKey { frame: k.frame, position: p, look_at: l, up: camera.up });
        }
    }
    let frames = animation.as_ref().map_or(1, |a| *a.get_ref().frames.get_ref());
    if let Some(f) = (0..frames).find(|&f| {
        let c = super::camera_at(&camera, &camera_keys, f);
        !crate::limits::camera_is_usable(c.position.to_array(), c.look_at.to_array(), c.up.to_array())
    }) {
        let (span, field) = match &raw.get_ref().keyframes {
            Some(k) => (k.span(), "camera.keyframes"),
            None => (raw.span(), "camera"),
        };
        return Err(cx.err(
            span,
            field,
            format!(
                "at frame {f} the camera looks along `up`, or from its look_at point (or beyond ±1e9 m): \
                 no rays can be made"
            ),
        ));
    }
    Ok((camera, camera_keys))
}

/// The glTF file a `[gltf]` table names (resolved against `base_dir`) and
/// the import options it gives, checked: a scene over a glTF file takes
/// its frames from the file, so has no `[animation]`; a whole `[camera]`
/// replaces the file's (no camera is looked up by name), a partial one
/// takes the rest from the camera named.
fn gltf_source(
    cx: &Ctx<'_>,
    g: &Spanned<RawGltf>,
    animation: &Option<Spanned<RawAnimation>>,
    camera: &Option<Spanned<RawCamera>>,
    base_dir: &Path,
) -> Result<(std::path::PathBuf, super::GltfOptions), SceneError> {
    let gs = g.get_ref();
    if let Some(a) = animation {
        return Err(cx.err(
            a.span(),
            "animation",
            "a scene with [gltf] takes its frames from the glTF file's animation (set its rate with [gltf] fps)",
        ));
    }
    let positive = |v: &Option<Spanned<f32>>, key: &str| -> Result<Option<f32>, SceneError> {
        match v {
            Some(x) if !(x.get_ref().is_finite() && *x.get_ref() > 0.0) => {
                Err(cx.err(x.span(), format!("gltf.{key}"), "must be a positive number"))
            }
            Some(x) => Ok(Some(*x.get_ref())),
            None => Ok(None),
        }
    };
    let options = super::GltfOptions {
        camera: if camera.as_ref().is_some_and(|c| c.get_ref().is_whole()) { None } else { gs.camera.clone() },
        light_radius: positive(&gs.light_radius, "light_radius")?,
        fps: positive(&gs.fps, "fps")?,
    };
    let path = base_dir.join(gs.file.get_ref());
    if !super::gltf::is_gltf_path(&path) {
        return Err(cx.err(gs.file.span(), "gltf.file", "must name a .gltf or .glb file"));
    }
    Ok((path, options))
}

/// An error importing the glTF file at `path` that `[gltf]` names: one
/// that cannot be read is named at the field naming it.
fn at_gltf_file(cx: &Ctx<'_>, g: &Spanned<RawGltf>, path: &Path, e: SceneError) -> SceneError {
    let file = &g.get_ref().file;
    match e.unreadable {
        true => SceneError {
            unreadable: true,
            ..cx.err(file.span(), "gltf.file", format!("`{}` {}", path.display(), e.message))
        },
        false => e,
    }
}

/// A file's `[camera]` (with its keyframes and `[animation]` frame count),
/// the rest of the file ignored: a scene file, or a camera file of those
/// two tables alone. With `[gltf]`, a partial or missing `[camera]` is
/// completed from the glTF file's camera, as in a scene.
#[derive(Deserialize)]
struct RawCameraFile {
    camera: Option<Spanned<RawCamera>>,
    animation: Option<Spanned<RawAnimation>>,
    gltf: Option<Spanned<RawGltf>>,
}

pub(super) fn parse_camera(text: &str, file: &Path, base_dir: &Path) -> Result<super::CameraPath, SceneError> {
    let cx = Ctx { text, file };
    let raw: RawCameraFile = cx.deserialize()?;
    let whole = raw.camera.as_ref().is_some_and(|c| c.get_ref().is_whole());
    if let (Some(g), false) = (&raw.gltf, whole) {
        // Only the camera is read from the glTF file, not its meshes.
        let (path, options) = gltf_source(&cx, g, &raw.animation, &raw.camera, base_dir)?;
        let Some(f) = super::gltf::import_camera_if_any(&path, &options).map_err(|e| at_gltf_file(&cx, g, &path, e))?
        else {
            // No camera in the file: the scene's, which frames its geometry.
            let s = super::Scene::from_toml(text, file, base_dir)?;
            return Ok(super::CameraPath { frames: s.frame_count(), camera: s.camera, keys: s.camera_keys });
        };
        let (camera, keys) = match &raw.camera {
            Some(c) => camera_of(&cx, c, &None, Some((&f.camera, &f.keys[..])), true)?,
            None => (f.camera, f.keys),
        };
        return Ok(super::CameraPath { camera, keys, frames: f.frames });
    }
    let Some(c) = &raw.camera else {
        return Err(cx.err(0..0, "camera", "the file has no [camera] table (nor a [gltf] file to take one from)"));
    };
    let (camera, keys) = camera_of(&cx, c, &raw.animation, None, false)?;
    let frames = raw.animation.as_ref().map_or(1, |a| *a.get_ref().frames.get_ref());
    Ok(super::CameraPath { camera, keys, frames })
}

/// Rejects non-finite, degenerate, non-planar and non-convex primitives.
pub(super) fn check_primitive(p: &Primitive) -> Result<(), String> {
    let n = p.corner_count();
    if !p.p[..n].iter().all(|v| v.abs().max_element() <= crate::limits::MAX_COORDINATE) {
        return Err(format!("coordinates must be finite and within ±{:e} m", crate::limits::MAX_COORDINATE));
    }
    let (lo, hi) = p.bounds();
    let size = (hi - lo).length();
    if p.area().is_nan() || p.area() <= 1e-12 * size.max(1e-3) * size.max(1e-3) || size == 0.0 {
        return Err("degenerate (zero area)".into());
    }
    if n == 4 {
        let nrm = p.normal();
        let off = (p.p[3] - p.p[0]).dot(nrm).abs().max((p.p[1] - p.p[0]).dot(nrm).abs());
        if off > 1e-4 * size {
            return Err(format!("quad is not planar (a corner is {off:.3e} m off its plane)"));
        }
        for k in 0..4 {
            let e0 = p.p[(k + 1) % 4] - p.p[k];
            let e1 = p.p[(k + 2) % 4] - p.p[(k + 1) % 4];
            if e0.cross(e1).dot(nrm) <= 0.0 {
                return Err("quad is not convex, or its corners are not in order around it".into());
            }
        }
    }
    Ok(())
}

fn box_quads(b: &RawBox) -> Result<Vec<Primitive>, String> {
    let (lo, hi) = (Vec3::from(b.min), Vec3::from(b.max));
    if !(lo.is_finite() && hi.is_finite()) || lo.cmpge(hi).any() {
        return Err("min must be below max on every axis".into());
    }
    const FACES: [&str; 6] = ["-x", "+x", "-y", "+y", "-z", "+z"];
    for o in &b.omit {
        if !FACES.contains(&o.as_str()) {
            return Err(format!("unknown face `{o}` in omit (known: {})", FACES.join(", ")));
        }
    }
    let mut out = Vec::new();
    for axis in 0..3 {
        for positive in [false, true] {
            let label = FACES[axis * 2 + positive as usize];
            if b.omit.iter().any(|o| o == label) {
                continue;
            }
            let (bx, cx) = ((axis + 1) % 3, (axis + 2) % 3);
            let corner = |s: bool, t: bool| {
                let mut v = Vec3::ZERO;
                v[axis] = if positive { hi[axis] } else { lo[axis] };
                v[bx] = if s { hi[bx] } else { lo[bx] };
                v[cx] = if t { hi[cx] } else { lo[cx] };
                v
            };
            // e_b × e_c = +e_axis: this order faces +axis.
            let mut q = [corner(false, false), corner(true, false), corner(true, true), corner(false, true)];
            if positive == b.inward {
                q.reverse();
            }
            out.push(Primitive::quad(q));
        }
    }
    Ok(out)
}

/// The surface's keyframes, checked against `[animation]`.
fn parse_motion(
    cx: &Ctx<'_>,
    s: &RawSurface,
    animation: &Option<Spanned<RawAnimation>>,
    field: &dyn Fn(&str) -> String,
) -> Result<Option<Motion>, SceneError> {
    let Some(keys) = &s.keyframes else {
        if let Some(i) = &s.interpolation {
            return Err(cx.err(i.span(), field("interpolation"), "interpolation without keyframes"));
        }
        return Ok(None);
    };
    let frames = match animation {
        Some(a) => *a.get_ref().frames.get_ref(),
        None => {
            return Err(cx.err(keys.span(), field("keyframes"), "keyframes need an [animation] table with `frames`"));
        }
    };
    if keys.get_ref().is_empty() {
        return Err(cx.err(keys.span(), field("keyframes"), "give at least one keyframe"));
    }
    let mut out = Vec::new();
    for (i, k) in keys.get_ref().iter().enumerate() {
        let f = format!("keyframes[{i}]");
        if k.frame >= frames {
            return Err(cx.err(
                keys.span(),
                field(&f),
                format!("frame {} is outside the sequence 0..{frames}", k.frame),
            ));
        }
        if let Some(prev) = out.last().map(|p: &Keyframe| p.frame)
            && k.frame <= prev
        {
            return Err(cx.err(
                keys.span(),
                field(&f),
                format!(
                    "keyframes out of order: frame {} follows frame {prev}; list them by increasing frame",
                    k.frame
                ),
            ));
        }
        let t = Vec3::from(k.translate.unwrap_or(Exact([0.0; 3])));
        let r = Vec3::from(k.rotate_deg.unwrap_or(Exact([0.0; 3])));
        let sc = Vec3::from(k.scale.unwrap_or(Exact([1.0; 3])));
        if !(t.is_finite() && r.is_finite() && sc.is_finite()) || sc.cmpeq(Vec3::ZERO).any() {
            return Err(cx.err(keys.span(), field(&f), "values must be finite and scale non-zero"));
        }
        out.push(Keyframe { frame: k.frame, translate: t, rotation: rotation_from_degrees(r), scale: sc });
    }
    let interpolation = match s.interpolation.as_ref().map(|i| i.get_ref().as_str()) {
        None | Some("linear") => Interpolation::Linear,
        Some("hold") => Interpolation::Hold,
        Some(other) => {
            let span = s.interpolation.as_ref().map(|i| i.span()).unwrap_or(0..0);
            return Err(cx.err(
                span,
                field("interpolation"),
                format!("unknown interpolation `{other}` (known: linear, hold)"),
            ));
        }
    };
    let pivot = s.pivot.as_ref().map_or(Vec3::ZERO, |p| Vec3::from(*p.get_ref()));
    if !pivot.is_finite() {
        return Err(cx.err(s.pivot.as_ref().map(|p| p.span()).unwrap_or(0..0), field("pivot"), "must be finite"));
    }
    Ok(Some(Motion { pivot, interpolation, keyframes: out }))
}

fn transform_matrix(t: &RawTransform) -> Result<(Mat3, Vec3), String> {
    let s = Vec3::from(t.scale.unwrap_or(Exact([1.0; 3])));
    let r = Vec3::from(t.rotate_deg.unwrap_or(Exact([0.0; 3])));
    let tr = Vec3::from(t.translate.unwrap_or(Exact([0.0; 3])));
    if !(s.is_finite() && r.is_finite() && tr.is_finite()) || s.cmpeq(Vec3::ZERO).any() {
        return Err("scale must be non-zero; all values finite".into());
    }
    let rot = Mat3::from_rotation_z(r.z.to_radians())
        * Mat3::from_rotation_y(r.y.to_radians())
        * Mat3::from_rotation_x(r.x.to_radians());
    Ok((rot * Mat3::from_diagonal(s), tr))
}

fn load_obj(path: &Path) -> Result<Vec<Primitive>, String> {
    let opts = tobj::LoadOptions { triangulate: true, single_index: true, ..Default::default() };
    match std::fs::metadata(path) {
        Err(e) => {
            return Err(format!(
                "cannot read OBJ `{}` (a mesh path is taken from the scene file's folder): {e}",
                path.display()
            ));
        }
        Ok(m) if m.is_dir() => return Err(format!("`{}` is a directory, not an OBJ file", path.display())),
        Ok(_) => {}
    }
    let (models, _) = tobj::load_obj(path, &opts).map_err(|e| format!("cannot load OBJ `{}`: {e}", path.display()))?;
    let mut out = Vec::new();
    for m in models {
        let pos = &m.mesh.positions;
        let vert = |i: u32| -> Result<Vec3, String> {
            let i = i as usize * 3;
            pos.get(i..i + 3)
                .map(|p| Vec3::new(p[0], p[1], p[2]))
                .ok_or_else(|| format!("OBJ `{}`: face index out of range", path.display()))
        };
        for f in m.mesh.indices.chunks_exact(3) {
            out.push(Primitive::triangle(vert(f[0])?, vert(f[1])?, vert(f[2])?));
        }
    }
    if out.is_empty() {
        return Err(format!("OBJ `{}` has no faces", path.display()));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse_str(s: &str) -> Result<Scene, SceneError> {
        parse(s, Path::new("t.toml"), Path::new("."), "t".into())
    }

    const CAM: &str = "[camera]\nposition=[0,0,-1]\nlook_at=[0,0,0]\nfov_y_deg=40\nwidth=8\nheight=8\n";

    /// A `[camera]` table read over a file camera (640 × 480, keyed at
    /// frames 0 and 9), or alone.
    fn camera_over(table: &str, file: bool) -> Result<(Camera, Vec<CameraKey>), SceneError> {
        let cx = Ctx { text: table, file: Path::new("c.toml") };
        let raw: RawCameraFile = cx.deserialize()?;
        // Rolled a little: its `up` is not the default.
        let cam = Camera {
            position: Vec3::new(0.0, 1.0, 5.0),
            look_at: Vec3::new(0.0, 1.0, 0.0),
            up: Vec3::new(0.1, 1.0, 0.0),
            fov_y_deg: 50.0,
            width: 640,
            height: 480,
        };
        let keys = [0, 9].map(|frame| CameraKey {
            frame,
            position: Vec3::new(frame as f32, 1.0, 5.0),
            look_at: Vec3::new(0.0, 1.0, 0.0),
            up: Vec3::Y,
        });
        camera_of(
            &cx,
            raw.camera.as_ref().expect("a [camera] table"),
            &raw.animation,
            file.then_some((&cam, &keys[..])),
            true,
        )
    }

    #[test]
    fn a_partial_camera_table_takes_the_rest_from_the_file_camera() {
        // The width alone: the height keeps the file's 4:3; the path stays.
        let (c, keys) = camera_over("[camera]\nwidth = 1000\n", true).unwrap();
        assert_eq!((c.width, c.height, c.fov_y_deg, c.position), (1000, 750, 50.0, Vec3::new(0.0, 1.0, 5.0)));
        assert_eq!(c.up, Vec3::new(0.1, 1.0, 0.0), "the file's up, with its view");
        assert_eq!(keys.len(), 2);
        // The height alone, and the field of view.
        let (c, keys) = camera_over("[camera]\nheight = 240\nfov_y_deg = 30\n", true).unwrap();
        assert_eq!((c.width, c.height, c.fov_y_deg, keys.len()), (320, 240, 30.0, 2));
        // Both sides as given, whatever the file's ratio.
        let (c, _) = camera_over("[camera]\nwidth = 64\nheight = 64\n", true).unwrap();
        assert_eq!((c.width, c.height), (64, 64));
        // Placing the camera drops the file's path; the rest is the file's.
        let (c, keys) = camera_over("[camera]\nposition = [3, 1, 3]\n", true).unwrap();
        assert_eq!((c.position, c.look_at, c.width, c.height), (Vec3::new(3.0, 1.0, 3.0), Vec3::Y, 640, 480));
        assert!(keys.is_empty());
        // A view of the table's own has the default up, not the file's.
        assert_eq!(c.up, Vec3::Y);
        let whole = camera_over(CAM, true).unwrap().0;
        assert_eq!((whole.up, whole.width), (Vec3::Y, 8), "a whole table owes the file nothing");
        // Over a file camera the values given are still checked.
        let e = camera_over("[camera]\nfov_y_deg = 190\n", true).unwrap_err();
        assert_eq!((e.line, e.field.as_str()), (2, "camera.fov_y_deg"), "{e}");
        let e = camera_over("[camera]\nlook_at = [0, 1, 5]\n", true).unwrap_err();
        assert_eq!(e.field, "camera.up", "{e}");
        // Without one, every field but `up` is needed, each named.
        let (c, _) = camera_over(CAM, false).unwrap();
        assert_eq!(c.up, Vec3::Y);
        for field in ["position", "look_at", "fov_y_deg", "width", "height"] {
            let table: String = CAM.lines().filter(|l| !l.starts_with(field)).map(|l| format!("{l}\n")).collect();
            let e = camera_over(&table, false).unwrap_err();
            assert_eq!((e.line, e.field.clone()), (1, format!("camera.{field}")), "{e}");
            assert!(e.message.contains(&format!("missing field `{field}`")) && e.message.contains("[gltf]"), "{e}");
        }
        // A camera file (`render --camera-from`) is read alone.
        let e = parse_camera("[camera]\nwidth = 8\n", Path::new("c.toml"), Path::new(".")).unwrap_err();
        assert!(e.field == "camera.position" && e.message.contains("read alone"), "{e}");
    }

    #[test]
    fn errors_name_line_and_field() {
        let s = format!(
            "{CAM}[[material]]\nname='w'\ntype='diffuse'\nreflectance=[0.5,0.5,0.5]\n[[surface]]\nname='a'\nmaterial='nope'\nquad=[[0,0,0],[1,0,0],[1,1,0],[0,1,0]]\n"
        );
        let e = parse_str(&s).unwrap_err();
        assert_eq!(e.line, 13, "{e}");
        assert_eq!(e.field, "surface[0].material");
        assert!(e.to_string().starts_with("t.toml:13:"), "{e}");

        let e = parse_str(&s.replace("reflectance=[0.5,0.5,0.5]", "reflectance=[1.5,0.5,0.5]")).unwrap_err();
        assert_eq!((e.line, e.field.as_str()), (10, "material[0].reflectance"), "{e}");

        let e = parse_str(&s.replace("'nope'", "'w'").replace("[0,1,0]]", "[0,1,0.5]]")).unwrap_err();
        assert!(e.message.contains("not planar"), "{e}");

        let e = parse_str(&s.replace("fov_y_deg=40", "fov_y_deg=400")).unwrap_err();
        assert_eq!((e.line, e.field.as_str()), (4, "camera.fov_y_deg"), "{e}");

        // Syntax errors carry a position too.
        let e = parse_str(&s.replace("name='a'", "name=")).unwrap_err();
        assert!(e.line >= 11, "{e}");
    }

    #[test]
    fn boxes_face_outwards_or_inwards() {
        let s = format!(
            "{CAM}[[material]]\nname='w'\ntype='diffuse'\nreflectance=[0.5,0.5,0.5]\n[[surface]]\nname='b'\nmaterial='w'\nbox={{min=[0,0,0],max=[1,2,3],omit=['-y']}}\n"
        );
        let sc = parse_str(&s).unwrap();
        let prims = &sc.surfaces[0].primitives;
        assert_eq!(prims.len(), 5);
        let centre = Vec3::new(0.5, 1.0, 1.5);
        for p in prims {
            let mid = (p.p[0] + p.p[2]) / 2.0;
            assert!(p.normal().dot(mid - centre) > 0.0);
        }
        assert!((sc.total_area() - (2.0 * (2.0 + 6.0 + 3.0) - 3.0)).abs() < 1e-5);
        let sc = parse_str(&s.replace("omit=['-y']", "inward=true")).unwrap();
        for p in &sc.surfaces[0].primitives {
            let mid = (p.p[0] + p.p[2]) / 2.0;
            assert!(p.normal().dot(mid - centre) < 0.0);
        }
    }

    #[test]
    fn cornell_box_parses() {
        let sc = Scene::cornell_box();
        assert_eq!(sc.surfaces.len(), 8);
        assert_eq!(sc.materials.len(), 4);
        assert_eq!(sc.primitives().count(), 1 + 4 + 1 + 3 + 10);
    }
}
