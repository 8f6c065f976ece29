#!/usr/bin/env bash
# Installs what `cargo build --features mpi` and `render --mpi` need, from
# Debian's packages: Open MPI (openmpi-bin: mpirun, the runtime;
# libopenmpi-dev: headers and mpicc, which the `mpi` crate's build script
# asks for the flags) and libclang-dev (the crate's bindgen). Does nothing
# when they are there. Needs root (apt-get). See docs/CLUSTER.md.
set -euo pipefail
cd "$(dirname "$0")/../.."
bash tools/apt-install.sh tools/mpi/install.sh openmpi-bin libopenmpi-dev libclang-dev
echo "tools/mpi/install.sh: $(mpirun --version 2>/dev/null | head -n 1)" >&2
