#!/usr/bin/env bash
# Builds Loomlight and starts the server on 127.0.0.1:50051 on PoCL's CPU device, and Loomlight Studio's gateway
# on 127.0.0.1:8080 in front of it (the page: docs/studio.md), printing the page's address. Extra arguments go to
# loomlight-server (see --help); LOOMLIGHT_STUDIO_LISTEN=HOST:PORT moves the page (loopback by default, as the
# server). SIGTERM or Ctrl-C stops both; the script exits with the server's status.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
"$root/scripts/install-deps.sh"
cmake -S "$root" -B "$root/build" -DCMAKE_BUILD_TYPE=Release
cmake --build "$root/build" -j"$(nproc)" --target loomlight-server loomlight
"$root/scripts/build-web.sh"

"$root/build/loomlight-server" --address 127.0.0.1:50051 --metrics-address 127.0.0.1:9464 \
  --environment-dir "$root/deploy/environments" "$@" &
server=$!
node "$root/web/gateway/main.mjs" --listen "${LOOMLIGHT_STUDIO_LISTEN:-127.0.0.1:8080}" --upstream 127.0.0.1:50051 &
gateway=$!
signalled=""
stop() {
  kill -TERM "$server" "$gateway" 2>/dev/null || true
}
trap 'signalled=1; stop' TERM INT
# Until either process ends, or a signal stops both: then the server's status is the script's (0 after SIGTERM); a
# gateway that ends on its own (its port taken, say) stops the server and fails the script.
wait -n "$server" "$gateway" || true
stop
status=0
wait "$server" || status=$?
wait "$gateway" 2>/dev/null || true
if [ -z "$signalled" ] && [ "$status" -eq 0 ]; then
  echo "serve.sh: the gateway stopped; the server was stopped with it" >&2
  status=1
fi
exit "$status"
