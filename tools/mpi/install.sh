#!/usr/bin/env bash
# Installs what `cargo build --features mpi` and `render --mpi` need, from
# Debian's packages: Open MPI (openmpi-bin: mpirun, the runtime;
# libopenmpi-dev: headers and mpicc, which the `mpi` crate's build script
# asks for the flags) and libclang-dev (the crate's bindgen). Does nothing
# when they are there. Needs root (apt-get). See docs/CLUSTER.md.
set -euo pipefail
prog=tools/mpi/install.sh
say() { echo "$prog: $*" >&2; }

packages=(openmpi-bin libopenmpi-dev libclang-dev)
missing=()
for p in "${packages[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]} == 0)); then
    say "already installed: ${packages[*]} ($(mpirun --version 2>/dev/null | head -n 1))"
    exit 0
fi
[[ $(id -u) == 0 ]] || {
    say "error: installing ${missing[*]} needs root (apt-get install -y ${missing[*]})"
    exit 1
}
say "installing ${missing[*]} with apt-get"
apt=(apt-get -o DPkg::Lock::Timeout=300 install -y -q --no-install-recommends "${missing[@]}")
if ! DEBIAN_FRONTEND=noninteractive "${apt[@]}" >&2; then
    say "apt-get install failed; running apt-get update and trying again"
    apt-get -o DPkg::Lock::Timeout=300 update -q >&2 || true
    DEBIAN_FRONTEND=noninteractive "${apt[@]}" >&2 || {
        say "error: apt-get install ${missing[*]} failed"
        exit 1
    }
fi
say "installed: $(mpirun --version 2>/dev/null | head -n 1)"
