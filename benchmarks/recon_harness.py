"""Shared harness of bench_headline.py and bench_ablations.py: Cycles datasets (cached), preprocessing,
fits with an error-vs-time curve, the BF Lidar baseline, and the evaluation on the dataset's test views.

Datasets come from the Cycles simulator (`pipeline/simulate.py --example NAME ...`) and are cached
under benchmarks/results/data/ (gitignored), keyed by every simulator argument; an existing
complete dataset with the same key is reused. Depth metrics are torch_recon.evaluate's
(depth_metrics: L1 and PSNR over the test views' pixels whose ground-truth ray hits something; a
reconstruction ray that hits nothing counts as depth 0). Every method is evaluated the same way: its
opacity volume -> marching cubes (torch_recon.mesh_export.mesh_from_volume, the exported mesh's
path, without UVs) -> Embree ray casting of the test views. (Volume rendering the 'platonerf' MLP for
every test pixel costs minutes per evaluation on a CPU; the volume it exports costs one pass.)
Wall time of a method = preprocessing + its own time (fit setup + training + volume extraction, or
carving); evaluation time is not counted.
"""

from __future__ import annotations

import hashlib
import json
import math
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchmarks.common import REPO_ROOT, RESULTS_DIR

DATA_DIR = RESULTS_DIR / "data"
PAPER_L1_M, PAPER_PSNR_DB = 0.0862, 26.58


def ensure_dataset(scene: str, resolution: int, test_views: int, view_res: int, extra=(), log=print):
    """Path of a cached simulator dataset (simulated now when missing) and the seconds simulation took."""
    args = ["--example", scene, "--resolution", str(resolution), "--test-views", str(test_views),
            "--test-view-resolution", str(view_res), *map(str, extra)]
    key = hashlib.sha256(" ".join(args).encode()).hexdigest()[:8]
    out = DATA_DIR / f"{scene}-{resolution}-{key}"
    stamp = out / "simulate_args.json"
    if (out / "dataset.json").is_file() and stamp.is_file() and json.loads(stamp.read_text())["args"] == args:
        return out, None
    log(f"  simulating {scene} at {resolution}x{resolution} ({' '.join(map(str, extra)) or 'defaults'}) -> {out}")
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, str(REPO_ROOT / "pipeline" / "simulate.py"), *args, "--out", str(out)],
                       capture_output=True, text=True, cwd=REPO_ROOT)
    if p.returncode != 0:
        raise RuntimeError(f"simulate.py {' '.join(args)} failed (exit {p.returncode}): {p.stderr.strip()[-1500:]}")
    sim_s = time.perf_counter() - t0
    stamp.write_text(json.dumps({"args": args, "simulate_seconds": sim_s}))
    return out, sim_s


def preprocess(path, **settings):
    """(dataset, measurements, seconds) with PreprocessSettings(**settings)."""
    import warnings

    from torch_recon.contract.dataset import load_dataset
    from torch_recon.preprocess import PreprocessSettings, preprocess_dataset
    ds = load_dataset(path)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")      # first-bounce disagreement warnings: reported by the measurements area
        meas = preprocess_dataset(ds, PreprocessSettings(**settings))
    return ds, meas, time.perf_counter() - t0


class Views:
    """The dataset's ground-truth test views, optionally every n-th one."""

    def __init__(self, ds, every: int = 1):
        tv = ds.test_views()
        if tv is None:
            raise ValueError(f"{ds.root}: dataset has no ground-truth test views")
        self.spec, cams, gt = tv
        self.cams, self.gt = cams[::every], gt[::every]

    def density_metrics(self, density, bbox_min, bbox_max, n_samples=192) -> dict:
        from torch_recon.evaluate import depth_metrics, render_density_depth
        s = self.spec
        pred = np.stack([render_density_depth(density, c, s.width, s.height, s.fov_rad, bbox_min, bbox_max,
                                              s.fov_axis, n_samples) for c in self.cams])
        return _keep(depth_metrics(pred, self.gt))

    def mesh_metrics(self, mesh) -> dict:
        """Metrics of a mesh (None: no surface, every ray misses)."""
        from torch_recon.evaluate import EvalSettings, depth_metrics, render_mesh_depth
        s = self.spec
        cull = EvalSettings().cull_back_faces       # the evaluator's convention (one-sided, outward normals)
        if mesh is None or len(mesh.faces) == 0:
            pred = np.full_like(self.gt, np.inf)
        else:
            pred = np.stack([render_mesh_depth(mesh, c, s.width, s.height, s.fov_rad, s.fov_axis, cull_back_faces=cull)
                             for c in self.cams])
        out = _keep(depth_metrics(pred, self.gt))
        ok = np.isfinite(self.gt)
        err = np.abs(np.where(np.isfinite(pred), pred, 0.0) - np.where(ok, self.gt, 0.0))   # misses count as depth 0
        per_view = [float(e[o].mean()) for e, o in zip(err, ok) if o.any()]
        out["view_l1_median_m"] = float(np.median(per_view))      # robust to a few views inside a thick wall
        return out

    def volume_metrics(self, volume, bbox_min, bbox_max, level) -> dict:
        """Metrics of an opacity volume with values at voxel centres of the box (the fit's convention)."""
        from torch_recon.mesh_export import MeshExportError, mesh_from_volume
        lo, hi = np.asarray(bbox_min, np.float64), np.asarray(bbox_max, np.float64)
        half = 0.5 * (hi - lo) / np.asarray(np.shape(volume), np.float64)
        try:
            mesh = mesh_from_volume(volume, lo + half, hi - half, level)[0]
        except MeshExportError:
            mesh = None
        return self.mesh_metrics(mesh)


def _keep(m):
    return {"depth_l1_m": float(m["depth_l1_m"]), "depth_psnr_db": float(m["depth_psnr_db"])}


def run_fit(meas, views: Views, mode="fast", budget_s=None, grid=None, eval_every_s=None, steps=None,
            threads=2, prep_seconds=0.0, label=None, sets=()) -> dict:
    """One fit with a time budget; its final depth metrics and (with eval_every_s) the error-vs-time curve."""
    import torch

    from torch_recon.recon import FitConfig, fit, override
    cfg = FitConfig(mode=mode, progress=False, threads=threads, max_seconds=budget_s, eval_every_s=eval_every_s,
                    steps=steps)
    if mode == "fast" and grid:
        cfg.fast.resolution = int(grid)
        cfg.fast.coarse_resolution = max(8, int(grid) // 2)
    cfg = override(cfg, list(sets))
    curve = []

    eval_s = [0.0]

    def on_eval(model, step, seconds):
        t = time.perf_counter()
        with torch.no_grad():
            vol, lo, hi = model.density_volume()
        m = views.volume_metrics(vol, lo, hi, cfg.mesh_level)
        curve.append({"step": step, "train_seconds": seconds, **m})
        eval_s[0] += time.perf_counter() - t
        return m

    t0 = time.perf_counter()
    r = fit(meas, mode=mode, config=cfg, export=False, on_eval=on_eval if eval_every_s else None)
    wall = time.perf_counter() - t0 - eval_s[0]      # evaluation is not the method's time
    final = views.volume_metrics(r.volume, r.bbox_min, r.bbox_max, r.level)
    offset = prep_seconds + r.setup_seconds
    curve = [{**c, "wall_seconds": offset + c["train_seconds"]} for c in curve]
    curve.append({"step": r.train.steps_done, "train_seconds": r.train.train_seconds,
                  "wall_seconds": prep_seconds + wall, **final})
    return {"label": label or f"{mode}", "method": f"platolidar-{mode}", "mode": mode, "grid": grid,
            "budget_s": budget_s, "steps": r.train.steps_done, "stopped": r.train.stopped,
            "preprocess_seconds": prep_seconds, "setup_seconds": r.setup_seconds,
            "train_seconds": r.train.train_seconds, "fit_seconds": wall, "wall_seconds": prep_seconds + wall,
            **final, "curve": curve}


def run_bflidar(meas, views: Views, prep_seconds=0.0, voxels=128, tune_every=2) -> dict:
    """BF Lidar with its occupancy threshold grid-searched on every `tune_every`-th test view (as the paper
    tuned it per scene against ground truth); reported on all views. Time: preprocessing + carving."""
    from torch_recon.bflidar import BFLidarSettings, carve, rethreshold
    t0 = time.perf_counter()
    res = carve(meas, BFLidarSettings(voxels=voxels))
    carve_s = time.perf_counter() - t0
    tune = Views.__new__(Views)
    tune.spec, tune.cams, tune.gt = views.spec, views.cams[::tune_every], views.gt[::tune_every]
    best, best_l1, table = None, math.inf, []
    for ot in (0.1, 0.2, 0.3, 0.5, 0.7):
        r = rethreshold(res, ot)
        try:
            l1 = tune.mesh_metrics(r.mesh())["depth_l1_m"]
        except ValueError:      # no surface at this threshold
            l1 = math.inf
        table.append({"occupancy_threshold": ot, "tune_depth_l1_m": l1})
        if l1 < best_l1:
            best, best_l1 = r, l1
    if best is None:
        raise RuntimeError("BF Lidar: no occupancy threshold gave a surface")
    final = views.mesh_metrics(best.mesh())
    return {"label": "bflidar", "method": "bflidar", "mode": "bflidar", "grid": voxels,
            "occupancy_threshold": best.settings["occupancy_threshold"], "grid_search": table,
            "preprocess_seconds": prep_seconds, "carve_seconds": carve_s, "wall_seconds": prep_seconds + carve_s,
            **final, "curve": [{"wall_seconds": prep_seconds + carve_s, **final}]}


def time_to_reach(run, target=PAPER_L1_M):
    """First wall time at which the run's curve is at or below `target` m (None: never)."""
    for c in run["curve"]:
        if c["depth_l1_m"] <= target:
            return c["wall_seconds"]
    return None


def pareto(points):
    """Indices of the (time, error) points no other point beats in both (smaller is better)."""
    idx = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1]))
    front, best = [], math.inf
    for i in idx:
        if points[i][1] < best:
            front.append(i)
            best = points[i][1]
    return front


def integrate_bins(src, dst, factor: int):
    """A new dataset at `dst` whose bins are sums of `factor` adjacent bins of `src` (the paper's temporal
    resolution ablation: 128 ps -> factor x 128 ps). Windows are re-aligned to the coarse bins; the
    pulse width is kept (the laser did not change) and the bin width grows by `factor`."""
    from torch_recon.contract.dataset import DatasetWriter, Transient, TransientLayout, load_dataset
    ds = load_dataset(src)
    man = ds.manifest
    s = man.sensor
    if factor < 1 or s.bins < factor:
        raise ValueError(f"factor: expected 1..{s.bins}, got {factor}")
    t_new = s.bins // factor
    sensor = replace(s, bins=t_new, bin_width_ps=s.bin_width_ps * factor, bin_width_m=s.bin_width_m * factor)
    spots, g_new = [], None
    with DatasetWriter(dst) as w:
        for sp in man.spots:
            dense = ds.read_transient(sp.id).dense()[:, :, :t_new * factor]
            coarse = dense.reshape(s.height, s.width, t_new, factor).sum(-1, dtype=np.float64).astype(np.float32)
            tr = Transient.from_dense(coarse, t_new)
            g_new = tr.window_bins
            spots.append(replace(sp, transient_file=w.write_transient(sp.id, tr, man.layout.sample_type),
                                 content_hash=None))
        for rel in filter(None, (man.ground_truth.train_depth_file, man.ground_truth.mesh_file,
                                 man.ground_truth.test_views.depth_file if man.ground_truth.test_views else None)):
            w.reuse_file(ds.path(rel), rel)
        layout = TransientLayout("dense" if g_new == t_new else "windowed", g_new, man.layout.sample_type)
        w.commit(replace(man, sensor=sensor, spots=spots, layout=layout))
    return Path(dst)
