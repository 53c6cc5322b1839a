"""Import/export of the public PlatoNeRF dataset layout.

That layout is a directory with ``transforms_train.json`` (``camera_angle_x``;
per frame a ``transform_matrix`` (OpenGL camera-to-world in the paper's y-up
world), ``light_origin``, ``light_direction`` and ``file_path``) and one dense
``.npy`` transient cube (H, W, T) per spot. Bin settings are not part of it;
they default to the paper's (128 ps, 0.0384 m, start 0). On export we add a
``platolidar`` block with everything else so that a round trip is exact.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from ..frames import blender_to_paper_c2w, blender_to_paper_points, paper_to_blender_c2w, paper_to_blender_points
from ..ground_truth import MESH_FILE, write_mesh, write_test_views, write_train_depth
from .schema import (DatasetError, GroundTruth, GroundTruthViews, Manifest, NoiseSpec, Provenance, PulseSpec,
                     SensorSpec, Spot, TimeGate, TransientLayout)
from .store import Dataset, DatasetWriter, _check_array, read_json, transient_relpath
from .transient import Transient

TRANSFORMS = "transforms_train.json"
TRANSFORMS_TEST = "transforms_test.json"
PAPER_BIN_WIDTH_PS = 128.0
PAPER_BIN_WIDTH_M = 0.0384


def _camera_angle_x(s: SensorSpec) -> float:
    if s.fov_axis == "x":
        return s.fov_rad
    return 2.0 * math.atan(math.tan(0.5 * s.fov_rad) * s.width / s.height)


def export_platonerf(dataset: Dataset | str | os.PathLike, out_dir: str | os.PathLike) -> Path:
    """Write `dataset` in the PlatoNeRF layout (dense .npy cubes, paper frame)."""
    ds = dataset if isinstance(dataset, Dataset) else Dataset(dataset)
    m, s = ds.manifest, ds.sensor
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    c2w_paper = blender_to_paper_c2w(s.camera_to_world)
    frames = []
    for spot, tr in ds.iter_transients(enabled_only=False):
        rel = f"transients/spot_{spot.id:04d}.npy"
        (out / "transients").mkdir(exist_ok=True)
        np.save(out / rel, tr.dense(np.float32))
        frames.append({
            "file_path": rel,
            "transform_matrix": c2w_paper.tolist(),
            "light_origin": blender_to_paper_points(s.laser_origin).tolist(),
            "light_direction": blender_to_paper_points(spot.laser_direction).tolist(),
            "platolidar_spot": {"id": spot.id, "enabled": spot.enabled, "content_hash": spot.content_hash,
                                "first_bounce": None if spot.first_bounce is None
                                else blender_to_paper_points(spot.first_bounce).tolist()},
        })
    extras = {k: v for k, v in m.to_dict().items() if k not in ("spots",)}
    doc = {"camera_angle_x": _camera_angle_x(s), "frames": frames, "platolidar": extras}
    (out / TRANSFORMS).write_text(json.dumps(doc, indent=1))
    _export_train_gt(ds, out)
    gt = ds.test_views()
    if gt is not None:
        tv, cams, depth = gt
        (out / "test_depth").mkdir(exist_ok=True)
        tframes = []
        for i, (c, d) in enumerate(zip(cams, depth)):
            rel = f"test_depth/view_{i:04d}.npy"
            np.save(out / rel, d)
            tframes.append({"file_path": rel, "transform_matrix": blender_to_paper_c2w(c).tolist()})
        (out / TRANSFORMS_TEST).write_text(json.dumps({"camera_angle_x": tv.fov_rad if tv.fov_axis == "x" else None,
                                                       "frames": tframes}, indent=1))
    return out


TRAIN_DEPTH_NPY = "ground_truth/train_depth.npy"
MESH_PLY = MESH_FILE


def _export_train_gt(ds: Dataset, out: Path) -> None:
    """Train-view range depth as .npy and the GT mesh as .ply, both in the paper's y-up frame."""
    depth = ds.train_depth()
    if depth is not None:
        (out / "ground_truth").mkdir(exist_ok=True)
        np.save(out / TRAIN_DEPTH_NPY, depth)
    rel = ds.manifest.ground_truth.mesh_file
    if rel is not None:
        import trimesh

        mesh = trimesh.load(ds.path(rel), force="mesh", process=False)
        mesh.vertices = blender_to_paper_points(mesh.vertices)  # a rotation: winding is kept
        (out / "ground_truth").mkdir(exist_ok=True)
        mesh.export(out / MESH_PLY)


def _import_train_gt(src: Path, wr: DatasetWriter, sensor: SensorSpec) -> dict:
    found = {}
    p = src / TRAIN_DEPTH_NPY
    if p.is_file():
        d = np.load(p, allow_pickle=False)
        if d.shape != (sensor.height, sensor.width):
            raise DatasetError(str(p), "train depth", f"expected shape {(sensor.height, sensor.width)}, got {d.shape}")
        found["train_depth_file"] = write_train_depth(wr, d)
    p = src / MESH_PLY
    if p.is_file():
        import trimesh

        try:
            mesh = trimesh.load(p, force="mesh", process=False)
        except Exception as exc:
            raise DatasetError(str(p), "ground-truth mesh", f"not a readable mesh ({exc})") from None
        mesh.vertices = paper_to_blender_points(mesh.vertices)
        found["mesh_file"] = write_mesh(wr, mesh)
    return found


def _load_cube(path: Path, field: str) -> np.ndarray:
    candidates = [path, path.with_name(path.name + ".npy")]
    p = next((c for c in candidates if c.is_file()), None)
    if p is None:
        raise DatasetError(str(path), field, "transient .npy file is missing")
    try:
        cube = np.load(p, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise DatasetError(str(p), field, f"not a readable .npy array ({exc})") from None
    if cube.ndim != 3:
        raise DatasetError(str(p), field, f"expected a transient cube H x W x T, got shape {cube.shape}")
    if not np.issubdtype(cube.dtype, np.number):
        raise DatasetError(str(p), field, f"expected numbers, got dtype {cube.dtype}")
    _check_array(cube, str(p), field, nonneg=True)
    return cube.astype(np.float32, copy=False)


def import_platonerf(src_dir: str | os.PathLike, out_dir: str | os.PathLike, *,
                     bin_width_ps: float = PAPER_BIN_WIDTH_PS, bin_width_m: float = PAPER_BIN_WIDTH_M,
                     start_m: float = 0.0, pulse_fwhm_ps: float = PAPER_BIN_WIDTH_PS,
                     window_bins: int | None = None) -> Dataset:
    """Convert a PlatoNeRF-layout directory into a dataset of ours at `out_dir` (atomic)."""
    src = Path(src_dir)
    tpath = src / TRANSFORMS
    if not tpath.is_file():
        raise DatasetError(str(tpath), "", "transforms_train.json is missing")
    doc = read_json(tpath)
    f = str(tpath)
    angle = doc.get("camera_angle_x") if isinstance(doc, dict) else None
    if isinstance(angle, bool) or not isinstance(angle, (int, float)) or not 0 < angle < math.pi:
        raise DatasetError(f, "camera_angle_x", f"expected a field of view in (0, pi) radians, got {angle!r}")
    frames = doc.get("frames")
    if not isinstance(frames, list) or not frames:
        raise DatasetError(f, "frames", "expected a non-empty list")
    extras = doc.get("platolidar") or {}
    c2w0 = None
    cubes, spots_meta = [], []
    for i, fr in enumerate(frames):
        for key in ("transform_matrix", "light_origin", "light_direction", "file_path"):
            if not isinstance(fr, dict) or key not in fr:
                raise DatasetError(f, f"frames[{i}].{key}", "missing")
        try:
            c2w = np.asarray(fr["transform_matrix"], dtype=np.float64)
            lo = np.asarray(fr["light_origin"], dtype=np.float64)
            ld = np.asarray(fr["light_direction"], dtype=np.float64)
        except (TypeError, ValueError):
            raise DatasetError(f, f"frames[{i}]", "transform_matrix/light_origin/light_direction must be numbers") from None
        if c2w.shape != (4, 4) or not np.all(np.isfinite(c2w)):
            raise DatasetError(f, f"frames[{i}].transform_matrix", f"expected a finite 4x4 matrix, got shape {c2w.shape}")
        if c2w0 is None:
            c2w0 = c2w
        elif not np.allclose(c2w, c2w0, atol=1e-6):
            raise DatasetError(f, f"frames[{i}].transform_matrix", "single-view lidar: every frame must share one camera")
        for name, v in (("light_origin", lo), ("light_direction", ld)):
            if v.shape != (3,) or not np.all(np.isfinite(v)):
                raise DatasetError(f, f"frames[{i}].{name}", "expected 3 finite numbers")
        n = np.linalg.norm(ld)
        if n < 1e-9:
            raise DatasetError(f, f"frames[{i}].light_direction", "zero-length direction")
        cube = _load_cube(src / fr["file_path"], f"frames[{i}].file_path")
        if cubes and cube.shape != cubes[0].shape:
            raise DatasetError(str(src / fr["file_path"]), f"frames[{i}].file_path",
                               f"shape {cube.shape} differs from the first frame's {cubes[0].shape}")
        cubes.append(cube)
        # renormalise only when needed, so our own exports round-trip bit-exactly
        spots_meta.append((lo, ld if abs(n - 1.0) < 1e-9 else ld / n, fr.get("platolidar_spot") or {}))
    h, w, t = cubes[0].shape
    if extras:
        sensor = SensorSpec.from_dict(extras["sensor"], _ck(f), "platolidar.sensor")
        layout = TransientLayout.from_dict(extras["layout"], _ck(f), "platolidar.layout")
        noise = NoiseSpec.from_dict(extras["noise"], _ck(f), "platolidar.noise")
        prov = Provenance.from_dict(extras["provenance"], _ck(f), "platolidar.provenance")
        if (sensor.height, sensor.width, sensor.bins) != (h, w, t):
            raise DatasetError(f, "platolidar.sensor", f"says {sensor.height}x{sensor.width}x{sensor.bins}, "
                                                       f"cubes are {h}x{w}x{t}")
    else:
        g = t if window_bins is None else int(window_bins)
        sensor = SensorSpec(width=w, height=h, fov_rad=float(angle), fov_axis="x",
                            camera_to_world=paper_to_blender_c2w(c2w0).tolist(),
                            laser_origin=paper_to_blender_points(spots_meta[0][0]).tolist(),
                            pulse=PulseSpec("gaussian", pulse_fwhm_ps), bin_width_ps=bin_width_ps,
                            bin_width_m=bin_width_m, bins=t, start_m=start_m,
                            time_gate=TimeGate(enabled=g < t, window_bins=g if g < t else 0))
        layout = TransientLayout("dense" if g == t else "windowed", g, "float32")
        noise = NoiseSpec()
        prov = Provenance(generator="platonerf-import", generator_version="1", seed=0, scene=src.name,
                          extra={"source": str(src)})
    spots = []
    with DatasetWriter(out_dir) as wr:
        for i, (cube, (lo, ld, meta)) in enumerate(zip(cubes, spots_meta)):
            sid = int(meta.get("id", i))
            tr = Transient.from_dense(cube, layout.window_bins)
            rel = wr.write_transient(sid, tr, layout.sample_type)
            fb = meta.get("first_bounce")
            spots.append(Spot(id=sid, laser_direction=paper_to_blender_points(ld).tolist(), transient_file=rel,
                              enabled=bool(meta.get("enabled", True)),
                              first_bounce=None if fb is None else paper_to_blender_points(fb).tolist(),
                              content_hash=meta.get("content_hash")))
        gt = _import_test_views(src, wr, sensor)
        for name, rel in _import_train_gt(src, wr, sensor).items():
            setattr(gt, name, rel)
        wr.commit(Manifest(sensor=sensor, spots=spots, layout=layout, noise=noise, ground_truth=gt, provenance=prov))
    return Dataset(out_dir)


def _ck(file):
    from .schema import _Checker
    return _Checker(file)


def _import_test_views(src: Path, wr: DatasetWriter, sensor: SensorSpec) -> GroundTruth:
    tpath = src / TRANSFORMS_TEST
    if not tpath.is_file():
        return GroundTruth()
    doc = json.loads(tpath.read_text())
    cams, depths = [], []
    for i, fr in enumerate(doc.get("frames", [])):
        p = src / fr["file_path"]
        if not p.is_file():
            raise DatasetError(str(p), f"frames[{i}].file_path", "test depth .npy is missing")
        d = np.load(p, allow_pickle=False).astype(np.float32)
        if d.ndim != 2 or (depths and d.shape != depths[0].shape):
            raise DatasetError(str(p), f"frames[{i}].file_path", f"unexpected depth shape {d.shape}")
        cams.append(paper_to_blender_c2w(fr["transform_matrix"]).tolist())
        depths.append(d)
    if not cams:
        return GroundTruth()
    angle = doc.get("camera_angle_x") or sensor.fov_rad
    return GroundTruth(test_views=write_test_views(wr, cams, np.stack(depths), float(angle)))


__all__ = ["export_platonerf", "import_platonerf", "transient_relpath"]
