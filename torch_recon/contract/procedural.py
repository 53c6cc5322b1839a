"""Procedural scenes for batch datasets: random rooms, objects and laser spots from a seed (no bpy).

`procedural_scene(seed, settings)` returns an `ExampleScene` (the same description the examples use), so
Blender builds it with `pipeline.blender_scene.build_example` and the analytic tests ray-cast the very
same triangles. Every random choice comes from one `numpy.random.default_rng(seed)`: the same seed and
settings give the same scene, bit for bit.

- Room: open towards the sensor (at the origin, looking along +Y, 90 degree view like the paper's),
  half width, depth, floor and ceiling heights and wall albedo drawn from ranges; sometimes a concave
  (curved) back wall, sometimes an L-shaped back (a block filling one back corner).
- Objects: 1..max_objects, each a primitive (box, cylinder, cone, sphere, capsule, torus, blob) with a
  random non-uniform scale and a turn about the vertical, or a mesh from `mesh_folder`; standing on the
  floor inside the room and inside the sensor's view, footprints apart from each other and the walls.
- Spots: the project's one spot recipe (contract.spots.random_spot_targets) with Embree ray casts
  against the scene: points the sensor sees and the co-located laser really lands on.
- Bins: the scene sets the simulator's `bins` (config_overrides) to hold its longest two-bounce path
  at the default bin width (bigger rooms than the paper's need more than its 391).

Object names are `obj{i}_{kind}`, each its own labelled object (Objects/<name> in Blender).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from .errors import SettingsError
from .scenes import MeshPart, ExampleScene, box, blob, curved_wall, room_walls, sensor_c2w
from .units import ps_to_m

PREFIX = "procedural-"
OBJECT_KINDS = ("box", "cylinder", "cone", "sphere", "capsule", "torus", "blob")
MESH_SUFFIXES = (".ply", ".obj", ".glb", ".gltf", ".stl", ".off")
#: footprint gap between objects and from the walls (m)
GAP_M = 0.1
#: the simulator's default bin width (SimulationConfig.bin_ps, the paper's 128 ps)
DEFAULT_BIN_PS = 128.0


@dataclass(frozen=True)
class ProceduralSettings:
    """Ranges the generator draws from (metres; albedo in [0, 1])."""

    half_width: tuple = (1.5, 2.5)        # room half width (x)
    depth: tuple = (3.0, 5.0)             # room depth (y) from the sensor's plane
    floor_z: tuple = (-2.0, -1.2)         # floor height below the sensor
    ceiling_z: tuple = (1.2, 2.2)         # ceiling height above the sensor
    wall_albedo: tuple = (0.3, 0.9)
    object_albedo: tuple = (0.3, 0.9)
    curved_wall_chance: float = 0.2       # chance of a concave back wall
    l_shape_chance: float = 0.2           # chance of a block filling one back corner (an L-shaped back)
    min_objects: int = 1
    max_objects: int = 3
    object_size: tuple = (0.25, 0.9)      # an object's largest horizontal extent
    object_height: tuple = (0.2, 1.2)
    near_y: float = 1.5                   # objects stand at least this far in front of the sensor
    kinds: tuple = OBJECT_KINDS           # primitive kinds to draw from
    mesh_folder: str | None = None        # also draw meshes (.ply/.obj/.glb/.stl/.off) from this folder
    spot_candidates: int = 24             # random candidate spots (paper: 24) ...
    spots: int = 16                       # ... of which this many spread-out ones are the scene's spots

    def validate(self):
        for name in ("half_width", "depth", "floor_z", "ceiling_z", "wall_albedo", "object_albedo", "object_size",
                     "object_height"):
            lo_hi = getattr(self, name)
            if len(lo_hi) != 2 or not lo_hi[0] <= lo_hi[1]:
                raise SettingsError(f"procedural.{name}", f"expected a range [low, high], got {list(lo_hi)}")
        if self.floor_z[1] >= 0 or self.ceiling_z[0] <= 0:
            raise SettingsError("procedural.floor_z", "the sensor (z = 0) must be between floor and ceiling")
        if not 1 <= self.min_objects <= self.max_objects:
            raise SettingsError("procedural.max_objects", f"expected 1 <= min_objects <= max_objects, got "
                                                          f"{self.min_objects}, {self.max_objects}")
        bad = [k for k in self.kinds if k not in OBJECT_KINDS]
        if bad or not (self.kinds or self.mesh_folder):
            raise SettingsError("procedural.kinds", f"expected some of {', '.join(OBJECT_KINDS)}, got {list(self.kinds)}")
        if self.mesh_folder is not None and not _mesh_files(self.mesh_folder):
            raise SettingsError("procedural.mesh_folder", f"{self.mesh_folder}: no mesh files "
                                                          f"({', '.join(MESH_SUFFIXES)})")
        if not 1 <= self.spots <= self.spot_candidates:
            raise SettingsError("procedural.spots", f"expected 1 <= spots <= spot_candidates, got {self.spots}")

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}


def _mesh_files(folder) -> list:
    p = Path(folder)
    return sorted(f for f in p.iterdir() if f.suffix.lower() in MESH_SUFFIXES) if p.is_dir() else []


def scene_name(seed: int) -> str:
    return f"{PREFIX}{int(seed):05d}"


# -- objects ------------------------------------------------------------------------------------------
def _unit_primitive(kind: str, rng, mesh_files):
    """A closed mesh of `kind` (trimesh) scaled into the unit cube [-0.5, 0.5]^3 (any aspect)."""
    import trimesh

    if kind == "box":
        m = trimesh.creation.box((1.0, 1.0, 1.0))
    elif kind == "cylinder":
        m = trimesh.creation.cylinder(radius=0.5, height=1.0, sections=32)
    elif kind == "cone":
        m = trimesh.creation.cone(radius=0.5, height=1.0, sections=32)
    elif kind == "sphere":
        m = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    elif kind == "capsule":
        m = trimesh.creation.capsule(height=1.0, radius=0.3, count=(16, 16))
    elif kind == "torus":     # lying flat: a ring on the floor, its hole a hidden surface
        m = trimesh.creation.torus(major_radius=0.35, minor_radius=0.15, major_sections=32, minor_sections=16)
    elif kind == "blob":
        part = blob("b", (0.0, 0.0, 0.0), 0.5, seed=int(rng.integers(2**31)))
        m = trimesh.Trimesh(part.vertices, part.faces, process=False)
    else:     # 'mesh': a file from the folder
        path = mesh_files[int(rng.integers(len(mesh_files)))]
        loaded = trimesh.load(path, force="mesh")
        m = trimesh.Trimesh(np.asarray(loaded.vertices, np.float64), np.asarray(loaded.faces, np.int64))
    v = np.asarray(m.vertices, np.float64)
    lo, hi = v.min(0), v.max(0)
    v = (v - (lo + hi) / 2) / np.maximum(hi - lo, 1e-9)
    return v, np.asarray(m.faces, np.int64)


def _turn_z(v, angle):
    c, s = math.cos(angle), math.sin(angle)
    return v @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


def _object(name, kind, rng, s: ProceduralSettings, mesh_files, max_height):
    """A MeshPart standing on z = 0, centred on the origin horizontally, and its footprint radius."""
    v, f = _unit_primitive(kind, rng, mesh_files)
    size = rng.uniform(*s.object_size)
    aspect = rng.uniform(0.5, 1.0)
    height = min(rng.uniform(*s.object_height), max_height)
    if kind == "torus":
        height = min(height, 0.4 * size)
    v = v * np.array([size, size * aspect, height])
    v = _turn_z(v, rng.uniform(0.0, 2.0 * math.pi))
    v[:, :2] -= (v[:, :2].min(0) + v[:, :2].max(0)) / 2
    v[:, 2] -= v[:, 2].min()
    radius = float(np.linalg.norm(v[:, :2], axis=1).max())
    return MeshPart(name, v, f, float(rng.uniform(*s.object_albedo))), radius


def _place(rng, radius, room, taken, notch, near_y):
    """(x, y) of a footprint of `radius` inside the room, in view (|x| + r < y), clear of others; or None."""
    w, d = room
    for _ in range(200):
        y = rng.uniform(near_y + radius, d - radius - GAP_M)
        lim = min(w - radius - GAP_M, y - radius)   # inside the walls and the 90 degree view
        if lim <= 0 or y <= near_y + radius:
            continue
        x = rng.uniform(-lim, lim)
        if notch is not None and x + radius > notch[0] - GAP_M and y + radius > notch[1] - GAP_M:
            continue
        if all(math.hypot(x - tx, y - ty) >= radius + tr + GAP_M for tx, ty, tr in taken):
            return x, y
    return None


# -- the scene ---------------------------------------------------------------------------------------------
def procedural_scene(seed: int, settings: ProceduralSettings | None = None) -> ExampleScene:
    """The scene of `seed` (an ExampleScene with labelled objects and spot targets)."""
    s = settings or ProceduralSettings()
    s.validate()
    rng = np.random.default_rng([int(seed), 0x9E3779B9])
    w, d = rng.uniform(*s.half_width), rng.uniform(*s.depth)
    z0, z1 = rng.uniform(*s.floor_z), rng.uniform(*s.ceiling_z)
    wall_albedo = float(rng.uniform(*s.wall_albedo))
    curved = rng.random() < s.curved_wall_chance
    l_shape = (not curved) and rng.random() < s.l_shape_chance
    parts = room_walls(albedo=wall_albedo, back_wall=not curved, half_width=w, depth=d, floor_z=z0, ceiling_z=z1)
    notch = None
    style = "box"
    if curved:
        style = "curved"
        radius = rng.uniform(1.2, 2.5) * w
        parts.append(curved_wall(wall_albedo, radius=radius, centre_y=d - radius, half_width=w, floor_z=z0,
                                 ceiling_z=z1))
    elif l_shape:    # a block filling the back corner on a random side; mirrored to +x below when needed
        style = "L"
        nx, ny = rng.uniform(0.3, 0.6) * w, rng.uniform(0.2, 0.4) * d
        notch = (w - nx, d - ny)
        parts.append(box("wall_notch", (w - nx, d - ny, z0), (w, d, z1), wall_albedo))
    # objects (near_y keeps them out of the open front; the notch is on +x, mirrored afterwards)
    mesh_files = _mesh_files(s.mesh_folder) if s.mesh_folder else []
    kinds = list(s.kinds) + (["mesh"] if mesh_files else [])
    n_obj = int(rng.integers(s.min_objects, s.max_objects + 1))
    taken, objects = [], {}
    near_y = min(s.near_y, 0.5 * d)
    for i in range(n_obj):
        kind = kinds[int(rng.integers(len(kinds)))]
        part, r = _object(f"obj{i}_{kind}", kind, rng, s, mesh_files, max_height=0.6 * (z1 - z0))
        xy = _place(rng, r, (w, d), taken, notch, near_y)
        if xy is None:
            continue      # no room left for it: fewer objects, still seeded
        part.vertices = part.vertices + np.array([xy[0], xy[1], z0])
        taken.append((xy[0], xy[1], r))
        parts.append(part)
        objects[part.name] = [part.name]
    if notch is not None and rng.random() < 0.5:     # the L's block on the left instead
        for p in parts:
            p.vertices = p.vertices * np.array([-1.0, 1.0, 1.0])
            p.faces = p.faces[:, ::-1].copy()          # keep outward winding after the mirror
    ex = ExampleScene(scene_name(seed), f"procedural room {2 * w:.2f} x {d:.2f} x {z1 - z0:.2f} m ({style} back), "
                      f"{len(objects)} object(s), seed {seed}", parts, sensor_c2w(), objects=objects)
    targets = scene_spots(ex, s.spot_candidates, s.spots, seed)
    ex.spot_targets = [list(map(float, t)) for t in targets]
    ex.spot_enabled = [True] * len(targets)
    ex.config_overrides = {"bins": bins_needed(ex, targets)}
    return ex


def bins_needed(ex: ExampleScene, targets, bin_ps: float = DEFAULT_BIN_PS, margin_bins: int = 16) -> int:
    """Bins of `bin_ps` that hold every two-bounce path of the scene: |l| + |x - l| + |x| over the spots l
    and the corners x of the scene's bounding box (an upper bound), plus a margin for the pulse."""
    v, _, _ = ex.triangles()
    lo, hi = v.min(0), v.max(0)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    o = np.asarray(ex.camera_to_world, np.float64)[:3, 3]
    t = np.asarray(targets, np.float64).reshape(-1, 3)
    if len(t) == 0:
        return 1
    path = np.linalg.norm(t - o, axis=1)[:, None] + np.linalg.norm(corners[None] - t[:, None], axis=2) \
        + np.linalg.norm(corners - o, axis=1)[None]
    return int(math.ceil(float(path.max()) / ps_to_m(bin_ps))) + margin_bins


def sensor_for(ex: ExampleScene, width: int = 512, height: int = 512):
    """What contract.spots needs of a sensor (co-located laser at the camera centre)."""
    c2w = np.asarray(ex.camera_to_world, np.float64)
    return SimpleNamespace(width=width, height=height, fov_rad=ex.fov_rad, fov_axis=ex.fov_axis,
                           camera_to_world=c2w, laser_origin=c2w[:3, 3].copy())


def scene_caster(ex: ExampleScene):
    """cast(origin, direction) -> (point, normal) | None: the first surface of the scene (Embree)."""
    import trimesh

    mesh, _ = ex.trimesh()
    ray = trimesh.ray.ray_pyembree.RayMeshIntersector(mesh) if trimesh.ray.has_embree else mesh.ray

    def cast(origin, direction):
        locs, _, tri = ray.intersects_location(np.asarray(origin, np.float64)[None],
                                               np.asarray(direction, np.float64)[None], multiple_hits=False)
        if len(locs) == 0:
            return None
        return locs[0], mesh.face_normals[tri[0]]
    return cast


def scene_spots(ex: ExampleScene, candidates: int, keep: int, seed: int) -> np.ndarray:
    """`keep` spread-out laser targets of the scene (the shared spot recipe), (k, 3)."""
    from .spots import random_spot_targets

    pts, _, _ = random_spot_targets(sensor_for(ex), scene_caster(ex), candidates, keep, seed)
    return pts


def procedural_scenes(count: int, first_seed: int = 0, settings: ProceduralSettings | None = None):
    """`count` scenes with seeds first_seed, first_seed + 1, ... (a generator)."""
    for i in range(int(count)):
        yield procedural_scene(first_seed + i, settings)


def settings_from_dict(data: dict | None, source: str = "") -> ProceduralSettings:
    """ProceduralSettings from a plan file's table (lists for ranges), every key checked."""
    from .settings import from_dict

    return from_dict(ProceduralSettings, dict(data or {}), source, prefix="procedural.")
