#!/usr/bin/env bash
# The refinement experiment, end to end: builds, installs the plotting
# package it needs (Debian's python3-matplotlib), runs every view and
# criterion, writes bench/refinement/results/ and docs/refinement.md.
# Usage: bench/refinement/run.sh [experiment.py options, e.g. --views cornell]
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
build_dir="$("$root/scripts/build.sh" | tail -n 1)"
if ! /usr/bin/python3 -c "import matplotlib" 2>/dev/null; then
  sudo=""; [ "$(id -u)" -eq 0 ] || sudo="sudo"
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends python3-matplotlib
fi
exec /usr/bin/python3 "$root/bench/refinement/experiment.py" --build "$build_dir" "$@"
