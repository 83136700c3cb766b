#!/usr/bin/env bash
# Proves the README's set-up commands on a clean Debian bookworm root made on the spot: mmdebstrap makes a
# bare root (variant apt: apt, dpkg and the essential packages, nothing else) with this machine's own apt
# sources and apt configuration (so it works behind this machine's mirror or proxy), the repository's files
# are copied in (git's tracked files plus untracked ones that are not ignored: never a host build/), and
# inside it, as root, run
#   ./scripts/test.sh                 the README's test command, exactly;
#   ./scripts/serve.sh                the README's serve command, in the background (in a private network
#                                     namespace, so a server already on this machine's port 50051 cannot
#                                     answer for it) until `loomlight health` reports SERVING and the page and
#                                     its API answer through the gateway; then SIGTERM, and it must exit 0;
#   ./scripts/fuzz.sh SECONDS         when LOOMLIGHT_CLEAN_ROOT_FUZZ_SECONDS is set (CI sets 60): coverage-guided
#                                     fuzzing of each libFuzzer target, with ASan and UBSan (a clang build of
#                                     its own, about 12 minutes on 2 cores); a crash fails the check.
# The root is unmounted and removed on exit, also on failure. Needs root (re-runs itself with sudo) and a few
# GiB of disk (10-20 minutes on 2 cores, most of it the build and the tests). Used by .ci/run;
# developers can run it too.
#
# Environment:
#   LOOMLIGHT_CLEAN_ROOT_PARENT   where the root is made (default /var/tmp, else the repository's parent
#                                 directory when /var/tmp has too little space)
#   LOOMLIGHT_CLEAN_ROOT_SOURCES  apt sources files for the root, space-separated (default: this machine's
#                                 /etc/apt/sources.list and /etc/apt/sources.list.d/*.{list,sources})
#   LOOMLIGHT_CLEAN_ROOT_APT_CONF apt configuration files for the root, space-separated (default: this
#                                 machine's /etc/apt/apt.conf and /etc/apt/apt.conf.d/* files that set how apt
#                                 reaches the mirror: Acquire::http(s)/ftp options, proxies, validity checks)
#   LOOMLIGHT_SERVE_TIMEOUT       seconds serve.sh may take to report SERVING (default 600)
#   LOOMLIGHT_KEEP_ROOT=1         keep the root on exit (for debugging; mounts are still undone)
#   LOOMLIGHT_CLEAN_ROOT_FUZZ_SECONDS  seconds of fuzzing per target after the serve check (default 0: none)
set -euo pipefail

if [ "$(id -u)" -ne 0 ]; then
  exec sudo --preserve-env=LOOMLIGHT_CLEAN_ROOT_FUZZ_SECONDS,LOOMLIGHT_CLEAN_ROOT_PARENT,LOOMLIGHT_CLEAN_ROOT_SOURCES,LOOMLIGHT_CLEAN_ROOT_APT_CONF,LOOMLIGHT_SERVE_TIMEOUT,LOOMLIGHT_KEEP_ROOT,http_proxy,https_proxy,no_proxy \
    "$0" "$@"
fi

repo="$(cd "$(dirname "$0")/.." && pwd)"
suite=bookworm
inner=/root/loomlight  # the repository's place inside the root
serve_timeout="${LOOMLIGHT_SERVE_TIMEOUT:-600}"
fuzz_seconds="${LOOMLIGHT_CLEAN_ROOT_FUZZ_SECONDS:-0}"
[[ "$fuzz_seconds" =~ ^[0-9]+$ ]] || { echo "LOOMLIGHT_CLEAN_ROOT_FUZZ_SECONDS must be a number of seconds" >&2; exit 2; }
need_gib=4  # measured: 2.1 GiB for the root with the dependencies and the build

log() { printf '[clean-root %s] %s\n' "$(date +%H:%M:%S)" "$*"; }
die() { log "FAILED: $*"; exit 1; }

# ---- Timings of each phase, printed at the end (also on failure) ----
phases=()
phase_start=0
begin_phase() { phase_name="$1"; phase_start=$(date +%s); log "== $1"; }
end_phase() {
  local seconds=$(($(date +%s) - phase_start))
  phases+=("$(printf '%-42s %4dm%02ds' "$phase_name" $((seconds / 60)) $((seconds % 60)))")
  log "== $phase_name: ${seconds}s"
  phase_name=""
}
script_start=$(date +%s)

# ---- Host tools: mmdebstrap makes the root, iproute2 brings up the serve phase's loopback ----
host_missing=()
command -v mmdebstrap >/dev/null || host_missing+=(mmdebstrap)
command -v ip >/dev/null || host_missing+=(iproute2)
if ((${#host_missing[@]})); then
  log "installing on this machine: ${host_missing[*]}"
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${host_missing[@]}"
fi

# ---- Where: enough free disk ----
free_gib() { df -P -BG "$1" | awk 'NR == 2 { sub("G", "", $4); print $4 }'; }
parent="${LOOMLIGHT_CLEAN_ROOT_PARENT:-}"
if [ -z "$parent" ]; then
  parent=/var/tmp
  if (($(free_gib /var/tmp) < need_gib)) && (($(free_gib "$repo/..") >= need_gib)); then parent="$(cd "$repo/.." && pwd)"; fi
fi
mkdir -p "$parent"
(($(free_gib "$parent") >= need_gib)) ||
  die "$parent has $(free_gib "$parent") GiB free, $need_gib needed: set LOOMLIGHT_CLEAN_ROOT_PARENT"
root="$(mktemp -d "$parent/loomlight-clean-root.XXXXXX")"
chmod 755 "$root"  # it is /, which every user (apt's _apt sandbox too) must be able to enter
log "root: $root ($(free_gib "$parent") GiB free)"

# ---- Clean-up on every exit: the server, the mounts, the root ----
server_pid=""
mounts_under_root() { awk -v r="$root" '$5 == r || index($5, r "/") == 1 { print $5 }' /proc/self/mountinfo | sort -r; }
cleanup() {
  local status=$?
  set +e
  [ -n "${phase_name:-}" ] && end_phase
  if [ -n "$server_pid" ] && kill -0 "$server_pid" 2>/dev/null; then
    kill -TERM "$server_pid"
    sleep 5
    kill -0 "$server_pid" 2>/dev/null && kill -KILL "$server_pid"
    wait "$server_pid" 2>/dev/null
  fi
  local m
  for m in $(mounts_under_root); do umount "$m" 2>/dev/null || umount -l "$m"; done
  if [ -n "$(mounts_under_root)" ]; then
    log "still mounted under $root, not removing it:"
    mounts_under_root
    status=1
  elif [ "${LOOMLIGHT_KEEP_ROOT:-0}" = 1 ]; then
    log "kept $root (LOOMLIGHT_KEEP_ROOT=1)"
  else
    rm -rf --one-file-system "$root"
  fi
  local total=$(($(date +%s) - script_start))
  log "timings:"
  local p
  for p in "${phases[@]}"; do log "  $p"; done
  log "  $(printf '%-42s %4dm%02ds' total $((total / 60)) $((total % 60)))"
  if [ "$status" -eq 0 ]; then log "PASSED"; else log "FAILED (exit status $status)"; fi
  exit "$status"
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

# ---- 1. The root: this machine's apt sources and configuration ----
sources=()
if [ -n "${LOOMLIGHT_CLEAN_ROOT_SOURCES:-}" ]; then
  read -ra sources <<<"$LOOMLIGHT_CLEAN_ROOT_SOURCES"
else
  for f in /etc/apt/sources.list /etc/apt/sources.list.d/*.list /etc/apt/sources.list.d/*.sources; do
    if [ -f "$f" ] && grep -qE '^[[:space:]]*(deb|Types:)' "$f"; then sources+=("$f"); fi
  done
fi
((${#sources[@]})) || die "no apt sources found: set LOOMLIGHT_CLEAN_ROOT_SOURCES"
apt_conf=()
if [ -n "${LOOMLIGHT_CLEAN_ROOT_APT_CONF:-}" ]; then
  read -ra apt_conf <<<"$LOOMLIGHT_CLEAN_ROOT_APT_CONF"
else
  for f in /etc/apt/apt.conf /etc/apt/apt.conf.d/*; do
    if [ -f "$f" ] && grep -qE 'Acquire::(https?|ftp)|Proxy|Check-Valid-Until|Check-Date' "$f"; then apt_conf+=("$f"); fi
  done
fi
mm_args=(--variant=apt --mode=root --format=directory)
for f in "${apt_conf[@]}"; do mm_args+=("--aptopt=$f"); done
# A machine whose mirror is https has ca-certificates; so must the root, or apt there cannot verify it.
grep -qs 'https://' "${sources[@]}" && mm_args+=(--include=ca-certificates)
# This machine's own certificate authorities (an egress proxy's, in /usr/local/share/ca-certificates) go into the
# root's trust store, as its apt configuration does: the tests fetch the glTF validator from npm's registry over
# https, through whatever this machine's traffic passes.
local_cas=()
for f in /usr/local/share/ca-certificates/*.crt; do [ -f "$f" ] && local_cas+=("$f"); done
((${#local_cas[@]})) && mm_args+=(--include=ca-certificates)
log "apt sources: ${sources[*]}"
log "apt configuration: ${apt_conf[*]:-none}"

begin_phase "root creation (mmdebstrap)"
mmdebstrap "${mm_args[@]}" "$suite" "$root" "${sources[@]}" </dev/null
end_phase

# ---- 2. The repository's files (no build trees: they are ignored) ----
mkdir -p "$root$inner"
(cd "$repo" && git ls-files -z --cached --others --exclude-standard |
  while IFS= read -r -d '' f; do if [ -e "$f" ] || [ -L "$f" ]; then printf '%s\0' "$f"; fi; done |
  tar --null -T - -cf -) | tar -xf - -C "$root$inner"
[ ! -e "$root$inner/build" ] || die "a build/ directory was copied into the root"
log "copied $(find "$root$inner" -type f | wc -l) files of $repo to $inner"

if ((${#local_cas[@]})); then
  cp "${local_cas[@]}" "$root/usr/local/share/ca-certificates/"
  chroot "$root" update-ca-certificates >/dev/null
  log "trusts this machine's certificate authorities: ${local_cas[*]}"
fi

# ---- 3. Kernel file systems ----
mount -t proc proc "$root/proc"
mount --bind /sys "$root/sys"
mount --bind /dev "$root/dev"
mount --bind /dev/pts "$root/dev/pts"
mount -t tmpfs -o mode=1777 tmpfs "$root/dev/shm"

# Runs a command in the root as root, in a clean environment (a proxy set here is passed on).
in_root_env=(env -i HOME=/root LANG=C.UTF-8 TERM="${TERM:-dumb}" PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin)
for v in http_proxy https_proxy no_proxy HTTP_PROXY HTTPS_PROXY NO_PROXY; do
  [ -n "${!v:-}" ] && in_root_env+=("$v=${!v}")
done
# Node (npm) reads its own CA bundle; the root's store, with this machine's authorities, is added to it.
((${#local_cas[@]})) && in_root_env+=(NODE_EXTRA_CA_CERTS=/etc/ssl/certs/ca-certificates.crt)
in_root() { chroot "$root" "${in_root_env[@]}" /bin/bash -c "$1"; }

# ---- 4. The README's test command (installs the dependencies first, then builds and runs CTest) ----
begin_phase "dependencies (scripts/install-deps.sh)"
in_root "cd $inner && ./scripts/install-deps.sh" </dev/null
end_phase
begin_phase "build and test (./scripts/test.sh)"
in_root "cd $inner && ./scripts/test.sh" </dev/null
end_phase
log "root size after the build: $(du -sh --one-file-system "$root" | cut -f1)"

# ---- 5. The README's serve command, until health reports SERVING ----
begin_phase "serve until SERVING (./scripts/serve.sh)"
serve_log="$root/root/serve.log"
# A private network namespace with only loopback: the server's fixed ports (50051, 9464) cannot clash with
# anything on this machine. unshare, bash and chroot exec into each other, so $server_pid ends up
# being serve.sh itself, which stops the server and the gateway on SIGTERM and exits with the server's status.
unshare --net -- bash -c 'ip link set lo up && exec "$@"' _ chroot "$root" "${in_root_env[@]}" /bin/bash -c \
  "cd $inner && exec ./scripts/serve.sh" </dev/null >"$serve_log" 2>&1 &
server_pid=$!
# Poll only once the server's own namespace exists, never this machine's (which may run another server).
until [ "$(readlink "/proc/$server_pid/ns/net" 2>/dev/null)" != "$(readlink /proc/self/ns/net)" ]; do
  kill -0 "$server_pid" 2>/dev/null || { cat "$serve_log"; die "serve.sh did not start"; }
  sleep 0.1
done
health() {
  nsenter --net="/proc/$server_pid/ns/net" -- chroot "$root" "${in_root_env[@]}" \
    "$inner/build/loomlight" health --server 127.0.0.1:50051 --timeout 5 2>&1
}
deadline=$(($(date +%s) + serve_timeout))
answer=""
last=""
until answer="$(health)"; do
  [ "$answer" = "$last" ] || log "health: $answer"  # each new answer once: UNAVAILABLE, NOT_SERVING, ...
  last="$answer"
  if ! kill -0 "$server_pid" 2>/dev/null; then
    cat "$serve_log"
    die "serve.sh exited before reporting SERVING"
  fi
  if (($(date +%s) > deadline)); then
    tail -n 50 "$serve_log"
    die "no SERVING within ${serve_timeout}s (last answer: $answer)"
  fi
  sleep 2
done
[ "$answer" = SERVING ] || die "health exited 0 but printed '$answer'"
log "health: $answer"
# The page serve.sh starts beside the server (Loomlight Studio's gateway on 127.0.0.1:8080), and its API through
# the gateway: the page's HTML, then ListModels as the browser calls it (the Connect protocol, JSON).
page_check='
  const get = (path, body) => fetch("http://127.0.0.1:8080/" + path, body && {
    method: "POST", headers: { "content-type": "application/json" }, body: "{}" }).then((r) => r.text());
  Promise.all([get(""), get("loomlight.v1.Loomlight/ListModels", true)]).then(([html, models]) => {
    if (!html.includes("Loomlight Studio") || !models.includes("microcylinder")) process.exit(1);
  }, () => process.exit(1));'
for attempt in $(seq 30); do
  if nsenter --net="/proc/$server_pid/ns/net" -- chroot "$root" "${in_root_env[@]}" node -e "$page_check"; then
    break
  fi
  ((attempt < 30)) || { tail -n 20 "$serve_log"; die "the page is not served on 127.0.0.1:8080"; }
  sleep 1
done
tail -n 4 "$serve_log"
log "page: served"
end_phase

# ---- 6. SIGTERM stops the server, which exits 0 ----
kill -TERM "$server_pid"
for _ in $(seq 60); do kill -0 "$server_pid" 2>/dev/null || break; sleep 1; done
kill -0 "$server_pid" 2>/dev/null && { tail -n 20 "$serve_log"; die "the server still runs 60 s after SIGTERM"; }
server_status=0
wait "$server_pid" || server_status=$?
server_pid=""
((server_status == 0)) || { tail -n 20 "$serve_log"; die "the server exited with status $server_status after SIGTERM"; }
log "the server stopped on SIGTERM (exit status 0)"

# ---- 7. Coverage-guided fuzzing (CI), after the README's commands are proven ----
if ((fuzz_seconds > 0)); then
  begin_phase "fuzz, ${fuzz_seconds} s per target (scripts/fuzz.sh)"
  in_root "cd $inner && ./scripts/fuzz.sh $fuzz_seconds" </dev/null || die "fuzzing found a crash or a failed check"
  end_phase
fi
