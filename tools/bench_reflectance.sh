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
