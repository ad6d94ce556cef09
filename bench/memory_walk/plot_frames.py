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

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    fig, ax = plt.subplots(figsize=(10, 4.5))
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
    ax.set_xlabel("client time (s)")
    ax.set_ylabel("frame interval (s)")
    ax.set_title("Headless client frame times over the street walk (Mesa llvmpipe)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(sys.argv[1], dpi=100)
    print(f"plot: {sys.argv[1]}")


if __name__ == "__main__":
    main()
