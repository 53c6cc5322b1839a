"""Simulator benchmark: paper-scale cave-chair (512 x 512, 16 spots, 391 bins of 128 ps).

Runs `pipeline/simulate.py` as a user would (a subprocess, bpy module), prints wall time and
peak memory (the child's max RSS), the simulator's own stage timings, the time of a second
run on unchanged inputs (every spot reused), and, side by side, the accuracy against the
independent analytic renderer at 128 x 128 (peak bin within +-1 bin of the analytic path at
the pixel centre; per-pixel energy ratio). Target: < 2 min and < 4 GB on a 2-core CPU.

    python benchmarks/bench_simulate.py [--resolutions 128,256,512] [--spots 16]
Writes benchmarks/results/simulate.json and benchmarks/results/simulate.png.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from benchmarks.common import REPO_ROOT, RESULTS_DIR, machine_info, write_json  # noqa: E402

SIM = [sys.executable, str(REPO_ROOT / "pipeline" / "simulate.py")]


def run_sim(out, *args):
    """(wall s, child peak RSS MiB, stage timings) of one simulate.py run."""
    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    before = ru0.ru_maxrss
    t0 = time.perf_counter()
    proc = subprocess.run(SIM + ["--out", str(out), *map(str, args)], cwd=REPO_ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"simulate failed:\n{proc.stderr[-2000:]}")
    ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    peak = ru1.ru_maxrss / 1024.0
    cpu = (ru1.ru_utime + ru1.ru_stime) - (ru0.ru_utime + ru0.ru_stime)
    line = next((ln for ln in proc.stderr.splitlines() if ln.startswith("timings:")), "timings:")
    stages = {}
    for item in line[len("timings:"):].split(","):
        if item.strip():
            k, v = item.split()
            stages[k] = float(v)
    # ru_maxrss of children is the max over all children so far: report it only when it grew
    stages["cpu_s"] = round(cpu, 2)       # user + system CPU time: less sensitive to other load
    return wall, (peak if peak > before / 1024.0 else float("nan")), stages, proc.stderr.count("reused")


def accuracy(out) -> dict:
    from torch_recon.contract import scenes
    from torch_recon import analytic
    from torch_recon.contract.dataset import load_dataset

    ds = load_dataset(out)
    s = ds.sensor
    mesh, albedo = scenes.cave_chair().trimesh()
    within, ratios = [], []
    for spot, tr in ds.iter_transients():
        ref, parts = analytic.render_two_bounce(mesh, s, [spot.laser_direction], albedo=albedo, subpixel=2,
                                                return_parts=True)
        cube, e_ref = tr.dense(), ref[0].sum(-1)
        l = parts["spots"][0].first_bounce
        x = parts["points"]
        path = np.linalg.norm(l - s.laser_origin) + np.linalg.norm(x - l, axis=-1) + np.linalg.norm(x - s.sensor_origin,
                                                                                                   axis=-1)
        lit = e_ref > 1e-3 * np.median(e_ref[e_ref > 0])
        lit[np.unravel_index(np.argmax(e_ref), e_ref.shape)] = False
        within.append(float((np.abs(cube.argmax(-1) - np.floor((path - s.start_m) / s.bin_width_m)) <= 1)[lit].mean()))
        ratios.append(cube.sum(-1)[lit] / e_ref[lit])
    r = np.concatenate(ratios)
    return {"resolution": s.width, "spots": len(within), "peak_within_1_bin_min": min(within),
            "peak_within_1_bin_mean": float(np.mean(within)),
            "energy_ratio_percentiles_1_50_99": np.percentile(r, [1, 50, 99]).round(4).tolist(),
            "energy_within_5pct": float(np.mean(np.abs(r - 1) < 0.05))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--resolutions", default="128,256,512")
    ap.add_argument("--spots", type=int, default=16)
    args = ap.parse_args(argv)
    resolutions = [int(r) for r in args.resolutions.split(",")]
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_simulate_") as tmp:
        for res in resolutions:
            out = Path(tmp) / f"ds{res}"
            common = ["--example", "cave-chair", "--resolution", res, "--spots", args.spots]
            load_before = os.getloadavg()[0]
            wall, peak, stages, _ = run_sim(out, *common)
            load_after = os.getloadavg()[0]
            rerun, _, _, reused = run_sim(out, *common)
            row = {"resolution": res, "spots": args.spots, "bins": 391, "wall_s": round(wall, 2),
                   "peak_rss_mib": round(peak, 1), "stages_s": stages, "rerun_unchanged_s": round(rerun, 2),
                   "rerun_spots_reused": reused,
                   "load_average_1min_before_after": [round(load_before, 2), round(load_after, 2)]}
            print(f"{res}x{res}, {args.spots} spots, 391 bins: {wall:.1f} s wall, peak {peak:.0f} MiB; "
                  f"unchanged rerun {rerun:.1f} s ({reused} spots reused); stages {stages}; "
                  f"load average {load_before:.1f} -> {load_after:.1f} on {os.cpu_count()} cores", flush=True)
            rows.append(row)
        acc_out = Path(tmp) / "acc128"
        run_sim(acc_out, "--example", "cave-chair", "--resolution", 128, "--spots", 4, "--photons", 0, "--no-gt")
        acc = accuracy(acc_out)
        print(f"accuracy at 128x128 vs analytic: {acc}", flush=True)
    result = {"benchmark": "simulate", "scene": "cave-chair", "target": "< 120 s and < 4096 MiB at 512x512",
              "machine": machine_info(), "runs": rows, "accuracy": acc}
    path = write_json(RESULTS_DIR / "simulate.json", result)
    plot(rows, RESULTS_DIR / "simulate.png")
    print(f"wrote {path} and {RESULTS_DIR / 'simulate.png'}")
    return 0


def plot(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = ["window_bound_s", "geometry_pass_s", "render_s", "binning_s", "sensor_model_s", "write_s", "ground_truth_s"]
    fig, ax = plt.subplots(figsize=(7, 4))
    x = np.arange(len(rows))
    bottom = np.zeros(len(rows))
    for k in keys:
        v = np.array([r["stages_s"].get(k, 0.0) for r in rows])
        ax.bar(x, v, bottom=bottom, label=k.replace("_s", ""))
        bottom += v
    ax.plot(x, [r["wall_s"] for r in rows], "k^", label="wall (incl. start-up)")
    ax.axhline(120, color="r", ls="--", lw=1, label="target 2 min")
    ax.set_xticks(x, [f"{r['resolution']}²\n{r['peak_rss_mib']:.0f} MiB" for r in rows])
    ax.set_ylabel("seconds")
    load = max(max(r["load_average_1min_before_after"]) for r in rows)
    ax.set_title(f"simulate.py cave-chair, {rows[0]['spots']} spots, 391 bins "
                 f"({os.cpu_count()} cores, load average up to {load:.1f})", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    sys.exit(main())
