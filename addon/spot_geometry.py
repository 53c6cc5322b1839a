"""Where the laser lands: ray casts in the evaluated scene, random candidates, diverse selection.

Kept apart from the operators so tests call the same code without a 3D View.
Errors are ``SpotError`` with a message for the user; operators turn them into reports.
"""

from __future__ import annotations

from mathutils import Vector

from .config_io import lidar_camera  # puts the project modules on sys.path (addon/_project.py)
from .props import ADVISED_PREFIX

from pipeline import blender_scene as bs  # noqa: E402
from torch_recon.contract.dataset import SensorSpec  # noqa: E402
from torch_recon.contract.errors import PlatolidarError  # noqa: E402


class SpotError(PlatolidarError, RuntimeError):
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


def cast(scene, depsgraph, origin, direction, exclude=()):
    """First surface along a ray, skipping objects in `exclude` (e.g. a laser's own mesh).

    Returns (location, normal, object) or None when the ray leaves the scene (the simulator's ray cast).
    """
    hit = bs.ray_cast(scene, depsgraph, origin, direction, exclude=exclude)
    return None if hit is None else (Vector(hit[0]), Vector(hit[1]), hit[2])


def _laser_exclude(scene) -> tuple:
    s = scene.platolidar
    return (s.laser_object,) if s.laser_mode == "OBJECT" and s.laser_object is not None else ()


def aim_laser(scene, depsgraph, toward) -> Vector | None:
    """Where the laser, aimed from its origin at the point `toward`, hits the scene (None: nothing)."""
    origin = laser_origin(scene)
    direction = Vector(toward) - origin
    if direction.length < 1e-9:
        raise SpotError("The aim point coincides with the laser origin")
    hit = cast(scene, depsgraph, origin, direction, _laser_exclude(scene))
    return None if hit is None else hit[0]


def add_spot(scene, target, name: str = "", advised: bool = False):
    """Append a spot aimed at the world point `target` and make it active; `advised`: from Advise Spots
    (named 'Advised NN', see props.ADVISED_PREFIX)."""
    s = scene.platolidar
    sp = s.spots.add()
    sp.target = tuple(target)
    sp.enabled = True
    sp.advised = advised
    sp.name = name or _unique_name(s.spots, ADVISED_PREFIX if advised else "Spot")
    s.active_spot_index = len(s.spots) - 1
    return sp


def _unique_name(spots, prefix: str = "Spot") -> str:
    used = {sp.name for sp in spots}
    i = 1
    while f"{prefix} {i:02d}" in used:
        i += 1
    return f"{prefix} {i:02d}"


def generate_spots(scene, depsgraph, n: int, keep: int, seed: int):
    """`keep` spread-out spots among up to `n` random candidates: the simulator's own random spots
    (contract.spots.random_spot_targets), so the same seed gives the same spots in both.

    Returns (points: list of Vectors in selection order, number of candidates found).
    """
    cam = lidar_camera(scene)
    if cam is None:
        raise SpotError("No lidar camera: pick one in the Sensor panel or set the scene camera")
    if cam.data.type != "PERSP":
        raise SpotError(f"Lidar camera '{cam.name}' must be a perspective camera (it is {cam.data.type.lower()})")
    s = scene.platolidar
    w, h = max(1, s.width), max(1, s.height)
    fov, axis = bs.camera_fov(cam, w, h)
    sensor = SensorSpec(width=w, height=h, fov_rad=fov, fov_axis=axis, camera_to_world=bs.rigid_c2w(cam).tolist(),
                        laser_origin=list(laser_origin(scene)))
    points, _, found = bs.random_spot_targets(scene, depsgraph, sensor, int(n), int(keep), int(seed),
                                              tuple(o.original for o in _laser_exclude(scene)))
    return [Vector(p) for p in points], found


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
