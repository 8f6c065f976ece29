#!/usr/bin/env bash
# Submits a whole illumnet job to Slurm, on one shared directory:
#
#   1. the build, as a job array of K shards  (build --shard auto/K)
#   2. the merge, after every shard succeeded  (--dependency=afterok)
#   3. the frames, as a throttled job array    (render --frames auto/T --skip-done)
#      or, with --mpi-ranks R, as one MPI job of R ranks sharing each
#      frame's distribution                    (mpirun render --mpi --skip-done)
#   4. a check that every frame is complete    (frames check; exit 8 if not)
#
#   tools/slurm/submit.sh SCENE WORKDIR [--shards K] [--tasks T] [--throttle M]
#       [--mpi-ranks R] [--build-args "ARGS"] [--render-args "ARGS"]
#       [--illumnet PATH] [--sbatch-args "ARGS"]
#
# --mpi-ranks needs an illumnet built with `--features mpi` and Open MPI on
# the nodes (tools/mpi/install.sh); its job runs Open MPI's mpirun, which
# starts its ranks through Slurm in the job's allocation (--ntasks=R).
#
# WORKDIR (on a file system every node sees) gets: shards/ (the shards'
# runs, counts and manifests), scene.inet (the merged archive), frames/
# (frame_NNNN.png and their sidecars), logs/ (one log per job and task),
# jobs/ (the batch scripts submitted) and timeline/ (each render task's
# start and end, epoch seconds). Prints the four job ids, the last line
# `jobs: BUILD MERGE RENDER CHECK`.
#
# Resuming after a failed task: run the same command again. A shard whose
# manifest exists is not traced again (the merge checks every file
# against it), the merge is skipped when WORKDIR/scene.inet exists, and
# the render tasks skip frames that are complete and match the archive
# (--skip-done), redoing stale or partial ones.
set -euo pipefail

usage() { sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'; }
die() {
    echo "submit.sh: $*" >&2
    exit 2
}

[[ $# -ge 2 ]] || {
    usage >&2
    exit 2
}
scene=$1 work=$2
shift 2
shards=4 tasks=4 throttle=2 mpi_ranks=0 build_args="" render_args="" sbatch_args=""
illumnet=$(command -v illumnet || true)
while [[ $# -gt 0 ]]; do
    case $1 in
    --shards) shards=$2 ;;
    --tasks) tasks=$2 ;;
    --throttle) throttle=$2 ;;
    --mpi-ranks) mpi_ranks=$2 ;;
    --build-args) build_args=$2 ;;
    --render-args) render_args=$2 ;;
    --sbatch-args) sbatch_args=$2 ;;
    --illumnet) illumnet=$2 ;;
    -h | --help)
        usage
        exit 0
        ;;
    *) die "unknown option $1 (see --help)" ;;
    esac
    shift 2
done
for n in "$shards" "$tasks" "$throttle"; do
    [[ $n =~ ^[1-9][0-9]*$ ]] || die "--shards, --tasks and --throttle take positive integers (got $n)"
done
[[ $mpi_ranks =~ ^[0-9]+$ ]] || die "--mpi-ranks takes a positive integer (got $mpi_ranks)"
mpi_ranks=$((10#$mpi_ranks))
((mpi_ranks == 0)) || command -v mpirun >/dev/null || die "--mpi-ranks: no mpirun (tools/mpi/install.sh installs Open MPI)"
[[ -n $illumnet && -x $illumnet ]] || die "no illumnet binary (put it on PATH or give --illumnet PATH)"
[[ -f $scene ]] || die "no scene file $scene"
command -v sbatch >/dev/null || die "sbatch not found: is this a Slurm submit host?"
illumnet=$(cd "$(dirname "$illumnet")" && pwd -P)/$(basename "$illumnet")
scene=$(cd "$(dirname "$scene")" && pwd -P)/$(basename "$scene")
mkdir -p "$work"
work=$(cd "$work" && pwd -P)
mkdir -p "$work"/{shards,frames,logs,jobs,timeline}
stem=$(printf 'shard-%%04d-of-%04d' "$shards")

cat >"$work/jobs/build.sh" <<EOF
#!/bin/bash
# One shard of the build (array task \$SLURM_ARRAY_TASK_ID of $shards).
set -euo pipefail
manifest="$work/shards/\$(printf '$stem' "\$SLURM_ARRAY_TASK_ID").manifest"
if [[ -f \$manifest ]]; then
    echo "\$manifest exists: this shard is done (the merge checks it)"
    exit 0
fi
exec "$illumnet" build "$scene" --shard auto/$shards --shard-dir "$work/shards" -q $build_args
EOF
cat >"$work/jobs/merge.sh" <<EOF
#!/bin/bash
# The merge of all $shards shards into the archive.
set -euo pipefail
if [[ -f "$work/scene.inet" ]]; then
    echo "$work/scene.inet exists: merged before"
    exit 0
fi
exec "$illumnet" merge "$work/shards" -o "$work/scene.inet" -q
EOF
cat >"$work/jobs/render.sh" <<EOF
#!/bin/bash
# One render task's share of the frames (array task \$SLURM_ARRAY_TASK_ID of $tasks).
set -euo pipefail
echo "start \$EPOCHREALTIME" >"$work/timeline/render_\$SLURM_ARRAY_TASK_ID"
"$illumnet" render "$work/scene.inet" --frames auto/$tasks --skip-done -q $render_args \\
    -o "$work/frames/frame_%04d.png"
echo "end \$EPOCHREALTIME" >>"$work/timeline/render_\$SLURM_ARRAY_TASK_ID"
EOF
# An MPI rank takes one worker thread per CPU Slurm gives its task, unless
# --render-args says how many.
threads_arg='--threads ${SLURM_CPUS_PER_TASK:-1}'
[[ $render_args != *--threads* ]] || threads_arg=
cat >"$work/jobs/render-mpi.sh" <<EOF
#!/bin/bash
# Every frame, each frame's distribution shared by the job's $mpi_ranks ranks
# (rank 0 writes the images).
set -euo pipefail
echo "start \$EPOCHREALTIME" >"$work/timeline/render_mpi"
# Open MPI refuses to run as root unless told.
[[ \$(id -u) != 0 ]] || export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
mpirun -np $mpi_ranks "$illumnet" render "$work/scene.inet" --mpi --skip-done -q $threads_arg $render_args \\
    -o "$work/frames/frame_%04d.png"
echo "end \$EPOCHREALTIME" >>"$work/timeline/render_mpi"
EOF
cat >"$work/jobs/check.sh" <<EOF
#!/bin/bash
# Every frame complete, from this archive, with the same settings (exit 8 if not).
set -euo pipefail
exec "$illumnet" frames check "$work/scene.inet" -o "$work/frames/frame_%04d.png"
EOF
chmod +x "$work"/jobs/*.sh

submit() { # sbatch options... script
    local id
    # shellcheck disable=SC2086 # --sbatch-args is split on purpose
    id=$(sbatch --parsable --chdir="$work" $sbatch_args "$@")
    echo "${id%%;*}"
}
build=$(submit --job-name=inet-build --array=0-$((shards - 1)) --output="$work/logs/build_%A_%a.out" "$work/jobs/build.sh")
merge=$(submit --job-name=inet-merge --dependency=afterok:"$build" --kill-on-invalid-dep=yes \
    --output="$work/logs/merge_%j.out" "$work/jobs/merge.sh")
if ((mpi_ranks > 0)); then
    render=$(submit --job-name=inet-render-mpi --ntasks="$mpi_ranks" --cpus-per-task=1 \
        --dependency=afterok:"$merge" --kill-on-invalid-dep=yes --output="$work/logs/render_mpi_%j.out" \
        "$work/jobs/render-mpi.sh")
else
    render=$(submit --job-name=inet-render --array=0-$((tasks - 1))%"$throttle" --cpus-per-task=1 \
        --dependency=afterok:"$merge" --kill-on-invalid-dep=yes --output="$work/logs/render_%A_%a.out" \
        "$work/jobs/render.sh")
fi
check=$(submit --job-name=inet-check --dependency=afterok:"$render" --kill-on-invalid-dep=yes \
    --output="$work/logs/check_%j.out" "$work/jobs/check.sh")
echo "build: job array $build ($shards shards into $work/shards)"
echo "merge: job $merge, after the build ($work/scene.inet)"
if ((mpi_ranks > 0)); then
    echo "render: MPI job $render ($mpi_ranks ranks, into $work/frames)"
else
    echo "render: job array $render ($tasks tasks, at most $throttle at once, into $work/frames)"
fi
echo "check: job $check, after the render (logs/check_$check.out)"
echo "jobs: $build $merge $render $check"
