#!/usr/bin/env bash
# The walkthrough comparison: the Penumbra stack (renderer + SMA + headless
# clients, real processes) against a progressive per-pixel path tracer that
# restarts whenever the camera moves (penumbra-reference --progressive: the
# renderer's own Shader, so the comparison is about the caching), along
# camera paths with stops, turns and returns (make_paths.py), on the same
# cores, one after the other:
#   1. one client walking walk-a, then one path tracer walking walk-a;
#   2. four clients walking walk-a..d through one SMA (and one renderer), then
#      four path tracers walking walk-a..d at once, started together.
# Both play their paths in real time and write the image shown at path times
# 0, INTERVAL, 2*INTERVAL, ... Then each distinct pose gets a converged
# reference (penumbra-reference, REF_SPP paths per pixel, cached by pose in
# OUT/refs), and walkthrough.py writes the error of every frame, a summary
# table (stdout) and the plot (OUT/walkthrough.png).
#
# Usage: bench/walkthrough/run.sh [OUT]   (default bench/walkthrough/results;
#   needs a build, ../shared and python3-matplotlib; about 10 minutes of
#   measurement on 2 cores, plus the references the first time)
# Environment: INTERVAL (1 s), REF_SPP (64), SUPERSAMPLE (2: the client's
# samples per pixel per axis, box-filtered as the path tracer's are),
# STEPS ("measure references report"), SMA_ARGS (more penumbra-sma flags),
# DRAW ("written": the clients rasterise only the frames they write, as the
# path tracers compute only theirs -- a client's display is its own GPU's
# work, not the two cores'; "every": every frame, 12-30 a second each, on
# Mesa's software rasteriser on the same two cores). OUT/cpu.txt says where
# the CPU went.
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
here="$root/bench/walkthrough"
out="${1:-$here/results}"
build="$root/build"
scene="$root/scenes/bathroom.json"
interval="${INTERVAL:-1}"
ref_spp="${REF_SPP:-64}"
supersample="${SUPERSAMPLE:-2}"
steps="${STEPS:-measure references report}"
case "${DRAW:-written}" in
  written) draw_flag=--draw-only-written-frames ;;
  every) draw_flag= ;;
  *) echo "DRAW is written or every" >&2; exit 2 ;;
esac
python=/usr/bin/python3  # Debian's, which has python3-matplotlib
mkdir -p "$out"
paths=(walk-a walk-b walk-c walk-d)
duration=38  # the paths' length (make_paths.py)

wait_for_file() { for _ in $(seq 1 3000); do [ -s "$1" ] && return 0; sleep 0.1; done; echo "no $1" >&2; return 1; }

# Renderer + SMA on the scene; sets rpid, spid, sma_port.
start_stack() {
  local logs="$1"
  rm -f "$logs/r.port" "$logs/s.port"
  "$build/renderer/penumbra-renderer" --scene "$scene" --listen 127.0.0.1:0 --port-file "$logs/r.port" \
    --log-level warn >"$logs/renderer.log" 2>&1 &
  rpid=$!
  wait_for_file "$logs/r.port"
  "$build/sma/penumbra-sma" --scene "$scene" --listen 127.0.0.1:0 --port-file "$logs/s.port" \
    --renderer "127.0.0.1:$(cat "$logs/r.port")" --criterion nld_os --log-level warn ${SMA_ARGS:-} >"$logs/sma.log" 2>&1 &
  spid=$!
  wait_for_file "$logs/s.port"
  sma_port="$(cat "$logs/s.port")"
}
stop_stack() { kill "$spid" "$rpid"; wait "$spid" "$rpid" 2>/dev/null || true; }

# CPU seconds (user + system) a live process has used so far.
cpu_seconds() { awk -v hz="$(getconf CLK_TCK)" '{ printf "%.1f", ($14 + $15) / hz }' "/proc/$1/stat"; }
# Where the two cores went: CPU seconds per process, appended to OUT/cpu.txt.
note_cpu() { echo "$(date -u +%T) $1" | tee -a "$out/cpu.txt"; }

# One headless client walking path $2, snapshots to $1/penumbra-$2_t*.exr. --anisotropy 16: the
# filtering nearest the references' area average, as the figures were measured (the default on
# llvmpipe is isotropic, for speed; client/README.md "Texture filtering").
client() {
  /usr/bin/time -f "%U %S" -o "$1/penumbra-$2.cpu" "$build/client/penumbra-client" --connect "127.0.0.1:$sma_port" --headless --gl egl \
    --camera-path "$here/$2.json" --supersample "$supersample" --anisotropy 16 --snapshot-path-interval "$interval" $draw_flag \
    --snapshot-prefix "$1/penumbra-$2" --seconds $((duration + 8)) --stats "$1/penumbra-$2-stats.jsonl" \
    --log-level warn >"$1/penumbra-$2.log" 2>&1
}

# Progressive path tracers for the given paths, all started together.
tracers() {
  local dir="$1"; shift
  rm -f "$dir/start"
  local pids=()
  for p in "$@"; do
    /usr/bin/time -f "%U %S" -o "$dir/pt-$p.cpu" "$build/renderer/penumbra-reference" --scene "$scene" \
      --camera-path "$here/$p.json" --progressive "$interval" \
      --snapshot-prefix "$dir/pt-$p" --start-file "$dir/start" --threads 2 >"$dir/pt-$p.log" 2>&1 &
    pids+=($!)
  done
  for p in "$@"; do until grep -q ready "$dir/pt-$p.log" 2>/dev/null; do sleep 0.1; done; done
  touch "$dir/start"
  for pid in "${pids[@]}"; do wait "$pid"; done
}

measure() {
  local dir="$1"; shift
  rm -rf "$dir"; mkdir -p "$dir"
  echo "$(date -u +%T) $dir: load before: $(cut -d' ' -f1-3 /proc/loadavg)" | tee -a "$out/load.txt"
  start_stack "$dir"
  local pids=()
  for p in "$@"; do client "$dir" "$p" & pids+=($!); done
  for pid in "${pids[@]}"; do wait "$pid"; done
  local clients_cpu
  clients_cpu="$(cat "$dir"/penumbra-*.cpu | awk '{ s += $1 + $2 } END { printf "%.1f", s }')"
  note_cpu "$dir: CPU seconds: renderer $(cpu_seconds "$rpid"), SMA $(cpu_seconds "$spid"), clients $clients_cpu"
  stop_stack
  echo "$(date -u +%T) $dir: Penumbra done, load $(cut -d' ' -f1-3 /proc/loadavg)" | tee -a "$out/load.txt"
  tracers "$dir" "$@"
  note_cpu "$dir: CPU seconds: path tracers $(cat "$dir"/pt-*.cpu | awk '{ s += $1 + $2 } END { printf "%.1f", s }')"
  echo "$(date -u +%T) $dir: path tracers done, load $(cut -d' ' -f1-3 /proc/loadavg)" | tee -a "$out/load.txt"
}

for step in $steps; do
  case "$step" in
    measure)
      measure "$out/one" walk-a
      measure "$out/four" "${paths[@]}" ;;
    references)
      "$python" "$here/walkthrough.py" references --out "$out" --build "$build" --scene "$scene" \
        --interval "$interval" --duration "$duration" --spp "$ref_spp" "${paths[@]/#/$here/}" ;;
    report)
      "$python" "$here/walkthrough.py" report --out "$out" --build "$build" --interval "$interval" \
        --duration "$duration" --spp "$ref_spp" "${paths[@]/#/$here/}" ;;
    *) echo "unknown step $step" >&2; exit 2 ;;
  esac
done
