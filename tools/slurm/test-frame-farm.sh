#!/usr/bin/env bash
# Whole jobs on a real single-node Slurm (tools/slurm/local-cluster.sh),
# submitted by tools/slurm/submit.sh: the Cornell box (4 shards, merge, its
# frame rendered by an MPI job of FARM_MPI_RANKS ranks, `render --mpi`, when
# that is set, else by a one-task array; archive and frame identical to one
# machine's) and the fan room built as a job array of
# 4 shards, merged by a job that depends on them (afterok), its 60 frames
# rendered by a throttled job array (4 tasks, each taking its share with
# `--frames auto/4 --skip-done`, at most 2 at once) after the merge, and a
# job after the array gating on `illumnet frames check` (every frame
# complete, from this archive, with the same settings). The merged archive
# must equal, byte for byte, a local one-machine build, and each frame the
# same frame of one local `--frames 0..60 --cold` render
# (docs/CLUSTER.md: a --cold frame does not depend on the range it is in).
# Then no daemon of the cluster may be left, nor anything on its ports.
#
#   ILLUMNET=/path/to/illumnet tools/slurm/test-frame-farm.sh
#
# Environment: ILLUMNET (default target/release/illumnet), FARM_DIR (work
# directory, default a fresh mktemp -d; removed after a success unless
# FARM_KEEP=1), FARM_TIMEOUT (seconds for the farm, default 300), FARM_MPI_RANKS (ranks
# of the Cornell box's MPI render job; needs ILLUMNET built with
# --features mpi and Open MPI, tools/mpi/install.sh; default 0: none), and
# local-cluster.sh's LOCAL_SLURM_* (ports, timeouts). Exit 0 only if all holds.
set -euo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd -P)
root=$(cd "$here/../.." && pwd -P)
cd "$root"
prog=test-frame-farm.sh

frames=60 # the fan room's whole sequence
tasks=4   # render array tasks 0-3
shards=4  # build array tasks 0-3
throttle=2
size=64x64
mpi_ranks=${FARM_MPI_RANKS:-0}
[[ $mpi_ranks =~ ^[0-9]+$ ]] || { echo "FARM_MPI_RANKS must be a number, not '$mpi_ranks'" >&2; exit 2; }

say() { echo "$prog: $*" >&2; }
die() {
    say "FAILED: $*"
    exit 1
}
now() { echo "$EPOCHREALTIME"; }
since() { awk -v a="$1" -v b="$EPOCHREALTIME" 'BEGIN { printf "%.1f", b - a }'; }

# --------------------------------------------------------------- in the cluster

# A job's field from `scontrol show job -o` (one line per job or array task).
job_field() { # job field
    scontrol show job -o "$1" 2>/dev/null | grep -o "\b$2=[^ ]*" | sed "s/^$2=//"
}

in_cluster() { # work
    local work=$1 t build merge arr check state reason deadline f i
    [[ -n ${SLURM_CONF:-} ]] || die "SLURM_CONF is not set: run through local-cluster.sh run"
    cat "$LOCAL_SLURM_RUN_DIR"/{munged,slurmctld,slurmd}.pid >"$work/daemon-pids"
    sed -n 's/^Slurm\(ctld\|d\)Port=//p' "$SLURM_CONF" >"$work/daemon-ports"
    sinfo

    # The Cornell box (a still) through the same pipeline, beside it: 4
    # shards, the merge, its one frame (by an MPI job of $mpi_ranks ranks
    # when asked), the check.
    local cornell c_check
    cornell=$(bash "$here/submit.sh" scenes/cornell_box.toml "$work/cornell" --illumnet "$ILLUMNET" --shards 4 \
        --tasks 1 --throttle 1 --mpi-ranks "$mpi_ranks" --build-args "--quality draft" \
        --render-args "--size $size --threads 1" |
        tee "$work/submit-cornell.log" | sed -n 's/^jobs: //p')
    c_check=${cornell##* }
    [[ -n $c_check ]] || die "submit.sh printed no job ids for the Cornell box: $(cat "$work/submit-cornell.log")"

    # The whole pipeline through the submit script: the build as a job
    # array of shards, the merge after it, the frames as a throttled array
    # after the merge, the check after the frames.
    t=$(now)
    local jobs
    jobs=$(bash "$here/submit.sh" scenes/fan_room.toml "$work" --illumnet "$ILLUMNET" --shards $shards \
        --tasks $tasks --throttle $throttle --build-args "--quality draft" \
        --render-args "--cold --size $size --threads 1" | tee "$work/submit.log" | sed -n 's/^jobs: //p')
    read -r build merge arr check <<<"$jobs"
    [[ -n ${check:-} ]] || die "submit.sh printed no job ids: $(cat "$work/submit.log")"
    say "submitted build array $build ($shards shards), merge $merge, render array $arr, check $check"
    [[ $(job_field "$arr" ArrayTaskThrottle | head -n 1) == "$throttle" ]] ||
        die "scontrol does not show ArrayTaskThrottle=$throttle for job $arr"
    squeue

    deadline=$((SECONDS + ${FARM_TIMEOUT:-300}))
    while true; do
        state=$(job_field "$check" JobState)
        case $state in
        COMPLETED) break ;;
        PENDING | CONFIGURING | RUNNING | COMPLETING) ;;
        *)
            reason=$(job_field "$check" Reason)
            scontrol show job -o "$arr" | grep -o 'ArrayTaskId=[^ ]*\|JobState=[^ ]*\|ExitCode=[^ ]*' |
                paste -d ' ' - - - >&2 || true
            tail -n +1 "$work"/logs/*.out >&2 || true
            die "check job $check ended $state (reason ${reason:-none}): logs in $work/logs"
            ;;
        esac
        if ((SECONDS >= deadline)); then
            squeue >&2 || true
            die "the farm did not finish within ${FARM_TIMEOUT:-300} s (check job $check is $state)"
        fi
        sleep 0.5
    done
    farm_s=$(since "$t")
    deadline=$((SECONDS + ${FARM_TIMEOUT:-300}))
    while [[ $(job_field "$c_check" JobState) != COMPLETED ]]; do
        state=$(job_field "$c_check" JobState)
        case $state in
        PENDING | CONFIGURING | RUNNING | COMPLETING) ;;
        *) die "the Cornell box's check job $c_check ended $state: logs in $work/cornell/logs" ;;
        esac
        ((SECONDS < deadline)) || die "the Cornell box's jobs did not finish in time (check job $c_check is $state)"
        sleep 0.5
    done
    say "the Cornell box's 4 shards, merge, frame and check done"
    if ((mpi_ranks > 0)); then
        grep -q "^MPI: $mpi_ranks ranks" "$work"/cornell/logs/render_mpi_*.out ||
            die "the Cornell box's render job did not run on $mpi_ranks MPI ranks: $(cat "$work"/cornell/logs/render_mpi_*.out)"
        say "the Cornell box's frame by $mpi_ranks MPI ranks: $(grep '^MPI:' "$work"/cornell/logs/render_mpi_*.out)"
    fi
    cat "$work"/logs/check_*.out
    # Every shard and the merge completed, and every render task, with exit code 0.
    scontrol show job -o "$build" | grep -o 'JobState=[^ ]*\|ExitCode=[^ ]*' | paste -d ' ' - - >"$work/build-states"
    [[ $(grep -c 'JobState=COMPLETED ExitCode=0:0' "$work/build-states") == "$shards" ]] ||
        die "not every build shard completed with exit code 0 (see $work/build-states, $work/logs)"
    [[ $(job_field "$merge" JobState) == COMPLETED ]] || die "the merge job $merge did not complete"
    scontrol show job -o "$arr" | grep -o 'ArrayTaskId=[^ ]*\|JobState=[^ ]*\|ExitCode=[^ ]*' |
        paste -d ' ' - - - >"$work/array-states"
    cat "$work/array-states"
    [[ $(grep -c 'JobState=COMPLETED ExitCode=0:0' "$work/array-states") == "$tasks" ]] ||
        die "not every array task completed with exit code 0 (see $work/array-states)"
    # The throttle: never more than $throttle tasks at once.
    local overlap
    overlap=$(for f in "$work"/timeline/render_*; do
        awk '{ print $2, ($1 == "start" ? 1 : -1) }' "$f"
    done | sort -n -k1,1 -k2,2n | awk '{ n += $2; if (n > m) m = n } END { print m }')
    say "farm: $tasks tasks and the check job done in $farm_s s after submission; at most $overlap tasks ran at once"
    ((overlap <= throttle)) || die "$overlap tasks ran at once, above the throttle of $throttle"
    echo "$farm_s" >"$work/farm-seconds"
}

# --------------------------------------------------------------- outside

outside() {
    local work t0 t rc=0 pid port i f mismatched=0 left=0
    ILLUMNET=${ILLUMNET:-target/release/illumnet}
    [[ -x $ILLUMNET ]] || die "no illumnet binary at $ILLUMNET (set ILLUMNET, or cargo build --release)"
    ILLUMNET=$(cd "$(dirname "$ILLUMNET")" && pwd -P)/$(basename "$ILLUMNET")
    export ILLUMNET
    if [[ -n ${FARM_DIR:-} ]]; then
        mkdir -p "$FARM_DIR"
        work=$(cd "$FARM_DIR" && pwd -P)
    else
        work=$(mktemp -d)
    fi
    chmod 0755 "$work" # the cluster's munged runs as the munge user
    say "work directory $work, illumnet $ILLUMNET"

    t0=$(now)
    "$here/local-cluster.sh" run "$work/cluster" -- "$here/$prog" --in-cluster "$work" || rc=$?
    say "local-cluster.sh run: status $rc, $(since "$t0") s (start, build, farm, stop)"

    # No daemon of the cluster is left, and nothing listens on its ports.
    local pids=() ports=()
    [[ ! -f $work/daemon-pids ]] || mapfile -t pids <"$work/daemon-pids"
    [[ ! -f $work/daemon-ports ]] || mapfile -t ports <"$work/daemon-ports"
    for pid in "${pids[@]}"; do
        if [[ -e /proc/$pid ]] && ! grep -q '^State:[[:space:]]*Z' "/proc/$pid/status" 2>/dev/null; then
            say "daemon pid $pid still runs: $(ps -o args= -p "$pid" || true)"
            left=1
        fi
    done
    for port in "${ports[@]}"; do
        if [[ -n $(ss -Hltn "sport = :$port") ]]; then
            say "something still listens on port $port: $(ss -Hltnp "sport = :$port")"
            left=1
        fi
    done
    ((rc == 0)) || die "the farm failed (status $rc): work directory $work kept"
    [[ -s $work/daemon-pids ]] || die "no daemon PIDs were recorded"
    ((left == 0)) || die "the cluster left processes or ports behind"
    say "no daemon left (pids ${pids[*]}), nothing listens on ports ${ports[*]}"

    # The Cornell box's merged archive and frame are one machine's.
    "$ILLUMNET" build scenes/cornell_box.toml --quality draft -q -o "$work/cornell-local.inet" >/dev/null 2>&1 ||
        die "the local Cornell box build failed"
    cmp -s "$work/cornell/scene.inet" "$work/cornell-local.inet" ||
        die "the Cornell box's archive merged from 4 shards on Slurm differs from the local build"
    mkdir -p "$work/cornell-ref"
    "$ILLUMNET" render "$work/cornell/scene.inet" --frames 0..1 --size $size -q \
        -o "$work/cornell-ref/frame_%04d.png" >/dev/null 2>&1 || die "the local Cornell box render failed"
    cmp -s "$work/cornell/frames/frame_0000.png" "$work/cornell-ref/frame_0000.png" ||
        die "the Cornell box's frame from Slurm differs from the local render"
    say "the Cornell box: archive from 4 shards and its frame identical to one machine's"

    # The merged archive is the one-machine build's, byte for byte.
    "$ILLUMNET" build scenes/fan_room.toml --quality draft -q -o "$work/local.inet" >"$work/local-build.log" 2>&1 ||
        die "the local build failed: $work/local-build.log"
    cmp -s "$work/scene.inet" "$work/local.inet" ||
        die "the archive merged from $shards shards on Slurm differs from the local build"
    say "the archive merged from $shards shards is byte-identical to the local build"

    t=$(now)
    mkdir -p "$work/ref"
    "$ILLUMNET" render "$work/scene.inet" --frames 0..$frames --cold --size $size -q \
        -o "$work/ref/frame_%04d.png" >"$work/ref.log" 2>&1 || die "the local render failed: $work/ref.log"
    say "rendered frames 0..$frames locally, in one run, in $(since "$t") s"
    for ((i = 0; i < frames; i++)); do
        f=$(printf 'frame_%04d.png' "$i")
        if [[ ! -s $work/frames/$f ]]; then
            say "$f: missing from the farm"
            mismatched=$((mismatched + 1))
        elif ! cmp -s "$work/frames/$f" "$work/ref/$f"; then
            say "$f: the farm's differs from the local render"
            mismatched=$((mismatched + 1))
        fi
    done
    # The frames show the fan turning: not one image twelve times.
    local distinct
    distinct=$(md5sum "$work"/ref/frame_*.png | awk '{ print $1 }' | sort -u | wc -l)
    ((distinct > 1)) || die "all $frames reference frames are the same image"
    echo "sharded build + frame farm on Slurm: archive from $shards shards identical; $((frames - mismatched))/$frames frames identical to the local render ($distinct distinct images);" \
        "farm $(cat "$work/farm-seconds") s, whole run $(since "$t0") s"
    ((mismatched == 0)) || die "$mismatched of $frames frames differ: work directory $work kept"
    if [[ -n ${FARM_KEEP:-} || -n ${FARM_DIR:-} ]]; then
        say "kept $work"
    else
        rm -rf "$work"
    fi
    echo "$prog: PASSED"
}

if [[ ${1:-} == --in-cluster ]]; then
    in_cluster "$2"
else
    outside
fi
