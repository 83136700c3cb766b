#!/usr/bin/env bash
# Builds Loomlight and runs every test (CTest over GoogleTest), on PoCL's CPU device.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
"$root/scripts/install-deps.sh"
cmake -S "$root" -B "$root/build" -DCMAKE_BUILD_TYPE=Release
cmake --build "$root/build" -j"$(nproc)"
# A private PoCL kernel cache per build tree: warm after the first run, never shared with a stale one.
export POCL_CACHE_DIR="${POCL_CACHE_DIR:-$root/build/pocl-cache}"
# Tests in parallel, one per core: every test uses port 0 (or a probed free port), its own temporary names and no
# assertion on speed, so none depends on running alone (2 cores: 6.5 minutes against 12 one at a time).
# `./scripts/test.sh -L fast` leaves out the slow ones (label slow: the soak, scale-out, the proxy).
cd "$root/build" && ctest --output-on-failure -j"$(nproc)" "$@"
