//! The subcommands.

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result};
use illumnet::archive::{self, Archive, tag_name};
use illumnet::bake::{self, BuildSettings};
use illumnet::distribute::{self, DistributeOptions};
use illumnet::geodesic::DirectionSetKind;
use illumnet::geometry;
use illumnet::memory::{self, BudgetSource, Bytes, MemoryBudget};
use illumnet::progress::Progress;
use illumnet::render::{self, RenderOptions, image_io, plan};
use illumnet::scene::{BuildHints, GltfOptions, Scene};

use super::camera::RenderCameras;
use super::exit::{BadInput, InputContext, IoFailure, ResultRefused, bail_input};
use super::{BuildArgs, FalseColour, RenderArgs, Shading};

fn hints(a: &BuildArgs) -> BuildHints {
    BuildHints { patch_size: a.patch_size, frequency: a.frequency, ray_spacing: a.ray_spacing, buckets: a.buckets }
}

fn build_scene(scene: &Scene, output: &Path, args: &BuildArgs, progress: &dyn Progress) -> Result<()> {
    // An archive named as an image is a slip (`-o scene.png` meant for
    // `render`): refused before any work.
    if let Some(ext) = output.extension().and_then(|e| e.to_str())
        && ["png", "exr", "jpg", "jpeg", "gif", "tif", "tiff", "hdr", "toml", "gltf", "glb", "obj"]
            .contains(&ext.to_ascii_lowercase().as_str())
    {
        bail_input!(
            "-o {}: an archive is written there, not a .{ext} file (name it .inet; `render` writes images)",
            output.display()
        );
    }
    let quality = match args.quality {
        super::Quality::Draft => bake::Quality::Draft,
        super::Quality::Default => bake::Quality::Default,
        super::Quality::High => bake::Quality::High,
    };
    let mut settings = BuildSettings::resolve_with(scene, hints(args), quality);
    if args.ray_space {
        settings.direction_set = DirectionSetKind::RaySpace;
    }
    settings.group_triangles = !args.no_grouping;
    settings.patch_order = match args.patch_order {
        super::PatchOrder::Spatial => illumnet::patch::order::PatchOrder::Spatial,
        super::PatchOrder::Primitives => illumnet::patch::order::PatchOrder::Primitives,
    };
    if args.no_prototype_library {
        settings.prototype_library = None;
    } else if let Some(dir) = &args.prototype_library {
        settings.prototype_library = Some(dir.clone());
    }
    if let Some(t) = args.table_threshold {
        settings.table_threshold = t;
    }
    if args.map_method.as_deref() == Some("rings") {
        settings.map_method = illumnet::reflectance::MapMethod::Rings;
    }
    let budget = match args.memory_budget {
        Some(bytes) => MemoryBudget { bytes, source: BudgetSource::Given },
        None => MemoryBudget::default_for_machine(),
    };
    // Made now, for a bounded build's scratch; removed again if the build
    // fails before anything is written there.
    let folder = illumnet::scratch::OutputDir::make(output).with_context(|| {
        format!("-o {}: cannot create the folder {}", output.display(), illumnet::scratch::dir_of(output).display())
    })?;
    // What an interrupted build of this archive left next to it.
    if let Ok(r) = illumnet::scratch::remove_stale(output)
        && !r.paths.is_empty()
    {
        println!(
            "removed {} temporary file{} ({}) left next to {} by an interrupted build",
            r.paths.len(),
            if r.paths.len() == 1 { "" } else { "s" },
            Bytes(r.bytes),
            output.display()
        );
    }
    let bound = bake::MemoryBound { budget: budget.bytes, output: output.to_path_buf() };
    let t = Instant::now();
    let (seq, mut spilled) = match bake::build_sequence_bounded(scene, &settings, &bound, progress) {
        Ok(x) => x,
        Err(bake::BuildError::Failed(m)) => return Err(BadInput(m).into()),
        Err(e) => return Err(e.into()),
    };
    for w in &seq.warnings {
        eprintln!("warning: {w}");
    }
    let spilled_changes = seq.contents.sequence.as_ref().map_or(0, |q| q.deltas.spilled_bytes());
    if let Some(s) = &spilled {
        println!(
            "memory: budget {budget}: spilled {} runs of link ends ({}) next to {}, merged as written",
            s.run_count(),
            Bytes(s.spilled_bytes()),
            output.display()
        );
    }
    if spilled_changes > 0 {
        println!(
            "memory: budget {budget}: spilled {} of per-frame link changes next to {}, copied as written",
            Bytes(spilled_changes),
            output.display()
        );
    }
    let (contents, stats) = (seq.contents, seq.stats);
    let t_w = Instant::now();
    let bytes =
        archive::write_with_links(output, &contents, spilled.as_mut().map(|s| s as &mut dyn archive::LinkEndSource))?;
    folder.keep();
    drop(spilled);
    let t_write = t_w.elapsed().as_secs_f64();
    let sequence = contents.sequence.as_ref().map(|q| {
        let frames = q.record.frames;
        let moving = q.instances.iter().filter(|i| i.frame_first > 0 || i.frame_last + 1 < frames).count();
        (frames, moving, q.deltas.stored_length())
    });
    drop(contents);
    // The written archive is read back and checked whole, as a render
    // opens it (every checksum, every link's bounds and weights): a build
    // never ends on a file its own reader refuses. Its emitters' link rows
    // then say which lamps face a nearby surface.
    let t_c = Instant::now();
    progress.busy("checking the written archive");
    let written = Archive::open_streamed(output, archive::CHUNK_ENDS);
    progress.finish();
    let written = written?;
    let t_check = t_c.elapsed().as_secs_f64();
    let secs = t.elapsed().as_secs_f64();
    println!(
        "built {}: {} patches, {} directions, {} rays ({:.1} M rays/s), {} links ({} ends; {} before merging \
         parallel rays), {:.1} MB, {:.2} s \
         (setup {:.2} s, trace {:.2} s, links {:.2} s, write {:.2} s, check {:.2} s)",
        output.display(),
        stats.patches,
        stats.directions,
        stats.rays,
        stats.rays as f64 / stats.trace_s.max(1e-9) / 1e6,
        stats.link_ends / 2,
        stats.link_ends,
        stats.links,
        bytes as f64 / 1e6,
        secs,
        stats.setup_s,
        stats.trace_s,
        stats.assemble_s,
        t_write,
        t_check,
    );
    if let Some((frames, moving, changes)) = sequence {
        println!(
            "sequence: {frames} frames, {moving} instances of moving surfaces (each present in some frames), {} of \
             per-frame link changes",
            Bytes(changes)
        );
    }
    if let Some(b) = memory::peak_resident() {
        println!("peak memory {}", Bytes(b));
    }
    if stats.tables > 0 {
        println!(
            "reflectance: {} non-diffuse patches, {} prototype table{} ({} from the library), {} orientation{}, {:.2} s",
            stats.nondiffuse_patches,
            stats.tables,
            if stats.tables == 1 { "" } else { "s" },
            stats.tables_cached,
            stats.orientations,
            if stats.orientations == 1 { "" } else { "s" },
            stats.reflectance_s
        );
    }
    for w in super::inspect_surface::facing_nearby(&written.view(), &written.meta().surface_names, settings.patch_size)?
    {
        eprintln!("illumnet: warning: {w}");
    }
    Ok(())
}

pub fn build(
    scene_path: &Path,
    gltf: &GltfOptions,
    output: &Path,
    frame: Option<u32>,
    args: BuildArgs,
    progress: &dyn Progress,
) -> Result<()> {
    let is_gltf = illumnet::scene::gltf::is_gltf_path(scene_path);
    if !is_gltf && *gltf != GltfOptions::default() {
        bail_input!("--camera, --light-radius and --fps are for glTF scenes; a TOML scene states them itself");
    }
    let mut scene = match Scene::from_file_with(scene_path, gltf) {
        Ok(s) => s,
        Err(_) if is_archive(scene_path) => bail_input!(
            "{} is an archive, not a scene: render it (`illumnet render {} -o image.png`) or inspect it",
            scene_path.display(),
            scene_path.display()
        ),
        Err(e) => return Err(e.into()),
    };
    for note in &scene.notes {
        eprintln!("illumnet: warning: {}: {note}", scene_path.display());
    }
    for t in &args.turn {
        let (name, deg) = t.split_once('=').input(|| format!("--turn `{t}`: expected SURFACE=DEGREES"))?;
        let deg: f32 = deg
            .trim()
            .parse()
            .ok()
            .filter(|d: &f32| d.is_finite())
            .input(|| format!("--turn `{t}`: `{deg}` is not a number of degrees"))?;
        scene.turn_surface(name, deg).map_err(|e| BadInput(format!("--turn `{t}`: {e}")))?;
    }
    let frames = scene.frame_count();
    match frame {
        Some(f) if frames == 1 && f > 0 => bail_input!("--frame {f}: the scene is a still (its one frame is 0)"),
        Some(f) if f >= frames => {
            bail_input!("--frame {f} is outside the sequence 0..{frames} (frames 0 to {})", frames - 1)
        }
        Some(f) => scene = scene.at_frame(f),
        None => {}
    }
    build_scene(&scene, output, &args, progress)
}

/// Replaces a printf-style `%d` / `%0Nd` in `pattern` with `frame`.
fn frame_path(pattern: &Path, frame: u32) -> Option<std::path::PathBuf> {
    let text = pattern.to_str()?;
    let start = text.find('%')?;
    let rest = &text[start + 1..];
    let digits: String = rest.chars().take_while(|c| c.is_ascii_digit()).collect();
    if !rest[digits.len()..].starts_with('d') {
        return None;
    }
    let width: usize = if digits.is_empty() { 0 } else { digits.parse().ok().filter(|&w| w <= 16)? };
    let number = format!("{frame:0width$}");
    Some(format!("{}{}{}", &text[..start], number, &rest[digits.len() + 1..]).into())
}

/// Parses a frame range of a sequence of `total` frames: `A..B` (B
/// excluded), `A..=B`, `A..` (to the end), `..B`, or a single frame `A`.
pub fn parse_frames(text: &str, total: u32) -> Result<std::ops::Range<u32>> {
    let parse = |t: &str| {
        t.trim()
            .parse::<u32>()
            .input(|| format!("--frames `{text}`: expected a range like 0..60, 2.., 0..=4 or one frame like 7"))
    };
    let (a, b) = match text.split_once("..") {
        Some((a, b)) => {
            let a = if a.trim().is_empty() { 0 } else { parse(a)? };
            let b = match b.strip_prefix('=') {
                Some(b) => parse(b)?.checked_add(1).input(|| format!("--frames `{text}`: frame out of range"))?,
                None if b.trim().is_empty() => total,
                None => parse(b)?,
            };
            (a, b)
        }
        None => {
            let a = parse(text)?;
            (a, a.checked_add(1).input(|| format!("frame {a} is out of range"))?)
        }
    };
    if a >= b {
        bail_input!("--frames `{text}` is empty (the archive has frames 0..{total})");
    }
    Ok(a..b)
}

/// Refuses an output (or input) path whose extension is not `ext`, naming
/// the option and what to do instead.
fn require_extension(path: &Path, ext: &str, option: &str, hint: &str) -> Result<()> {
    let given = path.extension().and_then(|e| e.to_str()).unwrap_or("");
    if !given.eq_ignore_ascii_case(ext) {
        bail_input!("{option} {}: {hint}", path.display());
    }
    Ok(())
}

/// Opens an archive, telling a scene file given in its place apart from a
/// corrupt archive.
fn open_archive(path: &Path) -> Result<Archive> {
    opened(path, Archive::open(path))
}

/// `result` of opening `path`, a scene file given in its place told apart
/// from a corrupt archive.
pub(super) fn opened<T>(path: &Path, result: Result<T, illumnet::archive::ArchiveError>) -> Result<T> {
    match result {
        Ok(a) => Ok(a),
        Err(illumnet::archive::ArchiveError::Corrupt(_)) if looks_like_scene(path) => {
            let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("scene");
            bail_input!(
                "{} is a scene, not an archive: build it first with `illumnet build {} -o {stem}.inet`",
                path.display(),
                path.display()
            )
        }
        // The OS error names the file already.
        Err(e @ illumnet::archive::ArchiveError::Io { .. }) => Err(anyhow::Error::new(e)),
        Err(e) => Err(anyhow::Error::new(e)).with_context(|| format!("cannot open {}", path.display())),
    }
}

/// Whether `path` starts with the archive magic (§3).
fn is_archive(path: &Path) -> bool {
    let mut head = [0u8; 8];
    std::fs::File::open(path).and_then(|mut f| std::io::Read::read_exact(&mut f, &mut head)).is_ok()
        && head == archive::layout::MAGIC
}

/// Whether `path` holds a TOML scene rather than an archive: no archive
/// magic, and a `.toml` name or text that starts like TOML (a table, a
/// comment or a `key =` line).
fn looks_like_scene(path: &Path) -> bool {
    let mut head = [0u8; 256];
    let n = std::fs::File::open(path).and_then(|mut f| std::io::Read::read(&mut f, &mut head)).unwrap_or(0);
    let head = &head[..n];
    if head.starts_with(&archive::layout::MAGIC) {
        return false;
    }
    if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("toml")) {
        return true;
    }
    // The text up to the first byte that is not UTF-8 (the read may cut a
    // character in two).
    let text = match std::str::from_utf8(head) {
        Ok(t) => t,
        Err(e) => std::str::from_utf8(&head[..e.valid_up_to()]).unwrap_or(""),
    };
    let first = text.lines().map(str::trim).find(|l| !l.is_empty()).unwrap_or("");
    first.starts_with('[') || first.starts_with('#') || first.split_once('=').is_some_and(|(k, _)| !k.trim().is_empty())
}

/// Applies `--set NAME.FIELD=R,G,B` changes to `lighting`.
fn relight(lighting: &mut distribute::Lighting, archive: &Archive, sets: &[String]) -> Result<()> {
    let meta = archive.meta();
    let materials = archive.view().surfaces.iter().map(|s| s.material as usize).collect::<Vec<_>>();
    for set in sets {
        let (target, value) = set.split_once('=').input(|| format!("--set `{set}`: expected NAME.FIELD=R,G,B"))?;
        let (name, field) = target.rsplit_once('.').input(|| format!("--set `{set}`: expected NAME.FIELD=R,G,B"))?;
        // Fields fixed at build time, or not fields at all: say so before
        // judging the value.
        match field {
            "emission" | "reflectance" | "specular" => {}
            "alpha" | "alpha_u" | "alpha_v" | "ior" | "type" => bail_input!(
                "--set `{set}`: `{field}` shapes the material's reflectance tables, which are built into the \
                 archive: change it in the scene and rebuild (--set changes emission, reflectance and specular)"
            ),
            _ => bail_input!(
                "--set `{set}`: unknown field `{field}`: --set changes SURFACE.emission, SURFACE.reflectance or \
                 MATERIAL.reflectance, and .specular of glossy materials"
            ),
        }
        let v: Vec<f32> = value
            .split(',')
            .map(|x| x.trim().parse::<f32>())
            .collect::<Result<_, _>>()
            .ok()
            .filter(|v: &Vec<f32>| v.len() == 3 && v.iter().all(|x| x.is_finite()))
            .input(|| format!("--set `{set}`: the value must be three numbers R,G,B"))?;
        let rgb = [v[0], v[1], v[2]];
        let surface = meta.surface_names.iter().position(|s| s == name);
        let material = meta.material_names.iter().position(|m| m == name);
        match field {
            "emission" => {
                let s = surface.input(|| {
                    format!("--set `{set}`: no surface named `{name}` (surfaces: {})", meta.surface_names.join(", "))
                })?;
                if rgb.iter().any(|&x| x < 0.0) {
                    bail_input!("--set `{set}`: emission must be non-negative");
                }
                lighting.emission[s] = rgb;
                lighting.emission_fixed[s] = true;
            }
            "reflectance" | "specular" => {
                if rgb.iter().any(|&x| !(0.0..=1.0).contains(&x)) {
                    bail_input!("--set `{set}`: {field} components must be in [0, 1]");
                }
                let column = if field == "reflectance" { &mut lighting.reflectance } else { &mut lighting.specular };
                let glossy = |m: usize| archive.view().materials[m].model != archive::layout::model::DIFFUSE;
                if field == "specular"
                    && !surface.map_or_else(|| material.is_some_and(glossy), |s| glossy(materials[s]))
                {
                    bail_input!(
                        "--set `{set}`: `{name}` is diffuse: only rough_conductor and broad_specular materials have a specular colour"
                    );
                }
                match (surface, material) {
                    (Some(s), _) => column[s] = rgb,
                    (None, Some(m)) => {
                        for (s, &sm) in materials.iter().enumerate() {
                            if sm == m {
                                column[s] = rgb;
                            }
                        }
                    }
                    (None, None) => bail_input!(
                        "--set `{set}`: no surface or material named `{name}` (surfaces: {}; materials: {})",
                        meta.surface_names.join(", "),
                        meta.material_names.join(", ")
                    ),
                }
            }
            other => bail_input!("--set `{set}`: unknown field `{other}` (known: emission, reflectance, specular)"),
        }
    }
    for (s, name) in meta.surface_names.iter().enumerate() {
        if (0..3).any(|c| lighting.reflectance[s][c] + lighting.specular[s][c] > 1.0) {
            bail_input!(
                "surface `{name}`: reflectance + specular exceeds 1 in some band (the surface would create energy)"
            );
        }
    }
    Ok(())
}

/// Optional outputs of `render`: whole-sequence previews, and a
/// false-colour picture instead of the shaded PNG.
#[derive(Clone, Copy, Default)]
pub struct Extras<'a> {
    pub gif: Option<&'a Path>,
    pub contact_sheet: Option<&'a Path>,
    pub false_colour: Option<FalseColour>,
    pub reference: Option<&'a Path>,
    pub error_scale: f32,
}

/// `render`'s options checked on their own (values and combinations), so
/// that `demo` refuses a bad one before it builds.
fn check_render_args(args: &RenderArgs) -> Result<()> {
    if args.anderson > distribute::MAX_ANDERSON_DEPTH {
        bail_input!("--anderson keeps at most {} secant pairs, got {}", distribute::MAX_ANDERSON_DEPTH, args.anderson);
    }
    if !(args.tolerance > 0.0 && args.tolerance < 1.0) {
        bail_input!("--tolerance must be in (0, 1), got {}", args.tolerance);
    }
    if !(args.exposure > 0.0 && args.exposure.is_finite()) {
        bail_input!("--exposure multiplies radiance: it must be a positive number, got {}", args.exposure);
    }
    if !(1..=1_000_000).contains(&args.max_iterations) {
        bail_input!("--max-iterations must be in 1..=1000000, got {}", args.max_iterations);
    }
    if !(1..=64).contains(&args.samples) {
        bail_input!("--samples must be in 1..=64, got {}", args.samples);
    }
    if !(1..=64).contains(&args.light_samples) {
        bail_input!("--light-samples must be in 1..=64, got {}", args.light_samples);
    }
    if args.gather.is_some_and(|n| n > 0) && args.shading != Shading::Direct {
        bail_input!("--gather takes the indirect light of direct shading from rays: it needs --shading direct");
    }
    if args.gather_reach.is_nan() || args.gather_reach < 0.0 {
        bail_input!("--gather-reach {}: expected a number of patch sides ≥ 0, or inf", args.gather_reach);
    }
    Ok(())
}

#[allow(clippy::too_many_arguments)]
pub fn render(
    path: &Path,
    png: &Path,
    exr: Option<&Path>,
    frames: Option<&str>,
    args: RenderArgs,
    cameras: &RenderCameras,
    sets: &[String],
    extras: Extras<'_>,
    progress: &dyn Progress,
) -> Result<()> {
    check_render_args(&args)?;
    let direct_shading = args.shading == Shading::Direct;
    if args.layers && (exr.is_none() || !direct_shading) {
        bail_input!("--layers writes EXR layers of direct and indirect light: it needs --exr and --shading direct");
    }
    require_extension(
        png,
        "png",
        "-o",
        "-o writes a PNG image (sRGB, 8-bit): name it .png (linear OpenEXR is --exr IMAGE.exr)",
    )?;
    if let Some(exr) = exr {
        require_extension(exr, "exr", "--exr", "--exr writes OpenEXR: name it .exr")?;
    }
    if let Some(gif) = extras.gif {
        require_extension(gif, "gif", "--gif", "--gif writes an animated GIF: name it .gif")?;
    }
    if let Some(sheet) = extras.contact_sheet {
        require_extension(sheet, "png", "--contact-sheet", "--contact-sheet writes a PNG: name it .png")?;
    }
    let reference = match (extras.false_colour, extras.reference) {
        (Some(FalseColour::Error), Some(r)) => {
            require_extension(r, "exr", "--reference", "--reference takes a linear OpenEXR image")?;
            if !(extras.error_scale > 0.0 && extras.error_scale.is_finite()) {
                bail_input!("--error-scale must be a positive number, got {}", extras.error_scale);
            }
            Some(image_io::read_exr(r).map_err(IoFailure)?)
        }
        (Some(FalseColour::Error), None) => bail_input!("--false-color error needs --reference REF.exr"),
        (_, Some(_)) => bail_input!("--reference is for --false-color error"),
        _ => None,
    };
    let budget = match args.memory_budget {
        Some(bytes) => MemoryBudget { bytes, source: BudgetSource::Given },
        None => MemoryBudget::default_for_machine(),
    };
    let t = Instant::now();
    let summary = opened(path, Archive::summary(path))?;
    let archive_frames = summary.section_count(archive::layout::tag::DELTA_INDEX).max(1) as u32;
    // A walkthrough renders its path's frames; over a still archive they
    // all show frame 0's light, solved once.
    let still_walk = cameras.walkthrough_frames().is_some() && archive_frames == 1;
    let total_frames = match cameras.walkthrough_frames() {
        Some(n) if archive_frames > 1 && n > archive_frames => bail_input!(
            "the camera path has {n} frames but the archive's sequence only {archive_frames}: a path over a \
             sequence shows frame k at path frame k"
        ),
        Some(n) => n,
        None => archive_frames,
    };
    let archive_frame = |f: u32| if still_walk { 0 } else { f };
    // All frames of a sequence (or a walkthrough) unless told otherwise.
    let range = match frames {
        Some(f) => parse_frames(f, total_frames)?,
        None => 0..total_frames,
    };
    if range.end > total_frames {
        if total_frames == 1 {
            bail_input!("--frames: the archive is a still (its one frame is 0)");
        }
        bail_input!(
            "frames {}..{} are outside the archive's sequence 0..{total_frames} (frames 0 to {})",
            range.start,
            range.end,
            total_frames - 1
        );
    }
    // Every frame's camera, checked before any work.
    let mut frame_cameras = Vec::new();
    if cameras.given() {
        for f in range.clone() {
            frame_cameras.push(cameras.at(summary.camera, f)?);
        }
    }
    // The largest image any frame makes, for the memory plan.
    let (width, height) = match frame_cameras.is_empty() {
        true => (summary.camera.width, summary.camera.height),
        false => frame_cameras.iter().fold((1, 1), |(w, h), c| (w.max(c.width), h.max(c.height))),
    };
    // An error picture compares each frame's image with the reference.
    if let Some(r) = &reference {
        let sizes: Vec<(u32, u32)> = match frame_cameras.is_empty() {
            true => vec![(summary.camera.width, summary.camera.height)],
            false => frame_cameras.iter().map(|c| (c.width, c.height)).collect(),
        };
        if let Some(&(w, h)) = sizes.iter().find(|&&s| s != (r.width, r.height)) {
            bail_input!(
                "--reference is {}×{} pixels but the image is {w}×{h}: render at the reference's size (--size {}x{})",
                r.width,
                r.height,
                r.width,
                r.height
            );
        }
    }
    let job = plan::RenderJob {
        width,
        height,
        samples_per_axis: args.samples,
        frames: range.len() as u32,
        keep_images: extras.gif.is_some() || extras.contact_sheet.is_some(),
        anderson_depth: args.anderson as u32,
        buckets: !args.no_buckets,
        threads: rayon::current_num_threads() as u32,
    };
    let memory = plan::plan(&summary, &job, budget)?;
    let samples = job.width as f64 * job.height as f64 * (args.samples * args.samples) as f64 * job.frames as f64;
    if samples >= 2e9 {
        progress.note(&format!(
            "this render shades {samples:.2e} image samples ({}×{} pixels, {}×{} samples each, {} frame{}): \
             expect minutes; fewer --samples or --frames make it cheaper",
            job.width,
            job.height,
            args.samples,
            args.samples,
            job.frames,
            if job.frames == 1 { "" } else { "s" }
        ));
    }
    if memory.access == plan::LinkAccess::Mapped && args.evict_each_pass {
        bail_input!("--evict-each-pass needs the link ends streamed: give a --memory-budget below the archive's size")
    }
    // Opening checks every checksum and link: about a minute for 15 GB.
    progress.busy("opening and checking the archive");
    let archive = match memory.access {
        plan::LinkAccess::Mapped => open_archive(path),
        plan::LinkAccess::Streamed { window_ends, .. } => opened(path, Archive::open_streamed(path, window_ends)),
    };
    progress.finish();
    let archive = archive?;
    if let Some(stream) = archive.link_stream() {
        stream.evict_each_pass(args.evict_each_pass);
        if let plan::LinkAccess::Streamed { in_flight, .. } = memory.access {
            stream.limit_windows_in_flight(in_flight);
        }
    }
    if budget.source == BudgetSource::Given || memory.access != plan::LinkAccess::Mapped {
        println!("memory: {memory}");
    }
    let view = archive.view();
    let t_open = t.elapsed().as_secs_f64();
    let sequence_output = range.len() > 1;
    // A false-colour picture other than the error's does not show the
    // shaded image: no gather for it by default.
    let picture_only = extras.false_colour.is_some_and(|f| !matches!(f, FalseColour::Error))
        && exr.is_none()
        && extras.gif.is_none()
        && extras.contact_sheet.is_none();
    let gather_rays = args.gather.unwrap_or(if sequence_output || picture_only {
        0
    } else {
        illumnet::render::direct::DEFAULT_GATHER_RAYS
    });
    let out_path = |pattern: &Path, f: u32| -> Result<std::path::PathBuf> {
        match frame_path(pattern, f) {
            Some(p) => Ok(p),
            None if !sequence_output => Ok(pattern.to_path_buf()),
            None => bail_input!(
                "{} needs a frame number pattern such as frame_%04d.png to render the {} frames {}..{} \
                 (or --frames N for one frame)",
                pattern.display(),
                range.len(),
                range.start,
                range.end
            ),
        }
    };
    // Check the pattern before any work.
    out_path(png, range.start)?;
    if let Some(exr) = exr {
        out_path(exr, range.start)?;
    }
    let opts = DistributeOptions {
        tolerance: args.tolerance,
        buckets: !args.no_buckets,
        patch_size_correction: !args.no_patch_size_correction,
        anderson_depth: args.anderson,
        split_direct: direct_shading,
        max_iterations: args.max_iterations,
        defer_glossy: !args.glossy_every_step,
    };
    let (mut t_dist, mut t_render, mut ends, mut t_delta) = (0.0, 0.0, 0.0, 0.0);
    let sum = |a: &[f64; 3]| a.iter().sum::<f64>();
    let mut lighting = distribute::Lighting::from_view(&view);
    relight(&mut lighting, &archive, sets)?;
    let t_s = Instant::now();
    let distributor = distribute::Distributor::new(&view, &opts, &lighting)?;
    let t_setup = t_s.elapsed().as_secs_f64();
    let mut previous: Option<distribute::Solution> = None;
    let edge_samples = args.edge_samples.unwrap_or(match sequence_output || !direct_shading {
        true => 0,
        false => illumnet::render::DEFAULT_EDGE_SAMPLES,
    });
    let render_opts = RenderOptions { samples_per_axis: args.samples, edge_samples_per_axis: edge_samples };
    let mut renderer = render::Renderer::new(&view, render_opts).with_cache_budget(memory.cache_bytes);
    let keep_images = extras.gif.is_some() || extras.contact_sheet.is_some();
    let mut images = Vec::new();
    let mut iterations = 0;
    let mut warned_dark = false;
    let mut size = (summary.camera.width, summary.camera.height);
    for f in range.clone() {
        let t1 = Instant::now();
        let af = archive_frame(f);
        // A walkthrough of a still archive solves the light once.
        let reuse = still_walk && previous.is_some();
        let solution = match previous.take() {
            Some(p) if reuse => p,
            p => {
                let start = if args.cold { None } else { p.as_ref() };
                distributor.frame(af, start, progress)?
            }
        };
        if cameras.given() {
            renderer.set_camera(None);
            let base = renderer.camera(af);
            renderer.set_camera(Some(cameras.at(base, f)?));
        }
        let camera = renderer.camera(af);
        size = (camera.width, camera.height);
        let eye = glam::Vec3::from(camera.position);
        if reuse {
            println!("frame {f}: the camera moved, the light is frame 0's: 0 iterations");
        }
        let b = &solution.balance;
        if !reuse {
            iterations += b.iterations;
            t_delta += solution.delta_s;
            t_dist += t1.elapsed().as_secs_f64();
            ends += b.ends_gathered as f64;
            println!(
                "{}energy balance: emitted {:.4} W, absorbed {:.4} W, {}, residual {:.2e} W (imbalance {:.1e}), {} iterations{}{}",
                if sequence_output { format!("frame {f}: ") } else { String::new() },
                sum(&b.emitted),
                sum(&b.absorbed),
                match view.patch_back_hits {
                    Some(_) =>
                        format!("absorbed by back faces {:.4} W, escaped {:.4} W", sum(&b.back_faces), sum(&b.escaped)),
                    // Without PBAK (built before version 9, or upgraded):
                    // the two are not told apart.
                    None => format!("escaped or met back faces {:.4} W (rebuild to tell them apart)", sum(&b.escaped)),
                },
                sum(&b.residual),
                b.imbalance(),
                b.iterations,
                match b.table_steps {
                    0 => String::new(),
                    k => format!(" ({k} reading glossy tables)"),
                },
                if b.converged { "" } else { " (NOT converged)" }
            );
        }
        if !b.converged && !args.allow_unconverged {
            return Err(anyhow::Error::new(ResultRefused(format!(
                "frame {f}: the distribution did not converge in {} iterations (unshot power {:.2e} of the {:.4} W \
                 emitted, tolerance {:e}): raise --max-iterations or --tolerance, or write it anyway with \
                 --allow-unconverged",
                b.iterations,
                sum(&b.residual) / sum(&b.emitted).max(f64::MIN_POSITIVE),
                sum(&b.emitted),
                args.tolerance
            ))));
        }
        let emitted = sum(&b.emitted);
        if emitted <= 0.0 && !warned_dark {
            warned_dark = true;
            eprintln!(
                "illumnet: warning: frame {f} emits no light (0 W), so only emitters seen directly will show: \
                 the scene has no surface with `emission`, or --set made them black"
            );
        } else if emitted > 0.0 && sum(&b.escaped) + sum(&b.back_faces) > 0.999 * emitted && !warned_dark {
            warned_dark = true;
            let (escaped, back) = (sum(&b.escaped), sum(&b.back_faces));
            if back > escaped {
                eprintln!(
                    "illumnet: warning: frame {f}: {:.1}% of the {emitted:.4} W emitted goes into the back faces of \
                     one-sided surfaces, which absorb it: does an emitter face a wall from behind it, or is a \
                     surface's front (the right-hand rule's normal) turned away from the room?",
                    100.0 * back / emitted
                );
            } else {
                eprintln!(
                    "illumnet: warning: frame {f}: {:.1}% of the {emitted:.4} W emitted escapes the scene without \
                     reaching a surface that absorbs it: does an emitter face away from the scene?",
                    100.0 * (escaped + back) / emitted
                );
            }
        }
        let t2 = Instant::now();
        let (image, direct) = if direct_shading {
            let mut light = render::DirectLight::new(&view, &solution, args.light_samples);
            if gather_rays > 0 {
                light = light.with_gather(&view, &solution, gather_rays, args.gather_reach);
            }
            let (image, direct) =
                renderer.frame_direct(af, &render::indirect_radiance_seen_from(&view, &solution, eye), &light);
            (image, Some(direct))
        } else {
            (renderer.frame(af, &render::radiance_seen_from(&view, &solution, eye)), None)
        };
        t_render += t2.elapsed().as_secs_f64();
        let samples = image.pixels.len() as f64 * (args.samples * args.samples) as f64;
        let (back, nothing) = (renderer.back_faces as f64 / samples, renderer.nothing_seen as f64 / samples);
        if f == range.start && back > 0.5 {
            eprintln!(
                "illumnet: warning: {:.0}% of the image shows back faces, which render black (surfaces are \
                 one-sided: their front is where the right-hand rule's normal points); is the camera inside \
                 a closed box or are some quads wound the wrong way?",
                100.0 * back
            );
        } else if f == range.start && back + nothing > 0.99 {
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
        for (what, im) in [("image", Some(&image)), ("direct light", direct.as_ref())] {
            if let Some(i) = im.and_then(|im| im.pixels.iter().position(|p| !p.iter().all(|c| c.is_finite()))) {
                return Err(anyhow::Error::new(ResultRefused(format!(
                    "frame {f}: the {what} has a non-finite pixel ({}, {}): nothing written; the archive holds values \
                     beyond what its checks bound: please report it, with the archive",
                    i % image.width as usize,
                    i / image.width as usize
                ))));
            }
        }
        // What made the image, recorded in it.
        let mut metadata = vec![
            ("Software".to_string(), format!("illumnet {}", env!("CARGO_PKG_VERSION"))),
            ("illumnet.archive".to_string(), path.display().to_string()),
            (
                "illumnet.frame".to_string(),
                format!("{f}{}", if af != f { format!(" (archive frame {af})") } else { String::new() }),
            ),
            (
                "illumnet.camera".to_string(),
                format!(
                    "position {:?}, look_at {:?}, up {:?}, fov_y {} deg, {}x{}",
                    camera.position, camera.look_at, camera.up, camera.fov_y_deg, camera.width, camera.height
                ),
            ),
            (
                "illumnet.settings".to_string(),
                format!(
                    "shading {:?}, samples {}x{}, light samples {}, gather {} rays within {} patch sides, edge \
                     samples {}x{}, tolerance {:e}, exposure {}, tone map {:?}",
                    args.shading,
                    args.samples,
                    args.samples,
                    args.light_samples,
                    gather_rays,
                    args.gather_reach,
                    edge_samples,
                    edge_samples,
                    args.tolerance,
                    args.exposure,
                    args.tone_map
                )
                .to_lowercase(),
            ),
        ];
        if !sets.is_empty() {
            metadata.push(("illumnet.set".to_string(), sets.join(" ")));
        }
        match extras.false_colour {
            None => {
                image_io::write_png_with(&image, &out_path(png, f)?, args.exposure, args.tone_map.into(), &metadata)
                    .map_err(IoFailure)?
            }
            Some(what) => {
                let picture = explain(&view, &renderer, af, what, &solution, &image, reference.as_ref(), extras)?;
                let mut m = metadata.clone();
                m.push(("illumnet.false-color".to_string(), format!("{what:?}").to_lowercase()));
                image_io::write_png_with(&picture, &out_path(png, f)?, 1.0, image_io::ToneMap::Clamp, &m)
                    .map_err(IoFailure)?;
            }
        }
        if let Some(exr) = exr {
            let path = out_path(exr, f)?;
            image_io::write_exr_with(&image, &path, &metadata).map_err(IoFailure)?;
            if let (true, Some(direct)) = (args.layers, &direct) {
                let indirect = render::Image {
                    pixels: image
                        .pixels
                        .iter()
                        .zip(&direct.pixels)
                        .map(|(t, d)| [0, 1, 2].map(|c| t[c] - d[c]))
                        .collect(),
                    ..*direct
                };
                image_io::write_exr(direct, &path.with_extension("direct.exr")).map_err(IoFailure)?;
                image_io::write_exr(&indirect, &path.with_extension("indirect.exr")).map_err(IoFailure)?;
            }
        }
        previous = Some(solution);
        if keep_images {
            images.push(image);
        }
    }
    if let Some(gif) = extras.gif {
        let fps = view.sequence.map_or(24.0, |s| s.record.fps);
        image_io::write_gif(&images, fps, args.exposure, gif).map_err(IoFailure)?;
        println!("wrote preview {}", gif.display());
    }
    if let Some(sheet) = extras.contact_sheet {
        image_io::write_contact_sheet(&images, 10, args.exposure, sheet).map_err(IoFailure)?;
        println!("wrote contact sheet {}", sheet.display());
    }
    println!(
        "rendered {} frame{} to {}{}: {}×{}, open {:.3} s, setup {:.3} s, delta apply {:.3} s, distribution {:.3} s ({} iterations, {:.0} M link ends/s; gather {:.0} M ends/s), render {:.3} s{}{}",
        range.len(),
        if range.len() == 1 { "" } else { "s" },
        png.display(),
        exr.map(|e| format!(" and {}", e.display())).unwrap_or_default(),
        size.0,
        size.1,
        t_open,
        t_setup,
        t_delta,
        t_dist - t_delta,
        iterations,
        ends / (t_dist - t_delta).max(1e-9) / 1e6,
        {
            let (seconds, gathered) = distributor.gather_totals();
            gathered as f64 / seconds.max(1e-9) / 1e6
        },
        t_render,
        if direct_shading && gather_rays > 0 {
            format!(" (one-bounce gather near corners: {gather_rays} rays per pixel)")
        } else {
            String::new()
        },
        memory::peak_resident().map(|b| format!(", peak memory {}", Bytes(b))).unwrap_or_default()
    );
    Ok(())
}

/// The false-colour picture `what` of frame `af` (`image`: its shaded
/// image, for `error`), its scale printed.
#[allow(clippy::too_many_arguments)]
fn explain(
    view: &archive::InetView<'_>,
    renderer: &render::Renderer<'_>,
    af: u32,
    what: FalseColour,
    solution: &distribute::Solution,
    image: &render::Image,
    reference: Option<&render::Image>,
    extras: Extras<'_>,
) -> Result<render::Image> {
    use render::false_colour::{self, Quantity};
    let q = match what {
        FalseColour::Error => {
            let reference = reference.expect("checked before the render");
            let picture = false_colour::error_picture(image, reference, extras.error_scale, 1.0).map_err(BadInput)?;
            println!(
                "false colour error: relative luminance error |a − r| / (r + 0.01) against the reference, 0 (dark) \
                 to {} (bright); emitters black",
                extras.error_scale
            );
            return Ok(picture);
        }
        FalseColour::Links => Quantity::Links,
        FalseColour::Hits => Quantity::Hits,
        FalseColour::Buckets => Quantity::Buckets,
        FalseColour::Patches => Quantity::Patches,
        FalseColour::Residual => Quantity::Residual,
    };
    let values = false_colour::patch_values(view, q, Some(&solution.residual)).map_err(anyhow::Error::new)?;
    let scale = false_colour::scale_of(q, &values);
    let what = match q {
        Quantity::Links => "link ends per patch",
        Quantity::Hits => "rays that reached a patch over those its area should catch (H_p / E[H_p])",
        Quantity::Buckets => "share of a patch's rays in wide buckets",
        Quantity::Patches => "every patch its own colour",
        Quantity::Residual => "power left unshot over power received, per patch",
    };
    if q == Quantity::Patches {
        println!("false colour patches: {what} ({} patches)", values.len());
    } else {
        println!(
            "false colour {}: {what}, {} scale from {} (dark) to {} (bright)",
            format!("{q:?}").to_lowercase(),
            if scale.log { "log" } else { "linear" },
            scale.min,
            scale.max
        );
    }
    Ok(false_colour::picture(&renderer.sample_patches(af), &values, q, &scale))
}

/// What `inspect` says of one surface: its primitives, patches, area and
/// emitted power (π·L·area per channel, W) at frame 0 (in a sequence, only
/// the instances present then: the others are the same surface at other
/// frames).
fn surface_summary(
    v: &archive::InetView<'_>,
    sf: &archive::layout::SurfaceRecord,
    present: &[bool],
) -> (u64, u64, f64, [f64; 3]) {
    let first = sf.first_primitive as usize;
    let range = first..first + sf.primitive_count as usize;
    let prims: Vec<&archive::layout::PrimitiveRecord> =
        range.filter(|&i| present.get(i).copied().unwrap_or(false)).map(|i| &v.primitives[i]).collect();
    // A group of grouped triangles (consecutive, one patch) counts once.
    let patches: u64 = prims
        .iter()
        .enumerate()
        .map(|(i, p)| match p.kind {
            archive::layout::kind::GROUPED_TRIANGLE => {
                u64::from(i == 0 || prims[i - 1].kind != p.kind || prims[i - 1].first_patch != p.first_patch)
            }
            _ => (p.grid_u as u64) * (p.grid_v as u64),
        })
        .sum();
    let primitives = prims.len() as u64;
    let area: f64 = prims
        .iter()
        .map(|p| {
            let kind = if p.kind == 0 { geometry::PrimitiveKind::Quad } else { geometry::PrimitiveKind::Triangle };
            geometry::Primitive { kind, p: p.corners.map(glam::Vec3::from) }.area() as f64
        })
        .sum();
    (primitives, patches, area, sf.emission.map(|e| std::f64::consts::PI * e as f64 * area))
}

/// The scene-format name of a material model code.
fn model_name(m: u32) -> &'static str {
    match m {
        archive::layout::model::DIFFUSE => "diffuse",
        archive::layout::model::ROUGH_CONDUCTOR => "rough_conductor",
        archive::layout::model::BROAD_SPECULAR => "broad_specular",
        _ => "unknown",
    }
}

/// Most materials and surfaces the text `inspect` lists one by one.
const LIST_LIMIT: usize = 24;

pub fn inspect(path: &Path, json: bool) -> Result<()> {
    // Inspecting reads no link end after validation: streamed, it holds a
    // chunk of them at a time whatever the archive's size.
    let archive = opened(path, Archive::open_streamed(path, archive::CHUNK_ENDS))?;
    let v = archive.view();
    let h = archive.header();
    let b = v.build;
    let meta = archive.meta();
    if json {
        let sections: Vec<serde_json::Value> = archive
            .sections()
            .iter()
            .map(|e| {
                serde_json::json!({
                    "tag": tag_name(e.tag),
                    "offset": e.offset,
                    "stored_length": e.stored_length,
                    "length": e.length,
                    "count": e.count,
                    "record_size": e.record_size,
                    "compression": match e.compression { 0 => "none", 1 => "zstd", _ => "unknown" },
                    "checksum": format!("{:016x}", e.checksum),
                })
            })
            .collect();
        let mut emitted_w = 0.0f64;
        let present = v.presence(0).primitives;
        let details: Vec<serde_json::Value> = v
            .surfaces
            .iter()
            .enumerate()
            .map(|(i, sf)| {
                let (primitives, patches, area, watts) = surface_summary(&v, sf, &present);
                emitted_w += watts.iter().sum::<f64>();
                serde_json::json!({
                    "name": meta.surface_names.get(i),
                    "material": sf.material,
                    "primitives": primitives,
                    "patches": patches,
                    "area_m2": area,
                    "emission": sf.emission,
                    "power_w": watts,
                })
            })
            .collect();
        let out = serde_json::json!({
            "format_version": h.version_write,
            "version_read": h.version_read,
            "file_length": h.file_length,
            "generator": meta.generator,
            "scene": meta.scene,
            "frequency": b.frequency,
            "directions": b.direction_count,
            "patches": b.patch_count,
            "vertices": b.vertex_count,
            "primitives": b.primitive_count,
            "surfaces": meta.surface_names,
            "materials": meta.material_names,
            "ray_spacing_m": b.ray_spacing_m,
            "patch_size_m": b.patch_size_m,
            "rays": b.ray_count,
            "hits": b.hit_count,
            "links": b.link_end_count / 2,
            "links_unmerged": b.link_count,
            "link_ends": b.link_end_count,
            "frames": v.sequence.map_or(1, |s| s.frames()),
            "instances": v.sequence.map_or(0, |s| s.instances.len()),
            "prototype_tables": v.reflectance.map_or(0, |r| r.prototypes.len()),
            "orientations": v.reflectance.map_or(0, |r| r.orientations.len()),
            "nondiffuse_patches": v.reflectance.map_or(0, |r| r.patches.len()),
            "sections": sections,
            "camera": {
                "position": v.camera.position,
                "look_at": v.camera.look_at,
                "up": v.camera.up,
                "fov_y_deg": v.camera.fov_y_deg,
                "width": v.camera.width,
                "height": v.camera.height,
            },
            "material_models": v.materials.iter().map(|m| model_name(m.model)).collect::<Vec<_>>(),
            "surface_details": details,
            "emitted_w": emitted_w,
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    println!(
        "{}: illumnet archive, format version {} (readable by version {}+)",
        path.display(),
        h.version_write,
        h.version_read
    );
    println!("  written by {}, scene `{}`, {} bytes", meta.generator, meta.scene, h.file_length);
    println!(
        "  {} directions (f = {}), {} patches, {} vertices, {} primitives, {} surfaces, {} materials",
        b.direction_count,
        b.frequency,
        b.patch_count,
        b.vertex_count,
        b.primitive_count,
        b.surface_count,
        b.material_count
    );
    println!(
        "  {} rays at δ = {} m, {} hits, {} links ({} before merging parallel rays), {} link ends",
        b.ray_count,
        b.ray_spacing_m,
        b.hit_count,
        b.link_end_count / 2,
        b.link_count,
        b.link_end_count
    );
    let c = v.camera;
    println!(
        "  camera: at {:?} looking at {:?}, up {:?}, {}° vertical field of view, {} × {} pixels",
        c.position, c.look_at, c.up, c.fov_y_deg, c.width, c.height
    );
    let name_or = |names: &[String], i: usize| names.get(i).cloned().unwrap_or_else(|| format!("#{i}"));
    println!("  materials:");
    for (i, m) in v.materials.iter().enumerate().take(LIST_LIMIT) {
        println!("    {}: {}", name_or(&meta.material_names, i), model_name(m.model));
    }
    if v.materials.len() > LIST_LIMIT {
        println!("    … and {} more (--json lists all)", v.materials.len() - LIST_LIMIT);
    }
    let at_frame_0 = if v.sequence.is_some() { " at frame 0" } else { "" };
    println!("  surfaces (material, primitives, patches{at_frame_0}; emitters with their power, π·L·area):");
    let (mut emitters, mut power) = (0usize, [0.0f64; 3]);
    let present = v.presence(0).primitives;
    for (i, sf) in v.surfaces.iter().enumerate() {
        let (primitives, patches, area, watts) = surface_summary(&v, sf, &present);
        let emits = sf.emission.iter().any(|&e| e > 0.0);
        if emits {
            emitters += 1;
            (0..3).for_each(|k| power[k] += watts[k]);
        }
        if i < LIST_LIMIT {
            let light = if emits {
                format!(", emits {:?} W·sr⁻¹·m⁻² over {area:.4} m²: {:.3} W", sf.emission, watts.iter().sum::<f64>())
            } else {
                String::new()
            };
            println!(
                "    {}: {}, {} primitive{}, {patches} patches{light}",
                name_or(&meta.surface_names, i),
                name_or(&meta.material_names, sf.material as usize),
                primitives,
                if primitives == 1 { "" } else { "s" },
            );
        }
    }
    if v.surfaces.len() > LIST_LIMIT {
        println!("    … and {} more (--json lists all)", v.surfaces.len() - LIST_LIMIT);
    }
    println!(
        "  emitters: {emitters} surface{} emitting {:.3} W in all at frame 0 ({:.3}, {:.3}, {:.3} W per channel)",
        if emitters == 1 { "" } else { "s" },
        power.iter().sum::<f64>(),
        power[0],
        power[1],
        power[2]
    );
    if let Some(s) = v.sequence {
        let changes: u64 = s.index.iter().map(|i| i.count).sum();
        let stored: u64 = s.index.iter().map(|i| i.stored_length).sum();
        println!(
            "  sequence: {} frames at {} fps, {} temporal instances, {} link changes against frame 0 ({:.1} MB zstd)",
            s.frames(),
            s.record.fps,
            s.instances.len(),
            changes,
            stored as f64 / 1e6
        );
    }
    if let Some(r) = v.reflectance {
        let (mean, max) = r.orientations.iter().fold((0.0f64, 0.0f32), |(m, x), o| {
            (m + o.error_mean_rad as f64 / r.orientations.len() as f64, x.max(o.error_max_rad))
        });
        println!(
            "  reflectance: {} non-diffuse patches, {} orientation{} (map error mean {:.2}°, max {:.2}°)",
            r.patches.len(),
            r.orientations.len(),
            if r.orientations.len() == 1 { "" } else { "s" },
            mean.to_degrees(),
            max.to_degrees()
        );
        for (t, p) in r.prototypes.iter().enumerate() {
            let model = if p.model == archive::layout::table_model::GGX { "GGX lobe" } else { "Lambertian" };
            let ior = if p.ior == [0.0; 3] { "Fresnel 1".to_string() } else { format!("ior {:?}", p.ior) };
            println!(
                "    table {t}: {model}, α = ({}, {}), {ior}, {} band{}, {} entries ({:.1} per direction), threshold {}",
                p.alpha_u,
                p.alpha_v,
                p.bands,
                if p.bands == 1 { "" } else { "s" },
                p.entry_count,
                p.entry_count as f64 / b.direction_count as f64,
                p.threshold
            );
        }
    }
    println!("  sections:");
    println!(
        "    {:4}  {:>12}  {:>12}  {:>12}  {:>6}  {:4}  checksum",
        "tag", "offset", "stored", "records", "size", "comp"
    );
    for e in archive.sections() {
        println!(
            "    {:4}  {:>12}  {:>12}  {:>12}  {:>6}  {:4}  {:016x}",
            tag_name(e.tag),
            e.offset,
            e.stored_length,
            e.count,
            e.record_size,
            if e.compression == 1 { "zstd" } else { "none" },
            e.checksum
        );
    }
    Ok(())
}

pub fn compare(image: &Path, reference: &Path, heatmap: Option<&Path>, full_scale: f32, below: f32) -> Result<()> {
    if !(below > 0.0 && below.is_finite()) {
        return Err(anyhow::Error::new(BadInput(format!("--below must be a positive radiance, got {below}"))));
    }
    for (path, what) in [(image, "IMAGE"), (reference, "REFERENCE")] {
        let is_image = path.extension().and_then(|e| e.to_str()).is_some_and(|e| {
            ["png", "jpg", "jpeg", "tif", "tiff", "bmp", "gif", "hdr"].contains(&e.to_ascii_lowercase().as_str())
        });
        let why = if is_image {
            "compare measures linear radiance and takes OpenEXR images; PNG and other 8-bit formats hold \
             sRGB-encoded values (write linear images with `render --exr`)"
        } else {
            "compare measures linear radiance and takes OpenEXR images (`render --exr` writes one)"
        };
        require_extension(path, "exr", what, why)?;
    }
    if let Some(map) = heatmap {
        require_extension(map, "png", "--heatmap", "--heatmap writes a PNG: name it .png")?;
    }
    let read = |p: &Path| {
        image_io::read_exr(p).map_err(|e| {
            let hint = if e.contains("missing bytes") || e.contains("end of file") {
                " (the file looks truncated)"
            } else {
                ""
            };
            IoFailure(format!("{e}{hint}"))
        })
    };
    let (a, r) = (read(image)?, read(reference)?);
    let (err, map) = image_io::compare_below(&a, &r, below).map_err(BadInput)?;
    println!(
        "relative L2 {:.4}, relative MSE {:.3e}, mean absolute error {:.4e} over {} pixels",
        err.relative_l2, err.relative_mse, err.mean_abs, err.pixels
    );
    if let Some(path) = heatmap {
        image_io::write_heatmap(a.width, a.height, &map, full_scale, path).map_err(IoFailure)?;
        println!("wrote heat map {} (white = relative error ≥ {full_scale})", path.display());
    }
    Ok(())
}

/// Link ends `inspect --patch` lists one by one (by other patch, heaviest first).
const PATCH_LIST: usize = 12;

pub fn inspect_patch(path: &Path, p: u32, json: bool) -> Result<()> {
    let archive = opened(path, Archive::open_streamed(path, archive::CHUNK_ENDS))?;
    let v = archive.view();
    let meta = archive.meta();
    let n = v.patch_count();
    if p as usize >= n {
        return Err(BadInput(format!("--patch {p}: the archive has patches 0..{n}")).into());
    }
    let i = p as usize;
    let prim = v.patch_primitive[i];
    let r = &v.primitives[prim as usize];
    let surface = r.surface as usize;
    let material = v.surfaces[surface].material as usize;
    let name = |names: &[String], k: usize| names.get(k).cloned().unwrap_or_else(|| format!("#{k}"));
    let kind = match r.kind {
        archive::layout::kind::QUAD => "quad",
        archive::layout::kind::TRIANGLE => "triangle",
        _ => "grouped triangles",
    };
    // Grouped patches: the triangles of the group (consecutive primitives).
    let triangles =
        v.primitives[prim as usize..].iter().take_while(|q| q.kind == r.kind && q.first_patch == r.first_patch).count();
    let adjacent = &v.adjacency[v.adjacency_offsets[i] as usize..v.adjacency_offsets[i + 1] as usize];
    let rows = v.link_rows(&[p])?;
    let (other, weight, direction) = rows.ends(0);
    // Ends by the patch at their other end.
    let mut by_other: std::collections::BTreeMap<u32, (f64, u32)> = std::collections::BTreeMap::new();
    for (&q, &w) in other.iter().zip(weight) {
        let e = by_other.entry(q).or_default();
        e.0 += w as f64;
        e.1 += 1;
    }
    let mut ranked: Vec<(u32, f64, u32)> = by_other.iter().map(|(&q, &(w, k))| (q, w, k)).collect();
    ranked.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
    let total: f64 = weight.iter().map(|&w| w as f64).sum();
    let mut directions: Vec<u32> = direction.to_vec();
    directions.sort_unstable();
    directions.dedup();
    let surface_of = |q: u32| v.primitives[v.patch_primitive[q as usize] as usize].surface as usize;
    let (hits, expected) = (v.patch_hits[i], v.patch_expected_hits[i]);
    let back = v.patch_back_hits.map(|b| b[i]);
    if json {
        let top: Vec<serde_json::Value> = ranked
            .iter()
            .take(PATCH_LIST)
            .map(|&(q, w, k)| {
                serde_json::json!({ "patch": q, "surface": name(&meta.surface_names, surface_of(q)), "ends": k, "rays": w })
            })
            .collect();
        let out = serde_json::json!({
            "patch": p,
            "surface": name(&meta.surface_names, surface),
            "material": name(&meta.material_names, material),
            "primitive": prim,
            "kind": kind,
            "triangles": if r.kind == archive::layout::kind::GROUPED_TRIANGLE { triangles } else { 0 },
            "centre": v.patch_centre[i],
            "normal": v.patch_normal[i],
            "area_m2": v.patch_area[i],
            "hits": hits,
            "expected_hits": expected,
            "back_face_rays": back,
            "adjacent": adjacent,
            "link_ends": other.len(),
            "rays": total,
            "directions": directions.len(),
            "other_patches": ranked.len(),
            "heaviest": top,
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    println!("{} patch {p} of {n}", path.display());
    println!(
        "  surface {} ({}), primitive {prim} ({kind}{})",
        name(&meta.surface_names, surface),
        name(&meta.material_names, material),
        if r.kind == archive::layout::kind::GROUPED_TRIANGLE {
            format!(", {triangles} of them")
        } else {
            String::new()
        }
    );
    println!("  centre {:?} m, normal {:?}, area {:.4e} m²", v.patch_centre[i], v.patch_normal[i], v.patch_area[i]);
    println!(
        "  crossed by {hits} rays (H_p), {expected:.1} expected from its area and orientation ({:.0}%)",
        if expected > 0.0 { 100.0 * hits as f64 / expected as f64 } else { 0.0 }
    );
    if let Some(back) = back {
        println!(
            "  of them, {total:.0} link, {back} meet a back face (absorbed there) and {:.0} leave the scene",
            (hits as f64 - total - back as f64).max(0.0)
        );
    }
    println!("  {} adjacent patches: {adjacent:?}", adjacent.len());
    println!(
        "  {} link ends carrying {total:.0} rays, along {} of {} directions, to {} patches; heaviest:",
        other.len(),
        directions.len(),
        v.directions.len(),
        ranked.len()
    );
    for &(q, w, k) in ranked.iter().take(PATCH_LIST) {
        println!(
            "    patch {q} ({}): {k} end{}, {w:.0} rays ({:.1}%)",
            name(&meta.surface_names, surface_of(q)),
            if k == 1 { "" } else { "s" },
            100.0 * w / total.max(1.0)
        );
    }
    if ranked.len() > PATCH_LIST {
        println!("    … and {} more patches", ranked.len() - PATCH_LIST);
    }
    Ok(())
}

pub fn verify(path: &Path, json: bool) -> Result<()> {
    let r = archive::verify::verify(path)?;
    // Whether the file opened as an archive (else its one finding says why).
    let opened_at_all = r.findings.first().is_none_or(|f| f.section != "file");
    if !opened_at_all && looks_like_scene(path) {
        let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("scene");
        bail_input!(
            "{} is a scene, not an archive: build it first with `illumnet build {} -o {stem}.inet`",
            path.display(),
            path.display()
        );
    }
    let rate = r.bytes as f64 / r.seconds.max(1e-9) / 1e9;
    if json {
        let findings: Vec<serde_json::Value> = r
            .findings
            .iter()
            .map(|f| serde_json::json!({ "section": f.section, "record": f.record, "what": f.what }))
            .collect();
        let out = serde_json::json!({
            "archive": path.display().to_string(),
            "sound": r.sound(),
            "finding_count": r.finding_count,
            "findings": findings,
            "bytes": r.bytes,
            "patches": r.patches,
            "link_ends": r.link_ends,
            "frames": r.frames,
            "seconds": r.seconds,
            "gb_per_s": if opened_at_all { serde_json::json!(rate) } else { serde_json::Value::Null },
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else if r.sound() {
        println!(
            "{}: sound: {} patches, {} link ends, {} frame{} checked; {} in {:.2} s ({rate:.2} GB/s)",
            path.display(),
            r.patches,
            r.link_ends,
            r.frames,
            if r.frames == 1 { "" } else { "s" },
            Bytes(r.bytes),
            r.seconds
        );
    } else {
        println!("{}: {} finding{}", path.display(), r.finding_count, if r.finding_count == 1 { "" } else { "s" });
        for f in &r.findings {
            let at = f.record.map(|i| format!("[{i}]")).unwrap_or_default();
            println!("  {}{at}: {}", f.section, f.what);
        }
        if r.findings.len() as u64 != r.finding_count {
            println!("  ({} more not listed)", r.finding_count - r.findings.len() as u64);
        }
    }
    if r.sound() {
        Ok(())
    } else {
        let e = super::exit::Findings(format!(
            "{} finding{} in {}",
            r.finding_count,
            if r.finding_count == 1 { "" } else { "s" },
            path.display()
        ));
        let e = anyhow::Error::new(e);
        // With --json the findings are the answer, already on stdout.
        if json { Err(e.context(super::exit::JsonReported)) } else { Err(e) }
    }
}

pub fn upgrade(input: &Path, output: &Path) -> Result<()> {
    let started = Instant::now();
    let done = archive::upgrade::upgrade(input, output)?;
    if done.already_current {
        let v = done.version_before;
        if archive::upgrade::same_file(input, output) {
            println!("{} is in the current format (version {v}) already: nothing to do", input.display());
        } else {
            println!(
                "{} is in the current format (version {v}) already: copied to {}",
                input.display(),
                output.display()
            );
        }
        return Ok(());
    }
    println!(
        "upgraded {} to format version {}: {:.1} MB -> {:.1} MB ({} weights kept apart in LCNX), {:.2} s",
        output.display(),
        archive::layout::VERSION_WRITE,
        done.bytes_before as f64 / 1e6,
        done.bytes_after as f64 / 1e6,
        done.escapes,
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

pub fn demo(dir: &Path, build_args: BuildArgs, render_args: RenderArgs, progress: &dyn Progress) -> Result<()> {
    if dir.is_file() {
        bail_input!("-o {}: demo writes its archive and images into a folder, and this is a file", dir.display());
    }
    check_render_args(&render_args)?;
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create the folder {}", dir.display()))?;
    let scene = Scene::cornell_box();
    let archive = dir.join("cornell_box.inet");
    build_scene(&scene, &archive, &build_args, progress)?;
    // The render's summary reports its own peak, not the build's.
    crate::return_freed_memory();
    illumnet::memory::reset_peak_resident();
    render(
        &archive,
        &dir.join("cornell_box.png"),
        Some(&dir.join("cornell_box.exr")),
        None,
        render_args,
        &RenderCameras::default(),
        &[],
        Extras::default(),
        progress,
    )
}
