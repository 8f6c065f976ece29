#!/usr/bin/env bash
# The test suites, as CI runs them (README: "tests" line).
#   1. every test (unit, integration, doc examples) in the `test` profile:
#      optimised like a release build, with overflow checks and debug
#      assertions on (clap's checks of the command line among them), so an
#      overflow on hostile input is a failure, not a wrap. One profile for
#      every suite: CI used to build the crate and its dependencies twice
#      (release, then this profile for the damage matrix alone);
#   2. the library's documentation, with warnings denied;
#   3. the guide (docs/guide/, an mdBook) built with `mdbook build`, when
#      mdbook is installed (`cargo install mdbook --locked`; .ci/run does;
#      skipped with a note otherwise). Its links, the README's tour and the
#      command-line reference are checked by tests/docs.rs in step 1;
#   4. `render --mpi` on Open MPI (tools/mpi/test.sh: 1, 2 and 4 ranks give
#      one process's images, a killed rank fails the job): Debian's Open MPI
#      installed by tools/mpi/install.sh, the binary rebuilt with
#      `--features mpi` (in the test profile, over the plain one), when run
#      as root or with Open MPI installed (skipped with a note otherwise;
#      ILLUMNET_SKIP_MPI=1 skips it);
#   5. a sharded build, its merge, a 2-rank MPI render (when step 4 ran)
#      and a frame farm on a real single-node Slurm through
#      tools/slurm/submit.sh (tools/slurm/: Debian's slurm-wlm and munge,
#      installed by the script, daemons on loopback, stopped by their PIDs),
#      when run as root (apt and the munge user need it; skipped with a note
#      otherwise; ILLUMNET_SKIP_SLURM=1 skips it);
#   6. the page of `illumnet serve` in headless Chromium over WebDriver
#      (tools/browser/test.sh: Debian's chromium and chromium-driver,
#      installed by tools/browser/install.sh, processes stopped by their
#      PIDs), when run as root or with them installed (skipped with a note
#      otherwise; ILLUMNET_SKIP_BROWSER=1 skips it);
#   7. a short smoke run of each fuzz target, when cargo-fuzz is installed
#      (tools/fuzz; skipped with a note otherwise).
# Each step prints how long it took (CI must stay under 30 minutes).
set -euo pipefail
cd "$(dirname "$0")/.."
step() { # name command...
    local name=$1 t=$SECONDS
    shift
    "$@"
    echo "tools/test.sh: $name: $((SECONDS - t)) s"
}
step "tests (profile test)" cargo test
# In the test profile too, which reuses its build scripts and proc macros
# (66 s; 346 s in the dev profile, measured on a fresh clone 2026-12-04).
step "docs" env RUSTDOCFLAGS="-D warnings" cargo doc --no-deps --quiet --profile test
if command -v mdbook >/dev/null 2>&1; then
    guide_out=$(mktemp -d)
    step "guide (mdbook build)" mdbook build docs/guide -d "$guide_out"
    rm -rf "$guide_out"
else
    echo "tools/test.sh: mdbook not installed: guide build skipped (cargo install mdbook --locked)"
fi
bin="${CARGO_TARGET_DIR:-target}/debug/illumnet"
mpi_ranks=0
if [[ ${ILLUMNET_SKIP_MPI:-} == 1 ]]; then
    echo "tools/test.sh: ILLUMNET_SKIP_MPI=1: MPI tests skipped"
elif [[ $EUID -eq 0 ]] || bash tools/mpi/install.sh >/dev/null 2>&1; then
    step "mpi: install" bash tools/mpi/install.sh
    step "mpi: build (--features mpi)" cargo build --quiet --profile test --features mpi --bin illumnet
    step "mpi: 1, 2 and 4 ranks, a killed rank" env ILLUMNET="$bin" bash tools/mpi/test.sh
    mpi_ranks=2
else
    echo "tools/test.sh: not root and Open MPI not installed: MPI tests skipped (tools/mpi/install.sh)"
fi
if [[ ${ILLUMNET_SKIP_SLURM:-} == 1 ]]; then
    echo "tools/test.sh: ILLUMNET_SKIP_SLURM=1: Slurm frame farm skipped"
elif [[ $EUID -eq 0 ]]; then
    step "slurm frame farm" env ILLUMNET="$bin" FARM_MPI_RANKS=$mpi_ranks bash tools/slurm/test-frame-farm.sh
else
    echo "tools/test.sh: not root: Slurm frame farm skipped (tools/slurm/README.md)"
fi
if [[ ${ILLUMNET_SKIP_BROWSER:-} == 1 ]]; then
    echo "tools/test.sh: ILLUMNET_SKIP_BROWSER=1: browser test skipped"
elif [[ $EUID -eq 0 ]] || bash tools/browser/install.sh >/dev/null 2>&1; then
    step "browser: illumnet serve's page in headless Chromium" env ILLUMNET="$bin" bash tools/browser/test.sh
else
    echo "tools/test.sh: not root and Chromium not installed: browser test skipped (tools/browser/install.sh)"
fi
if [[ -x tools/fuzz ]] && command -v cargo-fuzz >/dev/null 2>&1; then
    step "fuzz smoke" tools/fuzz smoke
else
    echo "tools/test.sh: cargo-fuzz not installed: fuzz smoke run skipped (cargo install cargo-fuzz)"
fi
