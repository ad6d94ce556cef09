#!/usr/bin/python3
"""What the SMA's data is made of over a walk, one colour per run: the sample
cache (solid) and the hierarchy (dashed), from run.sh's OUT/walk-BUDGET.csv
(memory_cache_bytes, memory_hierarchy_bytes), to compare runs of different
builds or flags on the same path and budget.

Usage: plot_parts.py OUT.png LABEL=WALK.csv [LABEL=...]
Prints per run: the cache and the hierarchy at the end and at their peaks,
samples shaded and evicted, and re-shaded after eviction."""
import csv
import sys

import figure  # first: it selects the Agg backend
import matplotlib.pyplot as plt  # noqa: E402

MIB = 1024.0 * 1024.0


def number(row, key):
    value = row.get(key, "")
    return float(value) if value not in ("", None) else 0.0


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    fig, ax = figure.new()
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, arg in enumerate(sys.argv[2:]):
        label, path = arg.split("=", 1)
        rows = list(csv.DictReader(open(path)))
        if not rows:
            continue
        t = [number(r, "t_s") for r in rows]
        cache = [number(r, "memory_cache_bytes") / MIB for r in rows]
        hierarchy = [number(r, "memory_hierarchy_bytes") / MIB for r in rows]
        last = rows[-1]
        shaded = number(last, "samples_shaded")
        reshaded = number(last, "samples_reshaded_after_eviction")
        print(f"{label}: cache {cache[-1]:.0f} MiB at the end (peak {max(cache):.0f}), hierarchy {hierarchy[-1]:.0f} "
              f"(peak {max(hierarchy):.0f}); {shaded / 1e6:.2f} M samples shaded, "
              f"{number(last, 'samples_evicted') / 1e3:.0f} k evicted, {reshaded / 1e3:.1f} k re-shaded after eviction "
              f"({100.0 * reshaded / max(shaded, 1.0):.2f} % of shaded)")
        colour = colours[i % len(colours)]
        ax.plot(t, cache, color=colour, label=f"{label}: sample cache")
        ax.plot(t, hierarchy, color=colour, linestyle="--", label=f"{label}: hierarchy")
    figure.save(fig, ax, sys.argv[1], "walk time (s)", "MiB", "The SMA's data by part over the street walk")


if __name__ == "__main__":
    main()
