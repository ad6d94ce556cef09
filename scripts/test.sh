#!/usr/bin/env bash
# Builds Penumbra and runs every test (unit and integration).
# Usage: scripts/test.sh [--asan|--tsan] [ctest arguments, e.g. -L unit]
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
build_flags=()
ctest_args=()
for arg in "$@"; do
  case "$arg" in
    --asan|--tsan) build_flags+=("$arg") ;;
    *) ctest_args+=("$arg") ;;
  esac
done
build_dir="$("$root/scripts/build.sh" "${build_flags[@]}" | tail -n 1)"
cd "$build_dir"
t0=$(date +%s)
status=0
ctest --output-on-failure -j"$(nproc)" "${ctest_args[@]}" || status=$?
echo "test.sh: tests $(( $(date +%s) - t0 )) s"
exit "$status"
