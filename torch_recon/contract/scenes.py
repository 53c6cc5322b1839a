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

import hashlib
import math
from dataclasses import dataclass, field, fields, is_dataclass

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
    objects: dict = field(default_factory=dict)   # label -> part names: the objects that matter (the rest
                                                  # is the room); Blender collection Objects/<label>

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

    def fingerprint(self) -> str:
        """A hash of everything that defines the scene (geometry, albedos, sensor, spots, lights, overrides):
        a cached dataset of this scene is stale when it changes."""
        h = hashlib.sha256()
        _feed(h, self)
        return h.hexdigest()[:12]

    def trimesh(self):
        """A trimesh.Trimesh of the scene (not merged: walls stay separate slabs) and face albedo."""
        import trimesh

        v, f, a = self.triangles()
        return trimesh.Trimesh(v, f, process=False), a


def _feed(h, x) -> None:
    """Hash a scene value exactly (arrays by their bytes: repr would elide large ones)."""
    if isinstance(x, np.ndarray):
        a = np.ascontiguousarray(x)
        h.update(f"{a.dtype}{a.shape}".encode())
        h.update(a.tobytes())
    elif is_dataclass(x):
        h.update(type(x).__name__.encode())
        for f in fields(x):
            h.update(f.name.encode())
            _feed(h, getattr(x, f.name))
    elif isinstance(x, dict):
        h.update(b"{")
        for k in sorted(x, key=str):
            _feed(h, k)
            _feed(h, x[k])
        h.update(b"}")
    elif isinstance(x, (list, tuple)):
        h.update(b"[")
        for v in x:
            _feed(h, v)
        h.update(b"]")
    else:
        h.update(repr(x).encode())


# -- geometry builders ----------------------------------------------------------------
_BOX_FACES = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
                       [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]])


def box(name, lo, hi, albedo) -> MeshPart:
    """Axis-aligned box between corners `lo` and `hi` (outward-facing triangles)."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    v = np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
                  [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]], np.float64)
    return MeshPart(name, v, _BOX_FACES.copy(), float(albedo))


def room_walls(albedo=WALL_ALBEDO, back_wall=True, half_width=2.0, depth=4.0, floor_z=-2.0,
               ceiling_z=2.0) -> list:
    """A room open towards the sensor (y = 0): side walls, floor, ceiling (and back wall) as thin slabs
    outside the interior x in [-half_width, half_width], y in [0, depth], z in [floor_z, ceiling_z].
    The defaults are the paper's room."""
    t, w, d, z0, z1 = WALL_THICKNESS, half_width, depth, floor_z, ceiling_z
    walls = [box("wall_left", (-w - t, 0, z0 - t), (-w, d + t, z1 + t), albedo),
             box("wall_right", (w, 0, z0 - t), (w + t, d + t, z1 + t), albedo),
             box("floor", (-w, 0, z0 - t), (w, d + t, z0), albedo),
             box("ceiling", (-w, 0, z1), (w, d + t, z1 + t), albedo)]
    if back_wall:
        walls.append(box("wall_back", (-w, d, z0), (w, d + t, z1), albedo))
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


def curved_wall(albedo=WALL_ALBEDO, radius=2.5, centre_y=1.5, segments=48, rows=8, half_width=2.0,
                floor_z=-2.0, ceiling_z=2.0) -> MeshPart:
    """Concave back wall: a vertical cylinder section (axis at y=centre_y) spanning x in [-half_width,
    half_width] and z in [floor_z, ceiling_z] (radius > half_width)."""
    half = math.asin(half_width / radius)
    ang = np.linspace(-half, half, segments + 1)
    zs = np.linspace(floor_z, ceiling_z, rows + 1)
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


def blob(name, base, radius, albedo=OBJECT_ALBEDO, seed=0, subdivisions=3) -> MeshPart:
    """An organic closed shape: an icosphere with smooth seeded radial bumps, its flattened base at `base`."""
    import trimesh

    ico = trimesh.creation.icosphere(subdivisions=subdivisions)
    v = np.asarray(ico.vertices, np.float64)
    rng = np.random.default_rng(seed)
    bump = np.zeros(len(v))
    for _ in range(5):     # a few low-frequency lobes: features a reconstruction can lose
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        bump += rng.uniform(0.1, 0.25) * np.exp(-4.0 * (1.0 - v @ d))
    v = v * (1.0 + bump)[:, None] * radius
    v[:, 2] = np.maximum(v[:, 2], -0.8 * radius)          # a flat base to stand on
    v += np.asarray(base, np.float64) - np.array([0.0, 0.0, v[:, 2].min()])
    return MeshPart(name, v, np.asarray(ico.faces, np.int64), float(albedo))


def floor_lamp(base=(0.9, 3.0), albedo=OBJECT_ALBEDO, prefix="lamp") -> list:
    """A floor lamp: thin base plate, a 2.5 cm pole, a shade (open box of 1 cm panels) held by a thin bar."""
    x, y = base
    r, t = 0.0125, 0.01
    h0, h1, w = -0.5, -0.2, 0.2
    parts = [box(f"{prefix}_base", (x - 0.15, y - 0.15, -2.0), (x + 0.15, y + 0.15, -1.98), albedo),
             box(f"{prefix}_pole", (x - r, y - r, -1.98), (x + r, y + r, -0.33), albedo),
             box(f"{prefix}_bar", (x - w + t, y - r, -0.35), (x + w - t, y + r, -0.33), albedo)]
    parts += [box(f"{prefix}_shade_front", (x - w, y - w, h0), (x + w, y - w + t, h1), albedo),
              box(f"{prefix}_shade_back", (x - w, y + w - t, h0), (x + w, y + w, h1), albedo),
              box(f"{prefix}_shade_left", (x - w, y - w + t, h0), (x - w + t, y + w - t, h1), albedo),
              box(f"{prefix}_shade_right", (x + w - t, y - w + t, h0), (x + w, y + w - t, h1), albedo)]
    return parts


def side_table(centre=(-0.6, 2.8), albedo=OBJECT_ALBEDO, prefix="table") -> list:
    """A table with four 2 cm legs (about one sensor pixel wide at 128 x 128 from 3 m)."""
    x, y = centre
    leg, hw, hd, top = 0.02, 0.35, 0.25, -1.35
    parts = [box(f"{prefix}_top", (x - hw, y - hd, top), (x + hw, y + hd, top + 0.03), albedo)]
    for i, (sx, sy) in enumerate(((-1, -1), (1, -1), (1, 1), (-1, 1))):
        lx, ly = x + sx * (hw - 0.03), y + sy * (hd - 0.03)
        parts.append(box(f"{prefix}_leg{i}", (lx - leg / 2, ly - leg / 2, -2.0), (lx + leg / 2, ly + leg / 2, top),
                         albedo))
    return parts


def _labels(parts, prefix_to_label: dict) -> dict:
    """label -> names of the parts whose name starts with one of the label's prefixes."""
    out = {}
    for prefix, label in prefix_to_label.items():
        names = [p.name for p in parts if p.name.startswith(prefix)]
        if names:
            out.setdefault(label, []).extend(names)
    return out


def _cave(name, description, parts, labels=None, **kw) -> ExampleScene:
    targets, enabled = paper_spots()
    return ExampleScene(name, description, parts, sensor_c2w(), spot_targets=targets, spot_enabled=enabled,
                        objects=_labels(parts, labels or {}), **kw)


CHAIR = {"chair_": "chair"}


def cave_chair() -> ExampleScene:
    # the paper's 139 test views stay this room's views (comparable with the paper's figures)
    return _cave("cave-chair", "the paper's room with a procedural chair", room_walls() + chair(), CHAIR,
                 config_overrides={"test_view_trajectory": "paper"})


def monkey() -> ExampleScene:
    parts = room_walls() + [box("pedestal", (-0.2, 2.8, -2.0), (0.2, 3.2, -1.6), OBJECT_ALBEDO),
                            BlenderPrimitive("monkey", "monkey", (0.0, 3.0, -1.15), 0.5, 2, OBJECT_ALBEDO)]
    return _cave("monkey", "a subdivided Suzanne on a pedestal in the paper's room", parts,
                 {"pedestal": "pedestal", "monkey": "monkey"})


def occluders() -> ExampleScene:
    parts = room_walls() + [box("occluder_front", (-0.45, 2.2, -2.0), (-0.05, 2.5, -0.9), OBJECT_ALBEDO),
                            box("occluder_back", (-0.2, 3.0, -2.0), (0.7, 3.4, -1.2), OBJECT_ALBEDO)]
    return _cave("occluders", "a tall box partly hiding a wide box", parts,
                 {"occluder_front": "occluder_front", "occluder_back": "occluder_back"})


def organic_occluded() -> ExampleScene:
    parts = room_walls() + [box("occluder", (-0.5, 2.1, -2.0), (0.05, 2.35, -1.1), OBJECT_ALBEDO),
                            blob("blob", (0.05, 3.0, -2.0), 0.32, seed=3)]
    return _cave("organic-occluded", "an organic shape (a lumpy blob) half hidden behind a box", parts,
                 {"occluder": "occluder", "blob": "blob"})


def thin_structures() -> ExampleScene:
    parts = room_walls() + floor_lamp() + side_table()
    return _cave("thin-structures", "a floor lamp (2.5 cm pole, thin shade) and a table on 2 cm legs", parts,
                 {"lamp_": "lamp", "table_": "table"})


def curved_wall_scene() -> ExampleScene:
    parts = room_walls(back_wall=False) + [curved_wall()] + chair()
    return _cave("curved-wall", "the chair in front of a concave back wall", parts, CHAIR)


def low_albedo() -> ExampleScene:
    return _cave("low-albedo", "the chair room with dark (albedo 0.1) walls",
                 room_walls(albedo=0.1) + chair(albedo=0.3), CHAIR)


def dark_room() -> ExampleScene:
    parts = room_walls(albedo=0.15) + chair() + [box("box", (0.5, 2.4, -2.0), (1.0, 2.9, -1.6), OBJECT_ALBEDO)]
    return _cave("dark-room", "dark walls (albedo 0.15) around the chair and a low box", parts,
                 {"chair_": "chair", "box": "box"})


#: out-of-view laser targets of `outside_fov` (the laser scans a wider field than the camera sees): the right
#: wall next to the sensor (three heights) and the floor near it; light from each passes the column on its way
#: to visible surfaces, so the column's shadows land in the image (tests/torch_recon/contract/test_scene_objects).
#: Five, from different sides: recon.init.in_view counts space beside the sensor as measured where at least
#: two spots' secondary rays cross it
OUTSIDE_FOV_TARGETS = ((2.0, 0.45, -0.6), (1.2, 0.15, -2.0), (1.9, 0.3, -2.0), (2.0, 0.5, -1.7), (2.0, 0.2, 1.2))


def outside_fov() -> ExampleScene:
    # a column beside the sensor, outside its 90 degree view (x > y everywhere on it). Spots inside the view
    # cannot measure it (a segment between two points of the convex view stays in the view); the
    # OUTSIDE_FOV_TARGETS spots can: their secondary rays cross the space beside the sensor. They replace the
    # last paper spots, so 16 spots stay 16. Preprocessing fits their range along the known laser direction
    # from two-bounce arrival times (torch_recon.first_bounce.fit_out_of_view_spot).
    parts = room_walls() + chair() + [box("column", (1.3, 0.7, -2.0), (1.6, 1.0, 0.5), OBJECT_ALBEDO)]
    scene = _cave("outside-fov", "the chair, and a column beside the sensor outside its field of view that "
                  "only the shadows of out-of-view spots reveal", parts, {"chair_": "chair", "column": "column"})
    extra = len(OUTSIDE_FOV_TARGETS)
    drop = [i for i, e in enumerate(scene.spot_enabled) if e][-extra:]
    scene.spot_enabled = [e and i not in drop for i, e in enumerate(scene.spot_enabled)] + [True] * extra
    scene.spot_targets = scene.spot_targets + [list(t) for t in OUTSIDE_FOV_TARGETS]
    return scene


def ambient() -> ExampleScene:
    return _cave("ambient", "the chair room lit by a ceiling area light (ambient background)",
                 room_walls() + chair(), CHAIR, lights=[AreaLight("ambient_light", (0.0, 2.0, 1.95), 1.0, 200.0)],
                 config_overrides={"ambient_per_bin": 0.05, "photon_counts": True})


EXAMPLES = {"cave-chair": cave_chair, "monkey": monkey, "occluders": occluders,
            "curved-wall": curved_wall_scene, "low-albedo": low_albedo, "ambient": ambient,
            "organic-occluded": organic_occluded, "thin-structures": thin_structures, "dark-room": dark_room,
            "outside-fov": outside_fov}
#: the scenes the object benchmark measures on (labelled objects, exact bpy-free meshes except monkey)
OBJECT_SCENES = ("cave-chair", "organic-occluded", "thin-structures", "curved-wall", "dark-room", "outside-fov")


def example(name: str) -> ExampleScene:
    if name not in EXAMPLES:
        raise KeyError(f"unknown example scene {name!r} (known: {', '.join(EXAMPLES)})")
    return EXAMPLES[name]()
