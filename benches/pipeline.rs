//! Throughput of each stage on the Cornell box (criterion).
//!
//! `cargo bench --bench pipeline` prints rays/s (tracing), link ends/s
//! (one distribution sweep), bytes/s (archive open + validation) and
//! samples/s (render). Numbers and their interpretation: docs/PERFORMANCE.md.

use std::hint::black_box;
use std::time::Duration;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use illumnet::archive::{self, Archive};
use illumnet::bake::{self, BuildSettings};
use illumnet::distribute::{self, DistributeOptions};
use illumnet::progress::NoProgress;
use illumnet::render::{self, RenderOptions};
use illumnet::scene::{BuildHints, Scene};

fn stages(c: &mut Criterion) {
    let scene = Scene::cornell_box();
    let defaults = BuildSettings::resolve(&scene, BuildHints::default());
    let (contents, stats) = bake::build(&scene, &defaults, &NoProgress).unwrap();
    let bytes = archive::write_to_vec(&contents).unwrap();
    let archive = Archive::from_bytes(&bytes).unwrap();
    let view = archive.view();

    let mut g = c.benchmark_group("cornell");
    g.sample_size(10).measurement_time(Duration::from_secs(8)).warm_up_time(Duration::from_secs(1));

    // Tracing at a quarter of the default directions keeps one sample near 1 s.
    let coarse = BuildSettings { frequency: 8, ..defaults };
    let (_, coarse_stats) = bake::build(&scene, &coarse, &NoProgress).unwrap();
    g.throughput(Throughput::Elements(coarse_stats.rays));
    g.bench_function("build_f8 (rays)", |b| b.iter(|| bake::build(black_box(&scene), &coarse, &NoProgress).unwrap()));

    // One sweep over all link ends (max_iterations = 1).
    let one = DistributeOptions { max_iterations: 1, tolerance: 0.0, ..Default::default() };
    g.throughput(Throughput::Elements(stats.link_ends));
    g.bench_function("distribute_1_iteration (link ends)", |b| {
        b.iter(|| distribute::distribute(black_box(&view), &one, &NoProgress).unwrap())
    });

    g.throughput(Throughput::Bytes(bytes.len() as u64));
    g.bench_function("archive_validate (bytes)", |b| b.iter(|| Archive::from_bytes(black_box(&bytes)).unwrap()));

    let sol = distribute::distribute(&view, &DistributeOptions::default(), &NoProgress).unwrap();
    let opts = RenderOptions::default();
    g.throughput(Throughput::Elements(256 * 256 * 16));
    g.bench_function("render_256_16spp (samples)", |b| {
        b.iter(|| render::render(black_box(&view), &sol.radiance, &opts))
    });
    g.finish();
}

criterion_group!(benches, stages);
criterion_main!(benches);
