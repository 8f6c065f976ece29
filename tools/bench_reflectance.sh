#!/usr/bin/env bash
# Non-diffuse reflectance, whole pipeline: the brushed plate end to end (with
# a fresh prototype table, then with the table from the library) at the four
# turns of the paper's Images 3-4, and the glossy Cornell box against the
# diffuse one in the same run (distribution cost of a non-diffuse patch).
# Usage: tools/bench_reflectance.sh
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --quiet
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
bin=target/release/illumnet
t() { /usr/bin/time -f "    wall %e s, cpu %P, peak RSS %M KiB" "$@"; }
echo "== brushed plate, fresh prototype library (table built)"
t "$bin" build -q scenes/brushed_plate.toml -o "$out/p.inet" --prototype-library "$out/lib"
t "$bin" render -q "$out/p.inet" -o "$out/p.png"
for a in 0 45 67.5 90; do
  echo "== brushed plate turned $a°, table from the library"
  t "$bin" build -q scenes/brushed_plate.toml -o "$out/p$a.inet" --turn plate=$a --prototype-library "$out/lib"
  t "$bin" render -q "$out/p$a.inet" -o "$out/p$a.png"
done
"$bin" inspect "$out/p0.inet" | sed -n '2,4p'
for s in cornell_box glossy_floor; do
  echo "== $s"
  t "$bin" build -q scenes/$s.toml -o "$out/$s.inet" --prototype-library "$out/lib"
  t "$bin" render "$out/$s.inet" -o "$out/$s.png" | grep -E "rendered|energy"
done
# The render command, glossy box against diffuse box (issue 12's bar: 3x),
# and against the glossy box with every iteration reading the tables (the
# schedule before deferral), alternating, ROUNDS times (default 5); medians.
# Both boxes again without the one-bounce gather (--gather 0), which a
# single frame takes by default and which costs both about the same.
rounds=${ROUNDS:-5}
declare -A walls
for ((r = 0; r < rounds; r++)); do
  for run in diffuse glossy every diffuse0 glossy0; do
    case $run in
      diffuse) args=("$out/cornell_box.inet") ;;
      glossy) args=("$out/glossy_floor.inet") ;;
      every) args=("$out/glossy_floor.inet" --glossy-every-step) ;;
      diffuse0) args=("$out/cornell_box.inet" --gather 0) ;;
      glossy0) args=("$out/glossy_floor.inet" --gather 0) ;;
    esac
    w=$( { /usr/bin/time -f "%e" "$bin" render -q "${args[@]}" -o "$out/x.png" >/dev/null; } 2>&1 | tail -1)
    walls[$run]+="$w "
  done
done
median() { tr ' ' '\n' <<<"$1" | grep . | sort -g | awk '{a[NR]=$1} END {print a[int((NR+1)/2)]}'; }
d=$(median "${walls[diffuse]}"); g=$(median "${walls[glossy]}"); e=$(median "${walls[every]}")
echo "== render command, median of $rounds: diffuse box $d s, glossy box $g s ($(awk "BEGIN{printf \"%.2f\", $g/$d}")x), glossy box reading tables every iteration $e s ($(awk "BEGIN{printf \"%.2f\", $e/$d}")x)"
d0=$(median "${walls[diffuse0]}"); g0=$(median "${walls[glossy0]}")
echo "== without the gather (--gather 0): diffuse box $d0 s, glossy box $g0 s ($(awk "BEGIN{printf \"%.2f\", $g0/$d0}")x)"

