#!/usr/bin/env bash
# The page of `illumnet serve` in headless Chromium (tools/test.sh runs it):
# installs Chromium and chromedriver (tools/browser/install.sh), builds the
# Cornell box and the fan room, starts `illumnet serve` for each and
# chromedriver, runs tools/browser/test_serve.py against them, and stops
# every process it started by its PID (never by name).
#   ILLUMNET=path/to/illumnet bash tools/browser/test.sh [--bench]
# --bench: instead of the test, the latency benchmark (bench_serve.py:
# change to drawn, median of 20 changes; record it in docs/PERFORMANCE.md;
# BENCH_SCREENSHOT=PATH also saves the Cornell box's page as a PNG;
# BENCH_ARCHIVE=A.inet also measures A's first emitter; BENCH_CHANGES=N).
set -euo pipefail
cd "$(dirname "$0")/../.."
prog=tools/browser/test.sh
say() { echo "$prog: $*" >&2; }
die() {
    say "FAILED: $*"
    exit 1
}
bin=$(realpath "${ILLUMNET:?set ILLUMNET to an illumnet binary}")
bash tools/browser/install.sh
work=$(mktemp -d)
pids=()
# A process's descendants (Chromium's processes under chromedriver).
descendants() { # pid
    local c
    for c in $(pgrep -P "$1" 2>/dev/null); do
        echo "$c"
        descendants "$c"
    done
}
stop() {
    local p
    # Chromium's processes, by PID, should chromedriver leave any behind.
    for p in "${pids[@]}"; do
        pids+=($(descendants "$p"))
    done
    for p in "${pids[@]}"; do
        kill "$p" 2>/dev/null || true
    done
    for p in "${pids[@]}"; do
        wait "$p" 2>/dev/null || true
        if [[ -e /proc/$p && $(awk '{print $3}' "/proc/$p/stat" 2>/dev/null) != Z ]]; then
            say "FAILED: process $p still runs after SIGTERM"
            kill -KILL "$p" 2>/dev/null || true
            left=1
        fi
    done
    rm -rf "$work"
    [[ -z ${left:-} ]] || exit 1
}
trap stop EXIT

# The test at draft quality (fast); the benchmark at the build's defaults.
quality=(--quality draft)
[[ ${1:-} != --bench ]] || quality=()
"$bin" build -q scenes/cornell_box.toml "${quality[@]}" -o "$work/cornell.inet" >/dev/null
"$bin" build -q scenes/fan_room.toml "${quality[@]}" -o "$work/fan.inet" >/dev/null

# Starts `illumnet serve` on an archive and sets `url` to its page (in this
# shell, not a subshell: its PID is recorded for stop).
start_serve() { # archive log
    "$bin" serve --port 0 "$1" >"$2" 2>&1 &
    pids+=($!)
    local i
    for i in $(seq 300); do
        grep -q '^serving on ' "$2" && break
        sleep 0.1
    done
    url=$(sed -n 's/^serving on \(http:[^ ]*\).*/\1/p' "$2" | head -n 1)
    [[ -n $url ]] || die "illumnet serve did not start: $(cat "$2")"
}
start_serve "$work/cornell.inet" "$work/cornell.log"
cornell=$url
start_serve "$work/fan.inet" "$work/fan.log"
fan=$url

port=$((20000 + RANDOM % 20000))
chromedriver --port=$port >"$work/chromedriver.log" 2>&1 &
pids+=($!)
for i in $(seq 300); do
    curl -fs "http://127.0.0.1:$port/status" >/dev/null 2>&1 && break
    sleep 0.1
done
if [[ ${1:-} == --bench ]]; then
    extra=
    if [[ -n ${BENCH_ARCHIVE:-} ]]; then
        start_serve "$BENCH_ARCHIVE" "$work/extra.log"
        extra=$url
    fi
    python3 tools/browser/bench_serve.py --webdriver "http://127.0.0.1:$port" --page "$cornell" --fan-page "$fan" \
        ${BENCH_SCREENSHOT:+--screenshot "$BENCH_SCREENSHOT"} ${extra:+--extra-page "$extra"} \
        --changes "${BENCH_CHANGES:-20}"
    exit
fi
python3 tools/browser/test_serve.py --webdriver "http://127.0.0.1:$port" --page "$cornell" --fan-page "$fan" \
    --illumnet "$bin" --fan-archive "$work/fan.inet" ||
    die "the page test failed (serve logs: $(tail -n 3 "$work"/*.log))"
say "passed"
