//! `render`'s frames, one after another: each frame's light solved (from
//! the previous frame's, unless `--cold`; once for a walkthrough of a
//! still archive), its camera set, its balance reported and checked, its
//! image shaded, checked and written.

use std::time::Instant;

use anyhow::Result;
use illumnet::archive::layout::CameraRecord;
use illumnet::distribute;
use illumnet::progress::Progress;
use illumnet::render;

use crate::cli::exit::ResultRefused;
use crate::cli::frames::{FrameState, frame_state};

use super::RenderSetup;
use super::balance::{print_balance, refuse_unconverged, warn_if_dark};
use super::options::Shading;
use super::outputs::{RenderedFrame, frame_files, metadata, write_frame};
use super::summary::Totals;

/// Renders every frame of `setup.frames` with `renderer`, adding to
/// `totals`; returns the images when a preview (`--gif`,
/// `--contact-sheet`) needs them, else none.
pub fn render_frames(
    setup: &RenderSetup<'_>,
    renderer: &mut render::Renderer<'_>,
    totals: &mut Totals,
    progress: &dyn Progress,
) -> Result<Vec<render::Image>> {
    let args = setup.args;
    let mut previous: Option<distribute::Solution> = None;
    let keep_images = setup.extras.gif.is_some() || setup.extras.contact_sheet.is_some();
    let mut images = Vec::new();
    let mut warned_dark = false;
    let mut skips = SkipCounts::default();
    for f in setup.frames.range.clone() {
        let t1 = Instant::now();
        let af = setup.frames.archive_frame(f);
        if setup.cameras.given() {
            renderer.set_camera(None);
            let base = renderer.camera(af);
            renderer.set_camera(Some(setup.cameras.at(base, f)?));
        }
        let camera = renderer.camera(af);
        let leader = setup.extras.leader();
        // Every member of an MPI job skips what rank 0 finds done.
        let done = setup.extras.skip_done && leader && skips.done(setup, f, &camera)?;
        let done = setup.extras.team.map_or(done, |t| t.leader_says(done));
        if done {
            // The next frame rendered starts cold: its warm start is gone.
            previous = None;
            totals.skipped += 1;
            continue;
        }
        // A walkthrough of a still archive solves the light once.
        let reuse = setup.frames.still_walk && previous.is_some();
        let mut solution = match previous.take() {
            Some(p) if reuse => p,
            p => {
                let start = if args.cold { None } else { p.as_ref() };
                illumnet::scratch::pause_point("distribute");
                let solution = setup.distributor.frame(af, start, progress)?;
                // Light from a file cut short or rewritten under the pass
                // is refused (a mapped one's bytes change unseen).
                setup.archive.check_unchanged()?;
                solution
            }
        };
        if f + 1 >= setup.frames.range.end {
            // No frame starts from the last one's light.
            solution.release_warm_start();
        }
        if !reuse {
            // The loop's vectors, the last frame's light and the link
            // windows, freed, are the room the shading's are made in (the
            // memory plan counts them once).
            if let Some(stream) = setup.archive.link_stream() {
                stream.release_buffers();
            }
            crate::return_freed_memory();
        }
        if !leader {
            // The other members of an MPI job solve the light with rank 0
            // (every frame's collectives) and leave the rest to it.
            previous = Some(solution);
            continue;
        }
        totals.size = (camera.width, camera.height);
        if reuse {
            println!("frame {f}: the camera moved, the light is frame 0's: 0 iterations");
        }
        let b = &solution.balance;
        if !reuse {
            totals.iterations += b.iterations;
            totals.delta_s += solution.delta_s;
            totals.distribution_s += t1.elapsed().as_secs_f64();
            totals.ends_gathered += b.ends_gathered as f64;
            print_balance(f, b, setup.frames.sequence_output(), setup.view);
        }
        refuse_unconverged(f, b, args)?;
        warn_if_dark(f, b, &mut warned_dark);
        let t2 = Instant::now();
        let (image, direct) = shade(setup, renderer, af, &solution, &camera);
        totals.render_s += t2.elapsed().as_secs_f64();
        if f == setup.frames.range.start {
            warn_of_the_view(renderer, &image, args.samples, &camera);
        }
        refuse_non_finite(f, &image, direct.as_ref())?;
        let frame = RenderedFrame {
            number: f,
            archive_frame: af,
            camera: &camera,
            solution: &solution,
            image: &image,
            direct: direct.as_ref(),
        };
        illumnet::scratch::pause_point("write");
        setup.archive.check_unchanged()?;
        write_frame(setup, renderer, &frame)?;
        if let Some(path) = setup.extras.patch_radiance {
            write_patch_radiance(path, &solution.radiance)?;
        }
        previous = Some(solution);
        if keep_images {
            images.push(image);
        }
    }
    if setup.extras.skip_done && setup.extras.leader() {
        skips.print();
    }
    Ok(images)
}

/// `--patch-radiance`: the radiance per patch as little-endian `f32` RGB,
/// written whole or not at all.
fn write_patch_radiance(path: &std::path::Path, radiance: &[[f32; 3]]) -> Result<()> {
    use std::io::Write;
    illumnet::scratch::write_atomic(path, |w| {
        for r in radiance {
            for c in r {
                w.write_all(&c.to_le_bytes())?;
            }
        }
        Ok(())
    })
    .map_err(|e| anyhow::Error::new(crate::cli::exit::IoFailure(format!("--patch-radiance {}: {e}", path.display()))))
}

/// What `--skip-done` found of the frames' files.
#[derive(Default)]
struct SkipCounts {
    skipped: u32,
    missing: u32,
    partial: u32,
    stale: u32,
    foreign: u32,
}

impl SkipCounts {
    /// Whether frame `f` (seen through `camera`) is done: every file it
    /// writes complete and recording what this render would (else its
    /// state is counted and said).
    fn done(&mut self, setup: &RenderSetup<'_>, f: u32, camera: &CameraRecord) -> Result<bool> {
        let expected = metadata(setup, f, setup.frames.archive_frame(f), camera);
        let (state, _) = frame_state(&frame_files(setup, f)?, &setup.archive_id, f, Some(&expected));
        match &state {
            FrameState::Complete => self.skipped += 1,
            FrameState::Missing(_) => self.missing += 1,
            FrameState::Partial(..) => self.partial += 1,
            FrameState::Stale(..) => self.stale += 1,
            FrameState::Foreign(..) => self.foreign += 1,
        }
        if let FrameState::Partial(p, why) | FrameState::Stale(p, why) | FrameState::Foreign(p, why) = &state {
            println!("frame {f}: rendering again: {} is {}: {why}", p.display(), state.name());
        }
        Ok(state == FrameState::Complete)
    }

    /// The summary line: frames skipped, redone (by why) and new.
    fn print(&self) {
        let redone = self.partial + self.stale + self.foreign;
        println!(
            "skip-done: {} frame{} complete and skipped, {redone} redone ({} partial, {} stale, {} foreign), {} missing rendered",
            self.skipped,
            if self.skipped == 1 { "" } else { "s" },
            self.partial,
            self.stale,
            self.foreign,
            self.missing
        );
    }
}

/// Archive frame `af` shaded as `camera` sees it: with `--shading direct`
/// the image and its direct light apart, else the I-net's image alone.
fn shade(
    setup: &RenderSetup<'_>,
    renderer: &mut render::Renderer<'_>,
    af: u32,
    solution: &distribute::Solution,
    camera: &CameraRecord,
) -> (render::Image, Option<render::Image>) {
    let (args, view) = (setup.args, setup.view);
    let eye = glam::Vec3::from(camera.position);
    if args.shading == Shading::Direct {
        let mut light = render::DirectLight::new(view, solution, args.light_samples);
        if setup.gather_rays > 0 {
            light = light.with_gather(view, solution, setup.gather_rays, args.gather_reach);
        }
        let (image, direct) =
            renderer.frame_direct(af, &render::indirect_radiance_seen_from(view, solution, eye), &light);
        (image, Some(direct))
    } else {
        (renderer.frame(af, &render::radiance_seen_from(view, solution, eye)), None)
    }
}

/// Warns when the first frame's image shows mostly back faces, or almost
/// no surface's front (a black image: the camera outside the scene or
/// looking away).
fn warn_of_the_view(renderer: &render::Renderer<'_>, image: &render::Image, samples: u32, camera: &CameraRecord) {
    let samples = image.pixels.len() as f64 * (samples * samples) as f64;
    let (back, nothing) = (renderer.back_faces as f64 / samples, renderer.nothing_seen as f64 / samples);
    if back > 0.5 {
        eprintln!(
            "illumnet: warning: {:.0}% of the image shows back faces, which render black (surfaces are \
             one-sided: their front is where the right-hand rule's normal points); is the camera inside \
             a closed box or are some quads wound the wrong way?",
            100.0 * back
        );
    } else if back + nothing > 0.99 {
        eprintln!(
            "illumnet: warning: the camera sees almost no surface's front ({:.0}% of the image shows back \
             faces, {:.0}% nothing), so the image is black: is it outside the scene or looking away from \
             it (position {:?}, look_at {:?})? Give one with --camera-position and --look-at",
            100.0 * back,
            100.0 * nothing,
            camera.position,
            camera.look_at
        );
    }
}

/// Refuses to write frame `f` when its image or direct light has a pixel
/// that is not finite.
fn refuse_non_finite(f: u32, image: &render::Image, direct: Option<&render::Image>) -> Result<()> {
    for (what, im) in [("image", Some(image)), ("direct light", direct)] {
        if let Some(i) = im.and_then(|im| im.pixels.iter().position(|p| !p.iter().all(|c| c.is_finite()))) {
            return Err(anyhow::Error::new(ResultRefused(format!(
                "frame {f}: the {what} has a non-finite pixel ({}, {}): nothing written; the archive holds values \
                 beyond what its checks bound: please report it, with the archive",
                i % image.width as usize,
                i / image.width as usize
            ))));
        }
    }
    Ok(())
}
