#!/usr/bin/env bash
# SMA memory over a long walk (issue 15): the same camera path walked by one
# headless client through a fresh stack (renderer + SMA, real processes) once
# per --memory-budget in BUDGETS (0 = unbounded), one after the other on the
# same cores. Every second the SMA's resident set (/proc/PID/status VmRSS)
# and its metrics (--http: memory_bytes and its parts, evictions, re-shading,
# prediction) are sampled into OUT/walk-<budget>.csv; plot.py draws
# OUT/memory.png (resident memory and the SMA's data over time, one line per
# budget, the budgets dashed) and prints the summary table: peak and final
# resident memory, peak data, the saving against the unbounded run measured
# in the same invocation, and what the budget cost: samples evicted and
# vertices re-made (re-shaded) after their collection, against all shaded.
#
# Usage: bench/memory_walk/run.sh [OUT]   (default bench/memory_walk/results)
# Environment:
#   SCENE    scene file (default scenes/street.json; needs ../shared)
#   CAMERA_PATH  the path's name in the scene file (default: its first)
#   BUDGETS  MiB, space separated (default "0 256")
#   SECONDS_LIMIT  walk length in seconds (default: the path's duration + 10)
#   SMA_FLAGS  extra flags for penumbra-sma (e.g. "--prediction off")
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
here="$root/bench/memory_walk"
out="${1:-$here/results}"
build="$root/build"
scene="${SCENE:-$root/scenes/street.json}"
budgets="${BUDGETS:-0 256}"
python=/usr/bin/python3  # Debian's, with python3-matplotlib for the plot
# Checked before the walk, not after it: a run lasts over ten minutes.
$python -c 'import matplotlib' 2>/dev/null ||
  { echo "memory_walk: plot.py needs Debian's python3-matplotlib (apt-get install python3-matplotlib)" >&2; exit 2; }
mkdir -p "$out"

path_name="${CAMERA_PATH:-$($python -c 'import json,sys; print(next(iter(json.load(open(sys.argv[1]))["paths"])))' "$scene")}"
# The path's length: inline keyframes, or a path file beside the scene.
duration="$($python -c '
import json, os, sys
scene, name = sys.argv[1], sys.argv[2]
path = json.load(open(scene))["paths"][name]
if "file" in path:
    path = json.load(open(os.path.join(os.path.dirname(scene), path["file"])))
print(int(max(k["t"] for k in path["keyframes"])) + 1)' "$scene" "$path_name")"
seconds="${SECONDS_LIMIT:-$((duration + 10))}"
echo "memory_walk: $scene, path '$path_name' (${duration} s), ${seconds} s per run, budgets: $budgets MiB" >&2

wait_for_file() { for _ in $(seq 1 6000); do [ -s "$1" ] && return 0; sleep 0.1; done; echo "no $1" >&2; return 1; }

for budget in $budgets; do
  logs="$out/logs-$budget"
  mkdir -p "$logs"
  rm -f "$logs"/*.port
  "$build/renderer/penumbra-renderer" --scene "$scene" --listen 127.0.0.1:0 --port-file "$logs/r.port" \
    --log-level info >"$logs/renderer.log" 2>&1 &
  rpid=$!
  wait_for_file "$logs/r.port"
  # shellcheck disable=SC2086
  "$build/sma/penumbra-sma" --scene "$scene" --listen 127.0.0.1:0 --port-file "$logs/s.port" \
    --http 127.0.0.1:0 --http-port-file "$logs/h.port" --renderer "127.0.0.1:$(cat "$logs/r.port")" \
    --memory-budget "$budget" --log-level info ${SMA_FLAGS:-} >"$logs/sma.log" 2>&1 &
  spid=$!
  wait_for_file "$logs/s.port"
  wait_for_file "$logs/h.port"
  csv="$out/walk-$budget.csv"
  echo "t_s,rss_bytes,hwm_bytes,memory_bytes,memory_cache_bytes,memory_hierarchy_bytes,memory_clients_bytes,samples_shaded,prediction_hit_rate,memory_in_use_bytes,samples_evicted,samples_reshaded_after_eviction,collected_nodes,trimmed_bytes" >"$csv"
  "$build/client/penumbra-client" --connect "127.0.0.1:$(cat "$logs/s.port")" --headless --gl egl \
    --camera-path "$scene#$path_name" --seconds "$seconds" --stats "$logs/client-stats.jsonl" \
    --log-level warn >"$logs/client.log" 2>&1 &
  cpid=$!
  t0=$(date +%s.%N)
  while kill -0 "$cpid" 2>/dev/null; do
    metrics="$("$build/common/tools/penumbra-stats" --raw "127.0.0.1:$(cat "$logs/h.port")" 2>/dev/null || true)"
    $python "$here/sample.py" "$t0" "$spid" <<<"$metrics" >>"$csv" || true
    sleep 1
  done
  wait "$cpid" || echo "memory_walk: the client exited with $? (budget $budget; $logs/client.log)" >&2
  kill "$spid" "$rpid"
  wait "$spid" "$rpid" 2>/dev/null || true
done
$python "$here/plot.py" "$out" $budgets
