#!/usr/bin/env bash
# Coverage-guided fuzzing (libFuzzer) of request validation, WIF parsing and mesh files: the targets in tests/fuzz/.
#
#     scripts/fuzz.sh [SECONDS] [--merge]
#
# Configures a clang build with ASan and UBSan in build-fuzz/ (LOOMLIGHT_FUZZ=ON, LOOMLIGHT_SANITIZE=ON), builds
# the fuzz targets and runs each for SECONDS (default 30), starting from its corpus in tests/fuzz/corpus/<target>/.
# New interesting inputs go to build-fuzz/fuzz-corpus/<target>/; --merge then adds those that reach new coverage
# to the corpus in the tree (libFuzzer -merge=1). A crash or a failed check stops that target, leaves the input in
# build-fuzz/crashes/<target>/ and makes the script exit 1: fix the bug, then copy the input into the corpus so
# every build replays it (ctest fuzz_<target>_corpus).
#
# Needs clang and libFuzzer, on Debian bookworm the packages clang and libclang-rt-14-dev (llvm-14 for symbolized
# stack traces): installed first when missing (scripts/install-deps.sh --fuzz). CI (.ci/run) runs each target for
# 60 s in its clean root.
set -euo pipefail
cd "$(dirname "$0")/.."

seconds=30
merge=0
for arg in "$@"; do
  case "$arg" in
    --merge) merge=1 ;;
    '' | *[!0-9]*) echo "usage: $0 [SECONDS] [--merge]" >&2; exit 2 ;;
    *) seconds=$arg ;;
  esac
done

./scripts/install-deps.sh --fuzz
build=build-fuzz
targets=(fuzz_request fuzz_wif fuzz_mesh)
cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_CXX_COMPILER=clang++ -DLOOMLIGHT_FUZZ=ON \
  -DLOOMLIGHT_SANITIZE=ON -DLOOMLIGHT_BENCH=OFF >/dev/null
cmake --build "$build" -j"$(nproc)" --target "${targets[@]}"

# UBSan reports are failures, not warnings: libFuzzer then keeps the input.
export UBSAN_OPTIONS=halt_on_error=1:print_stacktrace=1
max_len=$(( (1 << 20) + 4096 ))
failed=0
for target in "${targets[@]}"; do
  corpus=tests/fuzz/corpus/$target
  found=$build/fuzz-corpus/$target
  crashes=$build/crashes/$target
  mkdir -p "$found" "$crashes"
  # Inputs up to the request field limit (1 MiB, and a request's other fields): the parsers must stay linear
  # there, not only on small inputs; libFuzzer's RSS limit (2 GiB) turns a parse that multiplies memory into a crash.
  options=(-max_total_time="$seconds" -timeout=30 -max_len="$max_len" -rss_limit_mb=2048 -print_final_stats=1
           -artifact_prefix="$crashes/")
  [[ -f tests/fuzz/$target.dict ]] && options+=(-dict="tests/fuzz/$target.dict")
  echo "== $target: ${seconds} s from $(find "$corpus" -type f | wc -l) corpus inputs"
  # The first directory receives new inputs; the corpus in the tree is only read.
  if ! "$build/tests/fuzz/$target" "${options[@]}" "$found" "$corpus"; then
    echo "== $target FAILED: input in $crashes/" >&2
    failed=1
    continue
  fi
  if (( merge )); then
    "$build/tests/fuzz/$target" -merge=1 -max_len="$max_len" "$corpus" "$found"
    echo "== $target: corpus now $(find "$corpus" -type f | wc -l) inputs"
  fi
done
exit "$failed"
