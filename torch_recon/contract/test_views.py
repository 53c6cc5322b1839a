"""Test views for any scene: a dolly and an orbit around its objects, every camera in free space.

numpy + trimesh (Embree) only. The paper's 139 views (torch_recon.frames.paper_test_view_cameras) stay a
preset for the paper's room; `scene_test_view_cameras` builds views for any scene:
- centre: the centre of the labelled objects' bounding box (or of the whole scene without objects),
  at the objects' mid height;
- orbit: `orbit` cameras on a horizontal circle around the centre, radius the objects' half diagonal plus
  `orbit_margin_m`, shrunk to stay `clearance_m` + 5 cm inside the room's walls (horizontal rays from the
  centre against the room without its objects);
- dolly: `dolly` cameras from the sensor's position (at the orbit height) towards the centre, stopping
  `orbit_margin_m / 2` outside the objects;
- every camera looks at the centre (up +Z) and is checked with `free_space`; invalid ones are dropped
  and reported (index, reason), never silently kept.

free_space: a camera is valid when it lies inside the scene's bounding box,
at least `clearance_m` from every surface along FREE_SPACE_DIRECTIONS rays, and fewer than
BACK_FACE_SHARE of those rays first hit a back face (inside a solid, or behind a one-sided wall).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from .frames import look_at_c2w

FREE_SPACE_DIRECTIONS = 200
BACK_FACE_SHARE = 0.1


@dataclass
class SceneViewSettings:
    dolly: int = 39
    orbit: int = 100
    clearance_m: float = 0.05
    orbit_margin_m: float = 0.6


def sphere_directions(n: int) -> np.ndarray:
    """n unit vectors spread evenly over the sphere (Fibonacci lattice; deterministic)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    a = math.pi * (1.0 + math.sqrt(5.0)) * i
    return np.stack([r * np.cos(a), r * np.sin(a), z], axis=1)


def free_space(mesh, origins, clearance_m: float = 0.05, n_dirs: int = FREE_SPACE_DIRECTIONS):
    """Per camera origin: (valid bool (N,), reason str per origin ('' when valid))."""
    origins = np.asarray(origins, np.float64).reshape(-1, 3)
    # the bounding box itself, not shrunk: the paper's sensor and first dolly view sit in its open front
    lo, hi = np.asarray(mesh.bounds[0]) - 1e-6, np.asarray(mesh.bounds[1]) + 1e-6
    dirs = sphere_directions(n_dirs)
    valid = np.ones(len(origins), bool)
    reasons = [""] * len(origins)
    inside = np.all(np.isfinite(origins), axis=1) & ~np.any(origins < lo, axis=1) & ~np.any(origins > hi, axis=1)
    for i in np.flatnonzero(~inside):
        valid[i], reasons[i] = False, "outside the scene's bounding box"
    cams = np.flatnonzero(inside)
    if not len(cams):
        return valid, reasons
    # one Embree call for every camera's rays (ray r: camera cams[r // n_dirs], direction r % n_dirs); each
    # ray's first hit does not depend on the others, so this is the per-camera loop's result, ~100x fewer calls
    ray_origins = np.repeat(origins[cams], n_dirs, axis=0)
    locs, ray_idx, tri = mesh.ray.intersects_location(ray_origins, np.tile(dirs, (len(cams), 1)),
                                                      multiple_hits=False)
    order = np.argsort(ray_idx, kind="stable")
    locs, ray_idx, tri = locs[order], ray_idx[order], tri[order]
    cam_of_ray = ray_idx // n_dirs
    dist_all = np.linalg.norm(locs - ray_origins[ray_idx], axis=1)
    back_all = np.einsum("ij,ij->i", dirs[ray_idx % n_dirs], mesh.face_normals[tri]) > 0
    bounds = np.searchsorted(cam_of_ray, np.arange(len(cams) + 1))
    for k, i in enumerate(cams):
        a, b = bounds[k], bounds[k + 1]
        if a == b:
            continue
        dist, back = dist_all[a:b], back_all[a:b]
        if back.mean() * (b - a) >= BACK_FACE_SHARE * n_dirs:
            valid[i], reasons[i] = False, f"inside geometry ({int(back.sum())} of {n_dirs} rays hit a back face)"
        elif dist.min() < clearance_m:
            valid[i], reasons[i] = False, f"{dist.min():.3f} m from a surface (clearance {clearance_m} m)"
    return valid, reasons


def _orbit_radius(room_mesh, centre, want, clearance_m):
    """The wanted radius, shrunk to keep clear of the room's walls around the centre."""
    if room_mesh is None or len(room_mesh.faces) == 0:
        return want
    a = np.linspace(0, 2 * math.pi, 72, endpoint=False)
    dirs = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)
    locs, ray_idx, _ = room_mesh.ray.intersects_location(np.broadcast_to(centre, dirs.shape), dirs,
                                                         multiple_hits=False)
    if len(ray_idx) == 0:
        return want
    wall = float(np.linalg.norm(locs - centre, axis=1).min())
    return min(want, wall - clearance_m - 0.05)


def scene_test_view_cameras(gt_mesh, object_meshes, sensor_c2w, settings: SceneViewSettings | None = None,
                            room_mesh=None, warn=True):
    """(camera-to-world (N, 4, 4) of the valid views, report dict) for any scene (see module doc)."""
    s = settings or SceneViewSettings()
    if object_meshes:
        lo = np.min([m.bounds[0] for m in object_meshes], axis=0)
        hi = np.max([m.bounds[1] for m in object_meshes], axis=0)
    else:
        lo, hi = np.asarray(gt_mesh.bounds[0]), np.asarray(gt_mesh.bounds[1])
    centre = 0.5 * (lo + hi)
    half_diag = 0.5 * float(np.linalg.norm((hi - lo)[:2]))
    radius = _orbit_radius(room_mesh if object_meshes else gt_mesh, centre,
                           half_diag + s.orbit_margin_m if object_meshes else 0.5 * half_diag, s.clearance_m)
    radius = max(radius, half_diag + s.clearance_m if object_meshes else 0.1)
    sensor = np.asarray(sensor_c2w, np.float64)[:3, 3]
    start = np.array([sensor[0], sensor[1], centre[2]])
    to_c = centre - start
    dist = float(np.linalg.norm(to_c[:2]))
    stop = max(dist - (half_diag + 0.5 * s.orbit_margin_m), 0.0)
    origins, kinds = [], []
    for i in range(s.dolly):
        f = 0.0 if s.dolly == 1 else i / (s.dolly - 1)
        origins.append(start + (to_c / max(dist, 1e-9)) * stop * f)
        kinds.append("dolly")
    a0 = math.atan2(start[1] - centre[1], start[0] - centre[0])     # the orbit starts on the sensor's side
    for k in range(s.orbit):
        a = a0 + 2 * math.pi * k / max(s.orbit, 1)
        origins.append(centre + radius * np.array([math.cos(a), math.sin(a), 0.0]))
        kinds.append("orbit")
    cams, keep, report = check_cameras(gt_mesh, origins, centre, s.clearance_m, kinds, warn)
    report.update({"trajectory": "scene", "centre": centre.tolist(), "orbit_radius_m": float(radius),
                   "dolly_stop_m": float(stop)})
    return cams, report


def check_cameras(gt_mesh, origins, target, clearance_m, kinds=None, warn=True, c2ws=None):
    """Look-at cameras (or given c2ws) checked by free_space: (valid c2ws, valid mask, report)."""
    origins = np.asarray(origins, np.float64).reshape(-1, 3)
    valid, reasons = free_space(gt_mesh, origins, clearance_m)
    cams = []
    for i, o in enumerate(origins):
        if c2ws is not None:
            cams.append(np.asarray(c2ws[i], np.float64))
            continue
        try:
            cams.append(look_at_c2w(o, target, up=(0.0, 0.0, 1.0)))
        except ValueError as exc:   # a camera on the target or looking straight up/down
            valid[i], reasons[i] = False, str(exc)
            cams.append(np.eye(4))
    invalid = [{"index": i, "kind": (kinds[i] if kinds else None), "origin": origins[i].tolist(), "reason": r}
               for i, r in enumerate(reasons) if not valid[i]]
    if invalid and warn:
        warnings.warn(f"{len(invalid)} of {len(origins)} test views are not in free space and were dropped "
                      f"(first: view {invalid[0]['index']}: {invalid[0]['reason']})", stacklevel=2)
    report = {"n_requested": int(len(origins)), "n_valid": int(valid.sum()), "n_invalid": len(invalid),
              "clearance_m": float(clearance_m), "invalid": invalid}
    out = np.stack([c for c, v in zip(cams, valid) if v]) if valid.any() else np.zeros((0, 4, 4))
    return out, valid, report


def check_test_views(gt_mesh, c2ws, clearance_m: float = 0.005, warn=True):
    """Validity of given test cameras (e.g. a dataset's, or the paper's preset): (valid mask, report)."""
    c2ws = np.asarray(c2ws, np.float64).reshape(-1, 4, 4)
    _, valid, report = check_cameras(gt_mesh, c2ws[:, :3, 3], None, clearance_m, warn=warn, c2ws=c2ws)
    return valid, report
