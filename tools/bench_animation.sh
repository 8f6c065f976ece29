#!/usr/bin/env bash
# Times, in one run, the 60-frame fan_room sequence built once and rendered
# from its sequence archive, against 60 from-scratch build + render runs of
# single frames (issue #5). Prints the speedup, the per-frame cost split
# and the archive overhead.
# Usage: tools/bench_animation.sh [FRAMES]   (default: all 60)
#        SHADING=inet tools/bench_animation.sh   (both sides; default direct)
#        SHADING=inet,direct tools/bench_animation.sh   (each in turn, in one run:
#          the issue's "same shading on both sides", with each shading's cost)
#        GATHER=256 tools/bench_animation.sh     (--gather on both sides; default 0,
#          what a sequence renders with, while a single frame gathers 256 rays by default)
#        EDGE=16 tools/bench_animation.sh        (--edge-samples on both sides; default 0,
#          what a sequence renders with, while a single frame samples edges 16x16 by default)
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --quiet
bin=target/release/illumnet
scene=scenes/fan_room.toml
frames=${1:-60}
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
now() { date +%s.%N; }

# One comparison: the sequence and the 60 from-scratch runs, both with
# shading $1.
bench() {
  local shading=$1
  local gather=()
  [[ $shading == direct ]] && gather=(--gather "${GATHER:-0}" --edge-samples "${EDGE:-0}")

  t0=$(now)
  "$bin" build -q "$scene" -o "$out/seq.inet" | tee "$out/build.txt"
  t1=$(now)
  "$bin" render -q "$out/seq.inet" --shading "$shading" "${gather[@]}" --frames "0..$frames" -o "$out/seq_%04d.png" > "$out/render.txt"
  t2=$(now)
  tail -1 "$out/render.txt"

  t3=$(now)
  for ((f = 0; f < frames; f++)); do
    "$bin" build -q "$scene" --frame "$f" -o "$out/one.inet" > /dev/null
    "$bin" render -q "$out/one.inet" --shading "$shading" "${gather[@]}" -o "$out/one_$f.png" > /dev/null
  done
  t4=$(now)
  "$bin" build -q "$scene" --frame 0 -o "$out/still.inet" > /dev/null

  python3 - "$t0" "$t1" "$t2" "$t3" "$t4" "$frames" "$out" "$shading" <<'PY'
import os, re, sys
t0, t1, t2, t3, t4 = map(float, sys.argv[1:6]); frames = int(sys.argv[6]); out = sys.argv[7]
seq = t2 - t0; scratch = t4 - t3
r = open(os.path.join(out, "render.txt")).read().splitlines()[-1]
dist = float(re.search(r"distribution ([\d.]+) s", r)[1]); rend = float(re.search(r"render ([\d.]+) s", r)[1])
delta = float(re.search(r"delta apply ([\d.]+) s", r)[1])
size_seq = os.path.getsize(os.path.join(out, "seq.inet")); size_still = os.path.getsize(os.path.join(out, "still.inet"))
print(f"sequence: build {t1 - t0:.1f} s + {frames} frames {t2 - t1:.1f} s = {seq:.1f} s ({seq / frames:.2f} s/frame)")
print(f"  per frame: delta apply {delta / frames:.3f} s, distribution {dist / frames:.3f} s, shading {rend / frames:.3f} s, "
      f"image writing and rest {(t2 - t1 - delta - dist - rend) / frames:.3f} s")
print(f"from scratch: {frames} x (build + render) = {scratch:.1f} s ({scratch / frames:.2f} s/frame)")
shading = sys.argv[8]
gather = (f", --gather {os.environ.get('GATHER', '0')} --edge-samples {os.environ.get('EDGE', '0')}"
          if shading == 'direct' else '')
print(f"speedup: {scratch / seq:.1f}x (shading {shading}{gather} on both sides)")
print(f"archive: sequence {size_seq / 1e6:.1f} MB vs one still frame {size_still / 1e6:.1f} MB "
      f"(+{(size_seq - size_still) / 1e6:.1f} MB for temporal objects and deltas)")
PY
}

IFS=, read -ra shadings <<<"${SHADING:-direct}"
for shading in "${shadings[@]}"; do
  case $shading in inet | direct) ;; *) echo "SHADING: inet, direct, or both as inet,direct; not $shading" >&2; exit 2 ;; esac
done
for shading in "${shadings[@]}"; do
  bench "$shading"
done
