"""The whole chain as a user runs it: simulate -> fit (fast) -> evaluate, per sensor resolution.

Every stage is a subprocess of its real entry point (pipeline/simulate.py, torch_recon fit, torch_recon
evaluate), so the times include start-up and file I/O; simulation is run fresh here (not the dataset
cache) because its time is part of the chain. Error: depth L1 / PSNR on the dataset's test views,
Chamfer and F-score against the ground-truth mesh (torch_recon evaluate's report).
"""

from __future__ import annotations

from dataclasses import dataclass

from benchmarks.harness import Suite, report, runners
from benchmarks.harness.datasets import simulate_cli

FIELDS = ("evaluate_wall_s", "steps", "depth_l1_m", "depth_psnr_db", "chamfer_m", "fscore", "n_test_views")


@dataclass(frozen=True)
class Settings:
    resolutions: tuple[int, ...] = (128, 512)
    example: str = "cave-chair"
    fit_seconds: float = 900.0
    steps: int | None = None           # None: the fast mode's default
    test_views: int | None = None      # None: the simulator's default (the paper's 139)
    test_view_resolution: int | None = None
    seed: int = 0
    sets: tuple[str, ...] = ()         # FitConfig overrides, e.g. fast.resolution=48


def run(s: Settings, ctx) -> list[dict]:
    rows = []
    for res in s.resolutions:
        data = ctx.work_dir / f"sim{res}"
        opts = {"seed": s.seed, "test_views": s.test_views, "test_view_resolution": s.test_view_resolution}
        sim = ctx.run_cli(simulate_cli(s.example, res, 16, opts, data))
        r = runners.fit(ctx, data, f"fit{res}", max_seconds=s.fit_seconds, steps=s.steps, seed=s.seed, uv=True,
                         sets=s.sets)
        rows.append(runners.row("fast", s.example, r, FIELDS, resolution=res, simulate_wall_s=sim.wall_s,
                                simulate_cpu_s=sim.cpu_s, simulate_peak_rss_mb=sim.peak_rss_mb))
    return rows


def plot(rows, settings, path):
    report.plot_rows(rows, path, y="depth_l1_m", label=lambda r: f"fast, {r['resolution']} px",
                     hline=report.paper_line(), title=f"{settings.example}, Cycles-simulated, 16 spots")


def readme(results) -> str:
    rows = [{**r, "sensor": f"{r['resolution']} x {r['resolution']}"} for r in results["rows"]]
    rows.append({"sensor": "paper (PlatoNeRF, 512 x 512, 200k steps on a GPU)", "wall_s": "hours", **report.paper_result()})
    return report.markdown_table(rows, [("sensor", "sensor"), ("wall_s", "fast-mode fit (wall s, incl. preprocessing)", ".1f"),
                                        ("peak_rss_mb", "peak RSS (MB)", ".0f"), ("depth_l1_m", "depth L1 (m)", ".4f"),
                                        ("depth_psnr_db", "PSNR (dB)", ".2f"), ("chamfer_m", "Chamfer (m)", ".4f"),
                                        ("fscore", "F-score @ 5 cm", ".3f")])


SUITE = Suite("chain", __doc__.splitlines()[0], run=run, plot=plot, readme=readme,
              quick=Settings(resolutions=(32,), fit_seconds=60.0, steps=30, test_views=6, test_view_resolution=32,
                             sets=("fast.resolution=48", "fast.coarse_resolution=24")),
              full=Settings())
