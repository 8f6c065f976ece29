#!/usr/bin/env bash
# A/B of two illumnet binaries' archive formats in one run: each builds the
# same scenes, then their renders alternate, ROUNDS times. Reports archive
# size, and the distribution's link ends/s mapped and streamed
# (--memory-budget), medians and NEW/OLD ratios. The archives are in the
# page cache (just written): this measures bytes read and the gather, not
# the disk.
#
#   OLD: a binary of the baseline, e.g. version 6:
#        git worktree add /tmp/v6 46b68e9 && (cd /tmp/v6 && cargo build --release)
#   NEW: target/release/illumnet (built here)
#
# Scenes: the default Cornell box (8 539 patches, 13.9 M link ends) and the
# Cornell box cut into ~10^6 patches at frequency 4 (97 M ends: per-patch
# state 16 MB, out of the L2 cache).
# Usage: tools/bench_format.sh OLD_BINARY [ROUNDS]   (default 3)
set -euo pipefail
cd "$(dirname "$0")/.."
old=$(realpath "$1")
rounds=${2:-3}
cargo build --release --quiet
new=$(realpath target/release/illumnet)
out=${BENCH_DIR:-$(mktemp -d -p .)}
trap 'rm -rf "$out"' EXIT
declare -A scene_args=(
  [cornell]=""
  [million]="--patch-size 0.0014 --ray-spacing 0.0007 --frequency 4"
)
# Budgets that stream the link ends (a distribution over 10^6 patches holds ~820 MiB).
declare -A budget=([cornell]=32M [million]=1200M)
for s in cornell million; do
  for v in old new; do
    bin=${!v}
    # shellcheck disable=SC2086
    "$bin" build -q scenes/cornell_box.toml -o "$out/$s-$v.inet" ${scene_args[$s]} >/dev/null
    echo "$s $v archive $(stat -c %s "$out/$s-$v.inet") bytes"
  done
done
run() { # scene, version, label, extra args...
  local s=$1 v=$2 label=$3; shift 3
  local bin=${!v}
  "$bin" render -q "$out/$s-$v.inet" -o "$out/img.png" --samples 1 "$@" >"$out/log"
  local rate
  rate=$(grep -o '[0-9]* M link ends/s' "$out/log" | cut -d' ' -f1)
  echo "$s $label $v $rate" | tee -a "$out/results"
}
for r in $(seq "$rounds"); do
  for s in cornell million; do
    for v in old new; do
      run "$s" "$v" mapped
      run "$s" "$v" streamed --memory-budget "${budget[$s]}"
    done
  done
done
echo
echo "scene    mode       old M/s   new M/s   new/old"
python3 - "$out/results" <<'PY'
import statistics, sys
by = {}
for l in open(sys.argv[1]):
    s, mode, v, rate = l.split()
    by.setdefault((s, mode), {}).setdefault(v, []).append(float(rate))
for (s, mode), d in by.items():
    o, n = statistics.median(d["old"]), statistics.median(d["new"])
    print(f"{s:8s} {mode:9s} {o:8.0f}  {n:8.0f}  {n / o:6.2f}")
PY
