"""Where the laser lands: ray casts in the evaluated scene, random candidates, diverse selection.

Kept apart from the operators so tests call the same code without a 3D View.
Errors are ``SpotError`` with a message for the user; operators turn them into reports.
"""

from __future__ import annotations

import math
import random

from mathutils import Vector

from .config_io import lidar_camera


class SpotError(RuntimeError):
    """A state the user can fix (no camera, nothing hit, ...)."""


def laser_origin(scene) -> Vector:
    """World position of the laser: the lidar camera (co-located) or the chosen object."""
    s = scene.platolidar
    if s.laser_mode == "OBJECT":
        if s.laser_object is None:
            raise SpotError("Laser origin is 'Object' but no laser object is chosen (Sensor panel)")
        return s.laser_object.matrix_world.translation.copy()
    cam = lidar_camera(scene)
    if cam is None:
        raise SpotError("No lidar camera: pick one in the Sensor panel or set the scene camera")
    return cam.matrix_world.translation.copy()


def cast(scene, depsgraph, origin, direction, exclude=(), max_hops: int = 16):
    """First surface along a ray, skipping objects in `exclude` (e.g. a laser's own mesh).

    Returns (location, normal, object) or None when the ray leaves the scene.
    """
    origin, direction = Vector(origin), Vector(direction).normalized()
    for _ in range(max_hops):
        hit, loc, normal, _index, obj, _matrix = scene.ray_cast(depsgraph, origin, direction)
        if not hit:
            return None
        if obj is None or obj.original not in exclude:
            return loc.copy(), normal.copy(), obj
        origin = loc + direction * 1e-5
    return None


def aim_laser(scene, depsgraph, toward) -> Vector | None:
    """Where the laser, aimed from its origin at the point `toward`, hits the scene (None: nothing)."""
    origin = laser_origin(scene)
    direction = Vector(toward) - origin
    if direction.length < 1e-9:
        raise SpotError("The aim point coincides with the laser origin")
    s = scene.platolidar
    exclude = (s.laser_object,) if s.laser_mode == "OBJECT" and s.laser_object is not None else ()
    hit = cast(scene, depsgraph, origin, direction, exclude)
    return None if hit is None else hit[0]


def add_spot(scene, target, name: str = ""):
    """Append a spot aimed at the world point `target` and make it active."""
    s = scene.platolidar
    sp = s.spots.add()
    sp.target = tuple(target)
    sp.enabled = True
    sp.name = name or _unique_name(s.spots)
    s.active_spot_index = len(s.spots) - 1
    return sp


def _unique_name(spots) -> str:
    used = {sp.name for sp in spots}
    i = 1
    while f"Spot {i:02d}" in used:
        i += 1
    return f"Spot {i:02d}"


def camera_ray_direction(cam, scene, u: float, v: float) -> Vector:
    """World direction through the normalised image point (u right, v down, both in [0, 1])."""
    s = scene.platolidar
    data = cam.data
    if data.type != "PERSP":
        raise SpotError(f"Lidar camera '{cam.name}' must be a perspective camera (it is {data.type.lower()})")
    w, h = max(1, s.width), max(1, s.height)
    fit = data.sensor_fit
    axis_x = (w >= h) if fit == "AUTO" else (fit == "HORIZONTAL")
    fov = data.angle if fit == "AUTO" else (data.angle_x if axis_x else data.angle_y)
    half = math.tan(0.5 * fov)
    tx, ty = (half, half * h / w) if axis_x else (half * w / h, half)
    local = Vector(((2.0 * u - 1.0) * tx, (1.0 - 2.0 * v) * ty, -1.0))
    return (cam.matrix_world.to_3x3() @ local).normalized()


def random_candidates(scene, depsgraph, n: int, seed: int, max_tries_per_spot: int = 20, margin: float = 0.05):
    """Up to n surface points the camera sees and the laser reaches, at random pixel centres.

    Pixel centres (not any image point): the pixel that holds the spot then sees the spot itself,
    so its first-bounce return is recorded even next to a depth edge. Pixels within `margin` of
    the image border are skipped, as the simulator's own random spots do.
    Returns (points, normals): lists of Vectors (world frame).
    """
    cam = lidar_camera(scene)
    if cam is None:
        raise SpotError("No lidar camera: pick one in the Sensor panel or set the scene camera")
    rng = random.Random(seed)
    cam_origin = cam.matrix_world.translation.copy()
    points, normals = [], []
    for _ in range(max(1, n) * max_tries_per_spot):
        if len(points) >= n:
            break
        w, h = max(1, scene.platolidar.width), max(1, scene.platolidar.height)
        col = rng.randrange(int(margin * w), max(int(margin * w) + 1, w - int(margin * w)))
        row = rng.randrange(int(margin * h), max(int(margin * h) + 1, h - int(margin * h)))
        d = camera_ray_direction(cam, scene, (col + 0.5) / w, (row + 0.5) / h)
        hit = cast(scene, depsgraph, cam_origin, d)
        if hit is None:
            continue
        p, normal = hit[0], hit[1]
        q = aim_laser(scene, depsgraph, p)
        # the laser must land where the camera looks (not on an occluder in between)
        if q is not None and (q - p).length <= 1e-3 * (p - cam_origin).length + 1e-4:
            points.append(q)
            normals.append(normal)
    return points, normals


def select_diverse(points, normals, k: int, seed: int) -> list[int]:
    """Indices of k spread-out spots: the simulator's own heuristic (torch_recon.contract.spots)."""
    import numpy as np
    from torch_recon.contract.spots import select_diverse_spots

    idx = select_diverse_spots(np.array([tuple(p) for p in points], np.float64).reshape(-1, 3),
                               None if normals is None else
                               np.array([tuple(v) for v in normals], np.float64).reshape(-1, 3),
                               int(k), np.random.default_rng(seed))
    return [int(i) for i in idx]


def check_spots(scene, depsgraph) -> list[str]:
    """Raise SpotError for an enabled spot the laser cannot hit; return warnings for moved targets."""
    s = scene.platolidar
    if s.spot_source != "LIST":
        return []
    origin = laser_origin(scene)
    warnings = []
    for sp in s.spots:
        if not sp.enabled:
            continue
        target = Vector(sp.target)
        if (target - origin).length < 1e-6:
            raise SpotError(f"Spot '{sp.name}' sits at the laser origin")
        hit = aim_laser(scene, depsgraph, target)
        if hit is None:
            raise SpotError(f"Spot '{sp.name}' is aimed at nothing: the laser ray towards "
                            f"({target.x:.3f}, {target.y:.3f}, {target.z:.3f}) leaves the scene")
        miss = (hit - target).length
        if miss > 0.01:
            warnings.append(f"Spot '{sp.name}': the laser lands {miss:.3f} m from its target "
                            "(geometry moved or in the way)")
    return warnings
