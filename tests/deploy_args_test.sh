#!/usr/bin/env bash
# The shipped Kubernetes Deployment's server arguments (deploy/kubernetes/deployment.yaml, "--name=value" form)
# are ones loomlight-server accepts: run with them and then --help, it must print its usage and exit 0 (an
# unknown option or a bad value exits 2 before --help is reached). Also: "--name=value" means "--name value",
# and a flag that takes no value refuses one. The directories the server writes are mounted volumes (the
# container's root file system is read-only).
#
# usage: deploy_args_test.sh LOOMLIGHT_SERVER_BINARY
set -euo pipefail
server=$1
manifest="$(dirname "$0")/../deploy/kubernetes/deployment.yaml"

# The container's args: the "- --..." items after "args:", up to the next key.
mapfile -t args < <(awk '/^ *args:/ { on = 1; next } on && /^ *- --/ { sub(/^ *- /, ""); print; next }
                         on && /^ *#/ { next } on { on = 0 }' "$manifest")
((${#args[@]} >= 3)) || { echo "FAIL: found ${#args[@]} server arguments in $manifest"; exit 1; }
printf 'manifest arguments: %s\n' "${args[*]}"

out=$("$server" "${args[@]}" --help 2>&1) || { echo "FAIL: the manifest's arguments were refused: $out" | head -c 600; exit 1; }
grep -q "usage: loomlight-server" <<<"$out" || { echo "FAIL: no usage printed"; exit 1; }

# The root file system is read-only there, so every directory the server writes must be a mounted volume, and
# --data-dir must be given (its default is under $HOME, on the root).
if grep -q "readOnlyRootFilesystem: true" "$manifest"; then
  mapfile -t mounts < <(sed -n 's/^ *mountPath: *//p' "$manifest")
  data_dir=""
  for arg in "${args[@]}"; do
    case $arg in
      --cache-dir=* | --data-dir=*)
        path=${arg#*=}
        [[ $arg == --data-dir=* ]] && data_dir=$path
        mounted=0
        for m in "${mounts[@]}"; do [[ $path == "$m" || $path == "$m"/* ]] && mounted=1; done
        ((mounted)) || { echo "FAIL: $arg is not on a mounted volume (${mounts[*]}); the root is read-only"; exit 1; }
        ;;
    esac
  done
  [[ -n $data_dir ]] || { echo "FAIL: no --data-dir: the default under \$HOME is on the read-only root"; exit 1; }
fi

expect_refused() {  # MESSAGE ARGS...
  local message=$1 status=0
  shift
  out=$("$server" "$@" --help 2>&1) || status=$?
  ((status == 2)) || { echo "FAIL: '$*' exited $status, not 2"; exit 1; }
  grep -q -- "$message" <<<"$out" || { echo "FAIL: '$*' said: $(head -c 300 <<<"$out")"; exit 1; }
}
expect_refused "takes no value" --allow-plaintext-remote=yes
expect_refused "unknown option '--no-such-option'" --no-such-option=1
expect_refused "must be at least 1" --memory-budget-mb=0
expect_refused "not ADDRESS or ADDRESS/BITS" --trusted-proxy=proxy.example
echo "PASS"
