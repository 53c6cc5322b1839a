"""Simulator: paper-scale cave-chair (512 x 512, 16 spots, 391 bins of 128 ps): time, memory, re-run, accuracy.

Runs pipeline/simulate.py as a user would (a subprocess of the bpy module): wall, CPU and peak memory of
that process, the simulator's own stage timings, the time of a second run on unchanged inputs (every
spot reused); then the accuracy against the independent analytic renderer (torch_recon.contract.analytic) on a
4-spot radiance-unit dataset: peak bin within +-1 bin of the analytic path at the pixel centre, and the
per-pixel energy ratio. Goals (issue 14, 2-core CPU, idle): 512 x 512 in < 15 s and < 1 GB, 128 x 128 in < 3 s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from benchmarks.harness import Suite, report
from benchmarks.harness.datasets import simulate_cli

STAGES = ("window_bound_s", "geometry_pass_s", "render_s", "binning_s", "sensor_model_s", "write_s", "ground_truth_s")


@dataclass(frozen=True)
class Settings:
    resolutions: tuple[int, ...] = (128, 256, 512)
    example: str = "cave-chair"
    spots: int = 16
    accuracy_resolution: int = 128       # 0: skip the accuracy check
    accuracy_spots: int = 4


def stage_timings(stderr: str) -> dict:
    """The simulator's 'timings: name seconds, ...' line."""
    line = next((ln for ln in stderr.splitlines() if ln.startswith("timings:")), "timings:")
    out = {}
    for item in line[len("timings:"):].split(","):
        if item.strip():
            k, v = item.split()
            out[k] = float(v)
    return out


def accuracy(path) -> dict:
    from torch_recon.contract import scenes
    from torch_recon.contract import analytic
    from torch_recon.contract.dataset import load_dataset

    ds = load_dataset(path)
    s = ds.sensor
    mesh, albedo = scenes.cave_chair().trimesh()
    within, ratios = [], []
    for spot, tr in ds.iter_transients():
        ref, parts = analytic.render_two_bounce(mesh, s, [spot.laser_direction], albedo=albedo, subpixel=2,
                                                return_parts=True)
        cube, e_ref = tr.dense(), ref[0].sum(-1)
        lp, x = parts["spots"][0].first_bounce, parts["points"]
        path_m = (np.linalg.norm(lp - s.laser_origin) + np.linalg.norm(x - lp, axis=-1)
                  + np.linalg.norm(x - s.sensor_origin, axis=-1))
        lit = e_ref > 1e-3 * np.median(e_ref[e_ref > 0])
        lit[np.unravel_index(np.argmax(e_ref), e_ref.shape)] = False      # the first-bounce pixel
        peak_ok = np.abs(cube.argmax(-1) - np.floor((path_m - s.start_m) / s.bin_width_m)) <= 1
        within.append(float(peak_ok[lit].mean()))
        ratios.append(cube.sum(-1)[lit] / e_ref[lit])
    r = np.concatenate(ratios)
    p1, p50, p99 = np.percentile(r, [1, 50, 99])
    return {"peak_within_1_bin_min": min(within), "peak_within_1_bin_mean": float(np.mean(within)),
            "energy_ratio_p1": float(p1), "energy_ratio_median": float(p50), "energy_ratio_p99": float(p99),
            "energy_within_5pct": float(np.mean(np.abs(r - 1) < 0.05))}


def run(s: Settings, ctx) -> list[dict]:
    rows = []
    for res in s.resolutions:
        out = ctx.work_dir / f"ds{res}"
        cmd = simulate_cli(s.example, res, s.spots, {}, out)
        first = ctx.run_cli(cmd)
        again = ctx.run_cli(cmd)
        rows.append({"method": "cycles", "scene": s.example, **first.times(), "resolution": res, "spots": s.spots,
                     "rerun_unchanged_wall_s": again.wall_s, "rerun_spots_reused": again.stderr.count("reused"),
                     **{f"stage_{k}": v for k, v in stage_timings(first.stderr).items()}})
        ctx.log(f"  {res} x {res}: {first.wall_s:.1f} s wall, {first.cpu_s:.1f} s CPU, {first.peak_rss_mb:.0f} MB; "
                f"unchanged re-run {again.wall_s:.1f} s")
    if s.accuracy_resolution:
        out = ctx.work_dir / "accuracy"
        run_ = ctx.run_cli(simulate_cli(s.example, s.accuracy_resolution, s.accuracy_spots,
                                        {"photons": 0, "no_gt": True}, out))
        with ctx.timed() as t:
            acc = accuracy(out)
        rows.append({"method": "cycles vs analytic", "scene": s.example, **run_.times(),
                     "resolution": s.accuracy_resolution, "spots": s.accuracy_spots, "check_wall_s": t.wall_s, **acc})
        ctx.log(f"  accuracy at {s.accuracy_resolution} px vs analytic: {acc}")
    return rows


def plot(rows, settings, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    rows = [r for r in rows if r["method"] == "cycles"]
    fig, ax = plt.subplots(figsize=(7, 4))
    x = np.arange(len(rows))
    bottom = np.zeros(len(rows))
    for k in STAGES:
        v = np.array([r.get(f"stage_{k}", 0.0) for r in rows])
        ax.bar(x, v, bottom=bottom, label=k[:-2])
        bottom += v
    ax.plot(x, [r["wall_s"] for r in rows], "k^", label="wall (incl. start-up)")
    ax.axhline(15, color="r", ls="--", lw=1, label="goal at 512: 15 s")
    ax.set_xticks(x, [f"{r['resolution']}²\n{r['peak_rss_mb']:.0f} MB" for r in rows])
    ax.set_ylabel("seconds")
    ax.set_title(f"simulate.py {settings.example}, {settings.spots} spots, 391 bins", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def readme(results) -> str:
    rows = [{**r, "sensor": f"{r['resolution']} x {r['resolution']}"} for r in results["rows"] if r["method"] == "cycles"]
    table = report.markdown_table(rows, [("sensor", "resolution"), ("wall_s", "wall s", ".1f"), ("cpu_s", "CPU s", ".1f"),
                                         ("peak_rss_mb", "peak memory MB", ".0f"),
                                         ("rerun_unchanged_wall_s", "re-run, nothing changed (s)", ".1f")])
    acc = next((r for r in results["rows"] if r["method"] == "cycles vs analytic"), None)
    if acc:
        table += (f"\n\nAgainst the analytic renderer at {acc['resolution']} x {acc['resolution']} ({acc['spots']} spots): "
                  f"peak within +-1 bin for {100 * acc['peak_within_1_bin_min']:.1f} % (worst spot) of lit pixels; "
                  f"energy ratio median {acc['energy_ratio_median']:.3f} (1st-99th percentile "
                  f"{acc['energy_ratio_p1']:.3f}-{acc['energy_ratio_p99']:.3f}).")
    return table


SUITE = Suite("simulate", __doc__.splitlines()[0], run=run, plot=plot, readme=readme,
              quick=Settings(resolutions=(32,), accuracy_resolution=32, accuracy_spots=2), full=Settings())
