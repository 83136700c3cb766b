#!/usr/bin/env bash
# Tokens through a proxy (issue 44, part 9): two clients with their own bearer tokens call one replica through
# HAProxy, with TLS on both sides (as docs/operations.md "Scale out" and the cfg's own comments describe: the
# shipped deploy/haproxy/loomlight.cfg with `ssl crt` on the bind line, `ssl verify required ca-file ... alpn h2` on
# the replicas and `tcp-check connect ssl`).
# HAProxy sends different clients' calls over one backend connection (`http-reuse always` here makes that
# certain; its default, `safe`, does it too once a connection is idle), so a replica that took a connection for
# one client would refuse the other. Checked:
#   - every call of both clients succeeds, alternating over the one connection (HAProxy's statistics: the
#     replica saw one connection, the others reused it);
#   - the replica counts each call as the client its own token names (loomlight_client_calls_total);
#   - a call the token does not allow is PERMISSION_DENIED naming its own client, never the other one.
#
# usage: proxy_tokens_test.sh LOOMLIGHT_SERVER_BINARY LOOMLIGHT_CLIENT_BINARY
set -euo pipefail

server_binary=$(realpath "$1")
client_binary=$(realpath "$2")
source_dir=$(realpath "$(dirname "$0")/..")
tls="$source_dir/tests/data/tls"
command -v haproxy >/dev/null || { echo "FAIL: haproxy is not installed (scripts/install-deps.sh installs it)"; exit 1; }

readonly rounds=4
work=$(mktemp -d "${TMPDIR:-/tmp}/loomlight-proxy-tokens.XXXXXX")
started_pids=()

cleanup() {
  local status=$?
  for pid in "${started_pids[@]}"; do kill -KILL "$pid" 2>/dev/null || true; done
  wait 2>/dev/null || true
  if ((status == 0)); then rm -rf "$work"; else echo "proxy_tokens_test: files kept in $work" >&2; fi
}
trap cleanup EXIT

fail() {
  echo "FAIL: $*" >&2
  for log in "$work"/*.log; do [[ -f $log ]] && { echo "--- tail of $log" >&2; tail -n 15 "$log" >&2; }; done
  exit 1
}

# A loopback TCP port nothing listens on now, in $port.
next_free_port() {
  while :; do
    port=$((20000 + RANDOM % 40000))
    (exec 3<>"/dev/tcp/127.0.0.1/$port") 2>/dev/null || return 0
  done
}

# The body of http://127.0.0.1:PORT/PATH, with an extra request header line if given (HTTP/1.0 over /dev/tcp).
http_get() {  # PORT PATH [HEADER]
  exec 3<>"/dev/tcp/127.0.0.1/$1"
  printf 'GET %s HTTP/1.0\r\nHost: 127.0.0.1\r\n%s\r\n' "$2" "${3:+$3$'\r\n'}" >&3
  sed '1,/^\r*$/d' <&3
  exec 3<&-
}

# One field of HAProxy's statistics CSV for the replica.
replica_stat() {
  http_get "$stats_port" '/stats;csv' | awk -F, -v field="$1" '
    /^# / { sub(/^# /, ""); for (i = 1; i <= NF; ++i) column[$i] = i; next }
    $1 == "loomlight_replicas" && $2 == "replica1" { print $column[field] }'
}

# ---- the replica: TLS and the test tokens ----

"$server_binary" --address 127.0.0.1:0 --metrics-address 127.0.0.1:0 --tls-cert "$tls/server.pem" \
  --tls-key "$tls/server.key" --tokens "$tls/tokens.txt" >"$work/replica.log" 2>&1 &
started_pids+=($!)
replica_pid=$!
for ((i = 0; i < 1200; ++i)); do
  grep -q "metrics on port" "$work/replica.log" && break
  kill -0 "$replica_pid" 2>/dev/null || fail "the replica exited"
  sleep 0.1
done
replica_port=$(sed -n 's/.*serving on port \([0-9]*\).*/\1/p' "$work/replica.log" | head -n 1)
metrics_port=$(sed -n 's/.*metrics on port \([0-9]*\).*/\1/p' "$work/replica.log" | head -n 1)
[[ -n $replica_port && -n $metrics_port ]] || fail "the replica did not report its ports within 120 s"

# ---- HAProxy: the shipped configuration with TLS on both sides, one replica ----

cat "$tls/server.pem" "$tls/server.key" >"$work/haproxy.pem"
sed -e 's|^\(    bind "${LOOMLIGHT_HAPROXY_BIND-[^"]*}" proto h2\)$|\1 ssl crt '"$work"'/haproxy.pem alpn h2|' \
    -e 's|^\(    tcp-check connect\)$|\1 ssl alpn h2|' \
    -e 's|^\(    default-server proto h2 .*\)$|\1 ssl verify required ca-file '"$tls"'/ca.pem alpn h2 pool-purge-delay 10m|' \
    -e 's|^\(    balance leastconn\)$|\1\n    http-reuse always|' \
    -e '/^    server replica[23] /d' \
    "$source_dir/deploy/haproxy/loomlight.cfg" >"$work/haproxy.cfg"
for expected in 'haproxy.pem alpn h2' 'tcp-check connect ssl alpn h2' 'ca.pem alpn h2' 'http-reuse always'; do
  grep -qF "$expected" "$work/haproxy.cfg" || fail "the shipped configuration changed: no '$expected' after editing"
done
next_free_port
haproxy_port=$port
next_free_port
stats_port=$port
LOOMLIGHT_HAPROXY_BIND="127.0.0.1:$haproxy_port" LOOMLIGHT_HAPROXY_STATS="127.0.0.1:$stats_port" \
  LOOMLIGHT_REPLICA_1="127.0.0.1:$replica_port" haproxy -db -f "$work/haproxy.cfg" >"$work/haproxy.log" 2>&1 &
started_pids+=($!)
haproxy_pid=$!
for ((i = 0; i < 300; ++i)); do
  [[ $(replica_stat status 2>/dev/null) == UP ]] && break
  kill -0 "$haproxy_pid" 2>/dev/null || fail "haproxy exited"
  sleep 0.1
done
[[ $(replica_stat status) == UP ]] || fail "haproxy: the TLS replica is $(replica_stat status) ($(replica_stat check_status)), not UP"

# ---- two clients, alternating ----

printf '%s\n' editor-token-0123456789abcdef >"$work/editor.token"      # alice-editor: every call
printf '%s\n' pipeline-token-0123456789abcdef >"$work/pipeline.token"  # thumbs-pipeline: Render, ListModels, metrics
call() {  # TOKEN_NAME COMMAND...
  local token=$1
  shift
  "$client_binary" --server "127.0.0.1:$haproxy_port" --timeout 30 --tls-ca "$tls/ca.pem" \
    --token-file "$work/$token.token" "$@" >"$work/call.out" 2>&1
}
for ((round = 1; round <= rounds; ++round)); do
  call editor models || fail "alice-editor's call $round through HAProxy: $(tail -n 3 "$work/call.out")"
  call pipeline models || fail "thumbs-pipeline's call $round through HAProxy: $(tail -n 3 "$work/call.out")"
done
if call pipeline eval --preset linen_plain --wi 0,0,1 --wo 0,0,1; then fail "thumbs-pipeline may not Evaluate"; fi
grep -q PERMISSION_DENIED "$work/call.out" || fail "thumbs-pipeline's Evaluate: $(tail -n 3 "$work/call.out")"
grep -q thumbs-pipeline "$work/call.out" || fail "the refusal does not name its client: $(cat "$work/call.out")"
if grep -q alice-editor "$work/call.out"; then fail "the refusal names another client: $(cat "$work/call.out")"; fi

connections=$(replica_stat connect)
reuses=$(replica_stat reuse)
echo "HAProxy to the replica: $connections connection(s), $reuses reuse(s) for $((2 * rounds + 1)) calls"
# The calls shared one connection: each client's calls went over a connection the other's had used.
[[ $connections == 1 ]] || fail "HAProxy opened $connections connections to the replica; the test needs one shared"

# ---- the replica counted each call as its own client ----

basic=$(printf '%s' "thumbs-pipeline:pipeline-token-0123456789abcdef" | base64 -w0)
http_get "$metrics_port" /metrics "Authorization: Basic $basic" >"$work/metrics.txt"
for client in alice-editor thumbs-pipeline; do
  line="loomlight_client_calls_total{call=\"ListModels\",client=\"$client\",code=\"OK\"} $rounds"
  grep -qF "$line" "$work/metrics.txt" ||
    fail "no '$line' in the replica's metrics: $(grep loomlight_client_calls_total "$work/metrics.txt")"
done
echo "PASS: $((2 * rounds)) calls of two clients over one HAProxy connection, each counted as its own client"
