"""The one way benchmarks run a reconstruction and score it: the real entry points as subprocesses.

    p = preprocess(ctx, dataset, "meas", shadow_threshold=0.25)   # torch_recon preprocess -> .npz
    m = fit(ctx, dataset, "fit128", steps=200)          # torch_recon fit, then evaluate of its mesh
    b = baseline(ctx, dataset, "bflidar128")            # torch_recon baseline, then evaluate
    e = evaluate(ctx, mesh, dataset, "eval")            # torch_recon evaluate alone

Each returns the evaluate report's metrics (report.json: depth L1/PSNR on the dataset's test views,
Chamfer, F-score, ...) plus the method's times: wall_s / cpu_s / peak_rss_mb of the fit (or baseline)
process, which includes start-up, reading, preprocessing and mesh export; evaluation is timed apart
(evaluate_wall_s). A fit that refuses its input (exit 2, one line) raises Refused, one whose field has no
surface to mesh raises NoSurface (a Refused that carries the run's times), so a suite records either as a
row (refused_row).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from benchmarks.harness.context import CliError
from benchmarks.harness.report import fmt

RECON = ["python", "-m", "torch_recon"]
#: the evaluate report's fields a benchmark row carries
METRICS = ("depth_l1_m", "depth_psnr_db", "depth_l1_m_on_hits", "hit_fraction", "chamfer_m", "fscore",
           "n_test_views", "n_reconstruction_misses")
#: the object-level numbers (torch_recon.evaluation.objects; issue 11's targets) a result carries, by object_fields
OBJECT_FIELDS = ("n_test_views_invalid", "obj_f1cm", "obj_f2cm", "obj_f5cm", "hidden_recall_2cm", "visible_recall_2cm",
                 "spurious", "objects_spurious", "room_off_surface", "normal_consistency", "obj_normals",
                 "degenerate_faces", "objects")


class Refused(RuntimeError):
    """The entry point refused its input (exit status 2): the message is its one line."""
    outcome = "refused"

    def __init__(self, message: str, times: dict | None = None):
        super().__init__(message)
        self.times = times or {}


class NoSurface(Refused):
    """The fit ran but its field has no surface at the mesh level (e.g. still empty after a short budget):
    there is no mesh to evaluate (every test-view ray would miss)."""
    outcome = "no_surface"


TIMES = ("wall_s", "cpu_s", "peak_rss_mb")


def row(method: str, scene: str, result: dict, fields=METRICS, **extra) -> dict:
    """A results row: method, scene, the result's times, then `extra`, then the result's `fields`."""
    return {"method": method, "scene": scene, **{k: result.get(k) for k in TIMES}, **extra,
            **{k: result.get(k) for k in fields}}


def refused_row(method: str, scene: str, exc: Refused, times: dict | None = None, **extra) -> dict:
    """The row of a refused run (or one without a surface): its times if it ran, no metrics, and its message
    under 'refused' or 'no_surface'."""
    times = exc.times if times is None else times
    return {"method": method, "scene": scene, **{k: times.get(k) for k in TIMES}, **extra, exc.outcome: str(exc)}


def failure(row: dict) -> str | None:
    """'refused' / 'no surface' for a row refused_row made, else None (what a table shows instead of numbers)."""
    return "refused" if row.get("refused") else "no surface" if row.get("no_surface") else None


def _fresh(path: Path) -> Path:
    if path.exists():
        shutil.rmtree(path)
    return path


def _run(ctx, args, timeout):
    """ctx.run_cli; exit status 2 (the project's 'bad input': one line) raises Refused."""
    try:
        return ctx.run_cli(args, timeout=timeout)
    except CliError as exc:
        if exc.returncode == 2:
            ctx.log(f"  -> refused: {exc.last_line}")
            raise Refused(exc.last_line or "refused (exit 2)") from None
        raise


def _mesh_in(folder: Path) -> Path | None:
    """The mesh an entry point wrote into `folder` (.ply preferred: the fastest to read)."""
    return next((folder / f"mesh{ext}" for ext in (".ply", ".glb", ".obj") if (folder / f"mesh{ext}").is_file()), None)


def preprocess(ctx, dataset, out, timeout=None, **settings) -> dict:
    """`torch_recon preprocess DATASET --out OUT.npz --KEY VALUE ...` (PreprocessSettings by their flags,
    e.g. shadow_threshold=0.25, background="median"): the .npz path ("measurements") and the times."""
    npz = ctx.work_dir / f"{out}.npz"
    npz.unlink(missing_ok=True)
    cmd = [*RECON, "preprocess", dataset, "--out", npz]
    for key, value in settings.items():
        cmd += [f"--{key.replace('_', '-')}", value]
    run = _run(ctx, cmd, timeout)
    return {**run.times(), "measurements": npz}


def combined(*timings: dict) -> dict:
    """Times of stages run one after the other: wall and CPU add up, peak memory is the largest."""
    return {"wall_s": sum(t["wall_s"] for t in timings), "cpu_s": sum(t["cpu_s"] for t in timings),
            "peak_rss_mb": max(t["peak_rss_mb"] for t in timings)}


def object_fields(report: dict) -> dict:
    """OBJECT_FIELDS from an evaluate report (report.json): object F-score at 1 / 2 / 5 cm (mean over the
    scene's objects), hidden / visible recall at 2 cm, spurious-surface fraction (whole mesh, objects'
    region), the room's surface off by more than 5 mm (dents and bumps on walls), normal consistency (whole mesh; per object as obj_normals, the mean over the scene's objects: the
    lumps the distances miss), degenerate faces, the objects' names (None where the dataset has no labels)."""
    om = report.get("object_metrics") or {}
    summ, scene = om.get("summary", {}), om.get("scene", {})
    return {"n_test_views_invalid": report.get("n_test_views_invalid"),
            "obj_f1cm": summ.get("fscore@1cm"), "obj_f2cm": summ.get("fscore@2cm"), "obj_f5cm": summ.get("fscore@5cm"),
            "hidden_recall_2cm": summ.get("recall_hidden@2cm"), "visible_recall_2cm": summ.get("recall_visible@2cm"),
            "spurious": scene.get("spurious_fraction"), "objects_spurious": scene.get("objects_spurious_fraction"),
            "room_off_surface": scene.get("room_off_surface_fraction"),
            "normal_consistency": scene.get("normal_consistency"),
            "obj_normals": summ.get("normal_consistency"), "degenerate_faces": scene.get("degenerate_faces"),
            "objects": ",".join(om.get("objects", {})) or None}


def evaluate(ctx, mesh, dataset, out, timeout=None, args=()) -> dict:
    """`torch_recon evaluate MESH --dataset DATASET --out OUT`: the report's metrics, its object-level
    numbers (object_fields) and evaluate_* times."""
    out = _fresh(ctx.work_dir / out)
    run = _run(ctx, [*RECON, "evaluate", mesh, "--dataset", dataset, "--out", out, *args], timeout)
    report = json.loads((out / "report.json").read_text())
    return {**{k: report.get(k) for k in METRICS}, **object_fields(report), "evaluate_wall_s": run.wall_s,
            "evaluate_cpu_s": run.cpu_s}


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
        ctx.log(f"  -> {out}: {run.wall_s:.1f} s ({report.get('steps')} steps), no surface to evaluate")
        raise NoSurface(f"fit wrote no mesh ({report.get('mesh_error', 'no surface at the mesh level')})",
                        {**run.times(), "steps": report.get("steps")})
    metrics = evaluate(ctx, mesh, dataset or source, f"{out}-eval", timeout=timeout)
    _log_result(ctx, out, run, metrics, f"{report.get('steps')} steps, {report.get('stopped')}")
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
    _log_result(ctx, out, run, metrics, "BF Lidar")
    return {**run.times(), **metrics}


def _log_result(ctx, tag, run, metrics, note):
    ctx.log(f"  -> {tag}: {run.wall_s:.1f} s ({note}), depth L1 {fmt(metrics['depth_l1_m'], '.4f')} m, "
            f"PSNR {fmt(metrics['depth_psnr_db'], '.2f')} dB")
