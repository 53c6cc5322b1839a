"""Reconstructors on ideal measurements: fast mode vs the platonerf mode, and fast-mode parts switched off.

Data: IDEAL measurements of the cave-chair scene (torch_recon/contract/scenes.py, 16 of the paper's spots) from the
analytic ray caster (torch_recon.recon.synthetic_measurements): exact visible depth, exact shadows, exact
two-bounce paths at pixel centres, saved as a measurements .npz; no simulator or preprocessing error is
included (the 'fast (cycles)' row fits the Cycles dataset of the same scene and sensor instead, so the
difference between the two is what measurement error costs). Every fit goes through the harness runners
(`torch_recon fit` of the .npz, then `torch_recon evaluate` on the Cycles dataset's test views and
ground-truth mesh). Rows: fast, platonerf (a time budget), fast with only its initialisation (0 steps),
without shadow carving, without occupancy pruning.
"""

from __future__ import annotations

from dataclasses import dataclass

from benchmarks.harness import Refused, Suite, report, runners

VARIANTS = {"fast, init only": ("steps=0", "fast.coarse_fraction=0"),
            "fast, no carving": ("fast.carve_min_lit=1000000",),
            "fast, no pruning": ("fast.occupancy_threshold=-1",)}


@dataclass(frozen=True)
class Settings:
    resolution: int = 128
    grid: int = 128
    budget_s: float = 300.0                # fast-mode fits
    reference_budget_s: float | None = 300.0  # platonerf (None: skip)
    variants: bool = True                  # the fast mode with parts switched off
    test_views: int = 24
    test_view_resolution: int = 128


def ideal_npz(ctx, res: int):
    from torch_recon.contract.scenes import cave_chair
    from torch_recon.recon.synthetic_measurements import ideal_measurements
    with ctx.timed() as t:
        sc = cave_chair()
        mesh, _ = sc.trimesh()
        targets = [p for p, e in zip(sc.spot_targets, sc.spot_enabled) if e]
        meas = ideal_measurements(mesh, sc.camera_to_world, res, res, targets, sc.fov_rad, sc.fov_axis)
        path = meas.save(ctx.work_dir / f"ideal{res}.npz")
    return path, t


def run(s: Settings, ctx) -> list[dict]:
    data = ctx.dataset("cave-chair", s.resolution, test_views=s.test_views, test_view_resolution=s.test_view_resolution)
    ideal, t = ideal_npz(ctx, s.resolution)
    ctx.log(f"  ideal measurements {s.resolution} px: {t.wall_s:.1f} s")
    grid = (f"fast.resolution={s.grid}", f"fast.coarse_resolution={max(8, s.grid // 2)}")
    plan = [("fast", "fast (ideal)", ideal, {"max_seconds": s.budget_s, "sets": grid}),
            ("fast", "fast (cycles)", data, {"max_seconds": s.budget_s, "sets": grid})]
    if s.reference_budget_s is not None:
        plan.append(("platonerf", "platonerf (ideal)", ideal, {"mode": "platonerf", "max_seconds": s.reference_budget_s}))
    if s.variants:
        plan += [("fast", f"{name} (ideal)", ideal, {"max_seconds": s.budget_s, "sets": grid + sets})
                 for name, sets in VARIANTS.items()]
    rows = []
    for method, label, source, kw in plan:
        tag = label.replace(" ", "-").replace(",", "").replace("(", "").replace(")", "")
        try:
            r = runners.fit(ctx, source, tag, dataset=data, **kw)
        except Refused as exc:
            rows.append(runners.refused_row(method, "cave-chair", exc, label=label, steps=exc.times.get("steps")))
            continue
        rows.append(runners.row(method, "cave-chair", r, ("steps", "stopped", "train_s", *runners.METRICS),
                                label=label, resolution=s.resolution, grid=s.grid))
    return rows


def readme(results) -> str:
    rows = [{**r, "depth_l1_m": runners.failure(r) or r.get("depth_l1_m")} for r in results["rows"]]
    return report.markdown_table(rows, [
        ("label", "run"), ("wall_s", "wall s", ".1f"), ("steps", "steps"), ("peak_rss_mb", "peak MB", ".0f"),
        ("depth_l1_m", "depth L1 m"), ("depth_psnr_db", "PSNR dB"), ("chamfer_m", "Chamfer m"), ("fscore", "F@5cm")])


SUITE = Suite("recon", __doc__.splitlines()[0], run=run, readme=readme,
              plot=lambda rows, s, path: report.plot_rows(rows, path, y="depth_l1_m", label="label",
                                                          hline=report.paper_line(),
                                                          title="cave-chair, ideal measurements"),
              quick=Settings(resolution=32, grid=48, budget_s=30.0, reference_budget_s=15.0, variants=False,
                             test_views=6, test_view_resolution=32),
              full=Settings())
