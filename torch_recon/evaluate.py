"""Evaluation shared by every method and benchmark: depth L1 / PSNR on test views, Chamfer, F-score.

Definitions (DESIGN.md section 4; all depths are ranges along the pixel ray, metres):
- Valid pixels: the ground-truth ray hits something (finite GT range). GT misses
  (inf, e.g. out of the open front of the room) are excluded and counted.
- A reconstruction ray that hits nothing counts as depth 0 (what a NeRF's
  expected depth sum(w t) gives for empty space; the paper rendered depth that
  way), so a missing surface costs its full GT depth. `miss_depth='max'` uses the
  test set's largest GT depth instead.
- depth_l1_m: mean |pred - gt| over all valid pixels of all test views (pooled).
- depth_psnr_db: 10 log10(1 / MSE) of (pred - gt) / max_gt over the same pooled
  pixels, max_gt the largest finite GT depth of the test set (peak 1); MSE is
  floored at 1e-10 (100 dB). depth_psnr_db_view_mean: the mean of per-view PSNRs.
  For context only: depth_l1_m_on_hits (valid pixels the reconstruction did hit)
  and hit_fraction.
- chamfer_m, fscore: torch_recon.evaluation.surface (point-to-triangle, both directions, optionally
  cropped to `crop_min/crop_max`), on `n_surface_samples` points per surface.
Meshes are rendered by Embree ray casting (trimesh `mesh.ray`, all pixels of a
view in one call); density fields by volume rendering in torch.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from .contract.analytic import range_image
from .contract.errors import EvaluationError, SettingsError
from .contract.frames import camera_ray_directions
from .evaluation.surface import surface_metrics

PSNR_MSE_FLOOR = 1e-10


@dataclass
class EvalSettings:
    SETTINGS_META = {"fscore_threshold_m": {"flags": ("--fscore-threshold",), "unit": "m",
                                            "help": "F-score distance threshold"},
                     "n_surface_samples": {"flags": ("--samples",), "help": "surface samples for Chamfer/F-score",
                                           "range": (1, None)},
                     "miss_depth": {"choices": ("zero", "max"),
                                    "help": "depth a reconstruction ray that hits nothing counts as"},
                     "error_images": {"help": "write every n-th view's error PNG (0: none)", "range": (0, None)}}

    fscore_threshold_m: float = 0.05
    n_surface_samples: int = 100_000
    miss_depth: str = "zero"          # 'zero' | 'max' (see module doc)
    seed: int = 0
    error_images: int = 1             # write a PNG for every n-th test view (0: none)
    error_vmax_m: float = 0.5         # colour scale of the error images
    crop_min: tuple | None = None     # optional box for Chamfer / F-score
    crop_max: tuple | None = None
    density_samples: int = 192        # volume rendering samples per ray
    density_min_opacity: float = 0.5  # below this accumulated opacity a density ray counts as a miss
    objects: bool = True              # object-level metrics (torch_recon.evaluation.objects)
    pictures: bool = True             # shaded renders, error images, summary.html / summary.png
    picture_size: int = 192           # pixels per side of each render
    object_metric_settings: dict | None = None   # ObjectMetricSettings fields (sample densities, thresholds)
    check_test_views: bool = True     # drop (and count) test views whose camera is not in free space
    view_clearance_m: float = 0.005   # a test camera closer than this to a surface is not in free space
                                      # (the paper's orbit passes 1 cm from its back wall)
    cull_back_faces: bool = True      # mesh rays pass through faces seen from behind (a test camera just
                                      # inside a reconstructed wall, e.g. the paper's orbit 1 cm from the
                                      # back wall, sees the scene, not the wall's inside); GT stays two-sided

    def validate(self):
        if self.miss_depth not in ("zero", "max"):
            raise SettingsError("miss_depth", f"expected 'zero' or 'max', got {self.miss_depth!r}")
        if not self.fscore_threshold_m > 0:
            raise SettingsError("fscore_threshold_m", f"expected a length > 0 (m), got {self.fscore_threshold_m}")
        if self.n_surface_samples < 1:
            raise SettingsError("n_surface_samples", "expected an integer >= 1")
        if self.object_metric_settings is not None:     # checked here, by key, not after the whole evaluation
            from .contract.settings import from_dict
            from .evaluation.objects import ObjectMetricSettings

            from_dict(ObjectMetricSettings, self.object_metric_settings, prefix="object_metric_settings.")


# ---------------------------------------------------------------- rendering

def render_mesh_depth(mesh, c2w, width, height, fov_rad, fov_axis="x", cull_back_faces=False) -> np.ndarray:
    """Range image (H, W) of a trimesh mesh from a camera (Embree); inf where the ray misses."""
    return range_image(mesh, c2w, width, height, fov_rad, fov_axis, cull_back_faces).astype(np.float32)


def render_density_depth(density, c2w, width, height, fov_rad, bbox_min, bbox_max, fov_axis="x", n_samples=192,
                         min_opacity=0.5, device="cpu", chunk=1 << 16, pixels=None) -> np.ndarray:
    """Expected depth of a density field density(xyz (N, 3) torch) -> sigma (N,) along each pixel ray.

    Samples are spaced evenly over the ray's segment inside [bbox_min, bbox_max];
    depth = sum(w t) / sum(w) where the accumulated opacity sum(w) >= min_opacity,
    else inf (a miss). Returns (H, W) float32, or (len(pixels),) for the row-major pixel indices `pixels`.
    """
    import torch

    c2w = np.asarray(c2w, np.float64)
    dirs = (camera_ray_directions(width, height, fov_rad, fov_axis) @ c2w[:3, :3].T).reshape(-1, 3)
    if pixels is not None:
        dirs = dirs[np.asarray(pixels)]
    d = torch.as_tensor(dirs, dtype=torch.float32, device=device)
    o = torch.as_tensor(c2w[:3, 3], dtype=torch.float32, device=device)
    lo = torch.as_tensor(np.asarray(bbox_min, np.float64), dtype=torch.float32, device=device)
    hi = torch.as_tensor(np.asarray(bbox_max, np.float64), dtype=torch.float32, device=device)
    out = torch.full((d.shape[0],), float("inf"), device=device)
    u = (torch.arange(n_samples, device=device, dtype=torch.float32) + 0.5) / n_samples
    with torch.no_grad():
        for s in range(0, d.shape[0], chunk):
            dd = d[s:s + chunk]
            inv = 1.0 / torch.where(dd.abs() < 1e-12, torch.full_like(dd, 1e-12), dd)
            t0, t1 = (lo - o) * inv, (hi - o) * inv
            tn = torch.minimum(t0, t1).amax(1).clamp_min(0.0)
            tf = torch.maximum(t0, t1).amin(1)
            hit = tf > tn
            t = tn[:, None] + (tf - tn).clamp_min(0)[:, None] * u[None]            # (R, S)
            delta = ((tf - tn).clamp_min(0) / n_samples)[:, None].expand_as(t)
            pts = o + dd[:, None, :] * t[..., None]
            sigma = density(pts.reshape(-1, 3)).reshape(t.shape).clamp_min(0)
            alpha = 1.0 - torch.exp(-sigma * delta)
            trans = torch.cumprod(torch.cat([torch.ones_like(alpha[:, :1]), 1.0 - alpha + 1e-10], 1), 1)[:, :-1]
            w = alpha * trans
            acc = w.sum(1)
            dep = (w * t).sum(1) / acc.clamp_min(1e-10)
            out[s:s + chunk] = torch.where(hit & (acc >= min_opacity), dep, torch.full_like(dep, float("inf")))
    out = out.cpu().numpy().astype(np.float32)
    return out if pixels is not None else out.reshape(height, width)


# ---------------------------------------------------------------- metrics

def depth_metrics(pred, gt, miss_depth: str = "zero") -> dict:
    """Depth L1 / PSNR over stacks (N, H, W) (see module doc). pred: inf/NaN = reconstruction miss."""
    pred = np.asarray(pred, np.float64)
    gt = np.asarray(gt, np.float64)
    if pred.shape != gt.shape:
        raise EvaluationError(f"predicted depth {pred.shape} and ground truth {gt.shape} differ in shape")
    if pred.ndim == 2:
        pred, gt = pred[None], gt[None]
    valid = np.isfinite(gt)
    if not valid.any():
        raise EvaluationError("every ground-truth pixel is a miss (inf): nothing to evaluate")
    max_gt = float(gt[valid].max())
    if max_gt <= 0:
        raise EvaluationError("ground-truth depths are all zero")
    miss = ~np.isfinite(pred)
    filled = np.where(miss, 0.0 if miss_depth == "zero" else max_gt, pred)
    err = np.where(valid, filled - gt, 0.0)
    n_valid = int(valid.sum())
    l1 = float(np.abs(err).sum() / n_valid)
    mse = float(((err / max_gt) ** 2).sum() / n_valid)
    per_view_l1, per_view_psnr = [], []
    for e, v in zip(err, valid):
        nv = int(v.sum())
        if nv == 0:
            per_view_l1.append(None)
            per_view_psnr.append(None)
            continue
        per_view_l1.append(float(np.abs(e).sum() / nv))
        per_view_psnr.append(_psnr(float(((e / max_gt) ** 2).sum() / nv)))
    ps = [p for p in per_view_psnr if p is not None]
    hits = valid & ~miss
    l1_hits = float(np.abs(err[hits]).mean()) if hits.any() else None
    return {"depth_l1_m": l1, "depth_l1_m_on_hits": l1_hits, "hit_fraction": float(hits.sum() / n_valid), "depth_psnr_db": _psnr(mse), "depth_psnr_db_view_mean": float(np.mean(ps)),
            "max_gt_depth_m": max_gt, "n_valid_pixels": n_valid, "n_excluded_pixels": int((~valid).sum()),
            "n_reconstruction_misses": int((miss & valid).sum()), "miss_depth": miss_depth,
            "per_view_l1_m": per_view_l1, "per_view_psnr_db": per_view_psnr}


def _psnr(mse: float) -> float:
    return float(10.0 * math.log10(1.0 / max(mse, PSNR_MSE_FLOOR)))


# ---------------------------------------------------------------- images and the whole evaluation

def _colour(x, vmin, vmax, cmap):
    import matplotlib
    a = np.clip((np.nan_to_num(x, nan=vmin, posinf=vmax) - vmin) / max(vmax - vmin, 1e-12), 0, 1)
    rgb = matplotlib.colormaps[cmap](a)[..., :3]
    rgb[~np.isfinite(x)] = 0.0    # misses / excluded pixels are black
    return rgb


def write_error_image(path, pred, gt, max_depth, vmax_err):
    """One PNG: GT depth | predicted depth | |error| (black: miss or excluded)."""
    import matplotlib.pyplot as plt
    err = np.where(np.isfinite(gt), np.abs(np.where(np.isfinite(pred), pred, 0.0) - gt), np.nan)
    row = np.concatenate([_colour(gt, 0, max_depth, "viridis"), _colour(pred, 0, max_depth, "viridis"),
                          _colour(err, 0, vmax_err, "magma")], axis=1)
    plt.imsave(path, row)


def _sample_density_mesh(density, bbox_min, bbox_max, level, res=128, device="cpu"):
    import torch

    from .mesh_export import mesh_from_volume
    axes = [torch.linspace(float(a), float(b), res, device=device) for a, b in zip(bbox_min, bbox_max)]
    grid = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    with torch.no_grad():
        vol = torch.cat([density(grid[i:i + (1 << 18)]) for i in range(0, len(grid), 1 << 18)]).reshape(res, res, res)
    return mesh_from_volume(vol, bbox_min, bbox_max, level)[0]


def _load_gt_mesh(dataset):
    import trimesh
    rel = dataset.manifest.ground_truth.mesh_file
    return None if rel is None else trimesh.load(dataset.path(rel), force="mesh", process=False)


def _valid_test_views(dataset, gt_mesh, settings, report):
    """The dataset's test views with cameras in free space (others dropped with a warning and counted)."""
    tv = dataset.test_views()
    if tv is None:
        return None
    views, cams, gt = tv
    report["n_test_views_invalid"] = int(getattr(views, "n_invalid", 0) or 0)    # dropped by the simulator
    report["test_view_trajectory"] = getattr(views, "trajectory", None)
    if gt_mesh is not None and settings.check_test_views:
        from .contract.test_views import check_test_views
        valid, vrep = check_test_views(gt_mesh, cams, settings.view_clearance_m)
        report["n_test_views_invalid"] += int((~valid).sum())
        report["test_views_invalid"] = vrep["invalid"]
        cams, gt = cams[valid], gt[valid]
        if not len(cams):
            return None
    return views, cams, gt


class _StageLog:
    """Announces each evaluation stage after the view renders (object metrics and pictures take minutes on
    large meshes) and keeps its seconds for the report's time breakdown."""

    def __init__(self, progress: bool):
        self.progress, self.seconds, self._name, self._t = progress, {}, None, 0.0

    def start(self, name: str):
        self.stop()
        self._name, self._t = name, time.perf_counter()
        if self.progress:
            from tqdm import tqdm
            tqdm.write(f"evaluate: {name} ...")

    def stop(self):
        if self._name is not None:
            self.seconds[self._name] = round(time.perf_counter() - self._t, 3)
            if self.progress:
                from tqdm import tqdm
                tqdm.write(f"evaluate: {self._name} done in {self.seconds[self._name]:.1f} s")
        self._name = None


def evaluate(dataset, out_dir, mesh=None, density=None, bbox_min=None, bbox_max=None, density_mesh_level=None,
             settings: EvalSettings | None = None, device="cpu", progress=False, extra=None) -> dict:
    """Evaluate a reconstruction (a world-frame trimesh mesh, or a density callable + bbox) on a dataset.

    Writes out_dir/report.json and per-view error PNGs (out_dir/views/view_NNNN.png); returns the report.
    """
    settings = settings or EvalSettings()
    settings.validate()
    if (mesh is None) == (density is None):
        raise ValueError("give exactly one of mesh= or density=")
    if density is not None and (bbox_min is None or bbox_max is None):
        raise ValueError("a density field needs bbox_min and bbox_max")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    report = {"dataset": str(dataset.root), "dataset_hash": dataset.content_hash(),
              "reconstruction": "mesh" if mesh is not None else "density", "settings": asdict(settings)}
    gt_mesh = _load_gt_mesh(dataset)
    tv = _valid_test_views(dataset, gt_mesh, settings, report)
    preds = gt = None
    if tv is None:
        report.update({"depth_l1_m": None, "depth_psnr_db": None, "n_test_views": 0, "n_excluded_pixels": 0,
                       "note": "dataset has no ground_truth.test_views: no depth metrics"})
    else:
        views, cams, gt = tv
        preds = np.empty_like(gt)
        it = range(len(cams))
        if progress:
            from tqdm import tqdm
            it = tqdm(it, desc="render test views", unit="view")
        for i in it:
            if mesh is not None:
                preds[i] = render_mesh_depth(mesh, cams[i], views.width, views.height, views.fov_rad, views.fov_axis,
                                             settings.cull_back_faces)
            else:
                preds[i] = render_density_depth(density, cams[i], views.width, views.height, views.fov_rad, bbox_min,
                                                bbox_max, views.fov_axis, settings.density_samples,
                                                settings.density_min_opacity, device)
        dm = depth_metrics(preds, gt, settings.miss_depth)
        report.update(dm)
        report["n_test_views"] = int(len(cams))
        report["test_view_size"] = [views.width, views.height]
        if settings.error_images > 0:
            (out_dir / "views").mkdir(exist_ok=True)
            for i in range(0, len(cams), settings.error_images):
                write_error_image(out_dir / "views" / f"view_{i:04d}.png", preds[i], gt[i], dm["max_gt_depth_m"],
                                  settings.error_vmax_m)
        np.savez_compressed(out_dir / "test_depths.npz", pred=preds, gt=gt)
    rec = None
    stages = _StageLog(progress)
    if gt_mesh is None:
        report.update({"chamfer_m": None, "fscore": None, "surface_note": "dataset has no ground-truth mesh"})
    else:
        rec = mesh
        if rec is None and density_mesh_level is not None:
            rec = _sample_density_mesh(density, bbox_min, bbox_max, density_mesh_level, device=device)
        if rec is None:
            report.update({"chamfer_m": None, "fscore": None,
                           "surface_note": "density without density_mesh_level: no surface metrics"})
        else:
            stages.start("surface metrics")
            report.update(surface_metrics(rec, gt_mesh, settings.fscore_threshold_m, settings.n_surface_samples,
                                          settings.seed, settings.crop_min, settings.crop_max))
    if extra:
        report["extra"] = extra
    if rec is not None and (settings.objects or settings.pictures):
        from .evaluation.objects import ObjectMetricSettings, object_surface_metrics
        from .evaluation.report import load_gt_objects, write_summary
        objects, report["objects_source"] = load_gt_objects(dataset, gt_mesh)
        if settings.objects:
            stages.start(f"object metrics ({len(objects)} labelled objects)")
            report["object_metrics"] = object_surface_metrics(rec, gt_mesh, objects, dataset.manifest.sensor,
                                                              ObjectMetricSettings(**{"seed": settings.seed,
                                                                 **(settings.object_metric_settings or {})}))
        if settings.pictures:
            stages.start("summary pictures")
            report["pictures"] = write_summary(out_dir, report, gt_mesh, rec, objects,
                                               dataset.manifest.sensor.camera_to_world, preds, gt,
                                               size=settings.picture_size)
    stages.stop()
    report["stage_seconds"] = stages.seconds
    report["eval_seconds"] = round(time.perf_counter() - t0, 3)
    tmp = out_dir / ".report.json.partial"
    tmp.write_text(json.dumps(report, indent=1))
    tmp.replace(out_dir / "report.json")
    return report
