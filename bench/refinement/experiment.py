#!/usr/bin/python3
"""The founding paper's Table 1, reproduced on real scenes (issue: refinement).

For each view and each refinement criterion, a fresh renderer + SMA (empty
cache) serve a headless penumbra-client that looks at the view until the SMA
reports it converged, writing an EXR snapshot of what it shows every few
hundred milliseconds and one statistics line per frame. From those:

  T, Delta (triangles shown), Delta_total (triangles ever sent) at stage 1
  (every initially visible triangle shaded) and stage 2 (converged);
  image error against a per-pixel path-traced reference: relative mean
  absolute error on linear radiance, and SSIM on Drago-mapped images;
  error-vs-time and error-vs-Delta_total curves (one PNG per view);
  the brute-force baseline: how long per-pixel path tracing (penumbra-reference,
  same cores) needs to reach the error of NLD_OS's final image.

Results go to OUT/results.json, OUT/<view>/*.png, and docs/refinement.md is
written from them. Run through bench/refinement/run.sh, which builds first.
"""

import argparse
import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

VIEWS = {
    "cornell": {"scene": "scenes/cornell-box.json", "camera": "front", "size": (320, 240),
                "title": "Cornell box (area light)"},
    "sponza": {"scene": "scenes/sponza.json", "camera": "atrium", "size": (480, 270),
               "title": "Sponza atrium (sun shadows of the columns)"},
    "breakfast": {"scene": "scenes/breakfast-room.json", "camera": "table", "size": (480, 270),
                  "title": "Breakfast room (sun through the blinds)"},
}

# (label, SMA flags, renderer flags). The paper's criteria use its plain
# metric (noise z = 0) and a fixed number of paths per vertex.
ADAPTIVE_PATHS = ["--max-spp", "1024", "--target-error", "0.05"]
CRITERIA = [
    ("RND", ["--criterion", "rnd", "--noise-z", "0", "--pixel-fraction", "0.25"], []),
    ("NLD_IS", ["--criterion", "nld_is", "--noise-z", "0", "--pixel-fraction", "0.25"], []),
    ("NLD_OS", ["--criterion", "nld_os", "--noise-z", "0"], []),
    ("NLD_OS+RND", ["--criterion", "nld_os_rnd", "--noise-z", "0"], []),
    ("NLD_OS-N (ours)", ["--criterion", "nld_os", "--noise-z", "2"], []),
    ("NLD_OS-N + adaptive paths (ours)", ["--criterion", "nld_os", "--noise-z", "2"], ADAPTIVE_PATHS),
]


def log(*args):
    print("[experiment]", *args, flush=True)


def wait_port(path, process, timeout=120.0):
    deadline = time.time() + timeout
    while time.time() < deadline:
        if path.exists() and path.read_text().strip():
            return int(path.read_text())
        if process.poll() is not None:
            raise RuntimeError(f"{process.args[0]} exited before listening")
        time.sleep(0.05)
    raise RuntimeError(f"{process.args[0]} did not listen in time")


def stop(process):
    if process.poll() is None:
        process.send_signal(signal.SIGTERM)
        try:
            process.wait(10)
        except subprocess.TimeoutExpired:
            process.kill()


class Tools:
    def __init__(self, build):
        self.renderer = build / "renderer" / "penumbra-renderer"
        self.sma = build / "sma" / "penumbra-sma"
        self.client = build / "client" / "penumbra-client"
        self.reference = build / "renderer" / "penumbra-reference"
        self.image_tool = build / "bench" / "penumbra-image-tool"
        for tool in vars(self).values():
            if not tool.exists():
                raise SystemExit(f"missing {tool}: build first (bench/refinement/run.sh does)")

    def compare(self, reference, image):
        out = subprocess.run([self.image_tool, "compare", reference, image], check=True, capture_output=True, text=True)
        return json.loads(out.stdout)

    def tonemap(self, image, png, like):
        subprocess.run([self.image_tool, "tonemap", image, png, "--like", like], check=True)


def render_reference(tools, view, out, spp, seed, threads):
    """Per-pixel path tracing; returns render seconds (scene loading excluded)."""
    width, height = view["size"]
    args = [tools.reference, "--scene", ROOT / view["scene"], "--camera", view["camera"], "--width", str(width),
            "--height", str(height), "--spp", str(spp), "--seed", str(seed), "--threads", str(threads),
            # Pixel centres: what the SMA's visibility and the client's rasterizer
            # sample (docs/refinement.md says what this leaves out).
            "--pixel-filter", "centre", "--out", out]
    result = subprocess.run(args, check=True, capture_output=True, text=True)
    match = re.search(r"paths/pixel in ([0-9.]+) s", result.stdout + result.stderr)
    return float(match.group(1))


def run_criterion(tools, view, label, sma_flags, renderer_flags, work, args):
    """One fresh stack, one client until convergence. Returns the run's record."""
    work.mkdir(parents=True, exist_ok=True)
    for f in work.glob("*"):
        f.unlink() if f.is_file() else shutil.rmtree(f)
    width, height = view["size"]
    scene = ROOT / view["scene"]
    logs = []
    renderer = subprocess.Popen(
        [tools.renderer, "--scene", scene, "--listen", "127.0.0.1:0", "--port-file", work / "renderer.port",
         "--threads", str(args.threads), "--spp", str(args.paths), "--log-level", "warn"] + renderer_flags,
        stdout=open(work / "renderer.log", "w"), stderr=subprocess.STDOUT)
    logs.append(renderer)
    try:
        renderer_port = wait_port(work / "renderer.port", renderer)
        sma = subprocess.Popen(
            [tools.sma, "--scene", scene, "--listen", "127.0.0.1:0", "--port-file", work / "sma.port", "--renderer",
             f"127.0.0.1:{renderer_port}", "--log-level", "warn"] + sma_flags,
            stdout=open(work / "sma.log", "w"), stderr=subprocess.STDOUT)
        logs.append(sma)
        sma_port = wait_port(work / "sma.port", sma)
        client = [tools.client, "--connect", f"127.0.0.1:{sma_port}", "--headless", "--camera", view["camera"],
                  "--size", f"{width}x{height}", "--until-converged", "--timeout", str(args.timeout),
                  "--stats", work / "stats.jsonl", "--screenshot", work / "final.exr",
                  "--snapshot-every", str(args.snapshot_every), "--snapshot-prefix", work / "snap",
                  "--log-level", "warn"]
        subprocess.run(client, check=True, stdout=open(work / "client.log", "w"), stderr=subprocess.STDOUT)
    finally:
        for p in reversed(logs):
            stop(p)

    lines = [json.loads(l) for l in (work / "stats.jsonl").read_text().splitlines() if l.strip()]
    t0 = lines[0]["time_s"]
    stage1 = next((l for l in lines if l.get("refining") or l.get("converged")), lines[-1])
    stage2 = next((l for l in lines if l.get("converged")), lines[-1])
    frames = {l["frame"]: l for l in lines}
    curve = []
    for snap in sorted(work.glob("snap_*.exr")):
        frame = int(re.search(r"snap_(\d+)\.exr", snap.name).group(1))
        line = frames.get(frame)
        if line is None or line["triangles_held"] == 0:
            continue
        metrics = tools.compare(args.reference_of[view["name"]], snap)
        curve.append({"t": line["time_s"] - t0, "delta": line["triangles_held"], "delta_total": line["triangles_added"],
                      **metrics})
    final = tools.compare(args.reference_of[view["name"]], work / "final.exr")
    record = {
        "label": label,
        "stage1": {"t": stage1["time_s"] - t0, "delta": stage1["triangles_held"],
                   "delta_total": stage1["triangles_added"]},
        "stage2": {"t": stage2["time_s"] - t0, "delta": stage2["triangles_held"],
                   "delta_total": stage2["triangles_added"], **final},
        "curve": curve,
    }
    snapshot_at_stage1 = next((s for s in sorted(work.glob("snap_*.exr"))
                               if int(re.search(r"snap_(\d+)", s.name).group(1)) >= stage1["frame"]), None)
    if snapshot_at_stage1:
        record["stage1"].update(tools.compare(args.reference_of[view["name"]], snapshot_at_stage1))
        record["stage1_image"] = str(snapshot_at_stage1)
    record["final_image"] = str(work / "final.exr")
    log(f"  {label}: stage 1 {record['stage1']['t']:.2f} s, {record['stage1']['delta']} triangles; "
        f"stage 2 {record['stage2']['t']:.2f} s, {record['stage2']['delta']} shown, "
        f"{record['stage2']['delta_total']} sent, rel MAE {final['rel_mae']:.4f}, SSIM {final['ssim']:.4f}")
    return record


def brute_force(tools, view, target_error, out_dir, args):
    """Per-pixel path tracing at doubling paths per pixel until it matches `target_error`."""
    ladder = []
    spp = 1
    while spp <= args.brute_max_spp:
        image = out_dir / f"brute_{spp}.exr"
        seconds = render_reference(tools, view, image, spp, seed=7, threads=args.threads)
        metrics = tools.compare(args.reference_of[view["name"]], image)
        ladder.append({"spp": spp, "t": seconds, **metrics})
        log(f"  brute force {spp} spp: {seconds:.2f} s, rel MAE {metrics['rel_mae']:.4f}")
        if metrics["rel_mae"] <= target_error:
            break
        spp *= 2
    # Time to reach the target, interpolated in log-log between ladder steps.
    reached = None
    for a, b in zip(ladder, ladder[1:]):
        if a["rel_mae"] > target_error >= b["rel_mae"]:
            f = (math.log(target_error) - math.log(a["rel_mae"])) / (math.log(b["rel_mae"]) - math.log(a["rel_mae"]))
            reached = math.exp(math.log(a["t"]) + f * (math.log(b["t"]) - math.log(a["t"])))
    if ladder and ladder[0]["rel_mae"] <= target_error:
        reached = ladder[0]["t"]
    return {"ladder": ladder, "time_to_target": reached}


def delta_total_to_reach(curve, error):
    for point in curve:
        if point["rel_mae"] <= error:
            return point["delta_total"]
    return None


def plot(view_name, view, records, out_dir):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for r in records:
        c = r["curve"]
        if not c:
            continue
        axes[0].plot([p["t"] for p in c], [p["rel_mae"] for p in c], label=r["label"])
        axes[1].plot([p["delta_total"] for p in c], [p["rel_mae"] for p in c], label=r["label"])
    axes[0].set_xlabel("time since the view was sent (s)")
    axes[1].set_xlabel("triangles sent, $\\Delta_{total}$")
    axes[1].set_xscale("log")
    for ax in axes:
        ax.set_ylabel("relative MAE vs reference")
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend()
    fig.suptitle(view["title"])
    fig.tight_layout()
    path = out_dir / "curves.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--build", default=str(ROOT / "build"), help="build directory")
    parser.add_argument("--out", default=str(ROOT / "bench" / "refinement" / "results"), help="results directory")
    parser.add_argument("--views", default="cornell,sponza,breakfast")
    parser.add_argument("--paths", type=int, default=128, help="paths per vertex sample")
    parser.add_argument("--reference-spp", type=int, default=1024)
    parser.add_argument("--brute-max-spp", type=int, default=1024)
    parser.add_argument("--threads", type=int, default=os.cpu_count())
    parser.add_argument("--snapshot-every", type=float, default=0.2, help="client snapshot interval (s)")
    parser.add_argument("--timeout", type=int, default=1800, help="per run, seconds")
    parser.add_argument("--docs", default=str(ROOT / "docs" / "refinement.md"))
    args = parser.parse_args()

    tools = Tools(Path(args.build))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results = {"settings": {"paths_per_vertex": args.paths, "reference_spp": args.reference_spp,
                            "threads": args.threads, "machine": os.uname().machine, "cpus": os.cpu_count()},
               "views": {}}
    # A run of some views keeps the others' results from an earlier run.
    previous = out / "results.json"
    if previous.exists():
        old = json.loads(previous.read_text())
        if old.get("settings") == results["settings"]:
            results["views"] = old.get("views", {})
    args.reference_of = {}
    for name in args.views.split(","):
        view = dict(VIEWS[name], name=name)
        if not (ROOT / view["scene"]).exists() or "shared" in view["scene"] and not (ROOT.parent / "shared").exists():
            log(f"{name}: scene missing, skipped")
            continue
        view_dir = out / name
        view_dir.mkdir(parents=True, exist_ok=True)
        reference = view_dir / f"reference_{args.reference_spp}.exr"
        if not reference.exists():
            log(f"{name}: reference at {args.reference_spp} spp")
            render_reference(tools, view, reference, args.reference_spp, seed=0, threads=args.threads)
        args.reference_of[name] = reference
        tools.tonemap(reference, view_dir / "reference.png", reference)
        log(f"{name}: criteria")
        records = []
        for label, sma_flags, renderer_flags in CRITERIA:
            slug = re.sub(r"[^a-z0-9]+", "_", label.lower()).strip("_")
            record = run_criterion(tools, view, label, sma_flags, renderer_flags, view_dir / f"run_{slug}", args)
            record["sma_flags"] = sma_flags
            record["renderer_flags"] = renderer_flags
            tools.tonemap(record["final_image"], view_dir / f"{slug}.png", reference)
            record["final_png"] = f"{slug}.png"
            if label == "NLD_OS" and "stage1_image" in record:
                tools.tonemap(record["stage1_image"], view_dir / "stage1.png", reference)
            records.append(record)
        nld_os = next(r for r in records if r["label"] == "NLD_OS")
        target = nld_os["stage2"]["rel_mae"]
        for r in records:
            r["delta_total_to_nld_os_error"] = delta_total_to_reach(r["curve"], target)
        log(f"{name}: brute force to NLD_OS's error {target:.4f}")
        brute = brute_force(tools, view, target, view_dir, args)
        results["views"][name] = {"title": view["title"], "size": view["size"], "criteria": records, "brute_force": brute,
                                  "curves": str(plot(name, view, records, view_dir).relative_to(out))}
        (out / "results.json").write_text(json.dumps(results, indent=1))
    subprocess.run([sys.executable, Path(__file__).with_name("write_report.py"), out / "results.json", args.docs],
                   check=True)
    log("done:", out / "results.json", args.docs)


if __name__ == "__main__":
    main()
