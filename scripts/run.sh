#!/usr/bin/env bash
# Builds Penumbra and runs the whole stack locally -- renderer pool, SMA and
# the client window in the foreground -- on the default scene
# (scenes/cornell-box.json). Closing the window or Ctrl-C stops everything.
# Without a display the stack runs alone and the headless client command is printed.
# Usage: scripts/run.sh [--scene FILE] [--renderers N] [--spp N] [--memory-budget MIB] [--headless-check [PNG]]
#   --memory-budget: the SMA's --memory-budget (its age-based collector; sma/README.md, "Memory")
#   --headless-check: no window; render the default scene's front view headless
#   until it converges, write it to PNG (default build/headless-check.png), check
#   that it is a sane Cornell box, stop the stack, exit 0 if it is.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
scene="$root/scenes/cornell-box.json"
renderers=1
spp=64
memory_budget=0
check_png=""
while [ $# -gt 0 ]; do
  case "$1" in
    --headless-check)
      check_png="$root/build/headless-check.png"
      if [ $# -gt 1 ] && [ "${2#--}" = "$2" ]; then check_png="$2"; shift; fi
      shift ;;
    --scene) scene="$2"; shift 2 ;;
    --renderers) renderers="$2"; shift 2 ;;
    --spp) spp="$2"; shift 2 ;;
    --memory-budget) memory_budget="$2"; shift 2 ;;
    -h|--help) sed -n '2,10p' "$0"; exit 0 ;;
    *) echo "run.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
build_dir="$("$root/scripts/build.sh" | tail -n 1)"
logs="$(mktemp -d /tmp/penumbra-run-XXXXXX)"

pids=()
cleanup() {
  trap - EXIT INT TERM
  for pid in "${pids[@]}"; do kill -TERM "$pid" 2>/dev/null || true; done
  wait 2>/dev/null || true
  echo "run.sh: stopped; logs in $logs"
}
trap cleanup EXIT INT TERM

wait_port() {  # PORTFILE NAME PID: wait while the process lives (big scenes load for long) until it writes its port
  local waited=0
  while kill -0 "$3" 2>/dev/null; do
    [ -s "$1" ] && { cat "$1"; return 0; }
    sleep 0.2; waited=$((waited + 1))
    if [ $((waited % 50)) -eq 0 ]; then echo "run.sh: $2 still starting ($((waited / 5)) s): $(tail -n 1 "$logs/$2.log")" >&2; fi
  done
  echo "run.sh: $2 exited before it listened:" >&2; tail -n 5 "$logs/$2.log" >&2; return 1
}

threads=$(( $(nproc) / renderers )); [ "$threads" -ge 1 ] || threads=1
renderer_flags=()
for i in $(seq 0 $((renderers - 1))); do
  "$build_dir/renderer/penumbra-renderer" --scene "$scene" --listen 127.0.0.1:0 \
    --port-file "$logs/renderer-$i.port" --threads "$threads" --spp "$spp" --name "renderer-$i" \
    >"$logs/renderer-$i.log" 2>&1 &
  pid=$!; pids+=("$pid")
  port="$(wait_port "$logs/renderer-$i.port" "renderer-$i" "$pid")"
  renderer_flags+=(--renderer "127.0.0.1:$port")
  echo "run.sh: renderer $i on 127.0.0.1:$port"
done

"$build_dir/sma/penumbra-sma" --scene "$scene" --listen 127.0.0.1:0 --port-file "$logs/sma.port" \
  --memory-budget "$memory_budget" "${renderer_flags[@]}" >"$logs/sma.log" 2>&1 &
pid=$!; pids+=("$pid")
sma_port="$(wait_port "$logs/sma.port" sma "$pid")"
echo "run.sh: SMA on 127.0.0.1:$sma_port (logs in $logs)"

client=("$build_dir/client/penumbra-client" --connect "127.0.0.1:$sma_port")
if [ -n "$check_png" ]; then
  [ "$scene" = "$root/scenes/cornell-box.json" ] || { echo "run.sh: --headless-check judges the default scene only" >&2; exit 2; }
  echo "run.sh: headless check: rendering the front view until it converges"
  mkdir -p "$(dirname "$check_png")"
  "${client[@]}" --headless --gl egl --camera front --size 640x480 --until-converged --timeout 300 \
    --screenshot "$check_png" >"$logs/client.log" 2>&1 ||
    { echo "run.sh: the headless client failed:" >&2; tail -n 20 "$logs/client.log" >&2; exit 1; }
  if "$build_dir/bench/penumbra-image-tool" check-cornell-box "$check_png"; then
    echo "run.sh: headless check passed: $check_png is a sane Cornell box"
    exit 0
  fi
  echo "run.sh: headless check FAILED: $check_png is not a sane Cornell box (logs in $logs)" >&2
  exit 1
fi
if [ -n "${DISPLAY:-}" ]; then
  echo "run.sh: opening the client window (H or F1 in it lists the keys); closing it stops the stack"
  echo "run.sh: screenshots (P) go to $build_dir/screenshots"
  # In the foreground, so that Ctrl-C reaches it; the EXIT trap then stops the rest.
  "${client[@]}" --screenshot-dir "$build_dir/screenshots" 2>&1 | tee "$logs/client.log"
  exit 0
fi
echo "run.sh: no display (DISPLAY is not set), so no client window. The stack keeps running;"
echo "run.sh: render the default view headless from another terminal with:"
echo "  ${client[*]} --headless --until-converged --screenshot penumbra.png"
echo "run.sh: Ctrl-C stops the stack"
wait -n "${pids[@]}"
