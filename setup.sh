#!/usr/bin/env bash
# One-stop set-up for a Debian 12 machine: installs the build dependencies (a no-op when they are
# present), builds compose in Release, fetches and verifies the sample data, then
#   ./setup.sh demo    composites the bunny into the meadow plate: out/compose.exr + out/compose.jpg
#   ./setup.sh test    runs the whole test suite (what CI runs)
#   ./setup.sh build   stops after building
# Installing needs root: run as root, or with sudo available.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")"

PACKAGES=(
  build-essential cmake pkg-config ca-certificates
  libopencv-dev libopencv-contrib-dev libopenimageio-dev openimageio-tools
  libopencolorio-dev opencolorio-tools libopenexr-dev libglm-dev libtinygltf-dev
  libtinyobjloader-dev libembree-dev libtbb-dev libcli11-dev nlohmann-json3-dev
  libgtest-dev libbenchmark-dev libfilament-tools openexr
)
BUILD_DIR=${COMPOSE_BUILD_DIR:-build}

say() { printf 'setup: %s\n' "$*" >&2; }

install_packages() {
  local missing=()
  for p in "${PACKAGES[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed' || missing+=("$p")
  done
  [ ${#missing[@]} -eq 0 ] && return 0
  local sudo=()
  [ "$(id -u)" -ne 0 ] && sudo=(sudo)
  say "installing ${missing[*]}"
  "${sudo[@]}" apt-get update -q
  "${sudo[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends "${missing[@]}"
}

build() {
  cmake -S . -B "$BUILD_DIR" -DCMAKE_BUILD_TYPE=Release -DCOMPOSE_WERROR=ON >/dev/null
  cmake --build "$BUILD_DIR" -j"$(nproc)"
}

fetch_samples() {
  SAMPLES=$(bash samples/fetch.sh | tail -n 1)
  export COMPOSE_SAMPLES_DIR=$SAMPLES
}

case "${1:-demo}" in
  demo)
    install_packages
    build
    fetch_samples
    "$BUILD_DIR/src/app/compose" --plate "$SAMPLES/meadow.jpg" --object "$SAMPLES/bunny.obj" --out out/compose
    ;;
  test)
    install_packages
    build
    fetch_samples
    ctest --test-dir "$BUILD_DIR" --output-on-failure -j"$(nproc)"
    ;;
  build)
    install_packages
    build
    ;;
  *)
    echo "usage: $0 [demo|test|build]" >&2
    exit 2
    ;;
esac
