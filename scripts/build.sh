#!/usr/bin/env bash
# Configures and builds Penumbra. Usage: scripts/build.sh [--asan|--tsan] [--debug]
# Builds go to build/ (build-asan/, build-tsan/ for sanitizer builds).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
build_dir="$root/build"
build_type=RelWithDebInfo
cmake_args=()
for arg in "$@"; do
  case "$arg" in
    --asan) build_dir="$root/build-asan"; cmake_args+=(-DPENUMBRA_ENABLE_ASAN=ON) ;;
    --tsan) build_dir="$root/build-tsan"; cmake_args+=(-DPENUMBRA_ENABLE_TSAN=ON) ;;
    --debug) build_type=Debug ;;
    *) echo "build.sh: unknown option $arg" >&2; exit 2 ;;
  esac
done
"$root/scripts/install-deps.sh"
cmake -S "$root" -B "$build_dir" -DCMAKE_BUILD_TYPE="$build_type" "${cmake_args[@]}" >/dev/null
cmake --build "$build_dir" -j"$(nproc)"
echo "$build_dir"
