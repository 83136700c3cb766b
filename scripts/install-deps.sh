#!/usr/bin/env bash
# Installs the Debian bookworm packages Loomlight builds and runs with, when any is missing.
#     scripts/install-deps.sh [--fuzz]
# --fuzz adds the coverage-guided fuzzing toolchain scripts/fuzz.sh needs (clang, libFuzzer, llvm-symbolizer).
set -euo pipefail
packages=(
  build-essential cmake pkg-config
  pocl-opencl-icd ocl-icd-opencl-dev opencl-c-headers opencl-clhpp-headers clinfo
  libopenimageio-dev openimageio-tools libwebp-dev
  libgrpc++-dev libprotobuf-dev protobuf-compiler protobuf-compiler-grpc
  prometheus-cpp-dev
  libembree-dev
  libtinygltf-dev libtinyobjloader-dev libpugixml-dev
  libeigen3-dev
  libcli11-dev
  libgtest-dev libgmock-dev
  fonts-dejavu-core
  haproxy
  python3
  python3-grpcio python3-protobuf python3-numpy python3-openimageio  # the Python package (python/) and its tests
  python3-pytest python3-venv python3-pip python3-setuptools python3-wheel
  nodejs
  chromium  # Loomlight Studio's tests drive it headless (playwright-core, web/tests)
)
# npm installs the Khronos glTF validator the tests run (tests/gltf) and Loomlight Studio's packages (web/). A NodeSource nodejs brings its own npm, which
# Debian's npm package conflicts with: Debian's only when no npm command exists.
command -v npm >/dev/null 2>&1 || packages+=(npm)
case "${1:-}" in
  --fuzz) packages+=(clang libclang-rt-14-dev llvm-14) ;;
  '') ;;
  *) echo "usage: $0 [--fuzz]" >&2; exit 2 ;;
esac
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "installing: ${missing[*]}"
  sudo=""
  [ "$(id -u)" -eq 0 ] || sudo="sudo"
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi
