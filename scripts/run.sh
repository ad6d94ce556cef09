#!/usr/bin/env bash
# Builds Penumbra and runs the whole stack locally -- renderer pool, SMA and
# the client window in the foreground -- on the default scene
# (scenes/cornell-box.json). Closing the window or Ctrl-C stops everything.
# Without a display the stack runs alone and the headless client command is printed.
# Usage: scripts/run.sh [--scene FILE] [--renderers N] [--spp N]
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
scene="$root/scenes/cornell-box.json"
renderers=1
spp=64
while [ $# -gt 0 ]; do
  case "$1" in
    --scene) scene="$2"; shift 2 ;;
    --renderers) renderers="$2"; shift 2 ;;
    --spp) spp="$2"; shift 2 ;;
    -h|--help) sed -n '2,6p' "$0"; exit 0 ;;
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

wait_port() {  # wait until a process has written its port file
  for _ in $(seq 1 300); do [ -s "$1" ] && { cat "$1"; return 0; }; sleep 0.1; done
  echo "run.sh: $2 did not start; see $logs/$2.log" >&2; return 1
}

threads=$(( $(nproc) / renderers )); [ "$threads" -ge 1 ] || threads=1
renderer_flags=()
for i in $(seq 0 $((renderers - 1))); do
  "$build_dir/renderer/penumbra-renderer" --scene "$scene" --listen 127.0.0.1:0 \
    --port-file "$logs/renderer-$i.port" --threads "$threads" --spp "$spp" --name "renderer-$i" \
    >"$logs/renderer-$i.log" 2>&1 &
  pids+=("$!")
  port="$(wait_port "$logs/renderer-$i.port" "renderer-$i")"
  renderer_flags+=(--renderer "127.0.0.1:$port")
  echo "run.sh: renderer $i on 127.0.0.1:$port"
done

"$build_dir/sma/penumbra-sma" --scene "$scene" --listen 127.0.0.1:0 --port-file "$logs/sma.port" \
  "${renderer_flags[@]}" >"$logs/sma.log" 2>&1 &
pids+=("$!")
sma_port="$(wait_port "$logs/sma.port" sma)"
echo "run.sh: SMA on 127.0.0.1:$sma_port (logs in $logs)"

client=("$build_dir/client/penumbra-client" --connect "127.0.0.1:$sma_port")
if [ -n "${DISPLAY:-}" ]; then
  echo "run.sh: opening the client window (H or F1 in it lists the keys); closing it stops the stack"
  # In the foreground, so that Ctrl-C reaches it; the EXIT trap then stops the rest.
  "${client[@]}" 2>&1 | tee "$logs/client.log"
  exit 0
fi
echo "run.sh: no display (DISPLAY is not set), so no client window. The stack keeps running;"
echo "run.sh: render the default view headless from another terminal with:"
echo "  ${client[*]} --headless --until-converged --screenshot penumbra.png"
echo "run.sh: Ctrl-C stops the stack"
wait -n "${pids[@]}"
