#!/usr/bin/env bash
# The shipped Kubernetes manifests (deploy/kubernetes/) work and are safe as shipped:
# - the Deployment's server arguments ("--name=value" form) are ones loomlight-server accepts: run with them and
#   then --help, it must print its usage and exit 0 (an unknown option or a bad value exits 2 before --help is
#   reached). Also: "--name=value" means "--name value", and a flag that takes no value refuses one.
# - the directories the server writes are mounted volumes (the container's root file system is read-only);
# - TLS and tokens: --tls-cert, --tls-key and --tokens name files on read-only mounts of Secrets, and nothing
#   allows plaintext on the pod network (no --allow-plaintext-remote; metrics on loopback only, as they are
#   plaintext HTTP), and the Service publishes no metrics port;
# - liveness and readiness are different checks: readiness is `loomlight health` (SERVING), liveness
#   `loomlight health --alive` (it answers), so a busy, warming or draining pod leaves the Service's addresses
#   instead of being restarted with its calls; with the client binary given, every probe's command line is one
#   the client accepts (run as the kubelet runs it, with --help added);
# - a NetworkPolicy selects the Deployment's pods, admits the gRPC port only from labelled pods and the metrics
#   port only from the monitoring namespace, and has no rule that admits everyone.
# The manifests are read with PyYAML when python3 has it, else with careful greps of the same facts.
#
# usage: deploy_args_test.sh LOOMLIGHT_SERVER_BINARY [LOOMLIGHT_CLIENT_BINARY]
set -euo pipefail
server=$1
client=${2:-}
dir="$(dirname "$0")/../deploy/kubernetes"
manifest="$dir/deployment.yaml"
policy="$dir/networkpolicy.yaml"
service="$dir/service.yaml"
fail() { echo "FAIL: $*"; exit 1; }

args=() mounts=() secret_mounts=() probes=()
# LOOMLIGHT_NO_PYYAML=1 tries the grep path where PyYAML is installed.
if [[ -z ${LOOMLIGHT_NO_PYYAML:-} ]] && python3 -c "import yaml" 2>/dev/null; then
  echo "reading the manifests with PyYAML"
  # Prints "ARG x", "MOUNT path", "SECRETMOUNT path", "PROBE kind command" lines, or "FAIL why".
  facts=$(python3 - "$manifest" "$policy" "$service" <<'EOF'
import shlex, sys, yaml

def fail(why):
    print("FAIL " + why)
    sys.exit(0)

deployment = yaml.safe_load(open(sys.argv[1]))
policies = [d for d in yaml.safe_load_all(open(sys.argv[2])) if d]
services = [d for d in yaml.safe_load_all(open(sys.argv[3])) if d]
pod = deployment["spec"]["template"]["spec"]
labels = deployment["spec"]["template"]["metadata"]["labels"]
servers = [c for c in pod["containers"] if c["name"] == "loomlight-server"]
if len(servers) != 1:
    fail("no container named loomlight-server")
c = servers[0]
for arg in c.get("args", []):
    print("ARG " + arg)
if c.get("securityContext", {}).get("readOnlyRootFilesystem"):
    print("READONLYROOT")
volumes = {v["name"]: v for v in pod.get("volumes", [])}
for m in c.get("volumeMounts", []):
    print("MOUNT " + m["mountPath"])
    v = volumes.get(m["name"])
    if v is None:
        fail("volumeMount %s names no volume" % m["name"])
    if "secret" in v:
        if not m.get("readOnly"):
            fail("the Secret volume %s is mounted writable" % m["name"])
        print("SECRETMOUNT " + m["mountPath"])

# Probes: liveness and readiness both there, and not the same check.
for kind in ("startupProbe", "readinessProbe", "livenessProbe"):
    probe = c.get(kind)
    if probe is None:
        if kind == "startupProbe":
            continue
        fail("no " + kind)
    if "grpc" in probe:
        fail(kind + " is a native gRPC probe: the kubelet's speaks plaintext, the server TLS")
    if "exec" not in probe:
        fail(kind + " is not an exec probe running `loomlight health`")
    command = probe["exec"]["command"]
    line = command[2] if command[:2] == ["sh", "-c"] else " ".join(shlex.quote(w) for w in command)
    words = shlex.split(line)
    if "health" not in words:
        fail(kind + " does not run `loomlight health`: " + line)
    alive = "--alive" in words
    if kind == "readinessProbe" and alive:
        fail("readiness must be SERVING, not --alive")
    if kind != "readinessProbe" and not alive:
        fail(kind + " must not depend on SERVING (restarting a busy pod cancels its calls): add --alive")
    print("PROBE %s %s" % (kind, line))

# NetworkPolicy: the pods selected, ingress only, every rule with sources and ports.
ports = {p["name"]: p["containerPort"] for p in c.get("ports", [])}
grpc_port = ports.get("grpc")
if grpc_port is None:
    fail("no container port named grpc")
selecting = [p for p in policies if p.get("kind") == "NetworkPolicy" and
             all(labels.get(k) == v for k, v in p["spec"]["podSelector"].get("matchLabels", {}).items()) and
             p["spec"]["podSelector"].get("matchLabels")]
if not selecting:
    fail("no NetworkPolicy selects the Deployment's pods")
spec = selecting[0]["spec"]
if "Ingress" not in spec.get("policyTypes", []):
    fail("the NetworkPolicy does not restrict ingress")
grpc_sources, metrics_rules = [], []
for rule in spec.get("ingress", []):
    sources, rule_ports = rule.get("from"), rule.get("ports")
    if not sources or not rule_ports:
        fail("an ingress rule without sources or ports admits everyone: %r" % rule)
    for s in sources:
        if "ipBlock" in s or s.get("namespaceSelector") == {} or s.get("podSelector") == {}:
            fail("an ingress source admits everyone: %r" % s)
    numbers = [p.get("port") for p in rule_ports]
    if grpc_port in numbers or "grpc" in numbers:
        grpc_sources += sources
    else:
        metrics_rules.append(rule)
if not grpc_sources or not all("podSelector" in s and "namespaceSelector" not in s for s in grpc_sources):
    fail("the gRPC port must be admitted from labelled pods of the namespace only: %r" % grpc_sources)
for rule in metrics_rules:
    for s in rule["from"]:
        if s.get("namespaceSelector", {}).get("matchLabels", {}).get("kubernetes.io/metadata.name") != "monitoring":
            fail("a port other than gRPC is admitted from outside the monitoring namespace: %r" % s)

# The Service: the gRPC port only (metrics are not on the pod network).
for s in services:
    for p in s["spec"].get("ports", []):
        if p.get("targetPort") not in ("grpc", grpc_port):
            fail("the Service publishes a port other than gRPC: %r" % p)
print("OK")
EOF
)
  while IFS= read -r line; do
    case $line in
      FAIL*) fail "${line#FAIL }" ;;
      ARG*) args+=("${line#ARG }") ;;
      MOUNT*) mounts+=("${line#MOUNT }") ;;
      SECRETMOUNT*) secret_mounts+=("${line#SECRETMOUNT }") ;;
      PROBE*) probes+=("${line#PROBE }") ;;
    esac
  done <<<"$facts"
  [[ $facts == *$'\nOK' ]] || fail "the manifest checks did not finish: $facts"
else
  echo "no PyYAML: reading the manifests with grep"
  # Containers are the 8-space list items between "containers:" and "volumes:" (env, ports and mounts are deeper).
  ((1 == $(sed -n '/^      containers:/,/^      volumes:/p' "$manifest" | grep -c "^        - name: "))) ||
    fail "the Deployment must have exactly one container (loomlight-server)"
  # The container's args: the "- --..." items after "args:", up to the next key.
  mapfile -t args < <(awk '/^ *args:/ { on = 1; next } on && /^ *- --/ { sub(/^ *- /, ""); print; next }
                           on && /^ *#/ { next } on { on = 0 }' "$manifest")
  mapfile -t mounts < <(sed -n 's/^ *mountPath: *//p' "$manifest")
  # Secret volumes' mounts: a mount followed by readOnly: true whose volume is a secret.
  for name in $(awk '/^ *- name: / { n = $3 } /^ *secret:/ { print n }' "$manifest"); do
    path=$(awk -v n="$name" '$0 ~ "^ *- name: " n "$" { on = 1; next } on && /mountPath:/ { print $2; exit }' "$manifest")
    ro=$(awk -v n="$name" '$0 ~ "^ *- name: " n "$" { on = 1; next } on && /readOnly: true/ { print "yes"; exit }
                           on && /^ *- name:/ { exit }' "$manifest")
    [[ $ro == yes ]] || fail "the Secret volume $name is not mounted readOnly"
    secret_mounts+=("$path")
  done
  for kind in startupProbe readinessProbe livenessProbe; do
    block=$(awk -v k="$kind:" '$1 == k { on = 1; next } on && /^          [a-zA-Z]/ { exit } on' "$manifest")
    [[ -n $block || $kind == startupProbe ]] || fail "no $kind"
    [[ -z $block ]] && continue
    grep -q "grpc:" <<<"$block" && fail "$kind is a native gRPC probe: the kubelet's speaks plaintext, the server TLS"
    line=$(sed -n 's/.*command: \["sh", "-c", "\(.*\)"\]$/\1/p' <<<"$block" | sed 's/\\"/"/g')
    [[ $line == *" health"* ]] || fail "$kind does not run \`loomlight health\` through sh -c"
    if [[ $kind == readinessProbe ]]; then [[ $line != *--alive* ]] || fail "readiness must be SERVING, not --alive"
    else [[ $line == *--alive* ]] || fail "$kind must not depend on SERVING: add --alive"; fi
    probes+=("$kind $line")
  done
  grep -q "^kind: NetworkPolicy" "$policy" || fail "no NetworkPolicy"
  grep -q "app.kubernetes.io/name: loomlight" "$policy" || fail "the NetworkPolicy does not select the pods"
  grep -q -- "- Ingress" "$policy" || fail "the NetworkPolicy does not restrict ingress"
  grep -q "port: 50051" "$policy" || fail "the NetworkPolicy does not name the gRPC port"
  grep -q "kubernetes.io/metadata.name: monitoring" "$policy" || fail "metrics are not limited to monitoring"
  grep -Eq "(namespaceSelector|podSelector): \{\}|ipBlock" "$policy" && fail "an ingress source admits everyone"
  grep -q "9464" "$service" && fail "the Service publishes the metrics port"
fi

((${#args[@]} >= 3)) || fail "found ${#args[@]} server arguments in $manifest"
printf 'manifest arguments: %s\n' "${args[*]}"

out=$("$server" "${args[@]}" --help 2>&1) || fail "the manifest's arguments were refused: $(head -c 600 <<<"$out")"
grep -q "usage: loomlight-server" <<<"$out" || fail "no usage printed"

# TLS and tokens from read-only Secret mounts; no plaintext on the pod network.
declare -A given=()
for arg in "${args[@]}"; do
  name=${arg%%=*}
  given[$name]=${arg#*=}
  [[ $name == --allow-plaintext-remote ]] && fail "--allow-plaintext-remote: the pod network would be plaintext"
done
for flag in --tls-cert --tls-key --tokens; do
  path=${given[$flag]:-}
  [[ -n $path ]] || fail "no $flag: the Deployment must serve TLS with tokens"
  on_secret=0
  for m in "${secret_mounts[@]}"; do [[ $path == "$m"/* ]] && on_secret=1; done
  ((on_secret)) || fail "$flag=$path is not on a read-only Secret mount (${secret_mounts[*]:-none})"
done
metrics=${given[--metrics-address]:-}
if [[ -n $metrics ]]; then
  [[ $metrics == 127.* || $metrics == localhost:* || $metrics == "[::1]:"* ]] ||
    fail "--metrics-address=$metrics: metrics are plaintext HTTP and must stay on loopback"
fi

# The root file system is read-only there, so every directory the server writes must be a mounted volume, and
# --data-dir must be given (its default is under $HOME, on the root).
if grep -q "readOnlyRootFilesystem: true" "$manifest"; then
  data_dir=""
  for arg in "${args[@]}"; do
    case $arg in
      --cache-dir=* | --data-dir=*)
        path=${arg#*=}
        [[ $arg == --data-dir=* ]] && data_dir=$path
        mounted=0
        for m in "${mounts[@]}"; do [[ $path == "$m" || $path == "$m"/* ]] && mounted=1; done
        ((mounted)) || fail "$arg is not on a mounted volume (${mounts[*]}); the root is read-only"
        ;;
    esac
  done
  [[ -n $data_dir ]] || fail "no --data-dir: the default under \$HOME is on the read-only root"
fi

# Every probe's command, as the kubelet runs it (sh -c), is one the client accepts: with --help added it must
# print the command's help and exit 0 (an unknown option exits 2).
((${#probes[@]} >= 2)) || fail "found ${#probes[@]} probes"
if [[ -n $client ]]; then
  bin=$(mktemp -d)
  trap 'rm -rf "$bin"' EXIT
  ln -s "$(realpath "$client")" "$bin/loomlight"
  for probe in "${probes[@]}"; do
    kind=${probe%% *} line=${probe#* }
    out=$(PATH="$bin:$PATH" LOOMLIGHT_TLS_SERVER_NAME=loomlight.ns.svc.cluster.local sh -c "$line --help" 2>&1) ||
      fail "$kind: the client refused '$line': $(head -c 400 <<<"$out")"
    grep -q "usage: loomlight health" <<<"$out" || fail "$kind: '$line' is not \`loomlight health\`: $(head -c 300 <<<"$out")"
    echo "$kind: $line"
  done
else
  echo "no client binary given: the probes' command lines are not run"
fi

expect_refused() {  # MESSAGE ARGS...
  local message=$1 status=0
  shift
  out=$("$server" "$@" --help 2>&1) || status=$?
  ((status == 2)) || fail "'$*' exited $status, not 2"
  grep -q -- "$message" <<<"$out" || fail "'$*' said: $(head -c 300 <<<"$out")"
}
expect_refused "takes no value" --allow-plaintext-remote=yes
expect_refused "unknown option '--no-such-option'" --no-such-option=1
expect_refused "must be at least 1" --memory-budget-mb=0
expect_refused "not ADDRESS or ADDRESS/BITS" --trusted-proxy=proxy.example
expect_refused "takes N, interactive:N or bulk:N" --max-call-seconds=batch:5
expect_refused "takes N, interactive:N or bulk:N" --max-call-seconds=bulk:0
echo "PASS"
