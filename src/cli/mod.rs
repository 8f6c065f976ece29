//! Command-line interface: argument parsing, progress bars and summaries.
//! Only this module prints; the library reports through return values and
//! the [`illumnet::progress::Progress`] trait.

mod build;
mod camera;
mod common;
mod compare;
mod demo;
mod exit;
mod frames;
mod inspect;
mod mpi;
mod progress_bar;
mod render;
mod serve;
mod shard;
mod upgrade;
mod verify;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

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

// The commands, each with its arguments in its own file. (No doc comment:
// clap would take it for the program's `about`.)
#[derive(Subcommand)]
enum Command {
    /// Build an I-net archive from a scene file.
    Build(build::BuildCommand),
    /// Distribute light over an archive's links and render its camera view.
    Render(render::RenderCommand),
    /// Relight an archive interactively in the browser: a page of its
    /// patches coloured by their radiance, with controls for the emitters,
    /// the reflectances, the exposure and the frame, re-solved as they
    /// change. Serves on loopback; the archive is never written.
    Serve(serve::ServeCommand),
    /// Validate an archive and print its header, sections and counts.
    Inspect(inspect::InspectCommand),
    /// Check an archive beyond what opening it checks: every link end
    /// between two patches that face each other along its direction, every
    /// link stored at both its ends, every frame's changes applicable.
    /// Reads the link ends a window at a time (bounded memory). Exit 0 when
    /// sound, 4 with the findings listed.
    Verify(verify::VerifyCommand),
    /// Compare a linear EXR image with a reference EXR: relative L2 error,
    /// relative MSE and mean absolute error over pixels whose reference is
    /// below 1.0 (emitters seen directly are left out; see --below).
    Compare(compare::CompareCommand),
    /// Rewrite an archive written in an older format (versions 6 to 9) in
    /// the current one (version 11, its patches in their order, so that
    /// version 10 readers read it too): the same light, 7 bytes per link
    /// end instead of 10 (or 13). Writes a temporary file, validates it,
    /// then renames it over OUTPUT (default: the archive itself); an
    /// archive that needs no rewriting (version 10 or 11) is copied.
    Upgrade(upgrade::UpgradeCommand),
    /// Merge the shards of a sharded build (`build --shard I/K`) into the
    /// archive: every manifest and file checked first (exit 4 naming the
    /// shard), the same bytes as a one-machine build.
    Merge(shard::MergeCommand),
    /// Build and render the embedded Cornell box.
    Demo(demo::DemoCommand),
    /// Frames of a render farm: `frames check` reports which are complete,
    /// missing, partial, stale or foreign (exit 8 unless all complete).
    Frames(frames::FramesCommand),
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

/// A mapped archive cut short under the process (another program
/// truncating it in place) makes the next read of a page past its new end
/// fault with SIGBUS: inside a mapping recorded by `archive::mapped`, the
/// handler says so and exits 5, as the streamed reader's "ended early"
/// does; any other SIGBUS keeps its default action (a crash, with a core).
fn mapped_archive_cut_short_is_an_error() {
    #[cfg(target_os = "linux")]
    // SAFETY: the handler is async-signal-safe (atomic loads, write(2),
    // _exit(2), signal(2)); installed first thing, before other threads.
    unsafe {
        let mut action: libc::sigaction = std::mem::zeroed();
        action.sa_sigaction = on_sigbus as *const () as usize;
        action.sa_flags = libc::SA_SIGINFO;
        libc::sigemptyset(&mut action.sa_mask);
        libc::sigaction(libc::SIGBUS, &action, std::ptr::null_mut());
    }
}

#[cfg(target_os = "linux")]
extern "C" fn on_sigbus(_: libc::c_int, info: *mut libc::siginfo_t, _: *mut libc::c_void) {
    let mut path = [0u8; 256];
    // SAFETY: `info` is the kernel's, valid for a SA_SIGINFO handler.
    let addr = unsafe { (*info).si_addr() } as usize;
    let Some(n) = illumnet::archive::mapped::fault_in(addr, &mut path) else {
        // Not ours: the default action, taken when the faulting access
        // runs again on return.
        // SAFETY: signal(2) is async-signal-safe.
        unsafe { libc::signal(libc::SIGBUS, libc::SIG_DFL) };
        return;
    };
    let parts: [&[u8]; 3] = [
        b"illumnet: error: ",
        &path[..n],
        b": the archive was cut short while it was mapped: it changed on disk under the render (truncated while in use?)\n",
    ];
    for part in parts {
        // SAFETY: write(2) and _exit(2) are async-signal-safe; a short
        // write loses part of the message, nothing else.
        unsafe { libc::write(2, part.as_ptr().cast(), part.len()) };
    }
    // SAFETY: as above.
    unsafe { libc::_exit(5) }
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

/// Runs `illumnet render` with the command line `args` (without the
/// program's name), quietly: `serve`'s "render" button runs the very
/// command a user would, so that its image is that command's.
pub(crate) fn run_render(args: &[String]) -> anyhow::Result<()> {
    let cli = Cli::try_parse_from(std::iter::once("illumnet".to_string()).chain(args.iter().cloned()))
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    match cli.command {
        Command::Render(command) => render::run(command, &illumnet::progress::NoProgress),
        _ => anyhow::bail!("not a render command"),
    }
}

/// Runs the CLI; errors print as `illumnet: error: …` and exit with the
/// code of their kind (`exit.rs`, README).
pub fn main() -> ExitCode {
    file_size_limit_is_an_error();
    mapped_archive_cut_short_is_an_error();
    quiet_on_broken_pipe();
    illumnet::memory::fit_allocators_to_address_space();
    let cli = Cli::parse();
    // Started here, not at the first parallel loop, so that a machine or
    // `ulimit -v` that cannot give the threads their stacks is an error.
    if let Err(e) = rayon::ThreadPoolBuilder::new().num_threads(cli.threads.unwrap_or(0)).build_global() {
        let n = cli.threads.map_or("the worker".to_string(), |n| n.to_string());
        return match illumnet::memory::address_space_limit() {
            Some(limit) => {
                let limit = illumnet::memory::Bytes(limit);
                eprintln!(
                    "illumnet: error: cannot start {n} threads under the address-space limit of {limit} (`ulimit -v`): {e}; raise the limit or pass --threads 1"
                );
                ExitCode::from(exit::BUDGET)
            }
            None => {
                eprintln!("illumnet: error: cannot start {n} threads: {e}");
                ExitCode::FAILURE
            }
        };
    }
    let progress = progress_bar::BarProgress::new(cli.quiet);
    let json = matches!(
        &cli.command,
        Command::Inspect(inspect::InspectCommand { json: true, .. })
            | Command::Verify(verify::VerifyCommand { json: true, .. })
    );
    let result = match cli.command {
        Command::Build(mut command) => match command.shard_job() {
            Some(job) => shard::build_shard(job, &progress),
            None => build::run(command, &progress),
        },
        Command::Render(command) => render::run(command, &progress),
        Command::Serve(command) => serve::run(command),
        Command::Inspect(command) => inspect::run(command),
        Command::Verify(command) => verify::run(command),
        Command::Compare(command) => compare::run(command),
        Command::Upgrade(command) => upgrade::run(command),
        Command::Merge(command) => shard::run(command, &progress),
        Command::Demo(command) => demo::run(command, &progress),
        Command::Frames(command) => frames::run(command),
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
        let super::Command::Demo(demo) = cli.command else { panic!("not demo") };
        assert_eq!(demo.budget.memory_budget, Some(64 << 20));
    }
}
