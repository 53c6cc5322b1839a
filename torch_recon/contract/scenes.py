"""Example scenes as plain geometry (no bpy): Blender's Z-up world frame, metres.

Each scene is a list of parts with an albedo: triangle meshes generated here in
numpy (boxes, a curved wall), so Blender (pipeline/blender_scene.py) and the
independent trimesh/Embree tests (torch_recon.contract.analytic) see the very same
triangles. One part kind, Blender's built-in monkey, exists only inside Blender;
scenes that use it have no bpy-free mesh (`has_exact_mesh` is False) and their
tests use the exported ground-truth mesh instead.

The paper's cave (contract/data/platonerf_cave.json via contract.reference, y-up) maps to Blender by
(x, y, z) -> (-x, z, y): room x in [-2, 2], depth y in [0, 4], height z in
[-2, 2], no front wall; the sensor sits at the origin and looks along +Y.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from . import reference
from .frames import look_at_c2w, paper_to_blender_points

WALL_THICKNESS = 0.02
WALL_ALBEDO = 0.7
OBJECT_ALBEDO = 0.6


@dataclass
class MeshPart:
    name: str
    vertices: np.ndarray          # (V, 3) world frame
    faces: np.ndarray             # (F, 3) triangles, counter-clockwise seen from outside
    albedo: float


@dataclass
class BlenderPrimitive:
    """Geometry that only Blender builds (e.g. the monkey): no bpy-free triangles."""

    name: str
    kind: str                     # 'monkey'
    location: tuple
    scale: float
    subdivisions: int
    albedo: float


@dataclass
class AreaLight:
    """An ambient light (not the laser): square area light facing down -Z."""

    name: str
    location: tuple
    size: float
    power_w: float


@dataclass
class ExampleScene:
    name: str
    description: str
    parts: list
    camera_to_world: np.ndarray
    fov_rad: float = math.pi / 2
    fov_axis: str = "x"
    spot_targets: list = field(default_factory=list)   # world points the laser aims at
    spot_enabled: list = field(default_factory=list)
    lights: list = field(default_factory=list)
    config_overrides: dict = field(default_factory=dict)  # SimulationConfig fields this scene sets

    @property
    def has_exact_mesh(self) -> bool:
        return all(isinstance(p, MeshPart) for p in self.parts)

    def triangles(self):
        """(vertices (V, 3), faces (F, 3), face albedo (F,)) of all mesh parts."""
        verts, faces, alb, off = [], [], [], 0
        for p in self.parts:
            if not isinstance(p, MeshPart):
                raise ValueError(f"scene {self.name!r}: part {p.name!r} is a Blender primitive (no bpy-free mesh)")
            verts.append(p.vertices)
            faces.append(p.faces + off)
            alb.append(np.full(len(p.faces), p.albedo))
            off += len(p.vertices)
        return np.concatenate(verts), np.concatenate(faces), np.concatenate(alb)

    def trimesh(self):
        """A trimesh.Trimesh of the scene (not merged: walls stay separate slabs) and face albedo."""
        import trimesh

        v, f, a = self.triangles()
        return trimesh.Trimesh(v, f, process=False), a


# -- geometry builders ----------------------------------------------------------------
_BOX_FACES = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
                       [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]])


def box(name, lo, hi, albedo) -> MeshPart:
    """Axis-aligned box between corners `lo` and `hi` (outward-facing triangles)."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    v = np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
                  [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]], np.float64)
    return MeshPart(name, v, _BOX_FACES.copy(), float(albedo))


def room_walls(albedo=WALL_ALBEDO, back_wall=True) -> list:
    """The paper's room: side walls, floor, ceiling (and back wall) as thin slabs outside the interior."""
    t = WALL_THICKNESS
    walls = [box("wall_left", (-2 - t, 0, -2 - t), (-2, 4 + t, 2 + t), albedo),
             box("wall_right", (2, 0, -2 - t), (2 + t, 4 + t, 2 + t), albedo),
             box("floor", (-2, 0, -2 - t), (2, 4 + t, -2), albedo),
             box("ceiling", (-2, 0, 2), (2, 4 + t, 2 + t), albedo)]
    if back_wall:
        walls.append(box("wall_back", (-2, 4, -2), (2, 4 + t, 2), albedo))
    return walls


def chair(albedo=OBJECT_ALBEDO, scale=1.25, base=(0.0, 3.0, -2.0)) -> list:
    """A procedural chair of the paper's size and place (scale 1.25 standing at paper (0, -2, 3)).

    Unit chair (before scaling): seat 0.44 x 0.42 at height 0.40-0.44, four 0.03 legs,
    a back 0.36 high on the side away from the sensor (+Y).
    """
    bx, by, bz = base

    def part(name, lo, hi):
        lo = np.array(lo) * scale + (bx, by, bz)
        hi = np.array(hi) * scale + (bx, by, bz)
        return box(name, lo, hi, albedo)

    sw, sd, leg = 0.22, 0.21, 0.03
    parts = [part("chair_seat", (-sw, -sd, 0.40), (sw, sd, 0.44)),
             part("chair_back", (-sw, sd - 0.03, 0.44), (sw, sd, 0.80))]
    for i, (sx, sy) in enumerate(((-1, -1), (1, -1), (1, 1), (-1, 1))):
        x = sx * (sw - 0.02) - leg / 2
        y = sy * (sd - 0.02) - leg / 2
        parts.append(part(f"chair_leg{i}", (x, y, 0.0), (x + leg, y + leg, 0.40)))
    return parts


def curved_wall(albedo=WALL_ALBEDO, radius=2.5, centre_y=1.5, segments=48, rows=8) -> MeshPart:
    """Concave back wall: a vertical cylinder section (axis at y=centre_y) spanning x in [-2, 2]."""
    half = math.asin(2.0 / radius)
    ang = np.linspace(-half, half, segments + 1)
    zs = np.linspace(-2.0, 2.0, rows + 1)
    xs, ys = radius * np.sin(ang), centre_y + radius * np.cos(ang)
    v = np.array([[x, y, z] for z in zs for x, y in zip(xs, ys)], np.float64)
    n = segments + 1
    f = []
    for r in range(rows):
        for s in range(segments):
            a, b, c, d = r * n + s, r * n + s + 1, (r + 1) * n + s + 1, (r + 1) * n + s
            f += [[a, b, c], [a, c, d]]   # normals face the room (towards -Y)
    return MeshPart("wall_back_curved", v, np.array(f), float(albedo))


# -- the paper's reference numbers ------------------------------------------------------
def paper_spots():
    """(24 laser targets in Blender's frame, enabled flags of the paper's 16)."""
    targets = paper_to_blender_points(reference.laser_targets_24())
    used = set(reference.used_16_indices())
    return [list(map(float, t)) for t in targets], [i in used for i in range(len(targets))]


def sensor_c2w() -> np.ndarray:
    """Paper sensor: origin, looking along +Y (paper +z), up +Z."""
    return look_at_c2w([0.0, 0.0, 0.0], [0.0, 3.0, 0.0], up=(0.0, 0.0, 1.0))


def _cave(name, description, parts, **kw) -> ExampleScene:
    targets, enabled = paper_spots()
    return ExampleScene(name, description, parts, sensor_c2w(), spot_targets=targets, spot_enabled=enabled, **kw)


def cave_chair() -> ExampleScene:
    return _cave("cave-chair", "the paper's room with a procedural chair", room_walls() + chair())


def monkey() -> ExampleScene:
    parts = room_walls() + [box("pedestal", (-0.2, 2.8, -2.0), (0.2, 3.2, -1.6), OBJECT_ALBEDO),
                            BlenderPrimitive("monkey", "monkey", (0.0, 3.0, -1.15), 0.5, 2, OBJECT_ALBEDO)]
    return _cave("monkey", "a subdivided Suzanne on a pedestal in the paper's room", parts)


def occluders() -> ExampleScene:
    parts = room_walls() + [box("occluder_front", (-0.45, 2.2, -2.0), (-0.05, 2.5, -0.9), OBJECT_ALBEDO),
                            box("occluder_back", (-0.2, 3.0, -2.0), (0.7, 3.4, -1.2), OBJECT_ALBEDO)]
    return _cave("occluders", "a tall box partly hiding a wide box", parts)


def curved_wall_scene() -> ExampleScene:
    parts = room_walls(back_wall=False) + [curved_wall()] + chair()
    return _cave("curved-wall", "the chair in front of a concave back wall", parts)


def low_albedo() -> ExampleScene:
    return _cave("low-albedo", "the chair room with dark (albedo 0.1) walls",
                 room_walls(albedo=0.1) + chair(albedo=0.3))


def ambient() -> ExampleScene:
    return _cave("ambient", "the chair room lit by a ceiling area light (ambient background)",
                 room_walls() + chair(), lights=[AreaLight("ambient_light", (0.0, 2.0, 1.95), 1.0, 200.0)],
                 config_overrides={"ambient_per_bin": 0.05, "photon_counts": True})


EXAMPLES = {"cave-chair": cave_chair, "monkey": monkey, "occluders": occluders,
            "curved-wall": curved_wall_scene, "low-albedo": low_albedo, "ambient": ambient}


def example(name: str) -> ExampleScene:
    if name not in EXAMPLES:
        raise KeyError(f"unknown example scene {name!r} (known: {', '.join(EXAMPLES)})")
    return EXAMPLES[name]()
