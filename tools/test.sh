#!/usr/bin/env bash
# The test suites, as CI runs them (README: "cargo test" line).
#   1. every test, release build (what users run);
#   2. the damage matrix again in a debug build, with overflow checks and
#      debug assertions on (profile `test`: optimised, checks kept), so an
#      overflow on hostile input is a failure, not a wrap;
#   3. the library's documentation, with warnings denied (its examples
#      ran in 1 as doc tests);
#   4. a short smoke run of each fuzz target, when cargo-fuzz is installed
#      (tools/fuzz; skipped with a note otherwise).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo test --release
cargo test --profile test --test damage
RUSTDOCFLAGS="-D warnings" cargo doc --no-deps --quiet
if [[ -x tools/fuzz ]] && command -v cargo-fuzz >/dev/null 2>&1; then
    tools/fuzz smoke
else
    echo "tools/test.sh: cargo-fuzz not installed: fuzz smoke run skipped (cargo install cargo-fuzz)"
fi
