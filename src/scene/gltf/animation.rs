//! Node animation channels (translation, rotation, scale) sampled at the
//! frame rate: frame `f` is time `f / fps` seconds; the sequence runs from 0
//! to the last key of any channel. Between keys: `STEP` holds, `LINEAR`
//! interpolates (rotations spherically), `CUBICSPLINE` evaluates the Hermite
//! spline of the glTF specification (rotations renormalised).

use std::path::Path;

use glam::{Mat4, Quat, Vec3, Vec4};
use gltf::animation::{Interpolation, Property, util::ReadOutputs};

use super::GltfOptions;
use crate::scene::SceneError;
use crate::scene::error::error;
use crate::scene::import::Notes;

/// Most node placements (moving nodes × frames) an animation may make: 4 Mi
/// matrices, 256 MiB.
const MAX_ANIMATED_MATRICES: usize = 1 << 22;

/// One channel's keys: times and values (4 numbers; translation and scale
/// use 3), with the in- and out-tangents of a cubic spline.
struct Track {
    property: Property,
    interpolation: Interpolation,
    times: Vec<f32>,
    /// `values[k]`; for cubic splines `[in, value, out]` triples flattened.
    values: Vec<Vec4>,
}

impl Track {
    fn at(&self, t: f32) -> Vec4 {
        let cubic = self.interpolation == Interpolation::CubicSpline;
        let value = |k: usize| if cubic { self.values[3 * k + 1] } else { self.values[k] };
        let n = self.times.len();
        let i = self.times.partition_point(|&x| x <= t);
        if i == 0 {
            return value(0);
        }
        if i == n {
            return value(n - 1);
        }
        let (a, b) = (i - 1, i);
        let dt = self.times[b] - self.times[a];
        let s = if dt > 0.0 { (t - self.times[a]) / dt } else { 0.0 };
        let rotation = self.property == Property::Rotation;
        match self.interpolation {
            Interpolation::Step => value(a),
            Interpolation::Linear if rotation => {
                let qa = Quat::from_vec4(value(a)).normalize();
                let qb = Quat::from_vec4(value(b)).normalize();
                Vec4::from(qa.slerp(qb, s))
            }
            Interpolation::Linear => value(a).lerp(value(b), s),
            Interpolation::CubicSpline => {
                let (s2, s3) = (s * s, s * s * s);
                let out_a = self.values[3 * a + 2] * dt;
                let in_b = self.values[3 * b] * dt;
                let v = (2.0 * s3 - 3.0 * s2 + 1.0) * value(a)
                    + (s3 - 2.0 * s2 + s) * out_a
                    + (-2.0 * s3 + 3.0 * s2) * value(b)
                    + (s3 - s2) * in_b;
                if rotation { Vec4::from(Quat::from_vec4(v).normalize()) } else { v }
            }
        }
    }
}

/// Every node's local transform at every frame.
pub(super) struct Sampled {
    /// Frames in the sequence (1 without animation).
    pub(super) frames: u32,
    /// Frames per second.
    pub(super) fps: f32,
    /// Tracks by node index.
    tracks: std::collections::HashMap<usize, Vec<Track>>,
}

impl Sampled {
    /// Reads every node channel of every animation of the file.
    pub(super) fn new(
        path: &Path,
        doc: &gltf::Document,
        buffers: &[gltf::buffer::Data],
        options: &GltfOptions,
        notes: &mut Notes,
    ) -> Result<Self, SceneError> {
        let fps = options.fps.unwrap_or(super::DEFAULT_FPS);
        if !(fps.is_finite() && fps > 0.0 && fps <= 1000.0) {
            return Err(error(path, "", format!("frame rate {fps} is not in (0, 1000]")));
        }
        let mut tracks: std::collections::HashMap<usize, Vec<Track>> = Default::default();
        let mut end = 0.0f32;
        // Every key time of every node channel, for the note on keys the
        // frames miss.
        let mut key_times: Vec<f32> = Vec::new();
        for anim in doc.animations() {
            for (c, channel) in anim.channels().enumerate() {
                let at = format!("/animations/{}/channels/{c}", anim.index());
                let property = channel.target().property();
                if property == Property::MorphTargetWeights {
                    notes.add(format!("animation {}: morph target weights are not supported", anim.index()));
                    continue;
                }
                let track = read_track(path, &at, &channel, buffers)?;
                end = end.max(*track.times.last().expect("non-empty"));
                key_times.extend_from_slice(&track.times);
                tracks.entry(channel.target().node().index()).or_default().push(track);
            }
        }
        let frames = (end * fps).round() as f64 + 1.0;
        if frames > 100_000.0 {
            return Err(error(path, "/animations", format!("{frames} frames at {fps} fps: more than 100000")));
        }
        if doc.animations().len() > 1 {
            notes.add(format!("{} animations: all are played together from time 0", doc.animations().len()));
        }
        // A rate the user chose is theirs; the default may miss the keys.
        if options.fps.is_none()
            && let Some(note) = off_frame_note(key_times, fps)
        {
            notes.add(note);
        }
        Ok(Self { frames: frames as u32, fps, tracks })
    }

    /// The local transform of `node` at `frame`.
    fn local(&self, node: &gltf::Node<'_>, frame: u32) -> Mat4 {
        let Some(tracks) = self.tracks.get(&node.index()) else {
            return Mat4::from_cols_array_2d(&node.transform().matrix());
        };
        let (t, r, s) = node.transform().decomposed();
        let (mut t, mut r, mut s) = (Vec3::from(t), Quat::from_array(r).normalize(), Vec3::from(s));
        let time = frame as f32 / self.fps;
        for track in tracks {
            let v = track.at(time);
            match track.property {
                Property::Translation => t = v.truncate(),
                Property::Rotation => r = Quat::from_vec4(v).normalize(),
                Property::Scale => s = v.truncate(),
                Property::MorphTargetWeights => {}
            }
        }
        Mat4::from_scale_rotation_translation(s, r, t)
    }

    /// World matrices of the placed nodes (parents listed before children):
    /// one per frame for a node that an animation moves (itself or an
    /// ancestor), else just one.
    ///
    /// At most [`MAX_ANIMATED_MATRICES`] matrices over all moving nodes.
    pub(super) fn world_matrices(
        &self,
        path: &Path,
        parents: &[Option<usize>],
        nodes: &[gltf::Node<'_>],
    ) -> Result<Vec<Vec<Mat4>>, SceneError> {
        let mut out: Vec<Vec<Mat4>> = Vec::with_capacity(nodes.len());
        let mut animated_total = 0usize;
        for (i, node) in nodes.iter().enumerate() {
            let parent: Option<&Vec<Mat4>> = parents[i].map(|p| &out[p]);
            let animated = self.tracks.contains_key(&node.index()) || parent.is_some_and(|p| p.len() > 1);
            let frames = if animated { self.frames } else { 1 };
            if animated {
                animated_total += frames as usize;
                if animated_total > MAX_ANIMATED_MATRICES {
                    return Err(error(
                        path,
                        "/animations",
                        format!(
                            "{} frames of {} or more moving nodes: more than {MAX_ANIMATED_MATRICES} node placements",
                            self.frames,
                            animated_total / self.frames as usize
                        ),
                    ));
                }
            }
            let row = (0..frames)
                .map(|f| {
                    let local = self.local(node, f);
                    match parent {
                        Some(p) => p[(f as usize).min(p.len() - 1)] * local,
                        None => local,
                    }
                })
                .collect();
            out.push(row);
        }
        Ok(out)
    }
}

/// One node channel's keys (`channel`, at JSON pointer `at`), read and
/// checked: times finite, non-negative and increasing, one value (three
/// for a cubic spline) per time, values finite, no zero rotation.
fn read_track(
    path: &Path,
    at: &str,
    channel: &gltf::animation::Channel<'_>,
    buffers: &[gltf::buffer::Data],
) -> Result<Track, SceneError> {
    let property = channel.target().property();
    use gltf::accessor::{DataType::*, Dimensions};
    let sampler = channel.sampler();
    super::load::check_accessor(path, &sampler.input(), &[F32], Dimensions::Scalar, "key times")?;
    match property {
        Property::Rotation => super::load::check_accessor(
            path,
            &sampler.output(),
            &[F32, I8, U8, I16, U16],
            Dimensions::Vec4,
            "rotation keys",
        )?,
        _ => super::load::check_accessor(path, &sampler.output(), &[F32], Dimensions::Vec3, "keys")?,
    }
    let reader = channel.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
    let times: Vec<f32> = reader
        .read_inputs()
        .ok_or_else(|| error(path, format!("{at}/sampler"), "the sampler's input cannot be read"))?
        .collect();
    let values: Vec<Vec4> = match reader.read_outputs() {
        Some(ReadOutputs::Translations(v)) | Some(ReadOutputs::Scales(v)) => {
            v.map(|x| Vec3::from(x).extend(0.0)).collect()
        }
        Some(ReadOutputs::Rotations(r)) => r.into_f32().map(Vec4::from).collect(),
        _ => return Err(error(path, format!("{at}/sampler"), "the sampler's output cannot be read")),
    };
    let interpolation = channel.sampler().interpolation();
    let per_key = if interpolation == Interpolation::CubicSpline { 3 } else { 1 };
    if times.is_empty() || values.len() != per_key * times.len() {
        return Err(error(
            path,
            format!("{at}/sampler"),
            format!("{} keys but {} output values", times.len(), values.len()),
        ));
    }
    if times.windows(2).any(|w| w[0] >= w[1]) || !times.iter().all(|t| t.is_finite() && *t >= 0.0) {
        return Err(error(path, format!("{at}/sampler"), "key times must be finite, ≥ 0 and increasing"));
    }
    if !values.iter().all(|v| v.is_finite() && v.abs().max_element() <= crate::limits::MAX_COORDINATE) {
        return Err(error(path, format!("{at}/sampler"), "key values must be finite and within ±1e9"));
    }
    if property == Property::Rotation {
        let keys = values.iter().skip(per_key / 2).step_by(per_key);
        if keys.clone().any(|q| q.length() < 1e-6) {
            return Err(error(path, format!("{at}/sampler"), "a rotation key is the zero quaternion"));
        }
    }
    Ok(Track { property, interpolation, times, values })
}

/// Fewest distinct key times that make a rate worth a note.
const OFF_FRAME_MIN_KEYS: usize = 3;

/// The note for an animation whose keys the sampling rate misses, if it
/// does: of the distinct key times over all node channels (`times`, in any
/// order; times within 10⁻⁴ s of each other taken as one), at least
/// [`OFF_FRAME_MIN_KEYS`] of them, fewer than half fall on a frame
/// (within 10⁻³ of a frame, or the rounding of an `f32` time) at `fps`.
/// The rate the keys imply is one over the smallest step between them,
/// rounded to hundredths; one equal to `fps` (keys on its steps but off
/// its frames) gives no note. Keys every 1/15 s sampled at 24 fps fall on
/// a frame only every fifth time (every third of a second).
fn off_frame_note(mut times: Vec<f32>, fps: f32) -> Option<String> {
    times.sort_by(f32::total_cmp);
    times.dedup_by(|a, b| (*a - *b).abs() < 1e-4);
    if times.len() < OFF_FRAME_MIN_KEYS {
        return None;
    }
    let on_frame = |t: f32| {
        let x = t as f64 * fps as f64;
        (x - x.round()).abs() <= 1e-3f64.max(x * 1e-6)
    };
    let on = times.iter().filter(|&&t| on_frame(t)).count();
    if 2 * on >= times.len() {
        return None;
    }
    let step = times.windows(2).map(|w| w[1] as f64 - w[0] as f64).fold(f64::INFINITY, f64::min);
    let implied = (100.0 / step).round() / 100.0;
    if implied == fps as f64 {
        return None;
    }
    Some(format!(
        "animation: {} of {} key times fall between the frames of the default {fps} fps; the keys imply \
         {implied} fps: give it with --fps {implied} (or [gltf] fps = {implied})",
        times.len() - on,
        times.len()
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Key times every `step` seconds from 0 to `until`, as a file holds
    /// them (`f32`).
    fn every(step: f64, until: f64) -> Vec<f32> {
        (0..).map(|k| k as f64 * step).take_while(|t| *t <= until + 1e-9).map(|t| t as f32).collect()
    }

    #[test]
    fn keys_between_the_frames_are_said_with_the_rate_they_imply() {
        // Every 1/15 s for 4 s at 24 fps: a key on a frame every fifth time
        // (13 of 61).
        let note = off_frame_note(every(1.0 / 15.0, 4.0), 24.0).expect("a note");
        assert_eq!(
            note,
            "animation: 48 of 61 key times fall between the frames of the default 24 fps; the keys imply 15 fps: \
             give it with --fps 15 (or [gltf] fps = 15)"
        );
        // Channels keyed at the same times count them once.
        assert_eq!(off_frame_note([every(1.0 / 15.0, 4.0), every(1.0 / 15.0, 4.0)].concat(), 24.0), Some(note));
        let ntsc = off_frame_note(every(1.0 / 29.97, 2.0), 24.0).expect("a note");
        assert!(ntsc.ends_with("the keys imply 29.97 fps: give it with --fps 29.97 (or [gltf] fps = 29.97)"), "{ntsc}");
        // Keys on the frames, or on every other frame of a finer rate: no note.
        for (step, fps) in [(1.0 / 12.0, 24.0), (1.0 / 24.0, 24.0), (1.0 / 48.0, 24.0), (1.0 / 15.0, 15.0)] {
            assert_eq!(off_frame_note(every(step, 4.0), fps), None, "keys every {step} s at {fps} fps");
        }
        // An hour at 24 fps: f32 times far from 0 still land on their frames.
        assert_eq!(off_frame_note(every(1.0 / 24.0, 3600.0), 24.0), None);
        // Too few key times to imply a rate.
        assert_eq!(off_frame_note(vec![0.0, 0.51], 24.0), None);
        assert_eq!(off_frame_note(vec![0.0, 0.51, 0.51], 24.0), None);
    }
}
