//! `build --shard I/K --shard-dir DIR` and `illumnet merge DIR... -o
//! ARCHIVE`: a build's tracing cut into shards for a cluster's job array,
//! and the archive made from them (`illumnet::bake::shard`).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use illumnet::bake::shard::{self, ShardFailure, ShardSpec};
use illumnet::memory::Bytes;
use illumnet::progress::Progress;

use super::build::{ShardJob, read_scene};
use super::common::{BudgetArgs, memory_budget};
use super::exit::{BadInput, bail_input};

/// `illumnet merge`'s arguments.
#[derive(Args)]
pub struct MergeCommand {
    /// Directories holding the shards (`shard-*.manifest` and their files);
    /// every shard of the build, each once.
    #[arg(required = true, value_name = "DIR")]
    dirs: Vec<PathBuf>,
    /// Archive to write.
    #[arg(short, long, value_name = "ARCHIVE")]
    output: PathBuf,
    #[command(flatten)]
    budget: BudgetArgs,
}

/// Parses `I/K` or `auto/K` (I from the array index a scheduler sets).
fn shard_spec(text: &str) -> Result<ShardSpec> {
    let bad = || BadInput(format!("--shard `{text}`: expected I/K with 0 ≤ I < K (e.g. 0/4), or auto/K"));
    let (i, k) = text.split_once('/').ok_or_else(bad)?;
    let count: u32 = k.trim().parse().ok().filter(|&k| k > 0 && k <= 1 << 16).ok_or_else(bad)?;
    let index: u32 = if i.trim() == "auto" {
        let var = ["SLURM_ARRAY_TASK_ID", "JOB_COMPLETION_INDEX"]
            .into_iter()
            .find_map(|v| std::env::var(v).ok().map(|x| (v, x)));
        let Some((name, value)) = var else {
            bail_input!("--shard auto/{count}: neither $SLURM_ARRAY_TASK_ID nor $JOB_COMPLETION_INDEX is set");
        };
        value
            .trim()
            .parse()
            .map_err(|_| BadInput(format!("--shard auto/{count}: ${name} is `{value}`, not an index")))?
    } else {
        i.trim().parse().map_err(|_| bad())?
    };
    if index >= count {
        bail_input!("--shard {text}: shard {index} of {count} does not exist (0..{count})");
    }
    Ok(ShardSpec { index, count })
}

/// Builds one shard of `scene_path`'s build into `dir`.
pub fn build_shard(job: ShardJob, progress: &dyn Progress) -> Result<()> {
    let ShardJob { scene: scene_path, gltf, spec, dir, args } = job;
    let (scene_path, gltf, dir) = (scene_path.as_path(), &gltf, dir.as_path());
    let spec = shard_spec(&spec)?;
    let scene = read_scene(scene_path, gltf, None, &args)?;
    let settings = super::build::build_settings(&scene, &args);
    let budget = memory_budget(args.memory_budget);
    std::fs::create_dir_all(dir).with_context(|| format!("--shard-dir {}: cannot create it", dir.display()))?;
    // What the merge needs to read the scene again: this command's
    // arguments, less the shard's own.
    let invocation = invocation_without_shard(std::env::args().skip_while(|a| a != "build").skip(1));
    let directory = std::env::current_dir().map(|d| d.display().to_string()).unwrap_or_else(|_| ".".into());
    let r = shard::build_shard(&scene, &settings, spec, dir, budget.bytes, invocation, directory, progress).map_err(
        |e| match e {
            illumnet::bake::BuildError::Failed(m) => anyhow::Error::new(BadInput(m)),
            e => anyhow::Error::new(e),
        },
    )?;
    println!(
        "shard {}/{}: chunks {}..{} of {}, {} of {} rays ({:.1}%), {} runs ({}), trace {:.2} s; wrote {}",
        spec.index,
        spec.count,
        r.chunk_range.start,
        r.chunk_range.end,
        r.chunks,
        r.rays.0,
        r.rays.1,
        100.0 * r.rays.0 as f64 / r.rays.1.max(1) as f64,
        r.runs.0,
        Bytes(r.runs.1),
        r.trace_s,
        r.manifest.display()
    );
    if let Some(peak) = illumnet::memory::peak_resident() {
        println!("peak memory {}", Bytes(peak));
    }
    Ok(())
}

/// `build`'s arguments with `--shard`, `--shard-dir` and their values left
/// out (the merge reads the scene with the rest).
fn invocation_without_shard(args: impl Iterator<Item = String>) -> Vec<String> {
    let mut out = Vec::new();
    let mut skip_next = false;
    for a in args {
        if std::mem::take(&mut skip_next) {
            continue;
        }
        match a.as_str() {
            "--shard" | "--shard-dir" => skip_next = true,
            _ if a.starts_with("--shard=") || a.starts_with("--shard-dir=") => {}
            _ => out.push(a),
        }
    }
    out
}

/// Runs `illumnet merge`.
pub fn run(command: MergeCommand, progress: &dyn Progress) -> Result<()> {
    let MergeCommand { dirs, output, budget } = command;
    super::build::refuse_misnamed_archive(&output)?;
    let shards = shard::read_manifests(&dirs).and_then(shard::check_whole)?;
    let first = &shards[0].manifest;
    let (scene, settings) = super::build::replay(&first.invocation, Path::new(&first.directory))
        .context("reading the scene the shards were built from")?;
    let budget = memory_budget(budget.memory_budget);
    let folder = super::build::prepare_output_folder(&output)?;
    let t = Instant::now();
    let (seq, links) = match shard::merge_shards(&scene, &settings, &shards, &output, progress) {
        Ok(x) => x,
        Err(ShardFailure::Shards(e)) => return Err(e.into()),
        Err(ShardFailure::Build(illumnet::bake::BuildError::Failed(m))) => return Err(BadInput(m).into()),
        Err(ShardFailure::Build(e)) => return Err(e.into()),
    };
    let secs: Vec<f64> = shards.iter().map(|s| s.manifest.trace_seconds).collect();
    let mean = secs.iter().sum::<f64>() / secs.len() as f64;
    let slowest = secs.iter().copied().fold(0.0, f64::max);
    println!(
        "merging {} shards ({} runs; tracing slowest {slowest:.2} s, mean {mean:.2} s, ratio {:.2}); memory budget {budget}",
        shards.len(),
        links.run_count(),
        slowest / mean.max(1e-9)
    );
    super::build::write_and_check(&output, seq, Some(links), folder, t, settings.patch_size, progress)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shard_options_are_left_out_of_the_invocation() {
        let args = ["scene.toml", "--shard", "0/2", "--frequency", "4", "--shard-dir=d", "--shard-dir", "x"];
        let got = invocation_without_shard(args.iter().map(|s| s.to_string()));
        assert_eq!(got, ["scene.toml", "--frequency", "4"]);
    }

    #[test]
    fn shard_specs_parse_and_bad_ones_are_refused() {
        assert_eq!(shard_spec("1/4").unwrap(), ShardSpec { index: 1, count: 4 });
        for bad in ["4/4", "1", "a/2", "0/0", "-1/2", "1/"] {
            assert!(shard_spec(bad).is_err(), "{bad}");
        }
    }
}
