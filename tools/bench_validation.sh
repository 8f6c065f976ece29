#!/usr/bin/env bash
# What the reliability checks of issue 14 cost: the same archives opened
# and rendered by two illumnet binaries, alternating, ROUNDS times: BASE
# (a build of an earlier commit, e.g. before the checks) and this tree's.
# Reports the medians of the render's own `open` time (validation: every
# checksum, the content rules, the link-weight sums against PHIT) on the
# default Cornell box (174 MiB), and of `delta apply` (decoding and, now,
# checking each frame's records against PHIT and frame 0's links) over
# the fan room's 60 frames, and the ratios new/base. Archives are in the
# page cache throughout.
# Usage: tools/bench_validation.sh BASE_BINARY [ROUNDS]   (default 3 rounds)
#   e.g. git worktree add /tmp/base 4a0329e && (cd /tmp/base && cargo build --release)
#        tools/bench_validation.sh /tmp/base/target/release/illumnet
set -euo pipefail
cd "$(dirname "$0")/.."
base=${1:?usage: tools/bench_validation.sh BASE_BINARY [ROUNDS]}
rounds=${2:-3}
cargo build --release --quiet
new=target/release/illumnet
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
"$new" build -q scenes/cornell_box.toml -o "$out/cb.inet"
"$new" build -q scenes/fan_room.toml -o "$out/fan.inet" --quality draft
echo "archives: cornell $(du -h "$out/cb.inet" | cut -f1), fan room $(du -h "$out/fan.inet" | cut -f1); $(nproc) cores"
field() { grep -o "$2 [0-9.]* s" "$1" | head -1 | awk '{print $(NF-1)}'; }
for r in $(seq "$rounds"); do
    for who in base new; do
        bin=$base; [[ $who == new ]] && bin=$new
        "$bin" render -q "$out/cb.inet" -o "$out/cb.png" --samples 1 --shading inet >"$out/log"
        echo "$who open $(field "$out/log" open)" >>"$out/results"
        "$bin" render -q "$out/fan.inet" -o "$out/f_%04d.png" --samples 1 --shading inet >"$out/log"
        echo "$who delta $(field "$out/log" 'delta apply')" >>"$out/results"
    done
done
median() { sort -g | awk '{a[NR]=$1} END {print (NR%2) ? a[(NR+1)/2] : (a[NR/2]+a[NR/2+1])/2}'; }
for what in open delta; do
    b=$(awk -v w=$what '$1=="base" && $2==w {print $3}' "$out/results" | median)
    n=$(awk -v w=$what '$1=="new" && $2==w {print $3}' "$out/results" | median)
    echo "$what: base ${b} s, new ${n} s, new/base $(awk -v b="$b" -v n="$n" 'BEGIN {printf "%.2f", n/b}')"
done
