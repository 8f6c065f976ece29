#!/usr/bin/env bash
# A bounded build's spill and merge against an older binary (issue 41):
# the ladder's building (4 × 4 rooms, 3 boxes each, 1.05·10⁶ patches) at
# frequency 4 (1.26·10⁸ link ends) under a budget that spills ~80 runs,
# OLD and NEW alternated RUNS times: each run's whole build, trace and
# write seconds, the bytes spilled and the peak, then whether the two
# archives are the same bytes (they must be).
# Usage: tools/bench_spill.sh OLD [NEW] (NEW: the release binary, built
# first); RUNS (default 2), BUDGET (default 500M), FREQUENCY (default 4).
# Needs ~4 GB of disk in $TMPDIR.
set -euo pipefail
cd "$(dirname "$0")/.."
old=${1:?usage: tools/bench_spill.sh OLD [NEW]}
new=${2:-}
if [[ -z "$new" ]]; then
  cargo build --release --quiet
  new=target/release/illumnet
fi
runs=${RUNS:-2}
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
python3 tools/gen_building.py 4 4 --furniture 3 -o "$out/b.toml" > /dev/null
for i in $(seq "$runs"); do
  for side in old new; do
    bin=$old
    [[ $side == new ]] && bin=$new
    /usr/bin/time -f "%M" -o "$out/peak" "$bin" build -q "$out/b.toml" -o "$out/$side.inet" \
      --frequency "${FREQUENCY:-4}" --patch-size 0.036 --ray-spacing 0.018 --memory-budget "${BUDGET:-500M}" \
      > "$out/log" 2>&1
    times=$(grep '^built' "$out/log" | sed -E 's/.*MB, //')
    spilled=$(grep -o 'spilled [0-9]* runs of link ends ([0-9.]* [GM]iB)' "$out/log" || echo "no spill")
    echo "$side: $times; $spilled; peak $(( $(cat "$out/peak") / 1024 )) MiB"
  done
done
cmp -s "$out/old.inet" "$out/new.inet" && echo "archives: the same bytes" || { echo "archives: DIFFERENT"; exit 1; }
