#!/usr/bin/env bash
# Build cost against the number of mesh triangles: a building of 6 x 3
# rooms (tools/gen_building.py) with the Stanford bunny in every room, cut
# into 4^L triangles (L = 0..3: 6.7e4 to 4.2e6 primitives), each built at
# default settings under a memory budget, small triangles grouped (the
# default) and, for the 10^6 rung, one patch per triangle for comparison.
# Prints a markdown table: primitives, patches, setup / trace / total
# seconds, rays/s, peak resident memory (VmHWM, as the build reports it).
#
#   tools/bench_meshes.sh [BUDGET]      # default 3G; about 1 minute
#   TRACER=bvh tools/bench_meshes.sh    # the BVH tracer (default: scan)
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
BUDGET=${1:-3G}
TRACER=${TRACER:-scan}
BIN="$ROOT/target/release/illumnet"
cargo build --release --quiet --manifest-path "$ROOT/Cargo.toml"
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT
echo "| mesh cut | primitives | patches | patches of small triangles | setup (s) | trace (s) | build (s) | rays/s | peak memory | budget |"
echo "|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|"
for L in 0 1 2 3; do
  python3 "$ROOT/tools/gen_building.py" 6 3 --mesh "$ROOT/scenes/meshes/bunny.obj" --mesh-subdivide $L -o "$TMP/b$L.toml" >"$TMP/gen.txt"
  prims=$(sed -E 's/.*rooms, ([0-9]+) primitives.*/\1/' "$TMP/gen.txt")
  for mode in grouped per-triangle; do
    [ $mode = per-triangle ] && [ $L != 2 ] && continue
    extra=(); [ $mode = per-triangle ] && extra=(--no-grouping)
    out=$("$BIN" build "$TMP/b$L.toml" -o "$TMP/b.inet" -q --memory-budget "$BUDGET" --tracer "$TRACER" "${extra[@]}")
    line=$(grep '^built' <<<"$out")
    patches=$(sed -E 's/.*: ([0-9]+) patches.*/\1/' <<<"$line")
    rate=$(sed -E 's/.*rays \(([0-9.]+ M rays\/s)\).*/\1/' <<<"$line")
    total=$(sed -E 's/.*MB, ([0-9.]+) s \(.*/\1/' <<<"$line")
    setup=$(sed -E 's/.*setup ([0-9.]+) s.*/\1/' <<<"$line")
    trace=$(sed -E 's/.*trace ([0-9.]+) s.*/\1/' <<<"$line")
    peak=$(grep '^peak memory' <<<"$out" | sed 's/peak memory //')
    echo "| 4^$L | $prims | $patches | $mode | $setup | $trace | $total | $rate | $peak | $BUDGET |"
    rm -f "$TMP/b.inet"
  done
done
