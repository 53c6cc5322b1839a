"""Fixtures written the way the PlatoNeRF authors' code writes and reads them (conventions encoded here,
from reading their rendering/preprocess_tof.py, src/utils/load_tof.py and src/run_platonerf*.py).

- `write_their_simulated_layout`: transforms_train.json + ./train/NNN.npy as their preprocessing writes
  (camera pose of a camera at the origin looking at (0, 0, 3) with rows 0 and 2 negated, light origin
  and aimed-at point with x and z negated, camera_angle_x 90 degrees, float16 cubes, walls).
- `their_loader_view`: what their loader + training derive from such a directory (focal length from
  degrees, rows 0 and 2 of the pose negated, corner rays, normalised light directions, first bounce
  from the brightest bin read as (k + 1) * 0.0384 m of round trip).
- `write_their_real_capture`: t2.mat / detector_scan_200x200.mat / two_bounce_detections.mat as their
  real-scene loader reads them (row-major reshape then a vertical flip; rays from theta/phi maps).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

TIME_RES_M = 0.0384
SPEED_OF_LIGHT = 2.99792458e8


def paper_room_cubes(res=32, bins=391, ids=range(24), scene=None):
    """Noise-free analytic cubes of the paper's room (Blender frame) for the paper's laser targets `ids`."""
    from torch_recon.contract.analytic import render_two_bounce
    from torch_recon.contract.synthetic import box_room_scene, default_sensor, paper_laser_directions

    mesh = scene if scene is not None else box_room_scene()
    sensor = default_sensor(width=res, height=res, bins=bins)
    dirs = paper_laser_directions(used_only=False)[list(ids)]
    cubes, parts = render_two_bounce(mesh, sensor, dirs, return_parts=True)
    return mesh, sensor, dirs, cubes, parts


def write_paper_dataset(root, ids, enabled_ids, res=32, bins=391, test_cameras=None):
    """Our dataset of the paper's room with spot ids = indices into the paper's 24 targets."""
    from torch_recon.contract.analytic import range_image
    from torch_recon.contract.dataset import (DatasetWriter, GroundTruth, GroundTruthViews, Manifest, Provenance, Spot,
                                     Transient, TransientLayout)

    mesh, sensor, dirs, cubes, parts = paper_room_cubes(res, bins, ids)
    with DatasetWriter(root) as w:
        spots = [Spot(id=i, laser_direction=d.tolist(), transient_file=w.write_transient(i, Transient.from_dense(c, bins)),
                      enabled=i in enabled_ids, first_bounce=sp.first_bounce.tolist())
                 for i, d, c, sp in zip(ids, dirs, cubes, parts["spots"])]
        mesh.export(w.path("ground_truth/mesh.ply"))
        gt = GroundTruth(train_depth_file=w.write_depth("ground_truth/train_depth.exr", parts["range"]),
                         mesh_file="ground_truth/mesh.ply")
        if test_cameras is not None:
            d = np.stack([range_image(mesh, c, 16, 16, math.pi / 2) for c in test_cameras])
            gt.test_views = GroundTruthViews(16, 16, math.pi / 2, "x", [c.tolist() for c in test_cameras],
                                             w.write_depth("ground_truth/test_depth.exr", d))
        w.commit(Manifest(sensor=sensor, spots=spots, layout=TransientLayout("dense", bins, "float32"),
                          ground_truth=gt, provenance=Provenance(generator="tests", scene="paper-room")))
    return mesh, sensor, parts


def write_their_simulated_layout(out, cubes, targets_mitsuba, fov_deg=90, walls=True):
    """transforms_train.json + ./train/NNN.npy exactly as their preprocess_tof.py leaves them."""
    out = Path(out)
    (out / "train").mkdir(parents=True, exist_ok=True)
    pose = np.eye(4)                      # their look-at of (0,0,0) -> (0,0,3) with up y is the identity
    pose[0, :] *= -1                      # "x left, y up, z forward --> OpenGL"
    pose[2, :] *= -1
    frames = []
    n = len(cubes)
    for i, (cube, tgt) in enumerate(zip(cubes, targets_mitsuba)):
        np.save(out / "train" / f"{i:03d}.npy", np.asarray(cube, np.float16))
        origin = np.zeros(3)
        lookat = np.array(tgt, float)
        origin[[0, 2]] *= -1
        lookat[[0, 2]] *= -1
        fr = {"file_path": f"./train/{i:03d}", "transform_matrix": pose.tolist(),
              "light_origin": origin.tolist(), "light_direction": lookat.tolist()}
        fr.update({"wall_idx_cam": 1, "wall_idx_light": 0} if i < n / 2 else {"wall_idx_cam": 0, "wall_idx_light": 1})
        frames.append(fr)
    doc = {"camera_angle_x": float(fov_deg), "frames": frames}
    if walls:  # the room's side walls x = -2 and x = +2 of the paper's world, in their training frame
        doc["walls"] = [{"plane": [1.0, 0.0, 0.0], "point": [2.0, 0.0, -2.0], "x": 2.0, "y_min": -2.0, "y_max": 2.0,
                         "z_min": -4.0, "z_max": 0.0},
                        {"plane": [1.0, 0.0, 0.0], "point": [-2.0, 0.0, -2.0], "x": -2.0, "y_min": -2.0,
                         "y_max": 2.0, "z_min": -4.0, "z_max": 0.0}]
    (out / "transforms_train.json").write_text(json.dumps(doc, indent=4))
    return out


def their_test_cameras_blender():
    """Their ground-truth cameras as render_ground_truth.py places them (Mitsuba world: a dolly of 39 from
    (0, -1.5, 0) in steps of 0.06282 m along z, then 100 on a circle of 0.99 m around (0, -1.5, 3) from
    -pi/2; all look at (0, -1.5, 3) with up y), as Blender-frame camera-to-world matrices."""
    from torch_recon.contract.frames import look_at_c2w, paper_to_blender_points

    origins = [(0.0, -1.5, 0.06282151815625667 * i) for i in range(39)]
    a = np.linspace(-np.pi / 2, -np.pi / 2 + 2 * np.pi, 100, endpoint=False)
    origins += [(0.99 * np.cos(t), -1.5, 3 + 0.99 * np.sin(t)) for t in a]
    target = paper_to_blender_points([0.0, -1.5, 3.0])
    return np.stack([look_at_c2w(paper_to_blender_points(o), target, up=paper_to_blender_points([0, 1, 0]))
                     for o in origins])


def their_loader_view(datadir, ignore=()):
    """What their load_tof_data + run_platonerf.py derive (training frame), re-derived from their conventions."""
    datadir = Path(datadir)
    meta = json.loads((datadir / "transforms_train.json").read_text())
    walls = meta["walls"]
    out = {"tof": [], "light_o": [], "light_d": [], "walls_light": []}
    for i, fr in enumerate(meta["frames"]):
        if i in ignore:
            continue
        out["tof"].append(np.load(datadir / (fr["file_path"] + ".npy")))
        pose = np.array(fr["transform_matrix"], np.float32)
        d = np.array(fr["light_direction"], np.float32)
        out["light_o"].append(np.array(fr["light_origin"], np.float32))
        out["light_d"].append(d / np.linalg.norm(d))
        out["walls_light"].append(walls[fr["wall_idx_light"]])
    h, w = out["tof"][0].shape[:2]
    focal = 0.5 * w / np.tan(0.5 * np.radians(float(meta["camera_angle_x"])))
    pose = pose.copy()
    pose[2, :] *= -1
    pose[0, :] *= -1
    i, j = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32), indexing="xy")
    dirs = np.stack([(i - 0.5 * w) / focal, -(j - 0.5 * h) / focal, -np.ones_like(i)], -1) @ pose[:3, :3].T
    out.update(H=h, W=w, focal=focal, pose=pose, rays_d=dirs / np.linalg.norm(dirs, axis=-1, keepdims=True))
    out["first_bounce"] = []
    for tof, lo, ld in zip(out["tof"], out["light_o"], out["light_d"]):
        flat = tof.reshape(-1, tof.shape[-1])
        k = int(np.argmax(flat[int(np.argmax(flat.max(axis=1)))]))
        out["first_bounce"].append(lo + ((k + 1) * TIME_RES_M / 2.0) * ld)
    return out


def real_frame_from_blender(p):
    """Fixture choice: the real capture's frame is their training frame (y up, looking down -z)."""
    from torch_recon.contract.frames import blender_to_platonerf_train_points
    return blender_to_platonerf_train_points(p)


def write_their_real_capture(out, mesh, sensor, laser_dirs, laser_pos_real=(0.257, 0.0, 0.0)):
    """The three .mat files of their real-scene loader, from an analytic render of `mesh`.

    Returns (first bounces (S, 3) Blender, per-pixel lit masks (S, H, W), paths (S, H, W) m, image order)."""
    from scipy.io import savemat

    from torch_recon.contract.analytic import render_two_bounce
    from torch_recon.contract.frames import platonerf_train_to_blender_points

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    laser = platonerf_train_to_blender_points(np.asarray(laser_pos_real, float))
    sensor.laser_origin = laser.tolist()
    sensor.bins = 520                                               # every two-bounce path (< 20 m) lands
    two, parts = render_two_bounce(mesh, sensor, laser_dirs, include_first_bounce=False, return_parts=True)
    res = sensor.height
    lit = two.sum(-1) > 0                                           # (S, H, W), image order (row 0 top)
    x = parts["points"]
    c = np.asarray(sensor.camera_to_world)[:3, 3]
    ls = np.stack([sp.first_bounce for sp in parts["spots"]])
    paths = (np.linalg.norm(ls - laser, axis=1)[:, None, None] + np.linalg.norm(x[None] - ls[:, None, None], axis=-1)
             + np.linalg.norm(x - c, axis=-1)[None])
    t2 = np.where(lit, paths / SPEED_OF_LIGHT, np.nan)
    from torch_recon.contract.frames import pixel_rays
    _, d = pixel_rays(sensor.camera_to_world, sensor.width, sensor.height, sensor.fov_rad, sensor.fov_axis)
    dr = real_frame_from_blender(d)                                  # (H, W, 3) their frame
    theta = np.arccos(np.clip(dr[..., 0], -1, 1))                    # d = (cos t, -sin p sin t, cos p sin t)
    phi = np.arctan2(-dr[..., 1], dr[..., 2])
    # their loader reshapes row-major, then flips rows: store the image upside down, flattened
    flat = lambda a: np.flip(a, -2).reshape(a.shape[:-2] + (-1,))  # noqa: E731
    savemat(out / "t2.mat", {"t2": flat(t2)})
    savemat(out / "detector_scan_200x200.mat", {"phiMap": flat(phi), "thetaMap": flat(theta)})
    illum = real_frame_from_blender(ls)
    savemat(out / "two_bounce_detections.mat", {"has_2B": flat(lit.astype(np.float64)),
                                                "illum_pts": np.concatenate([illum, illum[:1] + 9.0])})
    return ls, lit, paths
