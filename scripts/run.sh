#!/usr/bin/env bash
# Builds Penumbra and runs the whole stack locally on the default scene
# (scenes/cornell-box.json) until Ctrl-C.
# Usage: scripts/run.sh [--scene FILE] [--renderers N]
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
scene="$root/scenes/cornell-box.json"
renderers=1
while [ $# -gt 0 ]; do
  case "$1" in
    --scene) scene="$2"; shift 2 ;;
    --renderers) renderers="$2"; shift 2 ;;
    -h|--help) sed -n '2,4p' "$0"; exit 0 ;;
    *) echo "run.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
build_dir="$("$root/scripts/build.sh" | tail -n 1)"

pids=()
cleanup() {
  for pid in "${pids[@]}"; do kill -TERM "$pid" 2>/dev/null || true; done
  wait 2>/dev/null || true
}
trap cleanup EXIT INT TERM

base_port=7100
threads=$(( $(nproc) / renderers )); [ "$threads" -ge 1 ] || threads=1
for i in $(seq 0 $((renderers - 1))); do
  port=$((base_port + i))
  "$build_dir/renderer/penumbra-renderer" --scene "$scene" --listen "127.0.0.1:$port" \
    --threads "$threads" --name "renderer-$i" &
  pids+=("$!")
  echo "run.sh: renderer $i on 127.0.0.1:$port (pid ${pids[-1]})"
done
echo "run.sh: stack running; Ctrl-C stops it"
wait -n "${pids[@]}"
