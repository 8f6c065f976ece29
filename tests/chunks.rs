//! Archives of more than 2¹⁶ patches (format version 10, §5.10): link
//! ends stored with 16-bit ids in runs of two sender chunks. Their rows
//! are ordered by bucket, then chunk; a bounded build writes the bytes of
//! an unbounded one; and the gather over the runs gives the reference
//! solver's light, mapped and streamed alike.

use std::path::{Path, PathBuf};
use std::process::Command;

use illumnet::archive::Archive;
use illumnet::archive::layout::CHUNK_PATCHES;
use illumnet::distribute::{self, DistributeOptions, Lighting, reference};
use illumnet::progress::NoProgress;

/// Builds the Cornell box cut into 120 253 patches of 4 mm (two sender
/// chunks), crossed by rays `rays` m apart along 42 directions, into
/// `dir/name`, with `extra` arguments; the build's stdout.
fn build(dir: &Path, name: &str, rays: &str, extra: &[&str]) -> (PathBuf, String) {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell_box.toml");
    let out = dir.join(name);
    let mut args = vec!["build", scene.to_str().unwrap(), "-q", "-o", out.to_str().unwrap()];
    args.extend(["--patch-size", "0.004", "--frequency", "2", "--ray-spacing", rays]);
    args.extend(extra);
    let o = Command::new(env!("CARGO_BIN_EXE_illumnet")).args(&args).output().unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(o.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&o.stderr));
    (out, stdout)
}

#[test]
fn a_bounded_build_of_two_chunks_writes_the_bytes_of_an_unbounded_one() {
    let dir = tempfile::tempdir().unwrap();
    let (full, _) = build(dir.path(), "full.inet", "0.003", &[]);
    let (bounded, out) = build(dir.path(), "bounded.inet", "0.003", &["--memory-budget", "60M"]);
    let at = out.find("spilled ").unwrap_or_else(|| panic!("no spill: {out}"));
    let runs: usize = out[at + 8..].split(' ').next().unwrap().parse().unwrap();
    assert!(runs >= 2, "{out}");
    assert!(std::fs::read(&full).unwrap() == std::fs::read(&bounded).unwrap(), "the archives differ");
    // Rows that reach both chunks, each in the format's order: by bucket,
    // then chunk, and the ids decode to the other patches.
    let a = Archive::open(&full).unwrap();
    let v = a.view();
    assert!(v.patch_count() > CHUNK_PATCHES);
    let runs = v.links.resident().unwrap().runs;
    let w = v.links.resident().unwrap().window();
    let mut across = 0;
    for q in 0..v.patch_count() {
        let r = runs.of(q);
        assert!(r.windows(2).all(|x| (x[0].bucket, x[0].chunk) < (x[1].bucket, x[1].chunk)), "patch {q}");
        across += (r.iter().any(|x| x.chunk == 0) && r.iter().any(|x| x.chunk == 1)) as usize;
        for run in w.runs_of(q) {
            for i in 0..run.ends().len() {
                assert_eq!(run.other(i) as usize / CHUNK_PATCHES, run.base() / CHUNK_PATCHES);
                assert!((run.other(i) as usize) < v.patch_count());
            }
        }
    }
    assert!(across > 1000, "{across} rows reach both chunks");
}

#[test]
fn the_gather_over_two_chunks_gives_the_reference_light_mapped_and_streamed() {
    let dir = tempfile::tempdir().unwrap();
    let (path, _) = build(dir.path(), "box.inet", "0.006", &[]);
    let mapped = Archive::open(&path).unwrap();
    // Windows of at least a chunk of ends (65 536): several windows.
    let streamed = Archive::open_streamed(&path, 1 << 16).unwrap();
    assert!(streamed.link_stream().unwrap().window_count() >= 3);
    let v = mapped.view();
    let lighting = Lighting::from_view(&v);
    for buckets in [true, false] {
        // Tight: patches of a ray or two a direction converge slowly (at
        // 1e-7, one lags the reference by 7·10⁻⁴ without buckets).
        let opts = DistributeOptions { tolerance: 1e-9, buckets, ..Default::default() };
        let fast = distribute::distribute(&v, &opts, &NoProgress).unwrap();
        let want = reference::solve(&v, 0, &lighting, &DistributeOptions { tolerance: 1e-10, ..opts }).unwrap();
        assert!(fast.balance.converged && want.converged);
        // Relative to each patch, above a floor of 10⁻³ of the brightest:
        // f32 sums against f64 (measured on one chunk: 0.7–1.6·10⁻⁶).
        let top = want.radiance.iter().flatten().fold(0.0f64, |m, &x| m.max(x));
        let worst = fast
            .radiance
            .iter()
            .zip(&want.radiance)
            .flat_map(|(a, b)| (0..3).map(move |c| (a[c] as f64 - b[c]).abs() / b[c].abs().max(1e-3 * top)))
            .fold(0.0, f64::max);
        assert!(worst < 1e-5, "buckets {buckets}: worst patch {worst:.2e} off the reference");
        let s = distribute::distribute(&streamed.view(), &opts, &NoProgress).unwrap();
        assert_eq!(s.balance.iterations, fast.balance.iterations);
        assert!(s.radiance == fast.radiance, "buckets {buckets}: streamed radiance differs from mapped");
    }
}
