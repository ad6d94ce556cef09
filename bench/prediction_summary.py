#!/usr/bin/env python3
"""One run of bench/prediction_bench.sh as a TSV row (summary MODE METRICS SMA_LOG),
the on/off table of its results (table RESULTS.tsv), or where a run's views
spent their time up to stage 1 (breakdown SMA_LOG... : any SMA debug log, e.g.
prediction_bench --sma-args='--log-level debug', one log per mode).

Latency to complete display, per view the SMA applied: from the view's arrival
at the SMA until the client next has a complete image (stage 1: every triangle
initially visible shaded) of it or of a later view. A walking client's views
are mostly superseded before their own stage 1, so their own stage-1 time
alone would describe the few views that happened to get there. Read from the
SMA's debug lines "view N: ... view->first delta X ms" (arrival = line time -
X) and "view N: stage 1 in X ms" (complete at the line's time)."""

import csv
import datetime
import re
import sys

COLUMNS = ["mode", "hit_rate", "new_triangles", "new_shaded", "complete_p50_ms", "complete_p99_ms", "views_applied",
           "views_never_complete", "stage1_p50_ms", "views_stage1", "predicted_views", "samples_predicted"]


# The SMA's debug line per new view (server.cpp, "view->first delta"), and its
# stage-1 line.
APPLIED = r": view (\d+): .*view->first delta ([0-9.]+) ms"
STEPS = re.compile(r": view (\d+): before its job ([0-9.]+) ms, queued ([0-9.]+) ms, trace ([0-9.]+) ms, "
                   r"map ([0-9.]+) ms, strand wait ([0-9.]+) ms, plan\+send ([0-9.]+) ms, "
                   r"view->first delta ([0-9.]+) ms; \d+ visible, \d+ held, (\d+) pending")
STAGE1 = r": view (\d+): stage 1 in ([0-9.]+) ms"


def percentile(values, p):
    values = sorted(values)
    return values[min(len(values) - 1, int(p * (len(values) - 1) + 0.5))] if values else float("nan")


def metrics(path):
    out = {}
    for line in open(path):
        if line.startswith("#") or not line.strip():
            continue
        name, value = line.split()[:2]
        out[name] = float(value)
    return out


def summary(mode, metrics_path, log_path):
    m = metrics(metrics_path)
    stamp = re.compile(r"^\[([0-9-]+ [0-9:.]+)\]")
    applied = re.compile(APPLIED)
    stage1 = re.compile(STAGE1)
    arrivals, completions, stage1_ms = {}, [], []
    for line in open(log_path, errors="replace"):
        s = stamp.match(line)
        if not s:
            continue
        t = datetime.datetime.strptime(s.group(1), "%Y-%m-%d %H:%M:%S.%f").timestamp()
        if a := applied.search(line):
            arrivals.setdefault(int(a.group(1)), t - float(a.group(2)) / 1000.0)
        elif c := stage1.search(line):
            completions.append((int(c.group(1)), t))
            stage1_ms.append(float(c.group(2)))
    latency, never = [], 0
    for view, arrived in arrivals.items():
        done = [t for w, t in completions if w >= view and t >= arrived]
        if done:
            latency.append(1000.0 * (min(done) - arrived))
        else:
            never += 1
    row = [mode, m.get("penumbra_sma_prediction_hit_ratio", float("nan")),
           int(m.get("penumbra_sma_view_triangles_new_total", 0)),
           int(m.get("penumbra_sma_view_triangles_new_shaded_total", 0)),
           round(percentile(latency, 0.5), 1), round(percentile(latency, 0.99), 1), len(arrivals), never,
           round(percentile(stage1_ms, 0.5), 1), len(stage1_ms), int(m.get("penumbra_sma_predicted_views_total", 0)),
           int(m.get("penumbra_sma_samples_requested_predicted_total", 0))]
    print("\t".join(str(x) for x in row))


def pooled(rows):
    """Runs of one mode: hit rate from the summed counts, the rest as means."""
    out = {}
    for key in COLUMNS[1:]:
        values = [float(r[key]) for r in rows]
        out[key] = sum(values) / len(values)
    new = sum(float(r["new_triangles"]) for r in rows)
    out["hit_rate"] = sum(float(r["new_shaded"]) for r in rows) / new if new else float("nan")
    return out


def table(results_path):
    rows = list(csv.DictReader(open(results_path), delimiter="\t"))
    off = pooled([r for r in rows if r["mode"] == "off"])
    on = pooled([r for r in rows if r["mode"] == "on"])
    print(f"{sum(r['mode'] == 'off' for r in rows)} run(s) each; per run:")
    labels = {"hit_rate": "hit rate", "complete_p50_ms": "view -> complete display p50 (ms)",
              "complete_p99_ms": "view -> complete display p99 (ms)", "views_applied": "views applied",
              "views_never_complete": "of which never complete", "stage1_p50_ms": "own stage 1 p50 (ms)",
              "views_stage1": "views reaching their own stage 1", "new_triangles": "newly displayed triangles",
              "new_shaded": "of which already shaded", "predicted_views": "predicted views traced",
              "samples_predicted": "samples asked by prediction"}
    print(f"| | off | on | on/off |\n|---|---|---|---|")
    for key, label in labels.items():
        a, b = float(off[key]), float(on[key])
        fmt = "{:.3f}" if key == "hit_rate" else "{:.0f}"
        ratio = f"{b / a:.2f}" if a and a == a and b == b else "-"
        print(f"| {label} | {fmt.format(a)} | {fmt.format(b)} | {ratio} |")


def breakdown(log_paths):
    """Medians over the views that reached their own stage 1 (the first two
    skipped: a cold start, and no prediction before two views): the steps to
    the view's first delta, its stage 1 (both timed by the SMA from the view's
    arrival), the triangles it had to wait for (pending: a corner not yet
    shaded), and how fast the views with none were complete."""
    print("| SMA log | views | trace | map | plan+send | first delta | stage 1 | stage 1 p90 | pending | "
          "views with none pending | their stage 1 |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    stage1 = re.compile(STAGE1)
    for path in log_paths:
        steps, done = {}, {}
        for line in open(path, errors="replace"):
            if a := STEPS.search(line):
                steps[int(a.group(1))] = [float(x) for x in a.group(2, 3, 4, 5, 6, 7, 8)] + [int(a.group(9))]
            elif c := stage1.search(line):
                done.setdefault(int(c.group(1)), float(c.group(2)))
        views = [v for v in steps if v > 2 and v in done]
        if not views:
            print(f"| {path} | 0 | | | | | | | | | |")
            continue
        med = lambda xs: percentile(xs, 0.5)
        col = lambda i: med([steps[v][i] for v in views])
        none = [v for v in views if steps[v][7] == 0]
        print(f"| {path} | {len(views)} | {col(2):.1f} | {col(3):.1f} | {col(5):.1f} | {col(6):.1f} | "
              f"{med([done[v] for v in views]):.0f} | {percentile([done[v] for v in views], 0.9):.0f} | "
              f"{col(7):.0f} | {len(none)} | {med([done[v] for v in none]) if none else float('nan'):.0f} |")


if __name__ == "__main__":
    if sys.argv[1] == "summary":
        summary(*sys.argv[2:5])
    elif sys.argv[1] == "table":
        table(sys.argv[2])
    elif sys.argv[1] == "breakdown":
        breakdown(sys.argv[2:])
    else:
        sys.exit("usage: prediction_summary.py summary MODE METRICS SMA_LOG | table RESULTS.tsv | breakdown SMA_LOG...")
