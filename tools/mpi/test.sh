#!/usr/bin/env bash
# `render --mpi` on Open MPI, on this host (tools/test.sh runs it; see
# docs/CLUSTER.md):
#   1. the Cornell box, the glossy floor and 8 frames of the fan room
#      (warm-started frames, per-frame deltas) rendered by 1, 2 and 4
#      ranks give the PNG of one process byte for byte and its EXR pixel
#      for pixel (the EXR's attribute order is not fixed, so its bytes are
#      not compared);
#   2. a rank killed in the middle of the distribution fails the whole job
#      (non-zero exit, the launcher naming the dead rank) and leaves no
#      image under the final name;
#   3. a rank that fails (a missing archive) ends the job with MPI_Abort,
#      naming itself, within a bounded time.
# Usage: ILLUMNET=path/to/illumnet-built-with-mpi bash tools/mpi/test.sh
# Installs Open MPI first (tools/mpi/install.sh) when it is missing.
set -euo pipefail
cd "$(dirname "$0")/../.."
prog=tools/mpi/test.sh
say() { echo "$prog: $*" >&2; }
die() {
    say "error: $*"
    exit 1
}

bin=$(realpath "${ILLUMNET:?set ILLUMNET to an illumnet binary built with --features mpi}")
bash tools/mpi/install.sh
# As root Open MPI needs to be told it may run; 4 ranks on fewer cores need
# --oversubscribe (which also makes waiting ranks yield their core).
mpirun=(mpirun --oversubscribe --bind-to none)
[[ $(id -u) != 0 ]] || mpirun+=(--allow-run-as-root)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
scenes=$PWD/scenes

# 1. 1, 2 and 4 ranks against one process.
same_pixels() { # image reference: every pixel equal (all of them: --below huge)
    local out
    out=$("$bin" compare --below 1e30 "$1" "$2") || die "compare $1 $2 failed"
    [[ $out == *"relative MSE 0.000e0, mean absolute error 0.0000e0"* ]] || die "$1 differs from $2: $out"
}
check_scene() { # name scene.toml render-options...
    local name=$1 scene=$2
    shift 2
    local dir=$work/$name
    mkdir -p "$dir"
    "$bin" build -q "$scene" -o "$dir/a.inet" >/dev/null
    "$bin" render -q "$dir/a.inet" -o "$dir/one_%02d.png" --exr "$dir/one_%02d.exr" "$@" >"$dir/one.log"
    local ranks png
    for ranks in 1 2 4; do
        "${mpirun[@]}" -np "$ranks" "$bin" render -q --mpi "$dir/a.inet" -o "$dir/r${ranks}_%02d.png" \
            --exr "$dir/r${ranks}_%02d.exr" "$@" >"$dir/r$ranks.log" 2>&1 ||
            die "$name on $ranks ranks failed: $(tail -n 5 "$dir/r$ranks.log")"
        for png in "$dir"/one_*.png; do
            local frame=${png##*/one_}
            cmp -s "$png" "$dir/r${ranks}_$frame" || die "$name, $ranks ranks: frame ${frame%.png}'s PNG differs from one process's"
            same_pixels "$dir/r${ranks}_${frame%.png}.exr" "${png%.png}.exr"
        done
        say "$name: $ranks rank(s): $(ls "$dir"/one_*.png | wc -l) frame(s) identical to one process's ($(grep -o 'exchanged [^)]*' "$dir/r$ranks.log" | head -n 1 || true))"
    done
}
t=$SECONDS
check_scene cornell "$scenes/cornell_box.toml"
check_scene glossy "$scenes/glossy_floor.toml"
check_scene fan_room "$scenes/fan_room.toml" --frames 0..8 --size 160x120
say "1, 2 and 4 ranks identical to one process: $((SECONDS - t)) s"

# 2. A rank killed mid-distribution ends the job, and no image is written.
dir=$work/killed
mkdir -p "$dir"
cp "$work/cornell/a.inet" "$dir/a.inet"
# Rank 1 stops itself where the distribution starts (the pause point of
# ILLUMNET_TEST_PAUSE_AT); rank 0 goes on into the first exchange and waits
# there. Then rank 1 is killed by its PID.
cat >"$dir/rank.sh" <<EOF
#!/usr/bin/env bash
if [[ \${OMPI_COMM_WORLD_RANK:-} == 1 ]]; then
    echo \$\$ >"$dir/rank1.pid"
    export ILLUMNET_TEST_PAUSE_AT=distribute
fi
exec "$bin" render -q --mpi "$dir/a.inet" -o "$dir/killed.png"
EOF
chmod +x "$dir/rank.sh"
"${mpirun[@]}" -np 2 "$dir/rank.sh" >"$dir/job.log" 2>&1 &
job=$!
pid=
for _ in $(seq 600); do
    [[ -s $dir/rank1.pid ]] && pid=$(cat "$dir/rank1.pid")
    [[ -n $pid && $(awk '{print $3}' "/proc/$pid/stat" 2>/dev/null) == T ]] && break
    kill -0 "$job" 2>/dev/null || die "the job ended before rank 1 paused: $(tail -n 5 "$dir/job.log")"
    sleep 0.1
done
[[ -n $pid && $(awk '{print $3}' "/proc/$pid/stat" 2>/dev/null) == T ]] || die "rank 1 never paused"
kill -KILL "$pid"
status=0
for _ in $(seq 300); do
    kill -0 "$job" 2>/dev/null || break
    sleep 0.1
done
if kill -0 "$job" 2>/dev/null; then
    kill -KILL "$job" 2>/dev/null || true
    die "the job still runs 30 s after rank 1 was killed: a rank waits forever"
fi
wait "$job" || status=$?
((status != 0)) || die "the job exited 0 although rank 1 was killed"
[[ ! -e $dir/killed.png ]] || die "an image was written by a job that lost a rank"
ls -A "$dir" | grep -q '^\.illumnet-killed' && die "a temporary image was left: $(ls -A "$dir")"
grep -qi "rank 1" "$dir/job.log" || die "the launcher did not name the dead rank: $(cat "$dir/job.log")"
say "killed rank: the job ended with status $status, no image; the launcher said: $(grep -i -m 1 'rank 1' "$dir/job.log")"
# 3. A rank that fails (here: its archive is missing) ends the job with
# MPI_Abort, naming itself, instead of leaving rank 0 waiting.
cat >"$dir/failing.sh" <<EOF
#!/usr/bin/env bash
archive="$dir/a.inet"
[[ \${OMPI_COMM_WORLD_RANK:-} != 1 ]] || archive="$dir/missing.inet"
exec "$bin" render -q --mpi "\$archive" -o "$dir/failed.png"
EOF
chmod +x "$dir/failing.sh"
status=0
timeout 120 "${mpirun[@]}" -np 2 "$dir/failing.sh" >"$dir/failing.log" 2>&1 || status=$?
((status != 0 && status != 124)) || die "a job with a failing rank ended with status $status (124: it hung)"
grep -q "MPI rank 1 of 2" "$dir/failing.log" || die "the failing rank did not name itself: $(cat "$dir/failing.log")"
[[ ! -e $dir/failed.png ]] || die "an image was written by a job whose rank failed"
say "failing rank: the job ended with status $status: $(grep -m 1 'MPI rank 1 of 2' "$dir/failing.log")"
say "passed"
