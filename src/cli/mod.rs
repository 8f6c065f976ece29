//! Command-line interface: argument parsing, progress bars and summaries.
//! Only this module prints; the library reports through return values and
//! the [`illumnet::progress::Progress`] trait.

mod camera;
mod charts;
mod commands;
mod exit;
mod histograms;
mod inspect_surface;
mod progress_bar;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Parser, Subcommand};

/// Geodesic illumination networks: build an I-net archive once, render it many times.
#[derive(Parser)]
#[command(name = "illumnet", version, about, long_about = None)]
struct Cli {
    /// No progress bars (summaries and errors still print).
    #[arg(short, long, global = true)]
    quiet: bool,
    /// Worker threads (default, or 0: all cores). Output does not depend on it.
    #[arg(long, global = true, value_name = "N")]
    threads: Option<usize>,
    #[command(subcommand)]
    command: Command,
}

/// `--memory-budget`, one argument shared by `build`, `render` and `demo`
/// (which hands it to both its stages): flattened once per command, since
/// clap refuses two arguments of one name in a command.
#[derive(Args, Clone, Default)]
struct BudgetArgs {
    /// Resident memory to stay within, e.g. 512M or 4G (powers of 1024;
    /// default: 75% of the cgroup memory limit, else of physical memory).
    /// A build spills links that would not fit as sorted runs to a scratch
    /// directory next to the output and merges them into the archive (the
    /// same bytes); a render streams the link ends of an archive that does
    /// not fit whole from disk. A job that cannot fit is refused before
    /// work starts (exit 6); peak memory stays below the budget plus 64 MiB.
    #[arg(long, value_name = "SIZE", value_parser = illumnet::memory::parse_size)]
    memory_budget: Option<u64>,
}

/// Build resolution overrides (default: the scene's `[build]` table, then
/// sizes scaled to the scene: patch = diagonal/64, spacing = diagonal/128,
/// frequency 16).
#[derive(Args, Clone, Default)]
struct BuildArgs {
    /// Resolution relative to the scene's size: `draft` (about 8× faster
    /// than default), `default`, `high` (about 7× slower). --patch-size,
    /// --ray-spacing, --frequency and the scene's [build] table override it.
    #[arg(long, value_enum, default_value_t = Quality::Default)]
    quality: Quality,
    /// From [`BudgetArgs`]: `demo` takes one `--memory-budget` for its
    /// build and its render.
    #[arg(skip)]
    memory_budget: Option<u64>,
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

#[derive(Args, Clone, Copy)]
struct RenderArgs {
    /// Stop distributing when unshot power falls below this fraction of the emitted power.
    #[arg(long, default_value_t = 1e-4, value_name = "FRACTION")]
    tolerance: f64,
    /// Samples per pixel along each axis (N×N per pixel, box filter).
    #[arg(long, default_value_t = 4, value_name = "N")]
    samples: u32,
    /// Samples per axis of pixels on an edge (a corner, a silhouette: their
    /// samples see surfaces that are not one plane), traced again N×N
    /// (0: off). Default: 16 for one frame with `--shading direct`; 0 for
    /// several (a sequence or a walkthrough: each frame's cost counts) and
    /// for the paper's shading. Edges are found among the pixel's --samples
    /// (none with one sample per pixel).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(0..=64))]
    edge_samples: Option<u32>,
    /// Multiply radiance by this before tone mapping and sRGB encoding the
    /// PNG (the EXR keeps radiance as it is).
    #[arg(long, default_value_t = 1.0, value_name = "X", allow_negative_numbers = true)]
    exposure: f32,
    /// How the PNG maps radiance to display values: `clamp` (exact below
    /// 1, highlights clipped), `reinhard` (x/(1+x): nothing clipped),
    /// `aces` (a filmic curve with a soft shoulder).
    #[arg(long, value_enum, default_value_t = ToneMapArg::Clamp, value_name = "CURVE")]
    tone_map: ToneMapArg,
    /// For measurement: ignore the archive's buckets (no spreading).
    #[arg(long)]
    no_buckets: bool,
    /// Secant pairs the Anderson acceleration of the distribution keeps
    /// (0: plain iteration; at most 8; diffuse archives only).
    #[arg(long, default_value_t = 5, value_name = "N")]
    anderson: usize,
    /// For measurement: glossy patches reflect through their tables every
    /// iteration, and iteration is plain (the default reflects what has
    /// waited when it outweighs the diffuse residual, same balance).
    #[arg(long)]
    glossy_every_step: bool,
    /// For measurement: drop the H_p/H_u patch-size correction of §3.4.
    #[arg(long)]
    no_patch_size_correction: bool,
    /// Start every frame's distribution from zero instead of from the
    /// previous frame's light (same answer, more iterations).
    #[arg(long)]
    cold: bool,
    /// `direct`: light straight from the emitters computed per image
    /// sample (exact, with shadows), the I-net giving the indirect light;
    /// `inet`: the paper's rendering, all light interpolated from the
    /// patches (§3.5).
    #[arg(long, value_enum, default_value_t = Shading::Direct)]
    shading: Shading,
    /// Shadow rays, N×N per pixel and primitive, that pixels near a
    /// blocked first ray take again, shared by all emitters in proportion
    /// to their light; only those to the emitters found blocked nearby are
    /// traced (`--shading direct`; every pixel first takes four).
    #[arg(long, default_value_t = illumnet::render::direct::DEFAULT_LIGHT_SAMPLES, value_name = "N")]
    light_samples: u32,
    /// One-bounce gather: diffuse image samples near other geometry
    /// (corners, contacts) take their indirect light from rays of their
    /// own, N per pixel, each computing the direct light where it lands
    /// and looking up the I-net's indirect light there, instead of
    /// interpolating it between patch vertices (`--shading direct`; 0:
    /// off). Default: 256 for one frame; 0 for several (a sequence or a
    /// walkthrough, where each frame's cost counts and fresh noise would
    /// flicker) and for a `--false-color` picture other than `error`
    /// written alone (it does not show the shaded image; with `--exr`,
    /// `--gif` or `--contact-sheet`, which do, the default is a frame's).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(0..=4096))]
    gather: Option<u32>,
    /// Where the gather applies: samples whose nearest geometry is within
    /// X patch sides take it whole, fading out to 2X (`inf`: every diffuse
    /// sample; the interpolated light is smooth elsewhere and the gather
    /// only adds noise there).
    #[arg(long, default_value_t = 1.0, value_name = "X")]
    gather_reach: f32,
    /// With --exr and `--shading direct`: also write the direct and the
    /// indirect light as IMAGE.direct.exr and IMAGE.indirect.exr.
    #[arg(long)]
    layers: bool,
    /// Most distribution iterations per frame.
    #[arg(long, default_value_t = 1000, value_name = "N")]
    max_iterations: u32,
    /// Write images even when the distribution stops at --max-iterations
    /// before unshot power is below --tolerance (otherwise an error,
    /// exit 7, after the frame's energy balance is printed).
    #[arg(long)]
    allow_unconverged: bool,
    /// From [`BudgetArgs`], as in [`BuildArgs`].
    #[arg(skip)]
    memory_budget: Option<u64>,
    /// For measurement: drop the archive's pages from the kernel's cache
    /// before every pass over its link ends, so each distribution
    /// iteration reads them from disk (needs a --memory-budget that
    /// streams them; Linux).
    #[arg(long)]
    evict_each_pass: bool,
}

/// `render`'s pictures that explain an archive (`--false-color`).
#[derive(Args, Clone)]
struct ExplainArgs {
    /// Write a false-colour picture to -o instead of the shaded image (the
    /// EXR, if asked, stays the shaded image): `links` (link ends per
    /// patch), `hits` (rays that reached a patch over those its area should
    /// catch), `buckets` (share of its rays in wide buckets), `patches` (the
    /// patch grid), `residual` (unshot over received power), `error` (per
    /// pixel against --reference); a colour bar beneath, its range printed.
    #[arg(long, value_enum, value_name = "WHAT")]
    false_color: Option<FalseColour>,
    /// Reference image (linear EXR, same size) for `--false-color error`.
    #[arg(long, value_name = "REF.exr")]
    reference: Option<PathBuf>,
    /// Relative error drawn brightest by `--false-color error`.
    #[arg(long, default_value_t = 0.25, value_name = "X")]
    error_scale: f32,
}

/// `--tone-map` curves.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
enum ToneMapArg {
    /// Clamped at 1.
    Clamp,
    /// x / (1 + x).
    Reinhard,
    /// The ACES filmic fit.
    Aces,
}

impl From<ToneMapArg> for illumnet::render::image_io::ToneMap {
    fn from(t: ToneMapArg) -> Self {
        match t {
            ToneMapArg::Clamp => Self::Clamp,
            ToneMapArg::Reinhard => Self::Reinhard,
            ToneMapArg::Aces => Self::Aces,
        }
    }
}

/// What `--false-color` draws.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum FalseColour {
    /// Link ends per patch (log scale).
    Links,
    /// H_p / E[H_p] per patch (0..2).
    Hits,
    /// Share of a patch's rays in wide buckets (0..1).
    Buckets,
    /// Every patch its own colour.
    Patches,
    /// Unshot over received power per patch (log scale).
    Residual,
    /// Relative luminance error per pixel against --reference.
    Error,
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

/// How images are shaded (see `--shading`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum Shading {
    /// Direct light per pixel, indirect light from the I-net.
    Direct,
    /// All light from the I-net (the paper's §3.5).
    Inet,
}

/// Relighting without a rebuild (repeatable): `SURFACE.emission=R,G,B`,
/// `SURFACE.reflectance=R,G,B` or `MATERIAL.reflectance=R,G,B`.
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

#[derive(Args, Clone, Default)]
struct RelightArgs {
    /// Change a surface's emitted radiance, or a surface's or material's
    /// reflectance (`.reflectance`) or a glossy one's `k_s` (`.specular`,
    /// each in [0, 1]), e.g. `--set light.emission=20,15,5`.
    #[arg(long = "set", value_name = "NAME.FIELD=R,G,B")]
    set: Vec<String>,
}

#[derive(Subcommand)]
enum Command {
    /// Build an I-net archive from a scene file.
    Build {
        /// Scene file: TOML (format-spec/scene.md), glTF 2.0 (.gltf, .glb) or
        /// Wavefront OBJ with its MTL (.obj).
        scene: PathBuf,
        /// Archive to write.
        #[arg(short, long, value_name = "ARCHIVE")]
        output: PathBuf,
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
    },
    /// Distribute light over an archive's links and render its camera view.
    Render {
        /// Archive written by `illumnet build`.
        archive: PathBuf,
        /// PNG image to write (sRGB, 8-bit).
        #[arg(short, long, value_name = "IMAGE.png")]
        output: PathBuf,
        /// Also write linear radiance as OpenEXR.
        #[arg(long, value_name = "IMAGE.exr")]
        exr: Option<PathBuf>,
        /// Frames of a sequence archive to render: `A..B` (B excluded),
        /// `A..=B`, `A..` (to the end), `..B` or one frame `N`; default all.
        /// Several frames need a frame number pattern, e.g. out/frame_%04d.png.
        #[arg(long, value_name = "A..B")]
        frames: Option<String>,
        /// Also write the rendered frames as a looping animated GIF preview.
        #[arg(long, value_name = "PREVIEW.gif")]
        gif: Option<PathBuf>,
        /// Also write the rendered frames side by side as one PNG, 10 per row.
        #[arg(long, value_name = "SHEET.png")]
        contact_sheet: Option<PathBuf>,
        #[command(flatten)]
        render: RenderArgs,
        #[command(flatten)]
        budget: BudgetArgs,
        #[command(flatten)]
        camera: camera::CameraArgs,
        #[command(flatten)]
        explain: ExplainArgs,
        #[command(flatten)]
        relight: RelightArgs,
    },
    /// Validate an archive and print its header, sections and counts.
    Inspect {
        /// Archive to read.
        archive: PathBuf,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        /// Explain one patch instead: its surface, geometry, hit counts,
        /// neighbours, and where its link ends lead (grouped by the patch
        /// at their other end, heaviest first).
        #[arg(long, value_name = "N", conflicts_with_all = ["histograms", "surface"])]
        patch: Option<u32>,
        /// Explain one surface instead: material, emission, patches, ray
        /// coverage (Σ H_p over its expectation), and the surfaces its links
        /// exchange light with (heaviest first).
        #[arg(long, value_name = "NAME", conflicts_with = "histograms")]
        surface: Option<String>,
        /// Print histograms instead: link ends per patch and per direction,
        /// link lengths, H_p over its expectation, bucket use, and a
        /// sequence's changes per frame.
        #[arg(long)]
        histograms: bool,
        /// With --histograms: also draw each as a PNG bar chart in DIR
        /// (DIR/KEY.png, KEY as in the JSON).
        #[arg(long, value_name = "DIR", requires = "histograms")]
        charts: Option<PathBuf>,
    },
    /// Check an archive beyond what opening it checks: every link end
    /// between two patches that face each other along its direction, every
    /// link stored at both its ends, every frame's changes applicable.
    /// Reads the link ends a window at a time (bounded memory). Exit 0 when
    /// sound, 4 with the findings listed.
    Verify {
        /// Archive to check.
        archive: PathBuf,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Compare a linear EXR image with a reference EXR: relative L2 error,
    /// relative MSE and mean absolute error over pixels whose reference is
    /// below 1.0 (emitters seen directly are left out; see --below).
    Compare {
        /// Image to judge.
        image: std::path::PathBuf,
        /// Reference image (same size).
        reference: std::path::PathBuf,
        /// Write a PNG heat map of per-pixel relative luminance error.
        #[arg(long, value_name = "MAP.png")]
        heatmap: Option<std::path::PathBuf>,
        /// Relative error shown as white in the heat map.
        #[arg(long, default_value_t = 0.25, value_name = "X")]
        full_scale: f32,
        /// Compare only pixels whose reference is below this in every
        /// channel: above the brightest surface, below the emitters'
        /// radiance (a bright highlight needs more than the default).
        #[arg(long, default_value_t = 1.0, value_name = "RADIANCE")]
        below: f32,
    },
    /// Rewrite an archive written in an older format (versions 6 to 9) in
    /// the current one (version 11, its patches in their order, so that
    /// version 10 readers read it too): the same light, 7 bytes per link
    /// end instead of 10 (or 13). Writes a temporary file, validates it,
    /// then renames it over OUTPUT (default: the archive itself); an
    /// archive that needs no rewriting (version 10 or 11) is copied.
    Upgrade {
        /// Archive to rewrite.
        archive: PathBuf,
        /// Where to write the result (default: replace ARCHIVE).
        #[arg(short, long, value_name = "ARCHIVE")]
        output: Option<PathBuf>,
    },
    /// Build and render the embedded Cornell box.
    Demo {
        /// Directory for cornell_box.inet, .png and .exr.
        #[arg(short, long, default_value = "demo-output", value_name = "DIR")]
        output: PathBuf,
        #[command(flatten)]
        settings: BuildArgs,
        #[command(flatten)]
        render: RenderArgs,
        #[command(flatten)]
        budget: BudgetArgs,
    },
}

/// A closed stdout (`illumnet inspect ARCHIVE | head`) ends the program
/// quietly, as it does other command-line tools, instead of with a panic
/// message: Rust ignores SIGPIPE, so `println!` panics on a broken pipe.
fn quiet_on_broken_pipe() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let message = info.payload().downcast_ref::<String>().map(String::as_str).unwrap_or("");
        if message.contains("failed printing to stdout") && message.contains("Broken pipe") {
            std::process::exit(0);
        }
        default(info);
    }));
}

/// A full disk or a file-size limit (`ulimit -f`) makes a write fail with
/// an error (EFBIG) the CLI reports and cleans up after, instead of the
/// default action of SIGXFSZ, which kills the process and leaves its
/// temporary file behind.
fn file_size_limit_is_an_error() {
    #[cfg(unix)]
    // SAFETY: setting a signal's disposition to SIG_IGN installs no
    // handler code; called first thing, before any other thread exists.
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
}

/// `e` and its causes, `: `-separated, leaving out a cause the message
/// already ends with (library errors such as `ArchiveError::Io` print
/// their source and also return it as `source()`).
fn report(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if out.ends_with(&text) {
            continue;
        }
        if !out.is_empty() {
            out.push_str(": ");
        }
        out.push_str(&text);
    }
    out
}

/// Runs the CLI; errors print as `illumnet: error: …` and exit with the
/// code of their kind (`exit.rs`, README).
pub fn main() -> ExitCode {
    file_size_limit_is_an_error();
    quiet_on_broken_pipe();
    let cli = Cli::parse();
    if let Some(n) = cli.threads
        && let Err(e) = rayon::ThreadPoolBuilder::new().num_threads(n).build_global()
    {
        eprintln!("illumnet: error: cannot start {n} threads: {e}");
        return ExitCode::FAILURE;
    }
    let progress = progress_bar::BarProgress::new(cli.quiet);
    let json = matches!(cli.command, Command::Inspect { json: true, .. } | Command::Verify { json: true, .. });
    let result = match cli.command {
        Command::Build { scene, output, frame, mut settings, budget, gltf } => {
            settings.memory_budget = budget.memory_budget;
            commands::build(&scene, &gltf.options(), &output, frame, settings, &progress)
        }
        Command::Render {
            archive,
            output,
            exr,
            frames,
            gif,
            contact_sheet,
            mut render,
            budget,
            camera,
            explain,
            relight,
        } => {
            render.memory_budget = budget.memory_budget;
            let extras = commands::Extras {
                gif: gif.as_deref(),
                contact_sheet: contact_sheet.as_deref(),
                false_colour: explain.false_color,
                reference: explain.reference.as_deref(),
                error_scale: explain.error_scale,
            };
            camera::RenderCameras::new(&camera).and_then(|cameras| {
                commands::render(
                    &archive,
                    &output,
                    exr.as_deref(),
                    frames.as_deref(),
                    render,
                    &cameras,
                    &relight.set,
                    extras,
                    &progress,
                )
            })
        }
        Command::Inspect { archive, json, patch: Some(p), .. } => commands::inspect_patch(&archive, p, json),
        Command::Inspect { archive, json, surface: Some(s), .. } => {
            inspect_surface::inspect_surface(&archive, &s, json)
        }
        Command::Inspect { archive, json, histograms: true, charts, .. } => {
            histograms::inspect_histograms(&archive, json, charts.as_deref())
        }
        Command::Inspect { archive, json, .. } => commands::inspect(&archive, json),
        Command::Verify { archive, json } => commands::verify(&archive, json),
        Command::Compare { image, reference, heatmap, full_scale, below } => {
            commands::compare(&image, &reference, heatmap.as_deref(), full_scale, below)
        }
        Command::Upgrade { archive, output } => commands::upgrade(&archive, output.as_deref().unwrap_or(&archive)),
        Command::Demo { output, mut settings, mut render, budget } => {
            (settings.memory_budget, render.memory_budget) = (budget.memory_budget, budget.memory_budget);
            commands::demo(&output, settings, render, &progress)
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            let code = exit::code(&e);
            eprintln!("illumnet: error: {}", report(&e));
            if json && e.downcast_ref::<exit::JsonReported>().is_none() {
                // A `--json` command answers on stdout in JSON, failures too.
                let error = serde_json::json!({ "exit_code": code, "kind": exit::kind(code), "message": report(&e) });
                println!("{}", serde_json::json!({ "error": error }));
            }
            ExitCode::from(code)
        }
    }
}

#[cfg(test)]
mod tests {
    use clap::CommandFactory;

    use super::Cli;

    /// clap checks a command's definition (unique names and flags, valid
    /// defaults) only in builds with debug assertions, and then only for
    /// the subcommand run: this checks every one, in any build. It caught
    /// `demo` flattening two `--memory-budget` arguments.
    #[test]
    fn every_command_line_definition_is_consistent() {
        Cli::command().debug_assert();
    }

    /// `demo` hands one budget to its build and its render.
    #[test]
    fn demo_takes_one_memory_budget_for_both_stages() {
        use clap::Parser;
        let cli = Cli::try_parse_from(["illumnet", "demo", "--memory-budget", "64M"]).expect("parses");
        let super::Command::Demo { budget, .. } = cli.command else { panic!("not demo") };
        assert_eq!(budget.memory_budget, Some(64 << 20));
    }
}
