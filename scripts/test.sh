#!/usr/bin/env bash
# Builds Loomlight and runs every test (CTest over GoogleTest), on PoCL's CPU device.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
"$root/scripts/install-deps.sh"
cmake -S "$root" -B "$root/build" -DCMAKE_BUILD_TYPE=Release
cmake --build "$root/build" -j"$(nproc)"
# A private PoCL kernel cache per build tree: warm after the first run, never shared with a stale one.
export POCL_CACHE_DIR="${POCL_CACHE_DIR:-$root/build/pocl-cache}"
cd "$root/build" && ctest --output-on-failure -j1 "$@"
