"""The plot and summary of bench/memory_walk/run.sh.

Usage: plot.py OUT BUDGET_MIB...   (reads OUT/walk-<budget>.csv, writes
OUT/memory.png, prints a Markdown table). Budget 0 is the unbounded run, the
baseline every saving is measured against (same invocation, same machine).
"""
import csv
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

MIB = 1024.0 * 1024.0


def load(path):
    rows = []
    with open(path) as f:
        for row in csv.DictReader(f):
            rows.append(row)
    return rows


def column(rows, key):
    out = []
    for r in rows:
        v = r.get(key, "")
        out.append(float(v) if v not in ("", None) else float("nan"))
    return out


def last_number(values):
    for v in reversed(values):
        if v == v:  # not NaN
            return v
    return float("nan")


def main():
    out, budgets = sys.argv[1], [int(b) for b in sys.argv[2:]]
    fig, (ax_rss, ax_data) = plt.subplots(2, 1, figsize=(10, 7.5), sharex=True)
    summary = {}
    for budget in budgets:
        path = os.path.join(out, f"walk-{budget}.csv")
        if not os.path.exists(path):
            print(f"plot.py: no {path}", file=sys.stderr)
            continue
        rows = load(path)
        if not rows:
            continue
        t = column(rows, "t_s")
        rss = [v / MIB for v in column(rows, "rss_bytes")]
        data = [v / MIB for v in column(rows, "memory_bytes")]
        in_use = [v / MIB for v in column(rows, "memory_in_use_bytes")]
        label = "unbounded" if budget == 0 else f"--memory-budget {budget}"
        (line,) = ax_rss.plot(t, rss, label=label)
        ax_data.plot(t, data, label=label + ": allocated", color=line.get_color())
        if any(v == v for v in in_use):
            ax_data.plot(t, in_use, label=label + ": in use", color=line.get_color(), linestyle=":")
        if budget > 0:
            # The data's budget; resident memory's is the same on top of what
            # the process held before any client (the scene, its BVH and
            # textures, the hierarchy's eager tables: the fixed overhead).
            ax_data.axhline(budget, color=line.get_color(), linestyle="--", linewidth=0.8)
            ax_rss.axhline(rss[0] + budget, color=line.get_color(), linestyle="--", linewidth=0.8)
        shaded = last_number(column(rows, "samples_shaded"))
        summary[budget] = {
            "peak_rss": max(v for v in rss if v == v),
            "start_rss": rss[0],
            "final_rss": last_number(rss),
            "hwm": last_number(column(rows, "hwm_bytes")) / MIB,
            "peak_data": max((v for v in data if v == v), default=float("nan")),
            "shaded": shaded,
            "hit": last_number(column(rows, "prediction_hit_rate")),
            "peak_in_use": max((v for v in in_use if v == v), default=float("nan")),
            "evicted": last_number(column(rows, "samples_evicted")),
            "remade": last_number(column(rows, "samples_reshaded_after_eviction")),
            "seconds": t[-1],
            "trimmed": last_number(column(rows, "trimmed_bytes")) / MIB,
        }
    ax_rss.set_ylabel("SMA resident memory (MiB)")
    ax_data.set_ylabel("SMA data: cache + hierarchy + clients (MiB)")
    ax_data.set_xlabel("walk time (s)")
    ax_rss.set_title("SMA memory over the walk (bench/memory_walk/run.sh); dashed: the budget\n"
                     "(for resident memory: on top of what the SMA held at the start of the walk)")
    for ax in (ax_rss, ax_data):
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper left")
    fig.tight_layout()
    png = os.path.join(out, "memory.png")
    fig.savefig(png, dpi=100)
    print(f"plot: {png}", file=sys.stderr)

    base = summary.get(0)
    print("| run | walk (s) | RSS at start (MiB) | peak RSS (MiB) | VmHWM (MiB) | final RSS (MiB) | peak data (MiB) | peak in use (MiB) |"
          " RSS saved vs unbounded | data saved | samples shaded | evicted | re-shaded after eviction |"
          " prediction hit rate | peak RSS - (start + budget) (MiB) | handed back by malloc_trim (MiB) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for budget, s in summary.items():
        saved = "baseline" if budget == 0 or not base else f"{100.0 * (1.0 - s['peak_rss'] / base['peak_rss']):.0f} %"
        data_saved = ("baseline" if budget == 0 or not base
                      else f"{100.0 * (1.0 - s['peak_data'] / base['peak_data']):.0f} %")
        remade = (f"{s['remade']:.0f} ({100.0 * s['remade'] / s['shaded']:.1f} %)"
                  if s['shaded'] == s['shaded'] and s['shaded'] > 0 and s['remade'] == s['remade'] else "")
        name = "unbounded" if budget == 0 else f"budget {budget} MiB"
        over = "" if budget == 0 else f"{s['peak_rss'] - (s['start_rss'] + budget):+.0f}"
        trimmed = f"{s['trimmed']:.0f}" if s['trimmed'] == s['trimmed'] else ""
        print(f"| {name} | {s['seconds']:.0f} | {s['start_rss']:.0f} | {s['peak_rss']:.0f} | {s['hwm']:.0f} | {s['final_rss']:.0f} |"
              f" {s['peak_data']:.0f} | {s['peak_in_use']:.0f} | {saved} | {data_saved} | {s['shaded']:.0f} |"
              f" {s['evicted']:.0f} | {remade} | {s['hit']:.3f} | {over} | {trimmed} |")


if __name__ == "__main__":
    main()
