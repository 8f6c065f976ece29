//! Keyframes and `[animation]`: a surface's motion and emission keys, the
//! sequence's length and rate, each checked against the sequence.

use std::ops::Range;

use glam::Vec3;
use toml::Spanned;

use super::errors::Ctx;
use super::raw::{Exact, RawAnimation, RawSurface};
use crate::scene::SceneError;
use crate::scene::motion::{Animation, EmissionKey, Interpolation, Keyframe, Motion, rotation_from_degrees};

/// Checks that keyed frames are in the sequence and strictly increasing.
pub(super) fn check_key_frames(
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

/// The surface's keyframes, checked against `[animation]`.
pub(super) fn parse_motion(
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

/// The surface's emission keyframes, checked against `[animation]`.
pub(super) fn emission_keys(
    cx: &Ctx<'_>,
    s: &RawSurface,
    animation: &Option<Spanned<RawAnimation>>,
    field: &dyn Fn(&str) -> String,
) -> Result<Vec<EmissionKey>, SceneError> {
    let mut emission_keys = Vec::new();
    if let Some(keys) = &s.emission_keyframes {
        check_key_frames(
            cx,
            keys.get_ref().iter().map(|k| k.frame),
            keys.span(),
            &field("emission_keyframes"),
            animation,
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
    Ok(emission_keys)
}

/// `[animation]`: the sequence's frames and rate, checked.
pub(super) fn animation_of(cx: &Ctx<'_>, a: &Spanned<RawAnimation>) -> Result<Animation, SceneError> {
    let (frames, fps) = (a.get_ref().frames.get_ref(), a.get_ref().fps.get_ref());
    if !(1..=100_000).contains(frames) {
        return Err(cx.err(a.get_ref().frames.span(), "animation.frames", "must be in 1..=100000"));
    }
    if !(fps.is_finite() && *fps > 0.0) {
        return Err(cx.err(a.get_ref().fps.span(), "animation.fps", "must be positive"));
    }
    Ok(Animation { frames: *frames, fps: *fps })
}
