#!/usr/bin/env bash
# Issue 15, part 5 (the large scene): load time and resident memory of
# penumbra-renderer and penumbra-sma on scenes/street.json (2.14 million
# triangles: 28 Sponza copies and the breakfast room) against scenes/sponza.json
# (67 thousand), measured in the same run, one process at a time.
#
#   bench/large_scene.sh [RUNS]        # RUNS per scene and process (default 1)
#
# Uses build/renderer/penumbra-renderer and build/sma/penumbra-sma of this
# checkout (scripts/build.sh first). Each process is started on its own with
# --port-file; it writes the file once the scene is loaded and its structures
# are built (the renderer: scene + BVH + shader; the SMA: scene + visibility BVH
# + hierarchy + server) and it listens. Load time = start -> port file. Then
# VmRSS and VmHWM are read from /proc/PID/status and the process is stopped
# (SIGTERM). The SMA is pointed at a renderer address nothing listens on: it
# loads and builds without one. Load time includes process start, so a
# shared, loaded machine shows in it: note the load average printed.
#
# Printed: one line per run, then a table of medians with "per million
# triangles" and the street/sponza ratios, and the marginal cost per million
# triangles (street - sponza) / (triangles street - triangles sponza), which
# leaves out the fixed cost of a process (code, libraries, thread stacks).
# Not in ctest: the street takes seconds and ~1 GB.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
runs="${1:-1}"
renderer="$root/build/renderer/penumbra-renderer"
sma="$root/build/sma/penumbra-sma"
for exe in "$renderer" "$sma"; do
  [[ -x "$exe" ]] || { echo "large_scene.sh: $exe missing (run scripts/build.sh)" >&2; exit 1; }
done
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT

# status_kb PID FIELD -> the field's kB value from /proc/PID/status
status_kb() { awk -v f="$2:" '$1 == f { print $2 }' "/proc/$1/status"; }

# measure NAME SCENE -> "seconds rss_kb hwm_kb triangles" of one process start
measure() {
  local kind="$1" scene="$2" log="$work/$kind.log" port="$work/$kind.port"
  rm -f "$port"
  local start end pid
  start=$(date +%s.%N)
  if [[ "$kind" == renderer ]]; then
    "$renderer" --scene "$scene" --listen 127.0.0.1:0 --port-file "$port" --threads 1 --log-level info >"$log" 2>&1 &
  else
    "$sma" --scene "$scene" --listen 127.0.0.1:0 --port-file "$port" --renderer 127.0.0.1:9 --log-level info \
      >"$log" 2>&1 &
  fi
  pid=$!
  while [[ ! -s "$port" ]]; do
    if ! kill -0 "$pid" 2>/dev/null; then
      echo "large_scene.sh: $kind on $scene exited before it was ready:" >&2
      tail -5 "$log" >&2
      return 1
    fi
    sleep 0.05
  done
  end=$(date +%s.%N)
  local rss hwm triangles
  rss=$(status_kb "$pid" VmRSS)
  hwm=$(status_kb "$pid" VmHWM)
  kill -TERM "$pid"
  wait "$pid" 2>/dev/null || true
  triangles=$(sed -n "s/.*loaded '[^']*' from [^:]*: \([0-9]*\) triangles.*/\1/p" "$log" | head -1)
  echo "$(echo "$end - $start" | bc -l) $rss $hwm $triangles"
}

echo "large_scene.sh: $(git -C "$root" rev-parse --short HEAD), $runs run(s); load average $(cut -d' ' -f1-3 /proc/loadavg)"
results="$work/results"
: >"$results"
for run in $(seq 1 "$runs"); do
  for scene in sponza street; do
    for kind in renderer sma; do
      read -r seconds rss hwm triangles < <(measure "$kind" "$root/scenes/$scene.json")
      printf '%-8s %-6s run %d: %s triangles, ready after %.2f s, VmRSS %d MB, VmHWM %d MB\n' "$kind" "$scene" "$run" \
        "$triangles" "$seconds" $((rss / 1024)) $((hwm / 1024))
      echo "$kind $scene $seconds $rss $hwm $triangles" >>"$results"
    done
  done
done

# Medians per (process, scene), then the table.
python3 - "$results" <<'EOF'
import statistics, sys
rows = [l.split() for l in open(sys.argv[1]) if l.strip()]
m = {}
for kind, scene, s, rss, hwm, tri in rows:
    m.setdefault((kind, scene), []).append((float(s), int(rss) / 1024, int(hwm) / 1024, int(tri)))
med = {k: tuple(statistics.median(x[i] for x in v) for i in range(4)) for k, v in m.items()}
print()
print("| process | scene | triangles | ready after (s) | VmRSS (MB) | VmHWM (MB) | VmRSS per M triangles (MB) | VmHWM per M triangles (MB) |")
print("|---|---|---|---|---|---|---|---|")
for kind in ("renderer", "sma"):
    for scene in ("sponza", "street"):
        s, rss, hwm, tri = med[(kind, scene)]
        mt = tri / 1e6
        print(f"| {kind} | {scene} | {int(tri):,} | {s:.2f} | {rss:.0f} | {hwm:.0f} | {rss / mt:.0f} | {hwm / mt:.0f} |")
print()
print("| process | street / sponza: triangles | load time | VmRSS | VmHWM | VmHWM per M triangles | marginal VmHWM per M triangles (MB) | marginal load time per M triangles (s) |")
print("|---|---|---|---|---|---|---|---|")
for kind in ("renderer", "sma"):
    a, b = med[(kind, "sponza")], med[(kind, "street")]
    dmt = (b[3] - a[3]) / 1e6
    print(f"| {kind} | {b[3] / a[3]:.1f} | {b[0] / a[0]:.1f} | {b[1] / a[1]:.1f} | {b[2] / a[2]:.1f} | "
          f"{(b[2] / b[3]) / (a[2] / a[3]):.2f} | {(b[2] - a[2]) / dmt:.0f} | {(b[0] - a[0]) / dmt:.2f} |")
EOF
