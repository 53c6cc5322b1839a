"""Ground truth in the PlatoNeRF layout: train-view depth, test-view depths and their poses.

Their ground-truth renderer (Mitsuba 3, ``render_ground_truth.py``) writes one range image per test
view, ``ground_truth/depth_XXXX.npy`` (512 x 512, 90 degrees, 0 where the ray hits nothing), with the
cameras made in code, not stored: a dolly from (0, -1.5, 0) towards (0, -1.5, 3) then 100 views on an
orbit of radius 0.99 m around it (the same poses their ``render_test_depth.py`` renders the fitted
field from). Without a pose file we rebuild those poses (``frames.paper_test_view_cameras``: the
last 100 files are the orbit, the ones before the dolly). Our exports add ``transforms_test.json``
with the poses (OpenGL camera-to-world in the paper's world, like the train pose) so any views
round-trip. Misses are 0 in these files (Mitsuba's convention) and inf in ours.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..frames import blender_to_paper_c2w, blender_to_paper_points, paper_to_blender_c2w, paper_to_blender_points
from ..units import deg_to_rad, rad_to_deg
from .schema import DatasetError, GroundTruth, SensorSpec
from .store import Dataset, DatasetWriter

GT_DIR = "ground_truth"
TRANSFORMS_TEST = "transforms_test.json"
TEST_DEPTH = GT_DIR + "/depth_{:04d}"
TRAIN_DEPTH_NPY = GT_DIR + "/train_depth.npy"
MESH_PLY = GT_DIR + "/mesh.ply"
ORBIT_VIEWS = 100                  # their orbit (render_ground_truth.py, render_test_depth.py)
THEIR_TEST_FOV_DEG = 90.0          # their rgb.xml camera


def _to_theirs(depth: np.ndarray) -> np.ndarray:
    return np.where(np.isfinite(depth), depth, 0.0).astype(np.float32)


def _to_ours(depth: np.ndarray, path: Path, field: str) -> np.ndarray:
    d = np.asarray(depth, np.float32)
    if d.ndim != 2 or not np.issubdtype(d.dtype, np.floating) or np.any(np.isnan(d)) or np.any(d < 0):
        raise DatasetError(str(path), field, f"expected a 2-D range image >= 0 without NaN, got shape {d.shape}")
    return np.where(d > 0, d, np.inf).astype(np.float32)


def export_ground_truth(ds: Dataset, out: Path, angle_deg: float) -> None:
    depth = ds.train_depth()
    if depth is not None:
        (out / GT_DIR).mkdir(exist_ok=True)
        np.save(out / TRAIN_DEPTH_NPY, _to_theirs(depth))
    rel = ds.manifest.ground_truth.mesh_file
    if rel is not None:
        import trimesh

        mesh = trimesh.load(ds.path(rel), force="mesh", process=False)
        mesh.vertices = blender_to_paper_points(mesh.vertices)  # a rotation: winding is kept
        (out / GT_DIR).mkdir(exist_ok=True)
        mesh.export(out / MESH_PLY)
    gt = ds.test_views()
    if gt is None:
        return
    tv, cams, depths = gt
    (out / GT_DIR).mkdir(exist_ok=True)
    frames = []
    for i, (c, d) in enumerate(zip(cams, depths)):
        np.save(out / (TEST_DEPTH.format(i) + ".npy"), _to_theirs(d))
        frames.append({"file_path": TEST_DEPTH.format(i), "transform_matrix": blender_to_paper_c2w(c).tolist()})
    fov = tv.fov_rad if tv.fov_axis == "x" else 2 * math.atan(math.tan(tv.fov_rad / 2) * tv.width / tv.height)
    (out / TRANSFORMS_TEST).write_text(json.dumps({"camera_angle_x": rad_to_deg(fov), "frames": frames}, indent=4))


def _test_views_from_pose_file(src: Path) -> tuple[list, list, float]:
    tpath = src / TRANSFORMS_TEST
    f = str(tpath)
    try:
        doc = json.loads(tpath.read_text())
        frames, angle = doc["frames"], float(doc["camera_angle_x"])
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError, ValueError) as exc:
        raise DatasetError(f, "frames", f"expected camera_angle_x and frames ({exc})") from None
    cams, depths = [], []
    for i, fr in enumerate(frames):
        p = src / (str(fr.get("file_path")) + ".npy")
        if not p.is_file():
            raise DatasetError(str(p), f"frames[{i}].file_path", "test depth .npy is missing")
        depths.append(_to_ours(np.load(p, allow_pickle=False), p, f"frames[{i}].file_path"))
        cams.append(paper_to_blender_c2w(fr["transform_matrix"]).tolist())
    return cams, depths, angle


def their_test_cameras(n_views: int) -> np.ndarray:
    """Their test poses (Blender frame) for `n_views` depth files: the last 100 on the orbit."""
    from ..ground_truth import test_view_cameras

    n_orbit = min(ORBIT_VIEWS, n_views)
    return test_view_cameras(n_views - n_orbit, n_orbit)


def _test_views_from_depth_files(src: Path) -> tuple[list, list, float]:
    files, i = [], 0
    while (src / (TEST_DEPTH.format(i) + ".npy")).is_file():
        files.append(src / (TEST_DEPTH.format(i) + ".npy"))
        i += 1
    depths = [_to_ours(np.load(p, allow_pickle=False), p, "test depth") for p in files]
    cams = [c.tolist() for c in their_test_cameras(len(files))] if files else []
    return cams, depths, THEIR_TEST_FOV_DEG


def import_ground_truth(src: Path, wr: DatasetWriter, sensor: SensorSpec, train_depth=None) -> GroundTruth:
    from ..ground_truth import write_mesh, write_test_views, write_train_depth

    gt = GroundTruth()
    if (src / TRANSFORMS_TEST).is_file():
        cams, depths, angle = _test_views_from_pose_file(src)
    else:
        cams, depths, angle = _test_views_from_depth_files(src)
    if depths:
        if any(d.shape != depths[0].shape for d in depths):
            raise DatasetError(str(src / GT_DIR), "test depth", "test depth images differ in size")
        gt.test_views = write_test_views(wr, cams, np.stack(depths), deg_to_rad(angle))
    p = Path(train_depth) if train_depth is not None else src / TRAIN_DEPTH_NPY
    if p.is_file():
        d = _to_ours(np.load(p, allow_pickle=False), p, "train depth")
        if d.shape != (sensor.height, sensor.width):
            raise DatasetError(str(p), "train depth", f"expected shape {(sensor.height, sensor.width)}, got {d.shape}")
        gt.train_depth_file = write_train_depth(wr, d)
    elif train_depth is not None:
        raise DatasetError(str(p), "train depth", "file is missing")
    p = src / MESH_PLY
    if p.is_file():
        import trimesh

        try:
            mesh = trimesh.load(p, force="mesh", process=False)
        except Exception as exc:  # noqa: BLE001 - any unreadable mesh is one clear error
            raise DatasetError(str(p), "ground-truth mesh", f"not a readable mesh ({exc})") from None
        mesh.vertices = paper_to_blender_points(mesh.vertices)
        gt.mesh_file = write_mesh(wr, mesh)
    return gt
