//! The one rule every reader (TOML, OBJ, glTF) holds its primitives to,
//! below them all so that none imports another for it.

use crate::geometry::Primitive;

/// Rejects non-finite, degenerate, non-planar and non-convex primitives.
pub(in crate::scene) fn check_primitive(p: &Primitive) -> Result<(), String> {
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
