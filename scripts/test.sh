#!/usr/bin/env bash
# Builds Loomlight and runs every test (CTest over GoogleTest), on PoCL's CPU device.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
"$root/scripts/install-deps.sh"
# The Khronos glTF validator material_export_test runs (npm gltf-validator, pinned by tests/gltf/package-lock.json),
# installed when missing or older than the lock file.
gltf="$root/tests/gltf"
if [ ! -f "$gltf/node_modules/.package-lock.json" ] || [ "$gltf/package-lock.json" -nt "$gltf/node_modules/.package-lock.json" ]; then
  (cd "$gltf" && npm ci --no-audit --no-fund --loglevel=error >/dev/null)
fi
# Loomlight Studio (web/): its npm packages, the API code generated from the .proto, the page bundled by Vite.
"$root/scripts/build-web.sh"
cmake -S "$root" -B "$root/build" -DCMAKE_BUILD_TYPE=Release
cmake --build "$root/build" -j"$(nproc)"
# A private PoCL kernel cache per build tree: warm after the first run, never shared with a stale one.
export POCL_CACHE_DIR="${POCL_CACHE_DIR:-$root/build/pocl-cache}"
# Tests in parallel, one per core: every test uses port 0 (or a probed free port), a temporary directory of its own
# and no assertion on speed, so none depends on running alone. A CTest test is one GoogleTest binary (its tests
# share a process, tests/CMakeLists.txt), labelled fast or slow.
# The fast tier, every test but the long-by-design ones (the soak, scale-out, the proxy, the docs, the fuzz corpus
# replays, a stuck launch, statistics over every preset; label slow): `./scripts/test.sh -L fast`, or in a built tree
# `cd build && POCL_CACHE_DIR=$PWD/pocl-cache ctest -L fast -j2`: under 3 minutes on 2 cores. Everything (no
# argument, as CI runs it): 5 to 6 minutes on 2 cores. Other CTest arguments pass through (-L slow, -R NAME).
cd "$root/build" && ctest --output-on-failure -j"$(nproc)" "$@"
