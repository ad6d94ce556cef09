#!/usr/bin/env bash
# Camera movement prediction (issue 15): one camera path, played in real time
# by the headless client against a fresh renderer + SMA, first with
# --prediction off, then on (each run starts with an empty cache). For each
# it prints (bench/prediction_summary.py)
#   * the prediction hit rate: of the triangles the client's new views newly
#     displayed, the fraction whose corners were already shaded when the
#     view's visibility was applied (the SMA's view_triangles_new_shaded /
#     view_triangles_new, counted the same way with prediction off);
#   * view -> complete display, p50 and p99 over the views the SMA applied:
#     from a view's arrival at the SMA until the client next has a complete
#     image (stage 1) of it or of a later view; and the own stage-1 time of
#     the views that reached it;
#   * predicted views traced and the samples they asked for;
# and the ratios on/off, from the same invocation. With REPEAT > 1 the runs
# alternate off, on, off, on, ... (the machine's load drifts) and the table
# pools them: hit rates from the summed counts, latencies and counts as the
# mean of the runs' figures.
#
# Usage: bench/prediction_bench.sh [SCENE.json#PATH] [OUT]
#   default scenes/sponza.json#walk, OUT build/prediction-bench
# Environment: SPEED (1: the path played at this times its speed), SIZE
#   (WxH, default the path's), MAX_FPS (5: the client's frame cap, so that it
#   sends views at one rate whatever the machine's load, as long as it can
#   draw that fast), REPEAT (1), EXTRA_SECONDS (4: the client runs
#   the path's length plus this), RENDERER_THREADS (0: all cores), SMA_FLAGS
#   (added to every run), HORIZON (0.5), WIDEN (1.15).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
path_spec="${1:-$root/scenes/sponza.json#walk}"
out="${2:-$root/build/prediction-bench}"
build="$root/build"
scene="${path_spec%%#*}"
extra="${EXTRA_SECONDS:-4}"
threads="${RENDERER_THREADS:-0}"
horizon="${HORIZON:-0.5}"
widen="${WIDEN:-1.15}"
summary="$root/bench/prediction_summary.py"
repeat="${REPEAT:-1}"
mkdir -p "$out"

# The path as played: its times divided by SPEED, at SIZE; and its length.
python3 - "$scene" "${path_spec#*#}" "${SPEED:-1}" "${SIZE:-}" "$out/path.json" <<'EOF'
import json, sys
scene, name, speed, size, out = sys.argv[1:]
path = json.load(open(scene))["paths"][name]
for k in path["keyframes"]:
    k["t"] = k["t"] / float(speed)
if size:
    path["width"], path["height"] = (int(x) for x in size.split("x"))
json.dump(path, open(out, "w"), indent=1)
EOF
duration="$(python3 -c 'import json, math, sys; print(math.ceil(json.load(open(sys.argv[1]))["keyframes"][-1]["t"]))' "$out/path.json")"

wait_for_file() { for _ in $(seq 1 3000); do [ -s "$1" ] && return 0; sleep 0.1; done; echo "no $1" >&2; return 1; }

run() {  # run on|off N: one row of results
  local mode="$1" logs="$out/$1-$2"
  mkdir -p "$logs"
  rm -f "$logs"/*.port
  local renderer_args=(--scene "$scene" --listen 127.0.0.1:0 --port-file "$logs/r.port" --log-level warn)
  [ "$threads" != 0 ] && renderer_args+=(--threads "$threads")
  "$build/renderer/penumbra-renderer" "${renderer_args[@]}" >"$logs/renderer.log" 2>&1 &
  local rpid=$!
  wait_for_file "$logs/r.port"
  # Debug: the per-view lines the latency is read from.
  # shellcheck disable=SC2086
  "$build/sma/penumbra-sma" --scene "$scene" --listen 127.0.0.1:0 --port-file "$logs/s.port" \
    --http 127.0.0.1:0 --http-port-file "$logs/h.port" --renderer "127.0.0.1:$(cat "$logs/r.port")" \
    --prediction "$mode" --prediction-horizon "$horizon" --prediction-widen "$widen" --log-level debug \
    ${SMA_FLAGS:-} >"$logs/sma.log" 2>&1 &
  local spid=$!
  wait_for_file "$logs/s.port"
  wait_for_file "$logs/h.port"
  "$build/client/penumbra-client" --connect "127.0.0.1:$(cat "$logs/s.port")" --headless --gl egl \
    --camera-path "$out/path.json" --max-fps "${MAX_FPS:-5}" --seconds $((duration + extra)) --stats "$logs/client-stats.jsonl" \
    --log-level warn >"$logs/client.log" 2>&1 || echo "prediction_bench: client exited with $?" >&2
  curl -fsS "http://127.0.0.1:$(cat "$logs/h.port")/metrics" >"$logs/metrics.txt"
  kill "$spid" "$rpid"
  wait "$spid" "$rpid" 2>/dev/null || true
  python3 "$summary" summary "$mode" "$logs/metrics.txt" "$logs/sma.log"
}

echo "prediction_bench: $path_spec at speed ${SPEED:-1}${SIZE:+, $SIZE}, ${MAX_FPS:-5} fps (${duration} s + ${extra} s), horizon ${horizon} s," \
  "widen ${widen}, ${repeat} run(s) each;" \
  "load average $(cut -d' ' -f1-3 /proc/loadavg)" >&2
printf 'mode\thit_rate\tnew_triangles\tnew_shaded\tcomplete_p50_ms\tcomplete_p99_ms\tviews_applied\tviews_never_complete\tstage1_p50_ms\tviews_stage1\tpredicted_views\tsamples_predicted\n' \
  >"$out/results.tsv"
for i in $(seq 1 "$repeat"); do
  run off "$i" >>"$out/results.tsv"
  run on "$i" >>"$out/results.tsv"
done
echo "prediction_bench: done; load average $(cut -d' ' -f1-3 /proc/loadavg)" >&2
python3 "$summary" table "$out/results.tsv"
