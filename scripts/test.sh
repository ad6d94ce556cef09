#!/usr/bin/env bash
# Builds Penumbra and runs every test (unit and integration); with no
# arguments (the CI command) it then runs every fuzz target briefly
# (scripts/fuzz.sh --quick-build, PENUMBRA_FUZZ_SECONDS each, default 10: a
# smoke run that keeps CI under 30 minutes; long runs are scripts/fuzz.sh TARGET).
# Usage: scripts/test.sh [--asan|--tsan] [--no-fuzz] [ctest arguments, e.g. -L unit]
# Sanitizer builds and runs narrowed by ctest arguments skip the fuzz step.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
build_flags=()
ctest_args=()
fuzz=1
for arg in "$@"; do
  case "$arg" in
    --asan|--tsan) build_flags+=("$arg"); fuzz=0 ;;
    --no-fuzz) fuzz=0 ;;
    *) ctest_args+=("$arg"); fuzz=0 ;;
  esac
done
build_dir="$("$root/scripts/build.sh" "${build_flags[@]}" | tail -n 1)"
cd "$build_dir"
t0=$(date +%s)
status=0
ctest --output-on-failure -j"$(nproc)" "${ctest_args[@]}" || status=$?
echo "test.sh: tests $(( $(date +%s) - t0 )) s"
if [ "$fuzz" -eq 1 ]; then
  t1=$(date +%s)
  "$root/scripts/fuzz.sh" --quick-build --seconds "${PENUMBRA_FUZZ_SECONDS:-10}" || status=1
  echo "test.sh: fuzz build and runs $(( $(date +%s) - t1 )) s"
fi
exit "$status"
