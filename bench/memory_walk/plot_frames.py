#!/usr/bin/python3
"""The client's frame times over a walk, one line per run: the interval
between consecutive --stats lines (one per frame) against walk time, on a
log scale so that a stalled frame and the ordinary ones show together.

Usage: plot_frames.py OUT.png LABEL=CLIENT-STATS.jsonl [LABEL=...]
(client-stats.jsonl is in run.sh's OUT/logs-BUDGET/). Prints per run: frames,
mean frame rate, median and p99 frame interval, frames of 2 s or more."""
import json
import statistics
import sys

import figure


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    fig, ax = figure.new()
    for arg in sys.argv[2:]:
        label, path = arg.split("=", 1)
        times = [json.loads(line)["time_s"] for line in open(path) if line.strip()]
        gaps = [b - a for a, b in zip(times, times[1:])]
        if not gaps:
            continue
        span = times[-1] - times[0]
        print(f"{label}: {len(times)} frames over {span:.0f} s, {len(times) / span:.1f} frames/s, "
              f"median {1000 * statistics.median(gaps):.0f} ms, p99 {1000 * sorted(gaps)[int(0.99 * len(gaps))]:.0f} ms, "
              f"{sum(g >= 2.0 for g in gaps)} frames >= 2 s (longest {max(gaps):.1f} s)")
        ax.plot(times[1:], gaps, label=label, linewidth=0.7, drawstyle="steps-pre")  # each interval over its span
    ax.set_yscale("log")
    figure.save(fig, ax, sys.argv[1], "client time (s)", "frame interval (s)", "Headless client frame times over the street walk (Mesa llvmpipe)", grid_which="both")


if __name__ == "__main__":
    main()
