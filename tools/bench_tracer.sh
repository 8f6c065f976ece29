#!/usr/bin/env bash
# The two tracers side by side (issue 41): `build --tracer bvh` and
# `--tracer scan` alternated RUNS times on one scene, each run's "trace"
# and whole-build seconds as the build reports them, then the medians and
# the ratios bvh ÷ scan, and whether the two archives differ in size.
# Usage: tools/bench_tracer.sh [scene.toml|archive-args...] (default: the
# Cornell box at defaults); RUNS (default 5); BIN (default the release
# binary, built first); extra build arguments after the scene.
set -euo pipefail
cd "$(dirname "$0")/.."
scene=${1:-scenes/cornell_box.toml}
shift || true
runs=${RUNS:-5}
if [[ -z "${BIN:-}" ]]; then
  cargo build --release --quiet
  BIN=target/release/illumnet
fi
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
declare -A trace total
for i in $(seq "$runs"); do
  for t in bvh scan; do
    line=$("$BIN" build "$scene" -o "$out/$t.inet" --tracer "$t" "$@" 2>&1 | grep '^built')
    trace[$t]+="$(sed -E 's/.*trace ([0-9.]+) s.*/\1/' <<<"$line") "
    total[$t]+="$(sed -E 's/.*, ([0-9.]+) s \(setup.*/\1/' <<<"$line") "
  done
done
median() { tr ' ' '\n' | sed '/^$/d' | sort -g | awk '{a[NR]=$1} END {print (NR % 2) ? a[(NR+1)/2] : (a[NR/2] + a[NR/2+1]) / 2}'; }
echo "$line" | sed -E 's/ \([0-9.]+ M rays\/s\)//; s/, [0-9.]+ s \(setup.*//'
for t in bvh scan; do
  echo "$t: trace ${trace[$t]}s (median $(median <<<"${trace[$t]}")), build ${total[$t]}s (median $(median <<<"${total[$t]}"))"
done
tb=$(median <<<"${trace[bvh]}"); ts=$(median <<<"${trace[scan]}")
bb=$(median <<<"${total[bvh]}"); bs=$(median <<<"${total[scan]}")
awk -v tb="$tb" -v ts="$ts" -v bb="$bb" -v bs="$bs" \
  'BEGIN { printf "bvh ÷ scan: trace %.2f×, whole build %.2f×\n", tb / ts, bb / bs }'
echo "archive bytes: bvh $(stat -c %s "$out/bvh.inet"), scan $(stat -c %s "$out/scan.inet")"
