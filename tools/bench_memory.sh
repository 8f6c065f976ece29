#!/usr/bin/env bash
# Rendering under a memory budget: the default Cornell box archive rendered
# mapped whole (no budget) and with its link ends streamed (budgets below
# the archive's size), alternating, ROUNDS times. Prints per run the
# distribution's link ends/s, the peak RSS the render reports (VmHWM) and
# that of /usr/bin/time, and at the end the medians and the streamed/mapped
# rate ratio. The archive is in the page cache throughout (it was just
# written): this measures the reader's cost, not the disk's.
# Usage: tools/bench_memory.sh [ROUNDS] [BUDGET...]   (default: 3 40M 96M)
set -euo pipefail
cd "$(dirname "$0")/.."
rounds=${1:-3}
shift || true
budgets=("$@")
[ ${#budgets[@]} -gt 0 ] || budgets=(40M 96M)
cargo build --release --quiet
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
bin=target/release/illumnet
"$bin" build -q scenes/cornell_box.toml -o "$out/cb.inet"
echo "archive: $(du -h "$out/cb.inet" | cut -f1)  ($(nproc) cores)"
run() { # label, extra args...
  local label=$1; shift
  local log="$out/log"
  /usr/bin/time -f "%M" -o "$out/time" "$bin" render -q "$out/cb.inet" -o "$out/img.png" --samples 4 \
    --shading inet --tolerance 1e-6 "$@" >"$log"
  local rate peak
  rate=$(grep -o '[0-9]* M link ends/s' "$log" | cut -d' ' -f1)
  peak=$(grep -o 'peak memory [0-9.]* [KMG]iB' "$log" | cut -d' ' -f3-)
  echo "$label $rate $peak $(($(cat "$out/time") / 1024))" | tee -a "$out/results"
}
for r in $(seq "$rounds"); do
  run mapped
  for b in "${budgets[@]}"; do run "budget-$b" --memory-budget "$b"; done
done
echo
echo "label  median M link ends/s  ratio to mapped  peak (VmHWM)"
python3 - "$out/results" <<'PY'
import statistics, sys
rows = [l.split() for l in open(sys.argv[1])]
by = {}
for r in rows:
    by.setdefault(r[0], []).append((float(r[1]), r[2] + " " + r[3]))
base = statistics.median(x[0] for x in by["mapped"])
for k, v in by.items():
    m = statistics.median(x[0] for x in v)
    print(f"{k:14s} {m:8.0f} {m / base:8.2f}  {max(v)[1]}")
PY
