//! Sharded builds: one build's tracing cut into shards that run on
//! different machines (a Slurm job array), and their merge into the
//! archive a one-machine build writes, byte for byte.
//!
//! A shard is a contiguous range of the build's chunks of direction pairs
//! (`trace::chunking`, fixed by the pair count), chosen so that the
//! shards' rays (the work) are about equal. Each shard sets the build up
//! itself (deterministic, and cheap next to tracing), traces its chunks
//! under its memory budget, spills every link as the bounded build's
//! sorted runs, and writes its counts and a manifest beside them
//! (`manifest`, `counts`; format-spec/shard.md). The merge checks every
//! manifest and file, sums the counts, and hands all runs, in the order
//! of their first link, to the bounded build's merge (`bake/spill`):
//! the merge that gives a budgeted build its one-machine bytes.

pub mod counts;
pub mod manifest;

use std::fmt::Write as _;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::time::Instant;

use super::spill::{Run, SpilledLinks};
use super::{BuildError, BuildSettings, Counts, MemoryBound, Sequence, prepare, trace};
use crate::progress::Progress;
use crate::scene::Scene;
use counts::ShardCounts;
use manifest::{FileSum, Manifest, RunEntry};

/// Which shard of how many (`--shard I/K`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ShardSpec {
    /// This shard, `0..count`.
    pub index: u32,
    /// Shards the build is cut into.
    pub count: u32,
}

/// What a shard wrote, for its report.
#[derive(Debug, Clone)]
pub struct ShardReport {
    /// The manifest written.
    pub manifest: PathBuf,
    /// Chunks traced, of `chunks`.
    pub chunk_range: Range<u32>,
    /// Chunks of the build.
    pub chunks: u32,
    /// Rays traced, and the build's.
    pub rays: (u64, u64),
    /// Link-end runs written, and their bytes.
    pub runs: (usize, u64),
    /// Seconds tracing took.
    pub trace_s: f64,
}

/// Errors of a shard or a merge that concern the shards' files (exit 4
/// at the CLI): a message naming the shard and file.
#[derive(Debug, Clone, PartialEq)]
pub struct ShardError(pub String);

impl std::fmt::Display for ShardError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for ShardError {}

/// A sharded build's or merge's failure: the build's own, or its shards'.
#[derive(Debug)]
pub enum ShardFailure {
    /// The build refused or failed (a scene error, over budget, scratch).
    Build(BuildError),
    /// A shard's files are damaged, missing, or of another build.
    Shards(ShardError),
}

impl From<BuildError> for ShardFailure {
    fn from(e: BuildError) -> Self {
        Self::Build(e)
    }
}

impl std::fmt::Display for ShardFailure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Build(e) => e.fmt(f),
            Self::Shards(e) => e.fmt(f),
        }
    }
}

impl std::error::Error for ShardFailure {}

fn shards_err(m: String) -> ShardFailure {
    ShardFailure::Shards(ShardError(m))
}

/// The build's fingerprint: XXH3-64 over the scene as read, the settings
/// that shape the archive, the format and program versions, and the
/// patch and pair counts. The scene is hashed through its parsed form, so
/// every file it names counts through what was read from it.
fn fingerprint(scene: &Scene, settings: &BuildSettings, patches: usize, pairs: usize) -> String {
    struct Hasher(xxhash_rust::xxh3::Xxh3);
    impl std::fmt::Write for Hasher {
        fn write_str(&mut self, s: &str) -> std::fmt::Result {
            self.0.update(s.as_bytes());
            Ok(())
        }
    }
    // Where prototype tables are cached does not change the archive; how
    // rays find their hits does (at edges), so shards traced by different
    // tracers are refused.
    let settings = BuildSettings { prototype_library: None, ..settings.clone() };
    let mut h = Hasher(xxhash_rust::xxh3::Xxh3::new());
    let version = crate::archive::layout::VERSION_WRITE;
    let _ = write!(h, "{version} {} {scene:?} {settings:?} {patches} {pairs}", env!("CARGO_PKG_VERSION"));
    format!("{:016x}", h.0.digest())
}

/// Chunk ranges of `shards` shards over chunks of `work` rays each, with
/// about equal rays: shard i starts after every chunk whose middle lies
/// before i/K of the total rays.
pub fn balanced_ranges(work: &[u64], shards: u32) -> Vec<Range<u32>> {
    let total: u128 = work.iter().map(|&w| w as u128).sum();
    let mut starts = Vec::with_capacity(shards as usize + 1);
    let (mut c, mut before) = (0usize, 0u128);
    for i in 0..shards as u128 {
        let target = total * i / shards as u128;
        while c < work.len() && 2 * before + work[c] as u128 <= 2 * target {
            before += work[c] as u128;
            c += 1;
        }
        starts.push(c as u32);
    }
    starts.push(work.len() as u32);
    starts.windows(2).map(|w| w[0]..w[1]).collect()
}

/// Builds shard `spec` of `scene` into `dir`: traces its chunks within
/// `budget`, writes every link end as sorted runs, its counts, and last
/// its manifest (so that a shard without a manifest is unfinished).
/// `invocation` and `directory` are recorded for the merge.
#[allow(clippy::too_many_arguments)]
pub fn build_shard(
    scene: &Scene,
    settings: &BuildSettings,
    spec: ShardSpec,
    dir: &Path,
    budget: u64,
    invocation: Vec<String>,
    directory: String,
    progress: &dyn Progress,
) -> Result<ShardReport, BuildError> {
    let stem = manifest::stem(spec.index, spec.count);
    let bound = MemoryBound { budget, output: dir.join(format!("{stem}.runs")) };
    let prepared = prepare(scene, settings, Some(&bound))?;
    let setup = &prepared.setup;
    let pairs = setup.dirs.len() / 2;
    let (per_chunk, chunks) = trace::chunking(pairs as u32);
    // The work: rays per chunk (equal chunks where the ray count is
    // beyond what a build traces: the tracer refuses it below).
    let rays = match trace::largest_pair_rays(&setup.dirs, settings.ray_spacing, prepared.bounds) {
        Some(_) => trace::pair_rays(&setup.dirs, settings.ray_spacing, prepared.bounds),
        None => vec![1; pairs],
    };
    let work: Vec<u64> = rays.chunks(per_chunk as usize).map(|c| c.iter().sum()).collect();
    let range = balanced_ranges(&work, spec.count)[spec.index as usize].clone();
    let shard_rays: u64 = work[range.start as usize..range.end as usize].iter().sum();
    let spill = prepared.spill_plan(Some(&bound), settings)?.expect("a shard is bounded");
    let t = Instant::now();
    let traced = prepared.trace(settings, Some(&spill), Some(range.clone()), progress)?;
    let trace_s = t.elapsed().as_secs_f64();
    let trace::Traced { bundles, hits, nd_hits, backs, nd_backs, deltas, stats } = traced;
    // Every link to runs: what was never spilled goes too, in runs of
    // consecutive pairs.
    let mut group = Vec::new();
    for b in bundles {
        if group.last().is_some_and(|l: &super::bundle::Bundle| l.pair + 1 != b.pair) {
            spill.spill(&mut group)?;
        }
        group.push(b);
    }
    spill.spill(&mut group)?;
    let delta_file = spill.delta_file();
    let (links, offsets) = spill.finish(progress)?;
    let io = |what: &str, e: std::io::Error| {
        BuildError::Scratch(format!("cannot write shard {what} in {}: {e}", dir.display()))
    };
    let read_block = |b: &crate::archive::deltas::Block| match &delta_file {
        Some(f) => f.block_bytes(b),
        None => match &b.stored {
            crate::archive::deltas::Stored::Held(v) => Ok(v.clone()),
            _ => Err(std::io::Error::other("a spilled block without its file")),
        },
    };
    let parts = deltas
        .iter()
        .map(|part| part.iter().map(|b| read_block(b).map(|bytes| (b.count, bytes))).collect())
        .collect::<std::io::Result<_>>()
        .map_err(|e| io("link changes", e))?;
    let counts = ShardCounts {
        hits,
        backs,
        ends: offsets.windows(2).map(|w| w[1] - w[0]).collect(),
        nd_hits,
        nd_backs,
        totals: [stats.rays, stats.hits, stats.links],
        parts,
    };
    let spilled_bytes = links.spilled_bytes();
    let runs = keep_runs(links, dir, &stem).map_err(|e| io("runs", e))?;
    let counts_name = format!("{stem}.counts");
    let counts_path = dir.join(&counts_name);
    crate::scratch::write_atomic(&counts_path, |out| counts.write(out)).map_err(|e| io("counts", e))?;
    let (bytes, xxh3) = manifest::file_sum(&counts_path).map_err(|e| io("counts", e))?;
    let m = Manifest {
        kind: manifest::KIND.into(),
        manifest_version: manifest::MANIFEST_VERSION,
        binary_version: env!("CARGO_PKG_VERSION").into(),
        archive_format: crate::archive::layout::VERSION_WRITE,
        fingerprint: fingerprint(scene, settings, setup.patches.len(), pairs),
        patches: setup.patches.len() as u64,
        pairs: pairs as u64,
        frames: prepared.frames,
        chunks,
        shard: spec.index,
        shards: spec.count,
        chunk_range: [range.start, range.end],
        rays: shard_rays,
        build_rays: work.iter().sum(),
        trace_seconds: trace_s,
        invocation,
        directory,
        counts: FileSum { file: counts_name, bytes, xxh3 },
        runs: runs.clone(),
    };
    let manifest_path = dir.join(Manifest::file_name(spec.index, spec.count));
    crate::scratch::write_atomic(&manifest_path, |out| std::io::Write::write_all(out, m.to_text().as_bytes()))
        .map_err(|e| io("manifest", e))?;
    Ok(ShardReport {
        manifest: manifest_path,
        chunk_range: range,
        chunks,
        rays: (shard_rays, m.build_rays),
        runs: (runs.len(), spilled_bytes),
        trace_s,
    })
}

/// Moves a shard's runs out of its scratch directory (removed after)
/// into `dir` as `STEM-run-NNNNNN.bin`, with their sums.
fn keep_runs(links: SpilledLinks, dir: &Path, stem: &str) -> std::io::Result<Vec<RunEntry>> {
    let SpilledLinks { _dir: scratch, runs, .. } = links;
    let mut kept = Vec::with_capacity(runs.len());
    for (i, run) in runs.iter().enumerate() {
        let name = format!("{stem}-run-{i:06}.bin");
        let path = dir.join(&name);
        std::fs::rename(&run.path, &path)?;
        let (bytes, xxh3) = manifest::file_sum(&path)?;
        let file = FileSum { file: name, bytes, xxh3 };
        kept.push(RunEntry {
            first_pair: run.first.0,
            first_link: run.first.1,
            ends: run.ends,
            slots: run.slots,
            end_bytes: run.end_bytes,
            file,
        });
    }
    drop(scratch);
    Ok(kept)
}

/// A manifest read from `path`, with its directory.
pub struct ShardFiles {
    /// The manifest file.
    pub path: PathBuf,
    /// Its contents.
    pub manifest: Manifest,
}

/// Reads the manifests in each of `dirs` (every `shard-*.manifest`):
/// an error names the file that does not read.
pub fn read_manifests(dirs: &[PathBuf]) -> Result<Vec<ShardFiles>, ShardError> {
    let mut out = Vec::new();
    for dir in dirs {
        let entries = std::fs::read_dir(dir).map_err(|e| ShardError(format!("{}: {e}", dir.display())))?;
        let mut names: Vec<PathBuf> = entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "manifest"))
            .collect();
        names.sort();
        for path in names {
            let text = crate::limits::read_regular(&path, 1 << 30)
                .map_err(|e| ShardError(format!("{}: {e}", path.display())))
                .and_then(|b| String::from_utf8(b).map_err(|_| ShardError(format!("{}: not text", path.display()))))?;
            let manifest = Manifest::from_text(&text).map_err(|e| ShardError(format!("{}: {e}", path.display())))?;
            out.push(ShardFiles { path, manifest });
        }
    }
    if out.is_empty() {
        return Err(ShardError("no shard manifests (`shard-*.manifest`) in the directories given".into()));
    }
    Ok(out)
}

/// Checks that `shards` are one whole build, each once: one shard count,
/// one fingerprint, chunk ranges that tile the build's chunks in shard
/// order. Returns them sorted by shard.
pub fn check_whole(mut shards: Vec<ShardFiles>) -> Result<Vec<ShardFiles>, ShardError> {
    shards.sort_by_key(|s| s.manifest.shard);
    let first = &shards[0];
    let (k, fp) = (first.manifest.shards, first.manifest.fingerprint.clone());
    let name = |s: &ShardFiles| s.path.display().to_string();
    for s in &shards {
        let m = &s.manifest;
        if m.fingerprint != fp || m.shards != k || m.chunks != first.manifest.chunks {
            return Err(ShardError(format!(
                "{} is shard {}/{} of another build (fingerprint {}, where {} has {fp}): merge the shards of one build",
                name(s),
                m.shard,
                m.shards,
                m.fingerprint,
                name(first)
            )));
        }
    }
    for w in shards.windows(2) {
        if w[0].manifest.shard == w[1].manifest.shard {
            return Err(ShardError(format!(
                "{} and {} are both shard {}/{k}: give each shard once",
                name(&w[0]),
                name(&w[1]),
                w[0].manifest.shard
            )));
        }
    }
    let mut at = 0u32;
    for s in &shards {
        let [a, b] = s.manifest.chunk_range;
        if a != at {
            let what = if a > at {
                format!("chunks {at}..{a} are in no shard (a gap)")
            } else {
                format!("chunks {a}..{at} are in two shards (an overlap)")
            };
            return Err(ShardError(format!("{}: {what}", name(s))));
        }
        at = b;
    }
    let present: Vec<u32> = shards.iter().map(|s| s.manifest.shard).collect();
    if let Some(missing) = (0..k).find(|i| !present.contains(i)) {
        return Err(ShardError(format!("shard {missing}/{k} is missing (chunks {at}.. of {})", first.manifest.chunks)));
    }
    if at != first.manifest.chunks {
        return Err(ShardError(format!("chunks {at}..{} are in no shard", first.manifest.chunks)));
    }
    Ok(shards)
}

/// Merges whole, checked `shards` of `scene` (read again as the shards
/// read it) into a [`Sequence`] and its links, to write with
/// [`crate::archive::write_with_links`] to `output` (scratch for merge
/// passes goes next to it): the bytes of a one-machine build.
pub fn merge_shards(
    scene: &Scene,
    settings: &BuildSettings,
    shards: &[ShardFiles],
    output: &Path,
    progress: &dyn Progress,
) -> Result<(Sequence, SpilledLinks), ShardFailure> {
    let prepared = prepare(scene, settings, None)?;
    let setup = &prepared.setup;
    let (patches, pairs) = (setup.patches.len(), setup.dirs.len() / 2);
    let fp = fingerprint(scene, settings, patches, pairs);
    let nd = prepared.nd_index.iter().filter(|&&i| i != u32::MAX).count() * pairs;
    let mut sum =
        ShardCounts { hits: vec![0; patches], backs: vec![0; patches], ends: vec![0; patches], ..Default::default() };
    let (mut nd_hits, mut nd_backs) = (vec![0u32; nd], vec![0u32; nd]);
    let mut hits = vec![0u64; patches];
    let mut runs = Vec::new();
    progress.start("checking shards", shards.len() as u64);
    for s in shards {
        let m = &s.manifest;
        let dir = s.path.parent().unwrap_or(Path::new("."));
        let here = |e: String| shards_err(format!("shard {}/{} ({}): {e}", m.shard, m.shards, s.path.display()));
        if m.binary_version != env!("CARGO_PKG_VERSION") {
            return Err(here(format!(
                "traced by illumnet {}, and this is {}: merge with the version that traced the shards, or trace them again",
                m.binary_version,
                env!("CARGO_PKG_VERSION")
            )));
        }
        if m.fingerprint != fp {
            return Err(here(format!(
                "built from another scene or settings (fingerprint {}, where the scene read now gives {fp}): the scene, a file it names, or the build options changed",
                m.fingerprint
            )));
        }
        let counts_path = manifest::check_file(dir, &m.counts).map_err(here)?;
        let mut file = std::fs::File::open(&counts_path).map_err(|e| here(e.to_string()))?;
        let mut reader = std::io::BufReader::new(&mut file);
        let c = ShardCounts::read(&mut reader, m.counts.bytes, patches, nd, prepared.frames as u64).map_err(here)?;
        // Sums that cannot wrap: what no build makes is refused below (the
        // ends against the runs, H_p against 2³²) or by the archive's check.
        for p in 0..patches {
            hits[p] = hits[p].saturating_add(c.hits[p] as u64);
            sum.backs[p] = sum.backs[p].saturating_add(c.backs[p]);
            sum.ends[p] = sum.ends[p].saturating_add(c.ends[p]);
        }
        for i in 0..nd {
            nd_hits[i] = nd_hits[i].saturating_add(c.nd_hits[i]);
            nd_backs[i] = nd_backs[i].saturating_add(c.nd_backs[i]);
        }
        for t in 0..3 {
            sum.totals[t] = sum.totals[t].saturating_add(c.totals[t]);
        }
        sum.parts.extend(c.parts);
        // A run's links are of the shard's own pairs.
        let per_chunk = trace::chunking(pairs as u32).0 as u64;
        let own = m.chunk_range[0] as u64 * per_chunk..m.chunk_range[1] as u64 * per_chunk;
        for r in &m.runs {
            if !own.contains(&(r.first_pair as u64)) {
                return Err(here(format!("a run starts at pair {}, outside the shard's pairs {own:?}", r.first_pair)));
            }
            let path = manifest::check_file(dir, &r.file).map_err(here)?;
            if r.end_bytes != 8 && r.end_bytes != 12 {
                return Err(here(format!("{}: end records of {} bytes (8 or 12)", path.display(), r.end_bytes)));
            }
            let bytes =
                r.ends.checked_mul(r.end_bytes).zip(r.slots.checked_mul(12)).and_then(|(e, s)| e.checked_add(s));
            if bytes != Some(r.file.bytes) {
                return Err(here(format!("{}: its length does not hold its records", path.display())));
            }
            let (ends, slots, end_bytes) = (r.ends, r.slots, r.end_bytes);
            runs.push(Run { first: (r.first_pair, r.first_link), path, ends, slots, end_bytes });
        }
        progress.advance(1);
    }
    progress.finish();
    // The shards' tracing, summed: what the summary's rate is over.
    let trace_s = shards.iter().map(|s| s.manifest.trace_seconds).sum();
    let ends_total = sum.ends.iter().fold(0u64, |a, &e| a.saturating_add(e));
    if ends_total != runs.iter().map(|r| r.ends).sum::<u64>() {
        return Err(shards_err("the shards' link-end counts do not match their runs".into()));
    }
    let hits = hits.into_iter().map(u32::try_from).collect::<Result<Vec<u32>, _>>().map_err(|_| {
        BuildError::Failed("a patch is hit by more than 2³² rays: use smaller patches or a larger ray spacing".into())
    })?;
    runs.sort_by_key(|r| r.first);
    let links = spilled_links(runs, output, progress)?;
    let mut offsets = Vec::with_capacity(patches + 1);
    offsets.push(0u64);
    for e in &sum.ends {
        offsets.push(offsets.last().copied().unwrap_or(0) + e);
    }
    let table = super::links::LinkTable {
        offsets,
        other: Vec::new(),
        weight: Vec::new(),
        direction: Vec::new(),
        bucket: Vec::new(),
    };
    let frame_links = super::assemble::FrameLinks { table, spilled: Some(links), base: None };
    let stats = super::bundle::BundleStats { rays: sum.totals[0], hits: sum.totals[1], links: sum.totals[2] };
    let counts = Counts {
        hits,
        nd_hits,
        backs: sum.backs,
        nd_backs,
        deltas: ShardCounts::blocks(sum.parts),
        spilled_deltas: None,
        stats,
    };
    let (seq, links) = prepared.finish(scene, settings, frame_links, counts, (trace_s, 0.0), progress)?;
    Ok((seq, links.expect("the merge's links are its runs")))
}

/// The shards' runs as the links to write, merged in passes first (into
/// scratch next to `output`) when more than one merge may open.
fn spilled_links(runs: Vec<Run>, output: &Path, progress: &dyn Progress) -> Result<SpilledLinks, BuildError> {
    let spilled = (runs.len(), runs.iter().map(Run::bytes).sum());
    let ends = runs.iter().map(|r| r.ends).sum();
    let fan_in = super::spill::merge_fan_in();
    if runs.len() <= fan_in {
        return Ok(SpilledLinks { _dir: None, runs, spilled, ends });
    }
    let scratch = crate::scratch::scratch_dir(output).map_err(|e| {
        BuildError::Scratch(format!(
            "cannot make a scratch directory in {}: {e}",
            crate::scratch::dir_of(output).display()
        ))
    })?;
    // Merge passes remove the runs they merged: here those are the
    // shards', which stay; pass copies instead.
    let copies = runs
        .into_iter()
        .enumerate()
        .map(|(i, r)| {
            let path = scratch.0.path().join(format!("shard-run-{i:06}.bin"));
            std::fs::copy(&r.path, &path).map(|_| Run { path, ..r })
        })
        .collect::<std::io::Result<Vec<Run>>>()
        .map_err(|e| {
            BuildError::Scratch(format!("cannot copy a shard's run to {}: {e}", scratch.0.path().display()))
        })?;
    let runs = super::spill::merge_passes(copies, fan_in, scratch.0.path(), progress)?;
    Ok(SpilledLinks { _dir: Some(scratch), runs, spilled, ends })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_take_about_equal_work_and_tile_the_chunks() {
        let work = [10, 10, 10, 10, 100, 10, 10, 10];
        let r = balanced_ranges(&work, 3);
        assert_eq!(r.len(), 3);
        assert_eq!(r[0].start, 0);
        assert_eq!(r[2].end, 8);
        assert!(r.windows(2).all(|w| w[0].end == w[1].start));
        assert_eq!(r[1], 4..5, "the heavy chunk alone: {r:?}");
        let one = balanced_ranges(&work, 1);
        assert_eq!((one.len(), one[0].clone()), (1, 0..8));
        let many = balanced_ranges(&[1, 1], 4);
        assert_eq!(many.len(), 4);
        assert_eq!(many.iter().map(|r| r.len()).sum::<usize>(), 2);
    }
}
