"""Checks of the stress suite: finiteness of every stage's output, and small pipelines that run them.

Stages checked: a dataset (transients, ground-truth depths, mesh), preprocessing (Measurements and
the closed-form visible depth), a short fast-mode fit (volume), the mesh export (vertices) and the
evaluation (metrics). NaN is a documented "unknown" marker in two places only: a shadowed
pixel's path length and a pixel without visible-depth estimate; +inf marks a ground-truth miss.
Anything else non-finite raises NonFinite.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


class NonFinite(AssertionError):
    """NaN or inf where the contract says finite."""


class CheckFailed(AssertionError):
    """A numerical check failed (not smooth, not reproducible, too inaccurate)."""

    def __init__(self, msg, metrics=None):
        super().__init__(msg)
        self.metrics = metrics or {}


def finite(name, a, allow_nan=False, allow_posinf=False):
    a = np.asarray(a, dtype=np.float64)
    bad = np.isneginf(a) | (np.isposinf(a) if not allow_posinf else False) | (np.isnan(a) if not allow_nan else False)
    if np.any(bad):
        raise NonFinite(f"{name}: {int(np.sum(bad))} of {a.size} values are NaN or inf")


# ---------------------------------------------------------------- stages

def check_dataset(path) -> dict:
    """Every transient finite and >= 0; GT depths without NaN (inf = miss); GT mesh vertices finite."""
    import trimesh

    from torch_recon.contract.dataset import load_dataset
    ds = load_dataset(path)
    peak = 0.0
    for s in ds.manifest.enabled_spots:
        tr = ds.read_transient(s.id)
        finite(f"spot {s.id} transient", tr.window)
        if np.any(tr.window < 0):
            raise NonFinite(f"spot {s.id} transient has negative counts")
        peak = max(peak, float(tr.window.max()))
    td = ds.train_depth()
    if td is not None:
        finite("ground_truth train depth", td, allow_posinf=True)
    tv = ds.test_views()
    if tv is not None:
        finite("ground_truth test depths", tv[2], allow_posinf=True)
    if ds.manifest.ground_truth.mesh_file:
        m = trimesh.load(ds.path(ds.manifest.ground_truth.mesh_file), force="mesh", process=False)
        finite("ground-truth mesh vertices", m.vertices)
    return {"spots": len(ds.manifest.enabled_spots), "peak_count": peak, "sample_type": ds.manifest.layout.sample_type}


def check_measurements(meas) -> dict:
    """Finite first bounces, confidences in [0, 1], paths finite exactly where signal, depth never inf."""
    for s in meas.spots:
        finite(f"spot {s.spot_id} first bounce", s.first_bounce)
        finite(f"spot {s.spot_id} shadow confidence", s.shadow_confidence)
        if np.any((s.shadow_confidence < 0) | (s.shadow_confidence > 1)):
            raise NonFinite(f"spot {s.spot_id}: shadow confidence outside [0, 1]")
        p = np.asarray(s.path_length, np.float64)
        if np.any(np.isinf(p)) or np.any(np.isnan(p[s.signal])):
            raise NonFinite(f"spot {s.spot_id}: path length NaN/inf on signal pixels")
    if meas.visible_depth is not None:
        finite("visible depth", meas.visible_depth, allow_nan=True)
        finite("visible confidence", meas.visible_confidence)
    return {"signal_fraction": float(np.mean([s.signal.mean() for s in meas.spots])),
            "shadow_fraction": float(np.mean([s.shadow.mean() for s in meas.spots]))}


def depth_error(meas, gt, min_conf=0.5) -> dict:
    """Visible-depth error against the GT range image on pixels both know (m)."""
    v = meas.visible_depth
    ok = np.isfinite(v) & np.isfinite(gt) & (meas.visible_confidence >= min_conf)
    if not ok.any():
        return {"depth_coverage": 0.0, "depth_median_err_m": None, "depth_p95_err_m": None}
    e = np.abs(v[ok] - gt[ok])
    return {"depth_coverage": float(ok.mean()), "depth_median_err_m": float(np.median(e)),
            "depth_p95_err_m": float(np.percentile(e, 95)), "depth_median_rel_err": float(np.median(e / gt[ok]))}


def shadow_agreement(ds, meas, rel_floor=1e-3) -> float:
    """Share of non-excluded pixels whose signal/shadow label matches the analytic two-bounce render of the
    dataset's ground-truth mesh (lit: expected two-bounce energy above rel_floor x the spot's brightest pixel)."""
    import trimesh

    from torch_recon.contract.analytic import render_two_bounce
    mesh = trimesh.load(ds.path(ds.manifest.ground_truth.mesh_file), force="mesh", process=False)
    spots = ds.manifest.enabled_spots
    two = render_two_bounce(mesh, ds.sensor, [s.laser_direction for s in spots], include_first_bounce=False)
    agree = []
    for k, s in enumerate(meas.spots):
        e = two[k].sum(-1)
        lit = e > rel_floor * max(float(e.max()), 1e-30)
        keep = ~s.excluded
        agree.append(float(np.mean(lit[keep] == s.signal[keep])))
    return float(np.mean(agree))


def reference_shadow_agreement(ds, settings, subpixel: int = 16) -> float:
    """shadow_agreement of the exact footprint-integrated transients (analytic render at subpixel^2 samples
    per pixel of the ground-truth mesh) through the same preprocessing: what perfect data scores. At very
    low resolution a pixel's return spreads over many bins and the matched-filter confidence of lit pixels
    falls under the threshold, so even perfect data scores low there (16 x 16 cave: 0.36)."""
    import trimesh

    from torch_recon.contract.analytic import render_two_bounce
    from torch_recon.contract.dataset import Transient
    from torch_recon.preprocess import process_spot
    mesh = trimesh.load(ds.path(ds.manifest.ground_truth.mesh_file), force="mesh", process=False)
    spots = ds.manifest.enabled_spots
    dirs = [s.laser_direction for s in spots]
    cubes = render_two_bounce(mesh, ds.sensor, dirs, subpixel=subpixel)
    two = render_two_bounce(mesh, ds.sensor, dirs, include_first_bounce=False)
    agree = []
    for k, s in enumerate(spots):
        cube = cubes[k].astype(np.float32)
        m = process_spot(Transient(np.zeros(cube.shape[:2], np.int64), cube, cube.shape[-1]), ds.sensor, s, settings)
        e = two[k].sum(-1)
        lit = e > 1e-3 * max(float(e.max()), 1e-30)
        agree.append(float(np.mean(lit[~m.excluded] == m.signal[~m.excluded])))
    return float(np.mean(agree))


def preprocess_checked(path, **settings):
    from torch_recon.contract.dataset import load_dataset
    from torch_recon.preprocess import PreprocessSettings, preprocess_dataset
    ds = load_dataset(path)
    meas = preprocess_dataset(ds, PreprocessSettings(**settings))
    metrics = check_measurements(meas)
    td = ds.train_depth()
    if td is not None and meas.visible_depth is not None:
        metrics.update(depth_error(meas, td))
    if ds.manifest.ground_truth.mesh_file:
        metrics["shadow_agreement"] = shadow_agreement(ds, meas)
    return ds, meas, metrics


def small_fit_config(steps=12, resolution=24):
    from torch_recon.recon import FitConfig
    cfg = FitConfig(progress=False, steps=steps, threads=1, plateau_patience=0, device="cpu")
    cfg.fast.resolution = resolution
    cfg.fast.coarse_resolution = max(4, resolution // 2)
    cfg.fast.rays_per_batch = 512
    return cfg


def fit_checked(meas, out: Path, steps=12, resolution=24, dataset=None) -> dict:
    """Short fast-mode fit exporting its mesh -> finite volume, finite mesh vertices, finite metrics."""
    from torch_recon.recon import fit
    r = fit(meas, out=out, config=small_fit_config(steps, resolution), export=True)
    finite("fitted volume", r.volume)
    metrics = {"fit_steps": r.train.steps_done, "fit_seconds": round(r.total_seconds, 2),
               "nan_restores": r.train.nan_restores, "occupied_fraction": float((r.volume > r.level).mean())}
    if r.train.nan_restores:
        raise NonFinite(f"fit restored {r.train.nan_restores} time(s) after a NaN step")
    if r.mesh is None:
        raise CheckFailed("fit(out=..., export=True) returned no mesh", metrics)
    finite("exported mesh vertices", r.mesh.vertices)
    metrics["mesh_faces"] = int(len(r.mesh.faces))
    if dataset is not None and dataset.test_views() is not None and len(r.mesh.faces):
        from torch_recon.evaluate import EvalSettings, evaluate
        rep = evaluate(dataset, out / "eval", mesh=r.mesh, settings=EvalSettings(n_surface_samples=2000,
                                                                                  error_images=0))
        for k in ("depth_l1_m", "depth_psnr_db", "chamfer_m", "fscore"):
            if rep.get(k) is not None:
                finite(f"evaluation {k}", rep[k])
                metrics[k] = rep[k]
    return metrics


def transient_bytes_equal(a, b) -> bool:
    fa = sorted(Path(a, "transients").glob("*.exr"))
    fb = sorted(Path(b, "transients").glob("*.exr"))
    return len(fa) == len(fb) and all(x.read_bytes() == y.read_bytes() for x, y in zip(fa, fb))


def smooth_sweep(levels, errors, max_jump=3.0, rise_tol=1.25, floor=1e-3):
    """Errors (noisiest first) must not rise as noise falls, beyond rise_tol x (+ floor m), and must not
    change by more than max_jump x between neighbouring levels. Returns a list of violations."""
    bad = []
    for i in range(1, len(errors)):
        a, b = errors[i - 1], errors[i]
        if a is None or b is None:
            continue
        if b > rise_tol * a + floor:
            bad.append(f"error rises from {a:.4g} to {b:.4g} m going from {levels[i - 1]} to {levels[i]}")
        hi, lo = max(a, b) + floor, min(a, b) + floor
        if hi / lo > max_jump:
            bad.append(f"error jumps x{hi / lo:.1f} between {levels[i - 1]} and {levels[i]}")
    return bad
