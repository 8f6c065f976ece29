#!/usr/bin/env bash
# Whole-pipeline run on the Cornell box: wall time, CPU use and peak RSS of
# `illumnet build` and `illumnet render`, plus the stage summaries they print.
# Usage: tools/bench_pipeline.sh [extra build args...]
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --quiet
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
bin=target/release/illumnet
echo "== build (default settings) $*"
/usr/bin/time -f "wall %e s, cpu %P, peak RSS %M KiB" "$bin" build -q scenes/cornell_box.toml -o "$out/cb.inet" "$@"
echo "== render (cold page cache not forced; the archive was just written)"
/usr/bin/time -f "wall %e s, cpu %P, peak RSS %M KiB" "$bin" render -q "$out/cb.inet" -o "$out/cb.png" --exr "$out/cb.exr"
echo "== archive"
"$bin" inspect "$out/cb.inet" | sed -n '2,4p'
