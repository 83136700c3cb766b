#!/usr/bin/env bash
# Builds Loomlight and starts the server on 127.0.0.1:50051 on PoCL's CPU device. Extra arguments go to
# loomlight-server (see --help).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
"$root/scripts/install-deps.sh"
cmake -S "$root" -B "$root/build" -DCMAKE_BUILD_TYPE=Release
cmake --build "$root/build" -j"$(nproc)" --target loomlight-server loomlight
exec "$root/build/loomlight-server" --address 127.0.0.1:50051 --metrics-address 127.0.0.1:9464 \
  --environment-dir "$root/deploy/environments" "$@"
