"""The one way benchmarks run a reconstruction and score it: the real entry points as subprocesses.

    m = fit(ctx, dataset, "fit128", steps=200)          # torch_recon fit, then evaluate of its mesh
    b = baseline(ctx, dataset, "bflidar128")            # torch_recon baseline, then evaluate
    e = evaluate(ctx, mesh, dataset, "eval")            # torch_recon evaluate alone

Each returns the evaluate report's metrics (report.json: depth L1/PSNR on the dataset's test views,
Chamfer, F-score, ...) plus the method's times: wall_s / cpu_s / peak_rss_mb of the fit (or baseline)
process, which includes start-up, reading, preprocessing and mesh export; evaluation is timed apart
(evaluate_wall_s). A fit that refuses its input (exit 2, one line) raises Refused, so a suite can record
a refusal as a row.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from benchmarks.harness.context import CliError

RECON = ["python", "-m", "torch_recon"]
#: the evaluate report's fields a benchmark row carries
METRICS = ("depth_l1_m", "depth_psnr_db", "depth_l1_m_on_hits", "hit_fraction", "chamfer_m", "fscore",
           "n_test_views", "n_reconstruction_misses")


class Refused(RuntimeError):
    """The entry point refused its input (exit status 2): the message is its one line."""


def _fresh(path: Path) -> Path:
    if path.exists():
        shutil.rmtree(path)
    return path


def _run(ctx, args, timeout):
    run = ctx.run_cli(args, timeout=timeout, check=False)
    if run.returncode == 2:
        lines = (run.stderr.strip() or run.stdout.strip()).splitlines()
        raise Refused(lines[-1] if lines else "refused (exit 2)")
    if run.returncode != 0:
        raise CliError(f"{' '.join(map(str, args))} exited {run.returncode}:\n{run.stderr.strip()[-2000:]}")
    return run


def _mesh_in(folder: Path) -> Path | None:
    """The mesh an entry point wrote into `folder` (.ply preferred: the fastest to read)."""
    return next((folder / f"mesh{ext}" for ext in (".ply", ".glb", ".obj") if (folder / f"mesh{ext}").is_file()), None)


def evaluate(ctx, mesh, dataset, out, timeout=None, args=()) -> dict:
    """`torch_recon evaluate MESH --dataset DATASET --out OUT`: the report's metrics and evaluate_* times."""
    out = _fresh(ctx.work_dir / out)
    run = _run(ctx, [*RECON, "evaluate", mesh, "--dataset", dataset, "--out", out, *args], timeout)
    report = json.loads((out / "report.json").read_text())
    return {**{k: report.get(k) for k in METRICS}, "evaluate_wall_s": run.wall_s, "evaluate_cpu_s": run.cpu_s}


def fit(ctx, source, out, dataset=None, mode="fast", steps=None, max_seconds=None, sets=(), seed=0,
        threads=2, uv=False, timeout=None, args=()) -> dict:
    """`torch_recon fit SOURCE --out OUT` (a dataset directory or a measurements .npz) then evaluate of its
    mesh on `dataset` (default: SOURCE). Returns times, the fit report's steps/stopped and the metrics."""
    fit_dir = _fresh(ctx.work_dir / out)
    cmd = [*RECON, "fit", source, "--out", fit_dir, "--mode", mode, "--no-resume", "--quiet", "--seed", seed,
           "--threads", threads]
    cmd += ["--steps", steps] if steps is not None else []
    cmd += ["--max-seconds", max_seconds] if max_seconds is not None else []
    cmd += [] if uv else ["--no-uv"]
    for s in sets:
        cmd += ["--set", s]
    run = _run(ctx, [*cmd, *args], timeout)
    report = json.loads((fit_dir / "fit.json").read_text())
    mesh = _mesh_in(fit_dir)
    if mesh is None:        # an empty field exports no mesh: every test-view ray misses
        raise Refused(f"fit wrote no mesh ({report.get('mesh_error', 'no surface at the mesh level')})")
    metrics = evaluate(ctx, mesh, dataset or source, f"{out}-eval", timeout=timeout)
    return {**run.times(), "steps": report.get("steps"), "stopped": report.get("stopped"),
            "train_s": report.get("train_seconds"), **metrics}


def baseline(ctx, source, out, measurements=None, voxels=None, grid_search=False, timeout=None, args=()) -> dict:
    """`torch_recon baseline DATASET --out OUT` (Bounce Flash Lidar) then evaluate of its mesh."""
    out_dir = _fresh(ctx.work_dir / out)
    cmd = [*RECON, "baseline", source, "--out", out_dir]
    cmd += ["--measurements", measurements] if measurements is not None else []
    cmd += ["--voxels", voxels] if voxels is not None else []
    cmd += ["--grid-search"] if grid_search else []
    run = _run(ctx, [*cmd, *args], timeout)
    metrics = evaluate(ctx, _mesh_in(out_dir), source, f"{out}-eval", timeout=timeout)
    return {**run.times(), **metrics}
