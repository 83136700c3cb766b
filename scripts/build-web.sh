#!/usr/bin/env bash
# Builds Loomlight Studio (web/: the page and its gateway): installs the npm packages pinned by
# web/package-lock.json when missing or older than the lock file, generates the API code from the .proto
# (web/gen/) and bundles the page with Vite (web/dist/). Run by scripts/serve.sh and scripts/test.sh.
set -euo pipefail
web="$(cd "$(dirname "$0")/../web" && pwd)"
cd "$web"
if [ ! -f node_modules/.package-lock.json ] || [ package-lock.json -nt node_modules/.package-lock.json ]; then
  npm ci --no-audit --no-fund --loglevel=error >/dev/null
fi
npm run --silent build >/dev/null
