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
# Phase times go to stderr: stdout's last line is the build folder (test.sh and run.sh read it).
t0=$(date +%s)
"$root/scripts/install-deps.sh" >&2
t1=$(date +%s)
cmake -S "$root" -B "$build_dir" -DCMAKE_BUILD_TYPE="$build_type" "${cmake_args[@]}" >/dev/null
cmake --build "$build_dir" -j"$(nproc)"
t2=$(date +%s)
echo "build.sh: dependencies $((t1 - t0)) s, configure and build $((t2 - t1)) s" >&2
echo "$build_dir"
