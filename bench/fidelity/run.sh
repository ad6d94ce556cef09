#!/usr/bin/env bash
# Fidelity of the full stack on real emitter-lit scenes, against an
# independent renderer (Blender Cycles, ../shared/tools/cycles_reference.py)
# and against penumbra-reference (our per-pixel path tracer, itself checked
# against Cycles first). Writes a Markdown table to stdout and images to OUT.
#
# Usage: bench/fidelity/run.sh [OUT]   (default bench/fidelity/results; needs
#   a build, ../shared, and Blender: apt-get install blender python3-numpy)
# Each case: scene file, camera preset, OBJ (for Cycles), image size. Scenes
# lit by sun and sky have no OBJ ("-"): Cycles is not run there (the tool
# renders emitter-lit OBJ scenes only) and the full stack is compared with
# penumbra-reference alone, which the emitter-lit cases check against Cycles.
# Metrics after a box blur of radius 2 (the references' noise): relative
# mean absolute error and mean luminance ratio (common/image_metrics.h). The
# client renders 4 x 4 samples per pixel (--supersample 4) and box-filters
# them, the pixel filter of the references. The last column is Penumbra
# against penumbra-reference over the reference's dim pixels only (at most
# twice its mean luminance: walls, furniture -- where blotches and dark
# vertices show), whose error a bright sun patch or window would otherwise
# outweigh; OUT/NAME-error.png shows where the error is (red: Penumbra
# brighter, blue: darker; full at the mean pixel).
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
shared="$root/../shared"
out="${1:-$root/bench/fidelity/results}"
build="${BUILD:-$root/build}"  # BUILD: another build tree (e.g. a copy of the binaries)
cycles_samples="${CYCLES_SAMPLES:-256}"
ref_spp="${REF_SPP:-1024}"
# penumbra-reference's pixel filters: "box" (the references' filter) and
# "centre" (pixel centres, to show what the box filter is worth).
ref_filters="${REF_FILTERS:-box centre}"
# CLIENT_ARGS: more client options (e.g. refinement parameters: --s-req 0.02).
client_args="${CLIENT_ARGS:-}"
# SMA_ARGS: more SMA options (e.g. --cache-dir DIR, for bench/vertex_census --snapshot).
sma_args="${SMA_ARGS:-}"
mkdir -p "$out"
tool="$build/bench/penumbra-image-tool"

cases=(
  # name            scene file                      camera       obj (relative to ../shared or the repo)            size
  "cornell-front    scenes/cornell-box.json          front        scenes/cornell-box/CornellBox-Original.obj          320x240"
  "inverted-walls   tests/data/inverted_room.json    walls        @tests/data/inverted_room.obj                       320x240"
  "bathroom-source  scenes/bathroom.json             source       scenes/contemporary-bathroom/contemporary-bathroom.obj 480x270"
  "bathroom-window  scenes/bathroom.json             from-window  scenes/contemporary-bathroom/contemporary-bathroom.obj 480x270"
  "living-source    scenes/grey-white-room.json      source       -                                                   480x270"
  "living-back      scenes/grey-white-room.json      back         -                                                   480x270"
)
# Only these cases (names, space-separated), if set.
only="${CASES:-}"
# Without Blender every case is compared with penumbra-reference alone.
have_blender=1
command -v blender >/dev/null || { echo "blender not found: comparing with penumbra-reference only" >&2; have_blender=0; }


# Camera of a preset, as Cycles arguments, from penumbra-scene-info.
camera_args() {
  "$build/common/tools/penumbra-scene-info" --scene "$root/$1" |
    awk -v cam="$2" '$1 == "camera" && $2 == cam":" {
      gsub(/[(),]/, " "); print "--eye", $4, $5, $6, "--target", $8, $9, $10, "--up", $12, $13, $14, "--fov-y", $16 }'
}

metric() { "$tool" compare "$1" "$2" --blur 2; }
field() { sed -E "s/.*\"$1\": ([0-9.eE+-]+).*/\\1/"; }

echo "| view | reference (box) vs Cycles | Penumbra vs Cycles | reference (pixel centres) vs Cycles | Penumbra vs reference (box) | first complete image | converged | Penumbra vs reference, dim pixels |"
echo "|---|---|---|---|---|---|---|---|"
for c in "${cases[@]}"; do
  read -r name scene camera obj size <<<"$c"
  [ -z "$only" ] || [[ " $only " == *" $name "* ]] || continue
  w="${size%x*}"; h="${size#*x}"
  why_no_cycles="sun and sky"
  if [ "$obj" != - ] && [ "$have_blender" = 0 ]; then obj=-; why_no_cycles="blender absent"; fi
  objpath="$shared/$obj"; [ "${obj#@}" != "$obj" ] && objpath="$root/${obj#@}"
  [ "$obj" = - ] || [ -f "$objpath" ] || { echo "| $name | skipped: $objpath absent | | | | | |"; continue; }
  cycles="$out/$name-cycles"
  if [ "$obj" != - ] && [ ! -s "$cycles.exr" ]; then
    (cd "$shared" && blender -b --python-exit-code 1 -P tools/cycles_reference.py -- render --obj "$objpath" \
       $(camera_args "$scene" "$camera") --width "$w" --height "$h" --samples "$cycles_samples" --out "$cycles") \
       >"$out/$name-cycles.log" 2>&1
  fi
  for filter in $ref_filters; do
    [ -s "$out/$name-ref-$filter.exr" ] ||
      "$build/renderer/penumbra-reference" --scene "$root/$scene" --camera "$camera" --width "$w" --height "$h" \
        --spp "$ref_spp" --pixel-filter "$filter" --out "$out/$name-ref-$filter.exr" --log-level warn
  done
  # The full stack, NLD_OS, until converged; the client's statistics give the times.
  logs="$(mktemp -d)"
  "$build/renderer/penumbra-renderer" --scene "$root/$scene" --listen 127.0.0.1:0 --port-file "$logs/r.port" \
    --log-level warn >"$logs/r.log" 2>&1 &
  rpid=$!
  while [ ! -s "$logs/r.port" ]; do sleep 0.2; done
  "$build/sma/penumbra-sma" --scene "$root/$scene" --listen 127.0.0.1:0 --port-file "$logs/s.port" \
    --renderer "127.0.0.1:$(cat "$logs/r.port")" --criterion nld_os --log-level warn $sma_args >"$logs/s.log" 2>&1 &
  spid=$!
  while [ ! -s "$logs/s.port" ]; do sleep 0.2; done
  # --anisotropy 16: the texture filtering nearest the references' area average (the client's
  # default on llvmpipe is isotropic, for speed; client/README.md "Texture filtering").
  "$build/client/penumbra-client" --connect "127.0.0.1:$(cat "$logs/s.port")" --headless --gl egl --camera "$camera" \
    --size "$size" --supersample 4 --anisotropy 16 --until-converged --timeout 1800 --screenshot "$out/$name-penumbra.exr" \
    --stats "$out/$name-stats.jsonl" --log-level warn $client_args >"$logs/c.log" 2>&1 || { cat "$logs/c.log" >&2; exit 1; }
  kill "$spid" "$rpid"; wait "$spid" "$rpid" 2>/dev/null || true
  cell() {
    if [ -z "$1" ]; then echo "not run"; return; fi
    printf '%.1f %%, ratio %.3f' "$(echo "$1" | field rel_mae | awk '{print 100 * $1}')" "$(echo "$1" | field mean_ratio)"
  }
  centre="$out/$name-ref-centre.exr"; refcentre=""
  penref="$(metric "$out/$name-ref-box.exr" "$out/$name-penumbra.exr")"
  dim="$("$tool" compare "$out/$name-ref-box.exr" "$out/$name-penumbra.exr" --blur 2 --split 2 \
    --error-map "$out/$name-error.png" | grep '"part": "dim"')"
  if [ "$obj" = - ]; then  # sun and sky: penumbra-reference is the reference
    "$tool" tonemap "$out/$name-penumbra.exr" "$out/$name-penumbra.png" --like "$out/$name-ref-box.exr"
    "$tool" tonemap "$out/$name-ref-box.exr" "$out/$name-ref-box.png"
    [ ! -s "$centre" ] || refcentre="$(metric "$out/$name-ref-box.exr" "$centre")"
    nocycles="no Cycles ($why_no_cycles)"
  else
    "$tool" tonemap "$out/$name-penumbra.exr" "$out/$name-penumbra.png" --like "$cycles.exr"
    "$tool" tonemap "$cycles.exr" "$out/$name-cycles.png"
    refbox="$(metric "$cycles.exr" "$out/$name-ref-box.exr")"
    pen="$(metric "$cycles.exr" "$out/$name-penumbra.exr")"
    [ ! -s "$centre" ] || refcentre="$(metric "$cycles.exr" "$centre")"
  fi
  # First complete image: the first frame after stage 1 (refining or converged); converged: the last frame.
  times="$(python3 -c 'import json, sys
lines = [json.loads(l) for l in open(sys.argv[1])]
first = next((l["time_s"] for l in lines if l.get("refining") or l.get("converged")), float("nan"))
print("%.2f s | %.1f s" % (first, lines[-1]["time_s"]))' "$out/$name-stats.jsonl")"
  if [ "$obj" = - ]; then
    echo "| $name | $nocycles | $nocycles | $(cell "$refcentre") (vs reference, box) | **$(cell "$penref")** | $times | $(cell "$dim") |"
  else
    echo "| $name | $(cell "$refbox") | $(cell "$pen") | $(cell "$refcentre") | $(cell "$penref") | $times | $(cell "$dim") |"
  fi
done
