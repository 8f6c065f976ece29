#!/usr/bin/env bash
# The distribution's gather over a spatial patch order (format 11, the
# default for still scenes) against primitive order (`--patch-order
# primitives`), one binary, in one run: builds each scene both ways, then
# alternates the renders ROUNDS times and prints the gather's median link
# ends/s per archive, the spatial/primitive ratio, and each building's rate
# as a fraction of the default Cornell box's (issue 11's bar). Archives are
# in the page cache (just written): this measures the gather, not the disk.
#
# Scenes: the default Cornell box (8 539 patches), and buildings from
# tools/gen_building.py cut into ~10^6 patches: 4 x 4 rooms at patch 0.036 m
# (rung 3' of docs/notebook/2026-12-02-ladder-format-7.md: ~65 000 patches, 1 MiB of state, a room)
# and 8 x 8 rooms at 0.072 m (~16 500 patches a room). Needs ~15 GB of disk
# and ~10 GB of memory for the building builds; takes ~15 minutes.
# Usage: tools/bench_patch_order.sh [ROUNDS]   (default 4)
set -euo pipefail
cd "$(dirname "$0")/.."
rounds=${1:-4}
cargo build --release --quiet
bin=$(realpath target/release/illumnet)
out=${BENCH_DIR:-$(mktemp -d -p .)}
trap 'rm -rf "$out"' EXIT
python3 tools/gen_building.py 4 4 --furniture 3 -o "$out/b4.toml" >/dev/null
python3 tools/gen_building.py 8 8 --furniture 3 -o "$out/b8.toml" >/dev/null
declare -A scene=([cornell]=scenes/cornell_box.toml [b4]="$out/b4.toml" [b8]="$out/b8.toml")
declare -A args=(
  [cornell]=""
  [b4]="--frequency 8 --patch-size 0.036 --ray-spacing 0.018"
  [b8]="--frequency 8 --patch-size 0.072 --ray-spacing 0.036"
)
# The Cornell box runs 46 plain iterations (enough time to measure), the
# buildings to the default tolerance's 10-11.
declare -A render_args=(
  [cornell]="--tolerance 1e-9 --max-iterations 200 --anderson 0"
  [b4]="--tolerance 1e-4"
  [b8]="--tolerance 1e-4"
)
for s in cornell b4 b8; do
  for o in primitives spatial; do
    # shellcheck disable=SC2086
    "$bin" build -q "${scene[$s]}" -o "$out/$s-$o.inet" --patch-order $o ${args[$s]} >/dev/null
    echo "$s $o: $(stat -c %s "$out/$s-$o.inet") bytes"
  done
done
declare -A rates
for ((r = 0; r < rounds; r++)); do
  for s in cornell b4 b8; do
    for o in primitives spatial; do
      # shellcheck disable=SC2086
      g=$("$bin" render "$out/$s-$o.inet" -o "$out/x.png" --shading inet --samples 1 ${render_args[$s]} 2>&1 |
        grep -o 'gather [0-9]* M ends/s' | grep -o '[0-9]*')
      rates[$s-$o]="${rates[$s-$o]:-} $g"
    done
  done
done
median() { tr ' ' '\n' | grep . | sort -n | awk '{a[NR]=$1} END {print (NR % 2) ? a[(NR+1)/2] : (a[NR/2] + a[NR/2+1]) / 2}'; }
declare -A med
for k in "${!rates[@]}"; do
  med[$k]=$(echo "${rates[$k]}" | median)
done
for s in cornell b4 b8; do
  for o in primitives spatial; do
    echo "$s $o: gather M ends/s:${rates[$s-$o]} (median ${med[$s-$o]}, $(awk "BEGIN {printf \"%.2f\", ${med[$s-$o]} / ${med[cornell-spatial]}}")x the Cornell box's)"
  done
  echo "$s spatial / primitives: $(awk "BEGIN {printf \"%.3f\", ${med[$s-spatial]} / ${med[$s-primitives]}}")"
done
