#!/usr/bin/env python3
"""References, errors and the plot of the walkthrough comparison (run.sh).

  walkthrough.py references --out OUT --build BUILD --scene SCENE --interval S --duration D --spp N PATH...
  walkthrough.py report --out OUT --build BUILD --interval S --duration D --spp N PATH...

PATH is a camera path without its .json. Frames are OUT/{one,four}/penumbra-NAME_tMS.exr
(the client) and OUT/{one,four}/pt-NAME_tMS.exr (the progressive path tracer).
References are cached by pose in OUT/refs (a pose seen at several times, or on
several runs, is rendered once). The error of a frame is the relative mean
absolute error against the reference of its pose (penumbra-image-tool compare),
per pixel (blur 0) and after a box blur of radius 2 (which takes most of the
reference's own noise out, and as much of the path tracer's).
"""
import argparse
import csv
import hashlib
import json
import os
import subprocess
import sys
import tempfile

STOPS = [(0, 4), (10, 14), (16, 20), (22, 26), (32, 38)]  # make_paths.py
RETURNS = [(22, 14, "turned back to the walk's end pose (seen 10-14 s)"),
           (32, 4, "walked back to the start pose (seen 0-4 s)")]


def load_path(path):
    with open(path + ".json") as f:
        return json.load(f)


def pose_at(path, t):
    """CameraPath::PoseAt: linear between keyframes, clamped; a stop is its keyframes' pose."""
    keys = path["keyframes"]
    if t <= keys[0]["t"]:
        k = keys[0]
        return k["eye"], k["target"], k.get("up", [0, 1, 0])
    for a, b in zip(keys, keys[1:]):
        if t <= b["t"]:
            if a["eye"] == b["eye"] and a["target"] == b["target"]:
                return a["eye"], a["target"], a.get("up", [0, 1, 0])
            s = (t - a["t"]) / (b["t"] - a["t"]) if b["t"] > a["t"] else 1.0
            mix = lambda u, v: [x + s * (y - x) for x, y in zip(u, v)]
            return mix(a["eye"], b["eye"]), mix(a["target"], b["target"]), mix(a.get("up", [0, 1, 0]), b.get("up", [0, 1, 0]))
    k = keys[-1]
    return k["eye"], k["target"], k.get("up", [0, 1, 0])


def pose_key(path, t, spp):
    eye, target, up = pose_at(path, t)
    text = json.dumps([[round(v, 5) for v in eye + target + up], path["fov_y_deg"], path["width"], path["height"], spp])
    return hashlib.sha1(text.encode()).hexdigest()[:16]


def times(interval, duration):
    n = int(duration / interval + 1e-9)
    return [round(k * interval, 6) for k in range(n + 1)]


def ms(t):
    return "%06d" % round(t * 1000)


def references(args):
    refs = os.path.join(args.out, "refs")
    os.makedirs(refs, exist_ok=True)
    for p in args.paths:
        path = load_path(p)
        wanted = {}
        for t in times(args.interval, args.duration):
            key = pose_key(path, t, args.spp)
            if not os.path.exists(os.path.join(refs, key + ".exr")):
                wanted.setdefault(key, t)
        if not wanted:
            continue
        print("%s: %d references at %d paths per pixel" % (os.path.basename(p), len(wanted), args.spp), flush=True)
        with tempfile.TemporaryDirectory(dir=refs) as tmp:
            subprocess.run([os.path.join(args.build, "renderer/penumbra-reference"), "--scene", args.scene,
                            "--camera-path", p + ".json", "--spp", str(args.spp), "--log-level", "warn",
                            "--out", os.path.join(tmp, "{t}.exr"), "--time"] + ["%g" % t for t in wanted.values()],
                           check=True)
            for key, t in wanted.items():
                src = os.path.join(tmp, ms(t) + ".exr") if len(wanted) > 1 else os.path.join(tmp, "{t}.exr")
                os.replace(src, os.path.join(refs, key + ".exr"))


def compare_all(build, triples):
    """rel. MAE of each (image, reference, blur), from one penumbra-image-tool compare-list run."""
    if not triples:
        return []
    text = "".join("%s %s %d\n" % (ref, image, blur) for image, ref, blur in triples)
    out = subprocess.run([os.path.join(build, "bench/penumbra-image-tool"), "compare-list"], input=text,
                         check=True, capture_output=True, text=True).stdout.splitlines()
    results = [json.loads(line) for line in out]
    if len(results) != len(triples) or any("error" in r for r in results):
        sys.exit("penumbra-image-tool compare-list failed")
    return [r["rel_mae"] for r in results]


def report(args):
    rows, triples = [], []
    for run in ("one", "four"):
        for p in args.paths:
            name = os.path.basename(p)
            path = load_path(p)
            for t in times(args.interval, args.duration):
                ref = os.path.join(args.out, "refs", pose_key(path, t, args.spp) + ".exr")
                for who, prefix in (("penumbra", "penumbra-"), ("pathtracer", "pt-")):
                    frame = os.path.join(args.out, run, "%s%s_t%s.exr" % (prefix, name, ms(t)))
                    if not os.path.exists(frame) or not os.path.exists(ref):
                        continue
                    rows.append({"run": run, "path": name, "t": t, "who": who})
                    triples += [(frame, ref, 0), (frame, ref, 2)]
    maes = compare_all(args.build, triples)
    for i, row in enumerate(rows):
        row["rel_mae"], row["rel_mae_blur2"] = maes[2 * i], maes[2 * i + 1]
    with open(os.path.join(args.out, "errors.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["run", "path", "t", "who", "rel_mae", "rel_mae_blur2"])
        w.writeheader()
        w.writerows(rows)

    def series(run, path, who, field):
        return {r["t"]: r[field] for r in rows if r["run"] == run and r["path"] == path and r["who"] == who}

    print("| run | path | Penumbra mean rel. MAE | path tracer | ratio | same, 2-px blur: Penumbra | path tracer | ratio |")
    print("|---|---|---|---|---|---|---|---|")
    for run in ("one", "four"):
        for p in args.paths:
            name = os.path.basename(p)
            cells = []
            for field in ("rel_mae", "rel_mae_blur2"):
                pen, pt = series(run, name, "penumbra", field), series(run, name, "pathtracer", field)
                common = sorted(set(pen) & set(pt))
                if not common:
                    break
                mp = sum(pen[t] for t in common) / len(common)
                mt = sum(pt[t] for t in common) / len(common)
                cells += ["%.1f %%" % (100 * mp), "%.1f %%" % (100 * mt), "%.2f" % (mp / mt)]
            if cells:
                print("| %s | %s | %s |" % (run, name, " | ".join(cells)))
    print()
    print("Returns (Penumbra, per-pixel rel. MAE): the first frame back, against the reference; the frame before leaving;")
    print("and the first frame back against the frame before leaving (the same image at once?)")
    print()
    print("| run | path | return | first frame back | before leaving | back vs before leaving |")
    print("|---|---|---|---|---|---|")
    returns = []
    for run in ("one", "four"):
        for p in args.paths:
            name = os.path.basename(p)
            pen = series(run, name, "penumbra", "rel_mae")
            for back, before, what in RETURNS:
                a = os.path.join(args.out, run, "penumbra-%s_t%s.exr" % (name, ms(back)))
                b = os.path.join(args.out, run, "penumbra-%s_t%s.exr" % (name, ms(before)))
                if back in pen and before in pen and os.path.exists(a) and os.path.exists(b):
                    returns.append((run, name, what, pen[back], pen[before], (a, b, 0)))
    between = compare_all(args.build, [r[5] for r in returns])
    for (run, name, what, back, before, _), d in zip(returns, between):
        print("| %s | %s | %s | %.1f %% | %.1f %% | %.1f %% |" % (run, name, what, 100 * back, 100 * before, 100 * d))
    plot(args, rows)


def plot(args, rows):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    names = [os.path.basename(p) for p in args.paths]
    fig, axes = plt.subplots(2, 1, figsize=(10, 8), sharex=True)
    for ax, run, title in ((axes[0], "one", "one client (walk-a) vs one progressive path tracer"),
                           (axes[1], "four", "four clients through one SMA vs four path tracers, same 2 cores")):
        for a, b in STOPS:
            ax.axvspan(a, b, color="0.92", lw=0)
        for i, name in enumerate(names if run == "four" else names[:1]):
            colour = "C%d" % i
            for who, style in (("penumbra", "-"), ("pathtracer", "--")):
                s = {r["t"]: r["rel_mae"] for r in rows if r["run"] == run and r["path"] == name and r["who"] == who}
                if s:
                    ts = sorted(s)
                    ax.plot(ts, [100 * s[t] for t in ts], style, color=colour, marker="." if who == "penumbra" else None,
                            label="%s %s" % ("Penumbra" if who == "penumbra" else "path tracer", name))
        for back, _, _ in RETURNS:
            ax.axvline(back, color="k", lw=0.6, ls=":")
        ax.set_ylabel("rel. MAE vs converged reference (%)")
        ax.set_title(title, fontsize=10)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
    axes[1].set_xlabel("path time (s); grey: camera still; dotted: back at a visited pose")
    fig.tight_layout()
    fig.savefig(os.path.join(args.out, "walkthrough.png"), dpi=90)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("step", choices=["references", "report"])
    ap.add_argument("--out", required=True)
    ap.add_argument("--build", required=True)
    ap.add_argument("--scene")
    ap.add_argument("--interval", type=float, required=True)
    ap.add_argument("--duration", type=float, required=True)
    ap.add_argument("--spp", type=int, required=True)
    ap.add_argument("paths", nargs="+")
    args = ap.parse_args()
    if args.step == "references":
        if not args.scene:
            sys.exit("references needs --scene")
        references(args)
    else:
        report(args)


if __name__ == "__main__":
    main()
