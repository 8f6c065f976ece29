#!/usr/bin/env bash
# Sharded build figures, one run: K shards of a scene traced one after
# another (as K nodes would, each with the whole machine), their balance
# (slowest ÷ mean tracing), the merge's throughput against this disk's
# write rate measured in the same run, and a one-machine build beside it.
#
#   tools/bench_shards.sh [SCENE] [K] [BUILD ARGS...]
#   (default: scenes/cornell_box.toml 4 --quality high)
#
# Environment: ILLUMNET (default target/release/illumnet), BENCH_DIR
# (default a fresh mktemp -d next to /tmp; removed after).
set -euo pipefail
cd "$(dirname "$0")/.."
scene=${1:-scenes/cornell_box.toml}
k=${2:-4}
shift $(($# > 2 ? 2 : $#))
args=("$@")
[[ ${#args[@]} -gt 0 ]] || args=(--quality high)
bin=${ILLUMNET:-target/release/illumnet}
work=${BENCH_DIR:-$(mktemp -d)}
mkdir -p "$work"
trap '[[ -n ${BENCH_DIR:-} ]] || rm -rf "$work"' EXIT

secs() { awk -v a="$1" -v b="$EPOCHREALTIME" 'BEGIN { printf "%.2f", b - a }'; }

# The disk: 2 GiB written and synced, the rate an archive is written at.
t=$EPOCHREALTIME
dd if=/dev/zero of="$work/dd" bs=1M count=2048 conv=fdatasync status=none
disk_s=$(secs "$t")
rm -f "$work/dd"

t=$EPOCHREALTIME
"$bin" build "$scene" "${args[@]}" -q -o "$work/one.inet" >"$work/one.log"
one_s=$(secs "$t")

for ((i = 0; i < k; i++)); do
    "$bin" build "$scene" "${args[@]}" -q --shard "$i/$k" --shard-dir "$work/shards" >"$work/shard-$i.log"
done
t=$EPOCHREALTIME
"$bin" merge "$work/shards" -q -o "$work/merged.inet" >"$work/merge.log"
merge_s=$(secs "$t")
cmp -s "$work/one.inet" "$work/merged.inet" || { echo "bench_shards: the merged archive differs" >&2; exit 1; }

bytes=$(stat -c %s "$work/one.inet")
runs=$(du -sb "$work/shards" | cut -f1)
grep -h "^shard" "$work"/shard-*.log
grep -h "^peak" "$work"/shard-*.log | tr '\n' ' '
echo
awk -v one="$one_s" -v merge="$merge_s" -v disk="$disk_s" -v bytes="$bytes" -v runs="$runs" -v k="$k" '
    FNR == 1 && FILENAME ~ /shard-/ { }
    /^shard/ { match($0, /trace [0-9.]+ s/); t = substr($0, RSTART + 6, RLENGTH - 8) + 0; n++; sum += t; if (t > max) max = t }
    END {
        printf "shards: %d, tracing slowest %.2f s, mean %.2f s, slowest/mean %.2f\n", k, max, sum / n, max / (sum / n)
        printf "one-machine build %.2f s; archive %.2f GB, shards %.2f GB\n", one, bytes / 1e9, runs / 1e9
        printf "merge %.2f s: %.2f GB/s of archive written (%.2f GB/s of runs read); disk write %.2f GB/s (dd 2 GiB, fdatasync): ratio %.2f\n",
            merge, bytes / 1e9 / merge, runs / 1e9 / merge, 2.147483648 / disk, (bytes / 1e9 / merge) / (2.147483648 / disk)
    }' "$work"/shard-*.log
grep -h "^peak" "$work/merge.log" "$work/one.log" | sed 's/^/merge, one build: /'
