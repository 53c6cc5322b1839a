"""The authors' real-capture layout -> a measurements-only dataset of ours (schema 1.1).

Their real-scene loader (``load_real`` in their src/utils/load_tof.py) reads three MATLAB files:
- ``t2.mat``: ``t2`` (S, N) two-bounce time of flight per pixel in SECONDS (laser -> l_k -> x -> sensor);
  NaN where nothing was detected;
- ``detector_scan_200x200.mat``: ``phiMap``, ``thetaMap`` (N values): the pixel ray angles, ray
  direction (cos t, -sin p sin t, cos p sin t) from the sensor at the origin;
- ``two_bounce_detections.mat``: ``has_2B`` (S, N) 1 where a two-bounce return was seen (0 = shadow),
  ``illum_pts`` (>= S, 3) the illuminated points l_k.
N = res x res pixels (200 x 200), reshaped row-major and then flipped vertically; 16 spots; the laser
sits at (0.257, 0, 0); bins of 8 ps. Nothing fixes the frame's up axis: we read it as their training
frame (y up, the camera looking down -z) like their simulated data, and convert with the same rotation
(``frames.platonerf_train_to_blender_points``). The per-pixel rays are stored exactly
(``sensor.ray_directions_file``); the sensor's pinhole (pose, field of view) is the best fit to them,
used only where something projects points into the image. If the rays' columns run right-to-left the
columns are flipped so that the image is a proper (unmirrored) camera image (recorded in provenance).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from ..frames import platonerf_train_to_blender_points
from ..units import m_to_ps, ps_to_m
from .schema import DatasetError, Manifest, Provenance, PulseSpec, SensorSpec, Spot, TimeGate, TransientLayout
from .store import Dataset, DatasetWriter

FILES = {"t2": "t2.mat", "angles": "detector_scan_200x200.mat", "detections": "two_bounce_detections.mat"}
THEIR_LASER_POSITION = (0.257, 0.0, 0.0)
THEIR_BIN_PS = 8.0


def _loadmat(path: Path, keys: tuple) -> dict:
    from scipy.io import loadmat

    if not path.is_file():
        raise DatasetError(str(path), "", "file is missing")
    try:
        d = loadmat(path)
    except Exception as exc:  # noqa: BLE001 - scipy raises several types on a bad file
        raise DatasetError(str(path), "", f"not a readable MATLAB file ({exc})") from None
    for k in keys:
        if k not in d:
            raise DatasetError(str(path), k, "missing")
    return {k: np.asarray(d[k], np.float64) for k in keys}


def _images(a: np.ndarray, n_img: int | None, res: int, path: Path, field: str) -> np.ndarray:
    """Row-major reshape to (n, res, res), then the vertical flip their loader applies."""
    want = res * res * (1 if n_img is None else n_img)
    if a.size < want or (n_img is None and a.size != want):
        raise DatasetError(str(path), field, f"expected {want} values ({'' if n_img is None else f'{n_img} x '}"
                                             f"{res} x {res}), got shape {a.shape}")
    if n_img is not None:
        a = a.reshape(a.shape[0], -1)[:n_img] if a.ndim >= 2 and a.shape[0] >= n_img else a
        return np.flip(a.reshape(n_img, res, res), 1)
    return np.flip(a.reshape(res, res), 0)


def _pinhole_fit(dirs: np.ndarray, valid: np.ndarray):
    """(rotation with columns right, up, back; fov_x; mirrored) of the pinhole best matching the rays.

    mirrored: image columns run against 'right' (the caller flips them and fits again)."""
    w = dirs.shape[1]
    rows, cols = np.nonzero(valid)
    d = dirs[valid]
    fwd = d.mean(0) / np.linalg.norm(d.mean(0))
    up = (d * -(rows - rows.mean())[:, None]).sum(0)                  # row 0 is the image top
    up -= fwd * (up @ fwd)
    up /= np.linalg.norm(up)
    right = np.cross(fwd, up)
    rot = np.stack([right, up, -fwd], 1)
    cam = d @ rot
    x = cam[:, 0] / -cam[:, 2]
    c = cols + 0.5 - 0.5 * w
    f = float((c * x).sum() / max((x * x).sum(), 1e-30))              # least squares: col offset = f x
    return rot, 2.0 * math.atan(0.5 * w / abs(f)), f < 0


def import_platonerf_real(src_dir: str | os.PathLike, out_dir: str | os.PathLike, *, spots: int = 16,
                          laser_position=THEIR_LASER_POSITION, bin_width_ps: float = THEIR_BIN_PS) -> Dataset:
    src = Path(src_dir)
    t2 = _loadmat(src / FILES["t2"], ("t2",))["t2"]
    ang = _loadmat(src / FILES["angles"], ("phiMap", "thetaMap"))
    det = _loadmat(src / FILES["detections"], ("has_2B", "illum_pts"))
    n = ang["phiMap"].size
    res = int(round(math.sqrt(n)))
    if res * res != n:
        raise DatasetError(str(src / FILES["angles"]), "phiMap", f"expected res x res values, got {n}")
    illum = det["illum_pts"]
    if illum.ndim != 2 or illum.shape[1] != 3 or illum.shape[0] < spots:
        raise DatasetError(str(src / FILES["detections"]), "illum_pts", f"expected >= {spots} x 3, got {illum.shape}")
    t2 = _images(t2, spots, res, src / FILES["t2"], "t2")
    has = _images(det["has_2B"], spots, res, src / FILES["detections"], "has_2B")
    phi = _images(ang["phiMap"], None, res, src / FILES["angles"], "phiMap")
    theta = _images(ang["thetaMap"], None, res, src / FILES["angles"], "thetaMap")
    ok = np.isfinite(phi) & np.isfinite(theta)
    d_real = np.stack([np.cos(theta), -np.sin(phi) * np.sin(theta), np.cos(phi) * np.sin(theta)], -1)
    dirs = platonerf_train_to_blender_points(np.where(ok[..., None], d_real, 0.0))
    if not ok.any():
        raise DatasetError(str(src / FILES["angles"]), "phiMap", "no finite pixel angle")
    rot, fov, flipped = _pinhole_fit(dirs, ok)
    if flipped:
        dirs, ok, t2, has = dirs[:, ::-1], ok[:, ::-1], t2[:, :, ::-1], has[:, :, ::-1]
        rot, fov, _ = _pinhole_fit(dirs, ok)
    dirs = np.where(ok[..., None], dirs, rot[:, 2] * -1.0)                # invalid pixels: any unit ray
    path = ps_to_m(np.where(np.isfinite(t2), t2, 0.0) * 1e12)
    if np.any(path < 0):
        raise DatasetError(str(src / FILES["t2"]), "t2", "negative times of flight")
    lit = (np.nan_to_num(has) > 0.5) & (path > 0)
    valid = ok[None] & (lit | (np.nan_to_num(has) <= 0.5))               # detected but no time: unusable
    laser = platonerf_train_to_blender_points(np.asarray(laser_position, np.float64))
    l_b = platonerf_train_to_blender_points(illum[:spots])
    if not np.all(np.isfinite(l_b)):
        raise DatasetError(str(src / FILES["detections"]), "illum_pts", "non-finite illuminated points")
    bw_m = ps_to_m(bin_width_ps)
    c2w = np.eye(4)
    c2w[:3, :3] = rot
    sensor = SensorSpec(width=res, height=res, fov_rad=fov, fov_axis="x", camera_to_world=c2w.tolist(),
                        laser_origin=laser.tolist(), pulse=PulseSpec("gaussian", bin_width_ps),
                        bin_width_ps=bin_width_ps, bin_width_m=bw_m,
                        bins=int(math.ceil(max(float(path.max()), bw_m) / bw_m)) + 1, start_m=0.0,
                        time_gate=TimeGate(False, 0))
    with DatasetWriter(out_dir) as wr:
        sensor.ray_directions_file = wr.write_ray_directions(dirs)
        spot_list = []
        for k in range(spots):
            ld = l_b[k] - laser
            spot_list.append(Spot(id=k, laser_direction=(ld / np.linalg.norm(ld)).tolist(), transient_file=None,
                                  first_bounce=l_b[k].tolist(),
                                  measurement_file=wr.write_spot_measurement(k, np.where(lit[k], path[k], 0.0),
                                                                             lit[k], valid[k])))
        prov = Provenance(generator="platonerf-real-import", generator_version="1", seed=0, scene=src.name,
                          extra={"source": str(src), "platonerf_real": {
                              "res": res, "spots": spots, "laser_position": list(map(float, laser_position)),
                              "bin_width_ps": bin_width_ps, "columns_flipped": flipped,
                              "max_time_ps": float(m_to_ps(path.max()))}})
        wr.commit(Manifest(sensor=sensor, spots=spot_list, layout=TransientLayout("dense", sensor.bins, "float32"),
                           provenance=prov, kind="measurements"))
    return Dataset(out_dir)
