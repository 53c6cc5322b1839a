"""Batch throughput: procedural scenes simulated, fitted (fast) and evaluated per hour, 1 vs N local workers.

Runs `python -m pipeline.batch PLAN --out DIR --workers W` as a user would, on a fresh output folder
for each worker count (nothing cached), with the same plan: `scenes` procedural rooms, each simulated,
fitted and evaluated. Rows: wall and CPU of the whole run, scenes per hour, speed-up over one worker,
the mean per-task wall time of each stage (from results.json), the machine's 1-minute load at the start,
and the extrapolation to 100k scenes at that rate (docs/batch.md).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass

from benchmarks.harness import Suite

TARGET_SCENES = 100_000


@dataclass(frozen=True)
class Settings:
    scenes: int = 8
    workers: tuple[int, ...] = (1, 2)
    resolution: int = 64
    spots: int = 8
    test_views: int = 8
    fit_steps: int = 200
    fit_resolution: int = 64
    evaluate: bool = True
    first_seed: int = 0


def plan_text(s: Settings) -> str:
    return f"""
[scenes.procedural]
count = {s.scenes}
first_seed = {s.first_seed}

[simulate]
resolution = {s.resolution}
spots = {s.spots}
test_views = {s.test_views}
test_view_resolution = {s.resolution}

[[methods]]
name = "fast"
settings = {{ steps = {s.fit_steps}, "fast.resolution" = {s.fit_resolution}, "fast.coarse_resolution" = {max(8, s.fit_resolution // 2)} }}

[evaluate]
enabled = {str(s.evaluate).lower()}
settings = {{ pictures = false, objects = false, n_surface_samples = 20000, error_images = 0 }}
"""


def _stage_means(out) -> dict:
    data = json.loads((out / "results.json").read_text())
    sums = {}
    for t in data["tasks"]:
        rec = t.get("record") or {}
        if rec.get("status") == "done" and rec.get("wall_s") is not None:
            sums.setdefault(t["stage"], []).append(rec["wall_s"])
    return {f"{st}_task_wall_s": round(sum(v) / len(v), 2) for st, v in sums.items()}


def run(s: Settings, ctx) -> list[dict]:
    plan = ctx.work_dir / "plan.toml"
    plan.write_text(plan_text(s))
    rows, base = [], None
    for w in s.workers:
        out = ctx.work_dir / f"out_w{w}"
        load = os.getloadavg()[0]
        r = ctx.run_cli(["python", "-m", "pipeline.batch", plan, "--out", out, "--workers", w, "--no-progress"],
                        timeout=24 * 3600)
        per_hour = 3600.0 * s.scenes / r.wall_s
        base = base or per_hour
        rows.append({"method": f"batch-{w}w", "scene": f"procedural x{s.scenes}", **r.times(), "workers": w,
                     "scenes": s.scenes, "resolution": s.resolution, "spots": s.spots, "fit_steps": s.fit_steps,
                     "scenes_per_hour": round(per_hour, 1), "speedup": round(per_hour / base, 2),
                     **_stage_means(out), "load_1min_start": round(load, 2),
                     "days_for_100k": round(TARGET_SCENES / per_hour / 24.0, 1)})
        ctx.log(f"  {w} worker(s): {s.scenes} scenes in {r.wall_s:.1f} s -> {per_hour:.0f} scenes/hour "
                f"(load {load:.1f} at start)")
    return rows


def plot(rows, settings, path):
    """Scenes per hour for each worker count (bars)."""
    from benchmarks.harness.report import plot_rows

    return plot_rows(rows, path, title=f"batch: {settings.scenes} procedural scenes, {settings.resolution} px",
                     y="scenes_per_hour", kind="bar")


def readme(results: dict) -> str:
    from benchmarks.harness.report import markdown_table

    cols = [("workers", "local workers"), ("scenes", "scenes"), ("resolution", "px"), ("wall_s", "wall s", ".1f"),
            ("cpu_s", "CPU s", ".1f"), ("scenes_per_hour", "scenes / hour", ".0f"), ("speedup", "speed-up", ".2f"),
            ("simulate_task_wall_s", "simulate s / task", ".1f"), ("fit_task_wall_s", "fit s / task", ".1f"),
            ("evaluate_task_wall_s", "evaluate s / task", ".1f"), ("load_1min_start", "load at start", ".1f"),
            ("days_for_100k", "days for 100k", ".0f")]
    return markdown_table(results["rows"], cols)    # the harness adds the provenance line


SUITE = Suite("batch", "procedural scenes simulated + fitted + evaluated per hour with 1 and 2 local Dask workers",
              quick=Settings(scenes=4, resolution=16, spots=3, test_views=2, fit_steps=10, fit_resolution=24),
              full=Settings(), run=run, plot=plot, readme=readme)
