#!/usr/bin/env bash
# Builds the libFuzzer targets (tests/fuzz, README there) with clang into
# build-fuzz/ and runs them.
# Usage:
#   scripts/fuzz.sh [--seconds N]               every target for N s (default 60), two at a time,
#                                               as the ctest tests labelled "fuzz"; fails on any crash
#   scripts/fuzz.sh TARGET [--seconds N] [-- LIBFUZZER_ARGS...]
#                                               one target for N s (default 600), on one core
#   scripts/fuzz.sh --build-only | --list
#   --quick-build (with any of the above): the tree at -O0, built in about
#                 half the time, running 2-3x slower (CI's smoke run)
# New inputs go to build-fuzz/tests/fuzz/corpus/TARGET/ (the committed seeds
# in tests/fuzz/corpus/ are only read); a crashing input is written to
# build-fuzz/tests/fuzz/artifacts/TARGET-crash-<sha1> and the run fails.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
build_dir="$root/build-fuzz"
target=""
seconds=""
build_only=0
optimize=1
list=0
extra=()
while [ $# -gt 0 ]; do
  case "$1" in
    --seconds) seconds="$2"; shift 2 ;;
    --build-only) build_only=1; shift ;;
    --quick-build) optimize=0; shift ;;
    --list) list=1; shift ;;
    --) shift; extra=("$@"); break ;;
    -h|--help) sed -n '2,14p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    -*) echo "fuzz.sh: unknown option $1" >&2; exit 2 ;;
    *) target="$1"; shift ;;
  esac
done
if [ $list -eq 1 ]; then
  ls "$root/tests/fuzz" | sed -n 's/^\(fuzz_.*\)\.cpp$/\1/p'
  exit 0
fi

t0=$(date +%s)
"$root/scripts/install-deps.sh" >&2
# A tree of its own: clang, and every library instrumented for fuzzing.
# No tests, benchmarks or GUI: only what the targets link is built. A unity
# build (CMake batches of 8 sources per translation unit): the tree is
# built from nothing in every CI run, and sharing the Boost, protobuf and
# standard headers' parsing and instantiation took it from 496 to 393 s on
# this 2-core machine (both from an empty folder, one after the other).
cmake -S "$root" -B "$build_dir" -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DCMAKE_CXX_COMPILER=clang++ -DCMAKE_UNITY_BUILD=ON \
  -DPENUMBRA_ENABLE_FUZZING=ON -DPENUMBRA_BUILD_TESTS=OFF -DPENUMBRA_BUILD_BENCH=OFF \
  -DPENUMBRA_BUILD_CLIENT_GUI=OFF -DPENUMBRA_FUZZ_SECONDS="${seconds:-60}" \
  -DPENUMBRA_FUZZ_OPTIMIZE="$optimize" >/dev/null
cmake --build "$build_dir" -j"$(nproc)" --target penumbra_fuzzers
t1=$(date +%s)
echo "fuzz.sh: build $((t1 - t0)) s" >&2
[ $build_only -eq 1 ] && exit 0

cd "$build_dir/tests/fuzz"
if [ -z "$target" ]; then
  status=0
  ctest --output-on-failure -L fuzz -j"$(nproc)" || status=$?
  echo "fuzz.sh: runs $(( $(date +%s) - t1 )) s" >&2
  exit "$status"
fi
if [ ! -x "./$target" ]; then
  echo "fuzz.sh: no target '$target' (scripts/fuzz.sh --list)" >&2
  exit 2
fi
mkdir -p "corpus/$target" artifacts
ASAN_OPTIONS=detect_leaks=1 LSAN_OPTIONS="suppressions=$root/tests/fuzz/lsan.supp" \
  UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  "./$target" -max_total_time="${seconds:-600}" -rss_limit_mb=2048 -malloc_limit_mb=1024 -timeout=10 \
  -print_final_stats=1 -artifact_prefix="artifacts/$target-" "${extra[@]}" \
  "corpus/$target" "$root/tests/fuzz/corpus/$target"
