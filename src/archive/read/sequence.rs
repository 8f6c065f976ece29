//! A sequence archive's animation sections (§5.13): `ANIM`, `INST` (its
//! instances covering the primitives), `CAMF`, `EMIF` and the `DIDX`
//! index into `DELT` (each frame's records are checked when decoded,
//! [`super::SequenceView::frame_delta`]).

use super::views::{InetView, SequenceView};
use super::{camera_geometry, check, count};
use crate::archive::{ArchiveError, deltas};
use crate::limits::MAX_RADIANCE;

/// Frames and rate, instances contiguous over every primitive, a camera
/// and emissions per frame when keyed, every frame's `DIDX` range inside
/// `DELT`.
pub(super) fn check_sequence(v: &InetView<'_>, s: &SequenceView<'_>) -> Result<(), ArchiveError> {
    let frames = s.record.frames;
    check(frames >= 1, || "ANIM: no frames".into())?;
    check(s.record.fps.is_finite() && s.record.fps > 0.0, || "ANIM: fps must be positive".into())?;
    count("INST", s.instances.len(), s.record.instance_count as usize)?;
    count("DIDX", s.index.len(), frames as usize)?;
    check(s.payload_count == frames as u64, || {
        format!("section DELT: count {} in the table, expected {frames} frames", s.payload_count)
    })?;
    let mut next = 0u64;
    for (i, r) in s.instances.iter().enumerate() {
        check(r.first_primitive as u64 == next && r.primitive_count > 0, || {
            format!("INST[{i}]: primitives not contiguous")
        })?;
        next += r.primitive_count as u64;
        check(r.frame_first <= r.frame_last && r.frame_last < frames, || format!("INST[{i}]: bad frame range"))?;
        check((r.surface as usize) < v.surfaces.len(), || format!("INST[{i}]: surface out of range"))?;
    }
    check(next == v.primitives.len() as u64, || "INST: instances do not cover all primitives".into())?;
    if let Some(cams) = s.cameras {
        count("CAMF", cams.len(), frames as usize)?;
        for (f, c) in cams.iter().enumerate() {
            check(camera_geometry(c), || format!("CAMF[{f}]: non-finite, beyond ±1e9 m or degenerate"))?;
            check(c.fov_y_deg > 0.0 && c.fov_y_deg < 180.0, || format!("CAMF[{f}]: field of view"))?;
            check((c.width, c.height) == (v.camera.width, v.camera.height), || {
                format!("CAMF[{f}]: image size differs from CAMR")
            })?;
        }
    }
    if let Some(e) = s.emissions {
        count("EMIF", e.len(), frames as usize * v.surfaces.len())?;
        check(e.iter().all(|x| x.iter().all(|c| (0.0..=MAX_RADIANCE).contains(c))), || {
            format!("EMIF: emission outside [0, {MAX_RADIANCE:e}]")
        })?;
    }
    for (f, ix) in s.index.iter().enumerate() {
        let end = ix.offset.checked_add(ix.stored_length);
        check(end.is_some_and(|e| e <= s.payload.len()), || format!("DIDX[{f}]: outside DELT"))?;
        check(
            ix.count <= u32::MAX as u64 && (ix.count == 0) == (ix.stored_length == 0) && (f > 0 || ix.count == 0),
            || format!("DIDX[{f}]: bad count"),
        )?;
        check_delta_count(f, ix.count, ix.stored_length)?;
    }
    Ok(())
}

/// `DIDX[f]`: a count its `stored` bytes can hold
/// ([`deltas::most_records`]); shared by open and
/// [`crate::archive::Archive::summary`], so that a render plans memory
/// only from counts the file can hold (issue 42, §5).
pub(super) fn check_delta_count(f: usize, count: u64, stored: u64) -> Result<(), ArchiveError> {
    check(count <= deltas::most_records(stored), || {
        format!("DIDX[{f}]: {count} records, more than its {stored} stored bytes can hold")
    })
}
