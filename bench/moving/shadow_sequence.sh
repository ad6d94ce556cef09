#!/usr/bin/env bash
# The moving shadow as a sequence of PNGs (issue 14): a renderer, an SMA and
# a headless client on scenes/cornell-box-floating.json; once the front view
# has converged the client moves the box along the floor in steps (the
# --moves script below) and writes what it shows every --every seconds.
# Frames are tone-mapped to PNG in OUT (default docs/images/moving), and,
# when oiiotool is installed, tiled into OUT/sequence.png.
#
#   bench/moving/shadow_sequence.sh [--build DIR] [--out DIR] [--every 0.5] [--size 320x240]
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
build="$root/build"
out="$root/docs/images/moving"
every=0.5
size=320x240
while [ $# -gt 0 ]; do
  case "$1" in
    --build) build="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    --every) every="$2"; shift 2 ;;
    --size) size="$2"; shift 2 ;;
    *) echo "shadow_sequence.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
scene="$root/scenes/cornell-box-floating.json"
work="$(mktemp -d /tmp/penumbra-shadow-XXXXXX)"
pids=()
cleanup() { for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null || true; done; wait 2>/dev/null || true; }
trap cleanup EXIT

"$build/renderer/penumbra-renderer" --scene "$scene" --listen 127.0.0.1:0 --port-file "$work/renderer.port" \
  --spp 64 --log-level warn >"$work/renderer.log" 2>&1 &
pids+=($!)
while [ ! -s "$work/renderer.port" ]; do sleep 0.1; done
"$build/sma/penumbra-sma" --scene "$scene" --listen 127.0.0.1:0 --port-file "$work/sma.port" \
  --renderer "127.0.0.1:$(cat "$work/renderer.port")" --log-level warn >"$work/sma.log" 2>&1 &
pids+=($!)
while [ ! -s "$work/sma.port" ]; do sleep 0.1; done

# The box starts at (-0.45, 0.55, 0.45), beside the short box; it comes
# towards the camera in two steps, slides left, then rises, 1.5 s apart,
# so its shadow travels across the floor and softens (it never enters the
# short or the tall box).
cat >"$work/moves.txt" <<'MOVES'
0.0  box translate -0.45 0.55 0.60
1.5  box translate -0.45 0.55 0.75
3.0  box translate -0.70 0.55 0.75
4.5  box translate -0.70 1.10 0.75
MOVES
"$build/client/penumbra-client" --connect "127.0.0.1:$(cat "$work/sma.port")" --headless --camera front \
  --size "$size" --moves "$work/moves.txt" --until-converged --snapshot-every "$every" \
  --snapshot-prefix "$work/frame" >"$work/client.log" 2>&1 || { cat "$work/client.log"; exit 1; }

mkdir -p "$out"
rm -f "$out"/frame_*.png
n=0
for exr in $(ls "$work"/frame_*.exr | sort -V); do
  png="$out/$(printf 'frame_%03d.png' "$n")"
  "$build/bench/penumbra-image-tool" tonemap "$exr" "$png" >/dev/null
  n=$((n + 1))
done
echo "shadow_sequence.sh: $n frames in $out (logs in $work)"
if command -v oiiotool >/dev/null; then
  frames=("$out"/frame_*.png)
  cols=5
  rows=$(( (${#frames[@]} + cols - 1) / cols ))
  oiiotool "${frames[@]}" --mosaic "${cols}x${rows}" -o "$out/sequence.png"
  echo "shadow_sequence.sh: tiled into $out/sequence.png"
fi
