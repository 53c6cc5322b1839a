"""`fit(...)`: measurements (or a dataset) -> density volume -> mesh, in one call.

    from torch_recon.recon import fit
    result = fit("datasets/cave", mode="fast", out="out/fit")
    result.mesh_files, result.train.stopped, result.total_seconds
"""

from __future__ import annotations

import hashlib
import json
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..contract.frames import pixel_rays
from ..contract.methods import method
from ..device import resolve_device
from ..measurements import Measurements, MeasurementsError
from .config import FitConfig
from .data import build_ray_data
from .grid_size import sensor_grid
from .models import build_model
from .trainer import CHECKPOINT_NAME, TrainResult, train

VOLUME_NAME = "volume.npz"
REPORT_NAME = "fit.json"
#: top-level names fits of earlier versions wrote (they kept no record); everything else in --out is the user's
FIT_ENTRIES = (VOLUME_NAME, REPORT_NAME, "mesh.*", "*.tmp", "*.tmp.npz")


@dataclass
class FitResult:
    mode: str
    model: object
    train: TrainResult
    setup_seconds: float              # measurements -> rays -> initial field
    total_seconds: float              # setup + optimisation + volume (+ mesh export)
    volume: np.ndarray                # (nx, ny, nz) opacity per voxel, in [0, 1]
    bbox_min: np.ndarray
    bbox_max: np.ndarray
    level: float
    source_hash: str
    out_dir: Path | None = None
    mesh_files: dict = field(default_factory=dict)
    mesh: object = None               # trimesh.Trimesh (Blender world frame) when exported
    metadata: dict = field(default_factory=dict)

    def density(self, pts: torch.Tensor) -> torch.Tensor:
        """sigma (1 / m) at world points (N, 3): the fitted field, for evaluate.render_density_depth."""
        with torch.no_grad():
            return self.model.density(pts.to(self.model.device)).to(pts.device)

    def render_depth(self, camera_to_world, width: int, height: int, fov_rad: float, fov_axis: str = "x",
                     min_opacity: float | None = None):
        """Range image (H, W) of the fitted field from any camera (the mode's own volume rendering).

        min_opacity None: leftover transmittance lands at the box exit; a number: torch_recon.evaluate's
        convention (depth normalised by opacity, inf = miss below that opacity)."""
        return render_model_depth(self.model, camera_to_world, width, height, fov_rad, fov_axis, min_opacity)


def render_model_depth(model, camera_to_world, width, height, fov_rad, fov_axis="x", min_opacity=None):
    o, d = pixel_rays(camera_to_world, width, height, fov_rad, fov_axis)
    t = lambda a: torch.as_tensor(a.reshape(-1, 3), dtype=torch.float32, device=model.device)  # noqa: E731
    return model.render_depth(t(o), t(d), min_opacity=min_opacity).cpu().numpy().reshape(height, width)


def measurements_hash(meas: Measurements) -> str:
    h = hashlib.sha256()
    h.update(np.asarray(meas.camera_to_world, np.float64).tobytes())
    for s in meas.spots:
        for a in (s.first_bounce, s.path_length, s.signal, s.shadow, s.excluded):
            h.update(np.ascontiguousarray(a).tobytes())
    if meas.visible_depth is not None:
        h.update(np.ascontiguousarray(meas.visible_depth).tobytes())
    return "measurements:" + h.hexdigest()


def source_path(source) -> Path:
    """The path of a dataset directory or measurements file (.npz); FileNotFoundError naming it if absent
    (commands check it before slower inputs)."""
    path = Path(source)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such dataset directory or measurements file")
    if path.is_file() and path.suffix.lower() == ".json":   # a dataset's own dataset.json, a fit.json, ...
        raise MeasurementsError(f"{path}: expected a dataset directory (the folder holding dataset.json: "
                                f"{path.parent}) or a measurements .npz, got a JSON file")
    return path


def load_source(source, progress: bool = True, device="cpu"):
    """Measurements and a hash naming the data: from a Measurements, a .npz, or a dataset directory
    (preprocessed, visible depth included, with torch on `device`)."""
    if isinstance(source, Measurements):
        return source, measurements_hash(source)
    path = source_path(source)
    if path.is_file():
        m = Measurements.load(path)
        return m, measurements_hash(m)
    if (path / "measurements.npz").is_file() and not (path / "dataset.json").is_file():
        m = Measurements.load(path / "measurements.npz")
        return m, measurements_hash(m)
    from ..contract.dataset import load_dataset
    from ..preprocess import preprocess_dataset

    ds = load_dataset(path)
    meas = preprocess_dataset(ds, device=device)
    return meas, "dataset:" + ds.content_hash()


def fit(source, mode: str | None = None, out=None, config: FitConfig | None = None, on_eval=None,
        export: bool = True, fault_hook=None, stop_after: int | None = None, uv: bool = True) -> FitResult:
    """Fit a density field to two-bounce measurements and (with `out` and `export`) write the mesh."""
    from threadpoolctl import threadpool_limits

    # numpy's products in a fit are small (the bounding planes' RANSAC: ~2400 of 20000 x 3 points by a normal): a
    # second OpenBLAS thread only adds wake-ups, and on a loaded machine each waits for a core (docs/reconstruction.md
    # "Fixed costs", session 17). torch keeps its own `--threads`.
    with threadpool_limits(limits=1, user_api="blas"):
        return _fit(source, mode, out, config, on_eval, export, fault_hook, stop_after, uv)


def _fit(source, mode, out, config, on_eval, export, fault_hook, stop_after, uv) -> FitResult:
    t_start = time.perf_counter()
    cfg = config or (FitConfig(mode=mode) if mode else FitConfig())
    if mode and mode != cfg.mode:
        cfg = FitConfig.from_dict({**cfg.to_dict(), "mode": mode})
    torch.manual_seed(cfg.seed)
    dev = resolve_device(cfg.device, cfg.threads)
    meas, src_hash = load_source(source, cfg.progress, dev)   # the setup runs on the fit's device too
    data = build_ray_data(meas).to(dev)     # refuses unusable measurements before anything is written
    cfg, grid_note = sensor_grid(data, cfg)  # no finer grid than the sensor's pixels resolve
    stage = None
    if out is not None:     # results are staged and swapped in whole; the checkpoint lives in the target
        from ..contract.dataset.staging import StagedDir
        stage = StagedDir(out, "fit", legacy=FIT_ENTRIES, marker=REPORT_NAME, keep=(CHECKPOINT_NAME,))
    try:
        return _fit_and_write(meas, src_hash, data, cfg, dev, stage, t_start, on_eval, export, fault_hook,
                              stop_after, uv, grid_note)
    finally:
        if stage is not None:
            stage.discard()


def _fit_and_write(meas, src_hash, data, cfg, dev, stage, t_start, on_eval, export, fault_hook, stop_after, uv,
                   grid_note=None):
    out_dir = None
    if stage is not None:
        out_dir = stage.target
        out_dir.mkdir(parents=True, exist_ok=True)
    gen = torch.Generator(device=dev)
    gen.manual_seed(cfg.seed)
    meta = {"camera_to_world": np.asarray(meas.camera_to_world), "fov_rad": meas.fov_rad, "fov_axis": meas.fov_axis}
    model = build_model(data, cfg, meta, gen)
    setup = time.perf_counter() - t_start
    tr = train(model, data, cfg, gen, out_dir, on_eval=on_eval, fault_hook=fault_hook, stop_after=stop_after,
               data_key=src_hash)
    vol, lo, hi = model.density_volume()
    free = model.free_evidence() if hasattr(model, "free_evidence") else None
    result = FitResult(mode=cfg.mode, model=model, train=tr, setup_seconds=setup, total_seconds=0.0,
                       volume=vol, bbox_min=lo, bbox_max=hi, level=cfg.mesh_level, source_hash=src_hash,
                       out_dir=out_dir)
    result.metadata = {"method": f"platolidar-{cfg.mode}", "settings": cfg.to_dict(), "source_hash": src_hash,
                       "device": str(dev), "steps": tr.steps_done, "stopped": tr.stopped,
                       "setup_seconds": round(setup, 3), "train_seconds": round(tr.train_seconds, 3),
                       "nan_restores": tr.nan_restores, "resumed_from": tr.resumed_from}
    if grid_note is not None:
        result.metadata["grid_from_sensor"] = grid_note
    if hasattr(model, "reinit_steps"):
        result.metadata["reinitialised_after_steps"] = list(model.reinit_steps)
    if stage is not None and tr.stopped == "interrupted":
        # Ctrl-C / SIGTERM: the checkpoint is saved for a resume; the previous results stay as they were
        result.total_seconds = time.perf_counter() - t_start
        return result
    if stage is not None:
        staged = stage.path
        extra = {} if free is None else {"free_evidence": free}
        np.savez_compressed(staged / VOLUME_NAME, opacity=vol.astype(np.float32), bbox_min=lo, bbox_max=hi,
                            level=cfg.mesh_level, **extra)
        if export:
            result.metadata["run_seconds"] = round(time.perf_counter() - t_start, 3)
            from ..mesh_export import MeshExportError

            try:
                mvol, mlevel, mesh_args = mesh_inputs(model, cfg, vol, free)
                files, result.mesh = export_volume(mvol, lo, hi, mlevel, staged / "mesh", result.metadata,
                                                   uv=uv, **mesh_args)
                result.mesh_files = {k: stage.final(v) for k, v in files.items()}
            except MeshExportError as exc:      # e.g. an early stop with nothing occupied yet
                result.metadata["mesh_error"] = str(exc)
                warnings.warn(f"no mesh written: {exc}", RuntimeWarning, stacklevel=2)
    result.total_seconds = time.perf_counter() - t_start
    result.metadata["run_seconds"] = round(result.total_seconds, 3)
    if stage is not None:
        report = {**result.metadata, "mesh_files": {k: str(v) for k, v in result.mesh_files.items()},
                  "history_tail": tr.history[-5:]}
        (stage.path / REPORT_NAME).write_text(json.dumps(report, indent=2, default=str) + "\n")
        stage.commit()      # volume, mesh files and fit.json replace the previous ones together
    return result


def mesh_inputs(model, cfg, vol, free):
    """What `fit` meshes from `model` (its density volume `vol`, free evidence `free`): (volume, level, the keyword
    arguments of `export_volume` / `mesh_export.mesh_from_volume` but the UVs). One place, so a benchmark scoring a
    checkpoint's mesh scores the mesh `fit` would write."""
    mvol, mlevel = model.surface_volume() if hasattr(model, "surface_volume") else (vol, cfg.mesh_level)
    return mvol, mlevel, {
        "free_space": free,
        "free_points": model.free_points_test() if hasattr(model, "free_points_test") else None,
        "smooth_iterations": cfg.mesh_smooth_iterations,
        "keep_near": _kept_island_centres(model),
        "inward": model.mesh_inward(mvol, mlevel) if hasattr(model, "mesh_inward") else None,
        "mend_gaps": method(cfg.mode).mends_mesh_gaps}


def voxel_centre_box(volume, bbox_min, bbox_max):
    """The box of the voxel centres of `volume` over the box (bbox_min, bbox_max): the mesh exporter's grid
    points span its box corner to corner."""
    lo, hi = np.asarray(bbox_min, np.float64), np.asarray(bbox_max, np.float64)
    half = 0.5 * (hi - lo) / np.asarray(np.shape(volume), np.float64)
    return lo + half, hi - half


def _kept_island_centres(model):
    """(centres (N, 3), one voxel) of the fast model's voxels whose small mesh islands are kept: thin parts and,
    with `fast.mesh_keep_restored_voxels`, restored blockers in runs that long; None without either."""
    tp = getattr(model, "thin_parts", None)
    mask = None if tp is None else tp[0, 0].permute(2, 1, 0)    # stored (z, y, x) for grid_sample; box (x, y, z)
    if getattr(model, "fc", None) is not None and model.fc.mesh_keep_restored_voxels > 0:
        from .shadow_blockers import restored_runs

        restored = restored_runs(model.start_evidence().restored, model.fc.mesh_keep_restored_voxels)
        restored = restored.to(model.grid.box.bbox_min.device)
        mask = restored if mask is None else mask.to(restored.device) | restored
    if mask is None:
        return None
    box = model.grid.box
    return box.centres()[mask.to(box.bbox_min.device)].cpu().double().numpy(), float(box.voxel)


def export_volume(volume, bbox_min, bbox_max, level, out_path: Path, metadata: dict, uv: bool = True,
                  free_space=None, smooth_iterations: int = 0, free_points=None, keep_near=None, inward=None,
                  mend_gaps: bool = False):
    """Marching cubes + cleanup + UVs -> .glb (+ .ply, .obj) through the shared mesh exporter.

    free_space (same shape as volume, bool): report only surfaces facing measured free space;
    free_points: a point test of the same (mesh_export.mesh_from_volume);
    smooth_iterations: Taubin smoothing passes; inward: the hull's bounded inward smoothing; mend_gaps: the
    fast mode's hole mending (all mesh_export.mesh_from_volume).

    Our values sit at voxel centres; the exporter's grid points span its bbox corner to corner, so
    it gets the box of the centres.
    """
    from ..mesh_export import export_mesh

    lo, hi = voxel_centre_box(volume, bbox_min, bbox_max)
    res = export_mesh(volume, lo, hi, level, Path(out_path).with_suffix(".glb"), metadata,
                      extra_formats=(".ply", ".obj"), uv=uv, free_space=free_space,
                      smooth_iterations=smooth_iterations, free_points=free_points, keep_near=keep_near,
                      inward=inward, mend_gaps=mend_gaps)
    files = {p.suffix.lstrip("."): p for p in res.paths}
    files["sidecar"] = res.sidecar
    return files, res.mesh
