//! The shading sections' rules (§5.15): `PSHD`, `TXHD`, `TXPX`.

use super::check;
use super::views::{InetView, ShadingView};
use crate::archive::ArchiveError;
use crate::archive::layout;
use crate::limits::MAX_TEXTURE_SIDE;

/// Largest texture coordinate magnitude and tint (§5.15).
const MAX_UV: f32 = 1e6;
const MAX_TINT: f32 = 1e6;

/// §5.15: one `PSHD` record per primitive, flags and textures in range,
/// every float finite; each texture's texels inside `TXPX`.
pub(super) fn validate_shading(v: &InetView<'_>, sh: &ShadingView<'_>) -> Result<(), ArchiveError> {
    check(sh.primitives.len() == v.primitives.len(), || {
        format!("PSHD: {} records, expected {} (one per primitive)", sh.primitives.len(), v.primitives.len())
    })?;
    for (i, t) in sh.textures.iter().enumerate() {
        let side = 1..=MAX_TEXTURE_SIDE;
        check(side.contains(&t.width) && side.contains(&t.height), || format!("TXHD[{i}]: size out of range"))?;
        check(t.wrap.iter().all(|&w| w <= 2) && t.filter <= 1, || format!("TXHD[{i}]: unknown wrap or filter"))?;
        let bytes = 3 * t.width as u64 * t.height as u64;
        check(t.first_byte.checked_add(bytes).is_some_and(|end| end <= sh.texels.len() as u64), || {
            format!("TXHD[{i}]: texels beyond TXPX's {} bytes", sh.texels.len())
        })?;
    }
    for (i, r) in sh.primitives.iter().enumerate() {
        use layout::shading_flags::{NORMALS, TEXTURE};
        check(r.flags & !(NORMALS | TEXTURE) == 0, || format!("PSHD[{i}]: unknown flags {:#x}", r.flags))?;
        check(r.flags & TEXTURE == 0 || (r.texture as usize) < sh.textures.len(), || {
            format!("PSHD[{i}]: texture {} out of range", r.texture)
        })?;
        check(r.tint.iter().all(|t| t.is_finite() && (0.0..=MAX_TINT).contains(t)), || {
            format!("PSHD[{i}]: tint negative, non-finite or above {MAX_TINT:e}")
        })?;
        check(r.normals.iter().flatten().all(|x| x.is_finite() && x.abs() <= 1.0 + 1e-3), || {
            format!("PSHD[{i}]: a normal is not a finite direction")
        })?;
        check(r.uvs.iter().flatten().all(|x| x.is_finite() && x.abs() <= MAX_UV), || {
            format!("PSHD[{i}]: a texture coordinate is non-finite or beyond ±{MAX_UV:e}")
        })?;
    }
    Ok(())
}
