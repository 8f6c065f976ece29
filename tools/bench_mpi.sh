#!/usr/bin/env bash
# `render --mpi` against one process, in one run, on one archive: seconds
# per iteration of the distribution and bytes exchanged per iteration at
# 1, 2 and 4 ranks, beside the plain binary's run without MPI (the
# baseline). Every run renders a 64×64 image with the paper's shading (one
# sample) so that the distribution is the time measured; the images must
# be identical to the baseline's. A first run warms the page cache.
#
#   ILLUMNET=target/release/illumnet tools/bench_mpi.sh ARCHIVE [RUNS]
#
# ILLUMNET must be built with --features mpi (tools/mpi/install.sh first).
# On one host the ranks share its cores: with 2 cores the baseline runs 2
# threads, each rank --threads T (default 1; set RANK_THREADS). Prints a
# table; record it in docs/PERFORMANCE.md, never in CI.
set -euo pipefail
archive=${1:?usage: tools/bench_mpi.sh ARCHIVE [RUNS]}
runs=${2:-3}
bin=$(realpath "${ILLUMNET:-target/release/illumnet}")
threads=${RANK_THREADS:-1}
mpirun=(mpirun --oversubscribe --bind-to none)
[[ $(id -u) != 0 ]] || mpirun+=(--allow-run-as-root)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
common=(render "$archive" --shading inet --samples 1 --size 64x64 -q)

# distribution seconds, iterations, MB exchanged, exchanges, seconds
# exchanging, from a log
parse() {
    local d it mb ex xs
    d=$(grep -o 'distribution [0-9.]* s' "$1" | awk '{print $2}')
    it=$(grep -o '([0-9]* iterations' "$1" | tr -dc '0-9')
    mb=$(grep -o 'exchanged [0-9.]* MB' "$1" | awk '{print $2}')
    ex=$(grep -o 'in [0-9]* exchanges' "$1" | awk '{print $2}')
    xs=$(grep -o 'each, [0-9.]* s in all' "$1" | awk '{print $2}')
    echo "${d:-nan} ${it:-0} ${mb:-0} ${ex:-0} ${xs:-0}"
}

"$bin" "${common[@]}" -o "$work/warm.png" >/dev/null
printf '%-22s %8s %6s %12s %12s %14s %8s\n' run "s/iter" iters "MB/exchange" "exchange s" "÷ baseline" "image"
base=
for r in $(seq "$runs"); do
    for ranks in 0 1 2 4; do
        log=$work/r$ranks.$r.log
        if ((ranks == 0)); then
            "$bin" "${common[@]}" -o "$work/base.png" --threads 2 >"$log"
            name="one process, 2 threads"
            same=base
        else
            "${mpirun[@]}" -np "$ranks" "$bin" "${common[@]}" --mpi --threads "$threads" -o "$work/r$ranks.png" >"$log" 2>&1
            name="$ranks rank(s) × $threads thread"
            cmp -s "$work/r$ranks.png" "$work/base.png" && same=same || same=DIFFERS
        fi
        read -r d it mb ex xs <<<"$(parse "$log")"
        per=$(awk -v d="$d" -v i="$it" 'BEGIN { printf "%.3f", d / i }')
        ((ranks == 0)) && base=$per
        # MB per exchange (one a gather: an iteration's, and the first
        # bounce's), seconds exchanging per exchange (waiting for the
        # slowest rank included)
        awk -v n="$name" -v p="$per" -v i="$it" -v mb="$mb" -v ex="$ex" -v xs="$xs" -v b="$base" -v s="$same" 'BEGIN {
            per_ex = ex > 0 ? mb / ex : 0; s_ex = ex > 0 ? xs / ex : 0
            printf "%-22s %8.3f %6d %12.2f %12.3f %14.2f %8s\n", n, p, i, per_ex, s_ex, p / b, s }'
    done
done
