//! An MTL file's values checked line by line before `tobj` reads it.
//! `tobj` keeps no line numbers and takes `inf`, `nan` or `1e10` as
//! written, and the OBJ importer then clamped them silently (`Ke inf`
//! became 0, `Ke 1e10` became 10⁹, `Kd 2` became 1: issue 42, §8). Here
//! each value the importer uses is held to the TOML reader's bounds,
//! naming the MTL file, line and field (format-spec/scene.md, "OBJ + MTL
//! scenes"):
//!
//! * `Ke`: each component in [0, [`crate::limits::MAX_RADIANCE`]], or
//!   refused (as a TOML `emission`): a clamped emitter is a wrong image;
//! * `Kd`, `Ks`: finite and ≥ 0, or refused; above 1, clamped to 1 with a
//!   warning. MTL is written by other tools, and the format bounds neither
//!   (exporters write colour × intensity); the importer already adapts
//!   such files (`Kd + Ks > 1` is scaled down, said), where a TOML scene,
//!   written for this program, is refused;
//! * `Ns`: finite and ≥ 0, or refused (any larger exponent is a sharper
//!   lobe, at least α = 0.01);
//! * `Ka`, `Kd`, `Ks`, `Ke` with fewer than three numbers are refused:
//!   `tobj` 4.0.5 panics on them (`parse_float3` unwraps), so such a file
//!   never reaches it.

use std::path::Path;

use super::SceneError;

/// A value of an MTL file the importer does not take as written.
pub(super) struct MtlFinding {
    /// Where and what (file, line, column, field `material `m`.Kd`).
    pub error: SceneError,
    /// Refused (the import fails with it); otherwise clamped and said.
    pub refused: bool,
}

/// What the scan of one MTL file found, in line order.
#[derive(Default)]
pub(super) struct MtlScan {
    /// Every finding.
    pub findings: Vec<MtlFinding>,
    /// A line `tobj` would panic on (too few numbers): the file must not
    /// be given to it.
    pub malformed: bool,
}

/// The values of the MTL text `text` (the file `path`) checked against
/// the rules of the module's header.
pub(super) fn scan(path: &Path, text: &[u8]) -> MtlScan {
    let mut out = MtlScan::default();
    let mut material = String::new();
    for (n, raw) in text.split(|&b| b == b'\n').enumerate() {
        // `tobj` fails on a line that is not UTF-8: nothing to check.
        let Ok(full) = std::str::from_utf8(raw) else { continue };
        let line = full.trim();
        let mut words = line.split_whitespace();
        let key = words.next().unwrap_or("");
        if key == "newmtl" {
            material = line[6..].trim().to_owned();
            continue;
        }
        let expected = match key {
            "Ka" | "Kd" | "Ks" | "Ke" => 3,
            "Ns" => 1,
            _ => continue,
        };
        // 1-based column of a word of `line`.
        let indent = full.len() - full.trim_start().len();
        let column = |w: &str| indent + (w.as_ptr() as usize - line.as_ptr() as usize) + 1;
        // The numbers `tobj` reads, with their columns.
        let values: Vec<(f32, usize)> =
            words.clone().take(expected).map_while(|w| Some((w.parse().ok()?, column(w)))).collect();
        let found = if values.len() < expected {
            // Fewer numbers than three and no other word: `tobj` would
            // panic (a word that is not a number is its parse error).
            if expected == 1 || !words.take(expected).all(|w| w.parse::<f32>().is_ok()) {
                continue;
            }
            out.malformed = true;
            (format!("give three numbers: `{key} r g b`"), indent + 1, true)
        } else {
            match problem(key, &values) {
                Some(p) => p,
                None => continue,
            }
        };
        let (message, column, refused) = found;
        let field = format!("material `{material}`.{key}");
        let error = SceneError { file: path.into(), line: n + 1, column, field, message, unreadable: false };
        out.findings.push(MtlFinding { error, refused });
    }
    out
}

/// What is wrong with the numbers `values` of `key` (with their columns):
/// the message, its column, and whether it is refused (else clamped).
fn problem(key: &str, values: &[(f32, usize)]) -> Option<(String, usize, bool)> {
    let bad = |ok: &dyn Fn(f32) -> bool| values.iter().find(|(v, _)| !ok(*v)).copied();
    let max = crate::limits::MAX_RADIANCE;
    match key {
        "Ke" => bad(&|v| (0.0..=max).contains(&v)).map(|(v, c)| {
            (format!("{v} is not an emitted radiance: each component must be in [0, 1e9] W·sr⁻¹·m⁻²"), c, true)
        }),
        "Kd" | "Ks" => {
            if let Some((v, c)) = bad(&|v| v.is_finite() && v >= 0.0) {
                return Some((format!("{v} is not a reflectance: each component must be in [0, 1]"), c, true));
            }
            bad(&|v| v <= 1.0)
                .map(|(v, c)| (format!("{v} is above 1: clamped to 1 (a reflectance is in [0, 1])"), c, false))
        }
        "Ns" => bad(&|v| v.is_finite() && v >= 0.0)
            .map(|(v, c)| (format!("{v} is not a specular exponent: it must be finite and at least 0"), c, true)),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn found(text: &str) -> Vec<(usize, usize, String, bool)> {
        scan(Path::new("m.mtl"), text.as_bytes())
            .findings
            .into_iter()
            .map(|f| (f.error.line, f.error.column, f.error.field, f.refused))
            .collect()
    }

    #[test]
    fn values_beyond_the_toml_readers_bounds_are_found_with_their_line() {
        let text =
            "newmtl a\nKd 0.5 0.5 0.5\nKe 1 inf 1\n\nnewmtl b\n  Kd 2 0.5 0.5\nKs 0.1 -0.1 0\nNs NaN\nKe 1e10 0 0\n";
        assert_eq!(
            found(text),
            [
                (3, 6, "material `a`.Ke".to_string(), true),
                (6, 6, "material `b`.Kd".to_string(), false),
                (7, 8, "material `b`.Ks".to_string(), true),
                (8, 4, "material `b`.Ns".to_string(), true),
                (9, 4, "material `b`.Ke".to_string(), true),
            ]
        );
        // In range, at the bounds: nothing.
        assert!(found("newmtl a\nKd 1 1 1\nKs 0 0 0\nKe 1e9 0 0\nNs 1e6\n").is_empty());
    }

    #[test]
    fn too_few_numbers_never_reach_tobj() {
        let s = scan(Path::new("m.mtl"), b"newmtl a\nKa 1\n");
        assert!(s.malformed && s.findings[0].refused && s.findings[0].error.line == 2);
        // A word that is not a number is tobj's own parse error.
        assert!(!scan(Path::new("m.mtl"), b"Kd spectral x.rfl\n").malformed);
    }
}
