#!/usr/bin/env bash
# Installs what is needed (Debian 12, as root), builds in Release and runs the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh --mpi  # the MPI build too: its tests run 1, 2 and 4 ranks
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release -DHYB_WERROR=ON -DHYB_MPI=ON > /dev/null
cmake --build build --parallel 2
ctest --test-dir build --output-on-failure -j2
bash scripts/fuzz.sh --regress  # every fuzz target over its corpus and the crashes found, under ASan+UBSan
