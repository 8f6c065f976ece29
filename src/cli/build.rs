//! `illumnet build`: a scene file to an I-net archive. Its arguments (and
//! the resolution overrides `demo` shares), the scene's preparation
//! (`--turn`, `--frame`), the bounded build, and its summary.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use illumnet::archive::{self, Archive};
use illumnet::bake::{self, BuildSettings};
use illumnet::geodesic::DirectionSetKind;
use illumnet::memory::{self, BudgetSource, Bytes, MemoryBudget};
use illumnet::progress::Progress;
use illumnet::scene::{BuildHints, GltfOptions, Scene};

use super::common::{BudgetArgs, is_archive, memory_budget};
use super::exit::{BadInput, InputContext, bail_input};
use super::inspect::surface::facing_nearby;

/// `illumnet build`'s arguments.
#[derive(Args)]
pub struct BuildCommand {
    /// Scene file: TOML (format-spec/scene.md), glTF 2.0 (.gltf, .glb) or
    /// Wavefront OBJ with its MTL (.obj).
    scene: PathBuf,
    /// Archive to write.
    #[arg(short, long, value_name = "ARCHIVE", required_unless_present = "shard")]
    output: Option<PathBuf>,
    /// Trace only shard I of K (`0/4`..`3/4`) of the build, for a cluster:
    /// its share of the direction pairs, balanced by rays, written as a
    /// shard (sorted link-end runs, counts, a checksummed manifest) into
    /// --shard-dir; `illumnet merge` makes the archive from all K, the
    /// bytes a one-machine build writes. `auto/K` takes I from
    /// $SLURM_ARRAY_TASK_ID or $JOB_COMPLETION_INDEX.
    #[arg(long, value_name = "I/K", requires = "shard_dir", conflicts_with_all = ["output", "frame"])]
    shard: Option<String>,
    /// Where a shard's files go (shared by all shards of a build).
    #[arg(long, value_name = "DIR", requires = "shard")]
    shard_dir: Option<PathBuf>,
    /// For an animated scene: build only this frame, as a still archive
    /// (default: the whole sequence in one archive).
    #[arg(long, value_name = "N")]
    frame: Option<u32>,
    #[command(flatten)]
    settings: BuildArgs,
    #[command(flatten)]
    budget: BudgetArgs,
    #[command(flatten)]
    gltf: GltfArgs,
}

/// Build resolution overrides (default: the scene's `[build]` table, then
/// sizes scaled to the scene: patch = diagonal/64, spacing = diagonal/128,
/// frequency 16).
#[derive(Args, Clone, Default)]
pub struct BuildArgs {
    /// Resolution relative to the scene's size: `draft` (about 8× faster
    /// than default), `default`, `high` (about 7× slower). --patch-size,
    /// --ray-spacing, --frequency and the scene's [build] table override it.
    #[arg(long, value_enum, default_value_t = Quality::Default)]
    quality: Quality,
    /// From [`BudgetArgs`]: `demo` takes one `--memory-budget` for its
    /// build and its render.
    #[arg(skip)]
    pub memory_budget: Option<u64>,
    /// Target patch edge length in metres.
    #[arg(long, value_name = "M")]
    patch_size: Option<f32>,
    /// Geodesic subdivision frequency f (10f²+2 directions).
    #[arg(long, value_name = "F")]
    frequency: Option<u32>,
    /// Distance between parallel rays in metres.
    #[arg(long, value_name = "M")]
    ray_spacing: Option<f32>,
    /// Widest bucket of §3.4 (0 = off; default 1): light arriving over a
    /// link whose footprint covers many patches is spread over a ring of them.
    #[arg(long, value_name = "K")]
    buckets: Option<u32>,
    /// BASELINE FOR MEASUREMENT ONLY, not a supported mode: build with the
    /// 1989 ray-space directions (uniform slopes over cube faces, rays through
    /// common intercept-plane points, no 1/cos correction) instead of the
    /// geodesic set, with about as many directions as --frequency gives.
    #[arg(long)]
    ray_space: bool,
    /// Give every triangle of a mesh its own patch (or grid of patches)
    /// instead of grouping triangles smaller than the patch size into
    /// patches of several (for comparison: docs/MESHES.md).
    #[arg(long)]
    no_grouping: bool,
    /// How patches are numbered: `spatial` (default) along a Morton curve
    /// over the primitives' centres, so that the distribution reads
    /// neighbouring per-patch state together (sequences keep primitive
    /// order); `primitives` in primitive order, as archives before format
    /// version 11.
    #[arg(long, value_enum, default_value_t = PatchOrder::Spatial)]
    patch_order: PatchOrder,
    /// How each direction's rays find their hits: `scan` (default)
    /// rasterises every primitive onto the direction's ray grid by a
    /// watertight fill rule (no ray slips between two rasterised
    /// primitives), leaving those smaller than the ray spacing squared to
    /// the rays through a BVH of them; `bvh` traverses a BVH of everything
    /// per ray, 1.2–3× slower, the reference. The archives differ only in
    /// rays within rounding of an edge (a few in 10⁵ of the link ends).
    #[arg(long, value_enum, default_value_t = Tracer::Scan)]
    tracer: Tracer,
    /// Turn a planar surface about its normal by DEG degrees before building
    /// (repeatable), e.g. `--turn plate=45` for the brushed plate.
    #[arg(long, value_name = "SURFACE=DEG")]
    turn: Vec<String>,
    /// Directory of cached prototype reflectance tables (default:
    /// $ILLUMNET_PROTOTYPES, else ~/.cache/illumnet/prototypes).
    #[arg(long, value_name = "DIR")]
    prototype_library: Option<PathBuf>,
    /// Build prototype tables without reading or writing the library.
    #[arg(long, conflicts_with = "prototype_library")]
    no_prototype_library: bool,
    /// Drop prototype-table factors below this fraction of their row's
    /// largest (default 1e-2); the dropped energy is put back by scaling.
    #[arg(long, value_name = "FRACTION")]
    table_threshold: Option<f64>,
    /// Actual-to-prototype maps: `nearest` (default) or the paper's `rings`.
    #[arg(long, value_name = "METHOD", value_parser = ["nearest", "rings"])]
    map_method: Option<String>,
}

/// Build resolution presets (see `--quality`).
#[derive(Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
enum Quality {
    /// Frequency 11, patches of diagonal/48, rays diagonal/64 apart.
    Draft,
    /// Frequency 16, patches of diagonal/64, rays diagonal/128 apart.
    #[default]
    Default,
    /// Frequency 24, patches of diagonal/64, rays diagonal/256 apart.
    High,
}

/// How a build numbers patches (see `--patch-order`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, clap::ValueEnum)]
enum PatchOrder {
    /// Along a Morton curve over the primitives' centres.
    #[default]
    Spatial,
    /// In primitive order.
    Primitives,
}

/// How a build's rays find their hits (see `--tracer`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, clap::ValueEnum)]
enum Tracer {
    /// A BVH traversal per ray.
    Bvh,
    /// Rasterisation of each primitive onto each direction's ray grid.
    #[default]
    Scan,
}

/// Choices a glTF file does not make (format-spec/scene.md, "glTF 2.0
/// scenes").
#[derive(Args, Clone, Default)]
#[command(next_help_heading = "glTF scenes")]
struct GltfArgs {
    /// The camera to use, by its node's or camera's name (default: the
    /// first camera node of the scene).
    #[arg(long = "camera", value_name = "NAME")]
    camera: Option<String>,
    /// Radius in metres of the small emitters that stand in for point and
    /// spot lights (default: the meshes' bounding diagonal / 64).
    #[arg(long, value_name = "M")]
    light_radius: Option<f32>,
    /// Frames per second at which animations are sampled (default 24).
    #[arg(long, value_name = "N")]
    fps: Option<f32>,
}

impl GltfArgs {
    fn options(&self) -> illumnet::scene::GltfOptions {
        illumnet::scene::GltfOptions { camera: self.camera.clone(), light_radius: self.light_radius, fps: self.fps }
    }
}

/// Runs `illumnet build` with its parsed arguments.
pub fn run(command: BuildCommand, progress: &dyn Progress) -> Result<()> {
    let BuildCommand { scene, output, frame, mut settings, budget, gltf, shard, shard_dir } = command;
    settings.memory_budget = budget.memory_budget;
    match (shard, shard_dir, output) {
        (None, None, Some(output)) => build(&scene, &gltf.options(), &output, frame, settings, progress),
        _ => bail_input!("give -o ARCHIVE, or --shard I/K with --shard-dir DIR"),
    }
}

/// A `build --shard I/K --shard-dir DIR` (`cli/shard.rs` runs it).
pub struct ShardJob {
    /// The scene file.
    pub scene: PathBuf,
    /// Its glTF options.
    pub gltf: GltfOptions,
    /// `I/K` or `auto/K`.
    pub spec: String,
    /// Where the shard's files go.
    pub dir: PathBuf,
    /// The build's options.
    pub args: BuildArgs,
}

impl BuildCommand {
    /// The shard this command builds, if it builds one (`--shard`).
    pub fn shard_job(&mut self) -> Option<ShardJob> {
        let (spec, dir) = (self.shard.take()?, self.shard_dir.take()?);
        let mut args = self.settings.clone();
        args.memory_budget = self.budget.memory_budget;
        Some(ShardJob { scene: self.scene.clone(), gltf: self.gltf.options(), spec, dir, args })
    }
}

/// A `build` command's scene and settings as the shards of a build gave
/// them (their manifests' invocation), read again by `merge`.
pub fn replay(invocation: &[String], directory: &Path) -> Result<(Scene, BuildSettings)> {
    #[derive(clap::Parser)]
    struct Replay {
        #[command(flatten)]
        build: BuildCommand,
        /// The global options, which may follow the command: ignored.
        #[arg(short, long)]
        quiet: bool,
        #[arg(long)]
        threads: Option<usize>,
    }
    // `-o` stands in for the shard options left out: the merge's own
    // output is not the shards'.
    let args = ["build"]
        .into_iter()
        .map(String::from)
        .chain(invocation.iter().cloned())
        .chain(["-o".into(), "merged.inet".into()]);
    let Replay { build, .. } = <Replay as clap::Parser>::try_parse_from(args)
        .map_err(|e| BadInput(format!("the shards' build command does not parse: {e}")))?;
    let scene_path = directory.join(&build.scene);
    let scene = read_scene(&scene_path, &build.gltf.options(), None, &build.settings)?;
    let settings = build_settings(&scene, &build.settings);
    Ok((scene, settings))
}

/// The sizes given on the command line, over the scene's own.
fn hints(a: &BuildArgs) -> BuildHints {
    BuildHints { patch_size: a.patch_size, frequency: a.frequency, ray_spacing: a.ray_spacing, buckets: a.buckets }
}

/// Refuses an archive named as an image or a scene: a slip (`-o scene.png`
/// meant for `render`), said before any work.
pub fn refuse_misnamed_archive(output: &Path) -> Result<()> {
    if let Some(ext) = output.extension().and_then(|e| e.to_str())
        && ["png", "exr", "jpg", "jpeg", "gif", "tif", "tiff", "hdr", "toml", "gltf", "glb", "obj"]
            .contains(&ext.to_ascii_lowercase().as_str())
    {
        bail_input!(
            "-o {}: an archive is written there, not a .{ext} file (name it .inet; `render` writes images)",
            output.display()
        );
    }
    Ok(())
}

/// The settings of a build of `scene`: the scene's own, resolved at the
/// `--quality` asked, with every option given on the command line over them.
pub fn build_settings(scene: &Scene, args: &BuildArgs) -> BuildSettings {
    let quality = match args.quality {
        Quality::Draft => bake::Quality::Draft,
        Quality::Default => bake::Quality::Default,
        Quality::High => bake::Quality::High,
    };
    let mut settings = BuildSettings::resolve_with(scene, hints(args), quality);
    if args.ray_space {
        settings.direction_set = DirectionSetKind::RaySpace;
    }
    settings.group_triangles = !args.no_grouping;
    settings.trace_method = match args.tracer {
        Tracer::Scan => illumnet::bake::TraceMethod::Scan,
        Tracer::Bvh => illumnet::bake::TraceMethod::Bvh,
    };
    settings.patch_order = match args.patch_order {
        PatchOrder::Spatial => illumnet::patch::order::PatchOrder::Spatial,
        PatchOrder::Primitives => illumnet::patch::order::PatchOrder::Primitives,
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
    settings
}

/// The folder `output` is written into, made now (for a bounded build's
/// scratch; removed again if the build fails before anything is written
/// there), cleared of what an interrupted build of this archive left.
pub fn prepare_output_folder(output: &Path) -> Result<illumnet::scratch::OutputDir> {
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
    Ok(folder)
}

/// Says what a build kept within `budget` by spilling to disk next to
/// `output`: runs of link ends, and per-frame link changes.
fn report_spills(seq: &bake::Sequence, spilled: Option<&bake::SpilledLinks>, budget: MemoryBudget, output: &Path) {
    let spilled_changes = seq.contents.sequence.as_ref().map_or(0, |q| q.deltas.spilled_bytes());
    if let Some(s) = spilled {
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
}

/// A sequence archive's shape, for the build's summary.
struct SequenceShape {
    frames: u32,
    /// Instances of moving surfaces (each present in some frames).
    moving: usize,
    /// Bytes of per-frame link changes.
    changes: u64,
}

/// Seconds of the stages a build's summary adds to the bake's own.
struct FinishSeconds {
    /// The whole build, from the bake's start to the check's end.
    total: f64,
    write: f64,
    check: f64,
}

/// Builds `scene` into the archive `output` with the resolution overrides
/// of `args` (`build` after reading the scene file, and `demo`), then
/// checks what it wrote and prints the summary.
pub fn build_scene(scene: &Scene, output: &Path, args: &BuildArgs, progress: &dyn Progress) -> Result<()> {
    // An archive named as an image is a slip (`-o scene.png` meant for
    // `render`): refused before any work.
    refuse_misnamed_archive(output)?;
    let settings = build_settings(scene, args);
    let budget = memory_budget(args.memory_budget);
    // Made now, for a bounded build's scratch; removed again if the build
    // fails before anything is written there.
    let folder = prepare_output_folder(output)?;
    let bound = bake::MemoryBound { budget: budget.bytes, output: output.to_path_buf() };
    let t = Instant::now();
    let (seq, spilled) = match bake::build_sequence_bounded(scene, &settings, &bound, progress) {
        Ok(x) => x,
        Err(bake::BuildError::Failed(m)) => return Err(BadInput(m).into()),
        // Says where a default budget came from (`ulimit -v`, the cgroup).
        Err(e @ bake::BuildError::OverBudget { .. }) if budget.source != BudgetSource::Given => {
            return Err(anyhow::Error::new(e).context(format!("the memory budget is {budget}")));
        }
        Err(e) => return Err(e.into()),
    };
    for w in &seq.warnings {
        eprintln!("warning: {w}");
    }
    report_spills(&seq, spilled.as_ref(), budget, output);
    write_and_check(output, seq, spilled, folder, t, settings.patch_size, progress)
}

/// Writes a built sequence (and its spilled links) to `output`, reads it
/// back and checks it whole, and prints the summary: the end of `build`
/// and of `merge`.
pub fn write_and_check(
    output: &Path,
    seq: bake::Sequence,
    mut spilled: Option<bake::SpilledLinks>,
    folder: illumnet::scratch::OutputDir,
    t: Instant,
    patch_size: f32,
    progress: &dyn Progress,
) -> Result<()> {
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
        SequenceShape { frames, moving, changes: q.deltas.stored_length() }
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
    let seconds = FinishSeconds { total: secs, write: t_write, check: t_check };
    print_summary(output, &stats, bytes, &seconds, sequence.as_ref());
    for w in facing_nearby(&written.view(), &written.meta().surface_names, patch_size)? {
        eprintln!("illumnet: warning: {w}");
    }
    Ok(())
}

/// The build's summary: what was built and how fast, a sequence's shape,
/// the peak memory, and the reflectance tables of non-diffuse patches.
fn print_summary(
    output: &Path,
    stats: &bake::BuildStats,
    bytes: u64,
    seconds: &FinishSeconds,
    sequence: Option<&SequenceShape>,
) {
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
        seconds.total,
        stats.setup_s,
        stats.trace_s,
        stats.assemble_s,
        seconds.write,
        seconds.check,
    );
    if let Some(&SequenceShape { frames, moving, changes }) = sequence {
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
}

/// Builds the scene of `scene_path` (with `--turn` applied, at `--frame`
/// if given) into the archive `output`.
pub fn build(
    scene_path: &Path,
    gltf: &GltfOptions,
    output: &Path,
    frame: Option<u32>,
    args: BuildArgs,
    progress: &dyn Progress,
) -> Result<()> {
    let scene = read_scene(scene_path, gltf, frame, &args)?;
    build_scene(&scene, output, &args, progress)
}

/// Reads the scene at `scene_path` as `build` does: glTF options, `--turn`,
/// and `--frame` applied.
pub fn read_scene(scene_path: &Path, gltf: &GltfOptions, frame: Option<u32>, args: &BuildArgs) -> Result<Scene> {
    let mut scene = read_turned(scene_path, gltf, args)?;
    let frames = scene.frame_count();
    match frame {
        Some(f) if frames == 1 && f > 0 => bail_input!("--frame {f}: the scene is a still (its one frame is 0)"),
        Some(f) if f >= frames => {
            bail_input!("--frame {f} is outside the sequence 0..{frames} (frames 0 to {})", frames - 1)
        }
        Some(f) => scene = scene.at_frame(f),
        None => {}
    }
    Ok(scene)
}

/// The scene file read (TOML, glTF or OBJ), its notes said, `--turn` applied.
fn read_turned(scene_path: &Path, gltf: &GltfOptions, args: &BuildArgs) -> Result<Scene> {
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
    Ok(scene)
}
