"""Reconstructor benchmark: fast mode vs the published PlatoNeRF mode on the cave-chair scene.

    python benchmarks/bench_recon.py                       # 128 x 128: fast, platonerf, ablations
    python benchmarks/bench_recon.py --res 128 512         # + fast at 512 x 512 (15 min budget)
    python benchmarks/bench_recon.py --quick               # a smoke run (seconds)

Data: IDEAL measurements of torch_recon/contract/scenes.py's cave-chair (the paper's room and a procedural
chair, 16 of the paper's spots) from the analytic ray caster (torch_recon.recon.synthetic_measurements):
exact visible depth, exact shadows, exact two-bounce paths at pixel centres. No simulator or
preprocessing noise is included; that is measured by the measurements benchmark.
Evaluation: the shared torch_recon.evaluate (depth L1 / PSNR of volume-rendered depth on test views;
Chamfer / F-score of the exported mesh against the scene mesh). Test views: the paper's dolly + orbit
trajectories, subsampled (default 8 dolly + 16 orbit views at 128 x 128 instead of 139 at 512 x 512)
to keep evaluation quick; the paper's numbers use all 139 views.
Each run is a separate process, so its peak memory (max RSS) is its own.
Writes benchmarks/results/recon.json and recon.png (test-view depth L1 against wall time).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from benchmarks.common import RESULTS_DIR, machine_info, machine_line, peak_rss_mb, write_json  # noqa: E402

PAPER_L1_M, PAPER_PSNR_DB = 0.0862, 26.58


def scene_and_views(res: int, n_dolly: int, n_orbit: int, view_res: int):
    from torch_recon.contract.scenes import cave_chair
    from torch_recon.contract.analytic import range_image
    from torch_recon.contract.frames import paper_test_view_cameras
    from torch_recon.recon.synthetic_measurements import ideal_measurements

    sc = cave_chair()
    mesh, _ = sc.trimesh()
    targets = [t for t, e in zip(sc.spot_targets, sc.spot_enabled) if e]
    meas = ideal_measurements(mesh, sc.camera_to_world, res, res, targets, sc.fov_rad, sc.fov_axis)
    cams = paper_test_view_cameras(dolly_count=n_dolly, orbit_count=n_orbit)
    gt = np.stack([range_image(mesh, c, view_res, view_res, sc.fov_rad) for c in cams]).astype(np.float32)
    return mesh, meas, cams, gt


def test_view_metrics(model, cams, gt, fov):
    """Depth metrics (torch_recon.evaluate.depth_metrics) of each mode's own volume rendering, with the
    evaluator's conventions (depth normalised by opacity; below opacity 0.5 a miss, counted as 0)."""
    from torch_recon.evaluate import depth_metrics
    from torch_recon.recon.api import render_model_depth

    vr = gt.shape[-1]
    pred = np.stack([render_model_depth(model, c, vr, vr, fov, min_opacity=0.5) for c in cams])
    m = depth_metrics(pred, gt)
    return {k: m[k] for k in ("depth_l1_m", "depth_psnr_db", "n_valid_pixels", "n_excluded_pixels",
                              "n_reconstruction_misses")}


def run_single(args) -> dict:
    """One fit in this process (called through a subprocess by main)."""
    import torch

    from torch_recon.contract.analytic import range_image
    from torch_recon.evaluate import surface_metrics
    from torch_recon.recon import FitConfig, fit, override

    t0 = time.perf_counter()
    mesh, meas, cams, gt = scene_and_views(args.res, args.dolly, args.orbit, args.view_res)
    data_s = time.perf_counter() - t0
    cfg = FitConfig(mode=args.mode, progress=False, threads=args.threads, max_seconds=args.budget,
                    eval_every_s=args.eval_every, resume=False)
    if args.mode == "fast":
        cfg.fast.resolution = args.grid
        cfg.fast.coarse_resolution = max(8, args.grid // 2)
    cfg = override(cfg, args.set or [])
    curve, eval_time = [], [0.0]
    # the learning curve uses every 6th test view at half resolution (cheap); final numbers use all
    # views, except for platonerf, whose MLP makes them too slow here (its numbers are on the subset)
    half = args.view_res // 2 if args.view_res >= 64 else args.view_res
    sub_cams = cams[::6]
    sub_gt = np.stack([range_image(mesh, c, half, half, meas.fov_rad) for c in sub_cams]).astype(np.float32)

    def on_eval(model, step, seconds):
        te = time.perf_counter()
        m = test_view_metrics(model, sub_cams, sub_gt, meas.fov_rad)
        curve.append({"step": step, "train_seconds": seconds, "subset": True, **m})
        eval_time[0] += time.perf_counter() - te
        return m

    out = Path(args.workdir) / f"{args.label}"
    if out.exists():
        import shutil
        shutil.rmtree(out)
    t1 = time.perf_counter()
    r = fit(meas, mode=args.mode, out=out, config=cfg, on_eval=on_eval if args.eval_every else None)
    wall = time.perf_counter() - t1 - eval_time[0]      # the learning-curve evaluations are not counted
    sub = test_view_metrics(r.model, sub_cams, sub_gt, meas.fov_rad)
    full = args.mode == "fast"
    tv = test_view_metrics(r.model, cams, gt, meas.fov_rad) if full else sub
    surf = surface_metrics(r.mesh, mesh, 0.05, n_samples=100_000) if r.mesh is not None else {}
    curve.append({"step": r.train.steps_done, "train_seconds": r.train.train_seconds, "subset": True, **sub})
    return {"label": args.label, "mode": args.mode, "resolution": args.res, "grid": args.grid,
            "settings_override": args.set or [], "threads": torch.get_num_threads(),
            "wall_seconds": wall, "setup_seconds": r.setup_seconds, "train_seconds": r.train.train_seconds,
            "steps": r.train.steps_done, "stopped": r.train.stopped, "peak_rss_mb": peak_rss_mb(),
            "data_seconds": data_s, "loadavg_after": list(__import__("os").getloadavg()), **tv,
            "chamfer_m": surf.get("chamfer_m"), "fscore": surf.get("fscore"),
            "n_test_views": len(cams) if full else len(sub_cams), "test_view_res": args.view_res if full else half,
            "subset_l1_m": sub["depth_l1_m"], "subset_psnr_db": sub["depth_psnr_db"], "curve": curve}


def _box(model):
    lo, hi = (model.grid.box.bbox_min, model.grid.box.bbox_max) if hasattr(model, "grid") else model.bbox
    return lo.cpu().numpy(), hi.cpu().numpy()


def launch(label, mode, res, budget, extra, common) -> dict:
    cmd = [sys.executable, __file__, "--single", "--label", label, "--mode", mode, "--res", str(res),
           "--budget", str(budget), *common, *extra]
    print(f"  running {label} ...", flush=True)
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        print(p.stdout[-2000:], p.stderr[-4000:])
        raise SystemExit(f"{label} failed")
    return json.loads(p.stdout.strip().splitlines()[-1])


def compare(runs):
    """platonerf vs fast at the same resolution: time to reach the fast mode's final (subset) L1."""
    for pn in runs:
        fast = next((r for r in runs if r["mode"] == "fast" and r["label"] == f"fast-{pn['resolution']}"), None)
        if pn["mode"] != "platonerf" or fast is None:
            continue
        t_reach = time_to_reach(pn["curve"], fast["curve"][-1]["depth_l1_m"])
        pn["fast_subset_l1_m"] = fast["curve"][-1]["depth_l1_m"]
        pn["time_to_fast_l1_s"] = t_reach
        pn["speedup_vs_fast"] = (t_reach / fast["train_seconds"]) if t_reach else None
        pn["speedup_lower_bound"] = None if t_reach else pn["train_seconds"] / max(fast["train_seconds"], 1e-9)


def time_to_reach(curve, target):
    """First training time at which the (subset) learning curve reaches `target` L1."""
    for c in curve:
        if c["depth_l1_m"] <= target:
            return c["train_seconds"]
    return None


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", type=int, nargs="+", default=[128])
    ap.add_argument("--quick", action="store_true", help="tiny budgets: a smoke run")
    ap.add_argument("--no-ablations", action="store_true")
    ap.add_argument("--no-platonerf", action="store_true")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--dolly", type=int, default=8)
    ap.add_argument("--orbit", type=int, default=16)
    ap.add_argument("--view-res", type=int, default=128)
    ap.add_argument("--workdir", default="/tmp/bench_recon")
    ap.add_argument("--merge", action="store_true", help="keep other runs already in results/recon.json")
    ap.add_argument("--table-only", action="store_true", help="reprint the table and plot from results/recon.json")
    # single-run arguments (internal)
    ap.add_argument("--single", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--label", default="run")
    ap.add_argument("--mode", default="fast")
    ap.add_argument("--budget", type=float, default=None)
    ap.add_argument("--grid", type=int, default=128)
    ap.add_argument("--eval-every", type=float, default=None)
    ap.add_argument("--set", nargs="*", default=None)
    args = ap.parse_args()
    if args.single:
        args.res = args.res[0]
        print(json.dumps(run_single(args)))
        return
    common = ["--threads", str(args.threads), "--dolly", str(args.dolly), "--orbit", str(args.orbit),
              "--view-res", str(args.view_res), "--workdir", args.workdir]
    if args.quick:
        common = ["--threads", str(args.threads), "--dolly", "2", "--orbit", "2", "--view-res", "32",
                  "--workdir", args.workdir]
    info = machine_info()
    print(machine_line(info))
    runs = []
    budget128 = 20 if args.quick else 300
    for res in args.res:
        grid = 48 if args.quick else 128          # the same grid at 512: denser rays, same voxels
        budget = budget128 if res <= 128 else (40 if args.quick else 900)
        fast = launch(f"fast-{res}", "fast", res, budget, ["--grid", str(grid), "--eval-every",
                                                               str(5 if args.quick else 20)], common)
        runs.append(fast)
        if res == args.res[0] and not args.no_platonerf:
            pn_budget = max(10.0, fast["wall_seconds"]) if not args.quick else 10
            pn = launch(f"platonerf-{res}", "platonerf", res, pn_budget,
                        ["--eval-every", str(max(5.0, pn_budget / 3))], common)
            runs.append(pn)
            t_reach = time_to_reach(pn["curve"], fast["curve"][-1]["depth_l1_m"])   # same view subset
            pn["time_to_fast_l1_s"] = t_reach
            pn["speedup_vs_fast"] = (t_reach / fast["train_seconds"]) if t_reach else None
            pn["speedup_lower_bound"] = None if t_reach else pn["train_seconds"] / max(fast["train_seconds"], 1e-9)
        if res == args.res[0] and not args.no_ablations:
            ab_budget = 10 if args.quick else 90
            g = ["--grid", str(grid)]
            for label, sets in (("fast-init-only", ["steps=0", "fast.coarse_fraction=0"]),
                                ("fast-no-carving", ["fast.carve_min_lit=1000000"]),
                                ("fast-no-pruning", ["fast.occupancy_threshold=-1"])):
                runs.append(launch(f"{label}-{res}", "fast", res, ab_budget, g + ["--set", *sets], common))
    prev = RESULTS_DIR / "recon.json"
    if args.table_only:
        out = json.loads(prev.read_text())
        compare(out["runs"])
        print_table(out["runs"], out["machine"])
        write_json(prev, out)
        plot(out["runs"], RESULTS_DIR / "recon.png")
        return
    if args.merge and prev.is_file():    # keep earlier runs (e.g. 128 x 128) when adding others (512 x 512)
        mine = {r["label"] for r in runs}
        runs = [r for r in json.loads(prev.read_text())["runs"] if r["label"] not in mine] + runs
    compare(runs)
    print_table(runs, info)
    out = {"machine": info, "data": "ideal measurements (analytic ray casting) of cave-chair, 16 spots",
           "test_views": {"dolly": args.dolly, "orbit": args.orbit, "resolution": args.view_res},
           "paper": {"depth_l1_m": PAPER_L1_M, "depth_psnr_db": PAPER_PSNR_DB}, "runs": runs}
    write_json(RESULTS_DIR / "recon.json", out)
    plot(runs, RESULTS_DIR / "recon.png")


def print_table(runs, info):
    print(f"\ncpu: {info.get('cpu')}  cores: {info.get('cpu_count')}  torch {info.get('torch')}")
    hdr = f"{'run':28s} {'res':>4s} {'wall s':>8s} {'train s':>8s} {'steps':>6s} {'peak MB':>8s} " \
          f"{'L1 m':>8s} {'PSNR dB':>8s} {'Chamfer m':>10s} {'F@5cm':>6s}  stop"
    print(hdr)
    print("-" * len(hdr))
    for r in runs:
        ch = "-" if r.get("chamfer_m") is None else f"{r['chamfer_m']:.4f}"
        fs = "-" if r.get("fscore") is None else f"{r['fscore']:.3f}"
        print(f"{r['label']:28s} {r['resolution']:4d} {r['wall_seconds']:8.1f} {r['train_seconds']:8.1f} "
              f"{r['steps']:6d} {r['peak_rss_mb']:8.0f} {r['depth_l1_m']:8.4f} {r['depth_psnr_db']:8.2f} "
              f"{ch:>10s} {fs:>6s}  {r['stopped']}")
    print(f"{'paper PlatoNeRF (16 spots)':28s} {'512':>4s} {'hours':>8s} {'':8s} {'200000':>6s} {'':8s} "
          f"{PAPER_L1_M:8.4f} {PAPER_PSNR_DB:8.2f}")
    for r in runs:
        if r["mode"] == "platonerf":
            if r.get("time_to_fast_l1_s"):
                print(f"platonerf reached the fast mode's L1 after {r['time_to_fast_l1_s']:.0f} s: "
                      f"{r['speedup_vs_fast']:.1f}x the fast mode's training time")
            else:
                print(f"platonerf did not reach the fast mode's L1 ({r['fast_subset_l1_m']:.4f} m on the view subset) "
                      f"within {r['train_seconds']:.0f} s of training (its subset L1 then: {r['depth_l1_m']:.4f} m); "
                      f"time ratio > {r['speedup_lower_bound']:.1f}x")


def plot(runs, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for r in runs:
        if len(r["curve"]) < 2 and not r["label"].startswith(("fast-1", "fast-5", "platonerf")):
            continue
        xs = [c["train_seconds"] + r["setup_seconds"] for c in r["curve"]]
        ax.plot(xs, [c["depth_l1_m"] for c in r["curve"]], marker="o", ms=3, label=r["label"])
    ax.axhline(PAPER_L1_M, color="k", ls="--", lw=1, label="paper PlatoNeRF (GPU, hours)")
    ax.set_xlabel("wall time (s): setup + training")
    ax.set_ylabel("test-view depth L1 (m)")
    ax.set_yscale("log")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("cave-chair, ideal measurements, 16 spots")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
