"""The one ground-truth writer (no bpy here): mesh, train-view range depth, test-view depths.

Depths come from Embree ray casting of the ground-truth mesh
(`analytic.range_image`), not from Cycles: one ray per pixel, exact range along
the pixel-centre ray (Cycles' Depth pass is planar depth), and the paper's 139
test views cost about a second instead of 139 renders. The simulator, the
analytic dataset builder and the PlatoNeRF-layout import all write through here,
so the file names below are the only ones a dataset holds.

Objects (scene_objects decides which parts are objects): one PLY per object under ground_truth/objects/,
listed in the manifest's ground_truth.objects. Test views: the scene-aware dolly + orbit around those objects
(test_views), or the paper's preset (`test_view_trajectory='paper'`); cameras not in free space are dropped
with a warning and counted (ground_truth.test_views.n_invalid).
"""

from __future__ import annotations

import math
import re
import warnings

import numpy as np

from .analytic import range_image
from .dataset.schema import GroundTruth, GroundTruthObject, GroundTruthViews
from .frames import paper_test_view_cameras
from .plain_mesh import PlainMesh
from .scene_objects import label_parts
from .test_views import SceneViewSettings, check_test_views, scene_test_view_cameras

MESH_FILE = "ground_truth/mesh.ply"
OBJECTS_DIR = "ground_truth/objects"
TRAIN_DEPTH_FILE = "ground_truth/train_depth.exr"
TEST_DEPTH_FILE = "ground_truth/test_depth.exr"
#: the paper's test views are square 90-degree views (contract/data/platonerf_cave.json)
TEST_VIEW_FOV_RAD = math.pi / 2


def scene_mesh(vertices: np.ndarray, faces: np.ndarray) -> PlainMesh:
    """The world-frame triangles (not merged or repaired: exactly what was rendered); a PlainMesh, which the
    functions here treat as a trimesh, so writing the ground truth does not import trimesh (~1 s CPU)."""
    return PlainMesh(vertices, faces)


def test_view_cameras(dolly: int, orbit: int) -> np.ndarray:
    return paper_test_view_cameras(dolly_count=dolly, orbit_count=orbit)


def write_train_depth(writer, depth: np.ndarray) -> str:
    return writer.write_depth(TRAIN_DEPTH_FILE, depth)


def write_test_views(writer, cameras, depths: np.ndarray, fov_rad: float, fov_axis: str = "x") -> GroundTruthViews:
    """Test-view depths (N, H, W) stacked into one EXR, cameras (N, 4, 4) inline."""
    depths = np.asarray(depths)
    rel = writer.write_depth(TEST_DEPTH_FILE, depths)
    return GroundTruthViews(width=int(depths.shape[2]), height=int(depths.shape[1]), fov_rad=float(fov_rad),
                            fov_axis=fov_axis, camera_to_world=[np.asarray(c).tolist() for c in cameras],
                            depth_file=rel)


def write_mesh(writer, mesh) -> str:
    mesh.export(str(writer.path(MESH_FILE)), file_type="ply")
    return MESH_FILE


def render_ground_truth(writer, mesh, sensor, *, train_depth: bool = True, test_cameras=None,
                        test_size: tuple[int, int] = (32, 32), test_fov_rad: float = TEST_VIEW_FOV_RAD,
                        export_mesh: bool = True, ranges=None) -> GroundTruth:
    """Ray-cast `mesh` for the train view and `test_cameras`, write what is asked, describe it.

    ranges: a faster caster of the same triangles, ranges(c2w, width, height, fov_rad, fov_axis) -> (H, W)
    with analytic.range_image's numbers (the simulator's Embree scene); default: range_image on `mesh`."""
    gt = GroundTruth()
    if mesh is None or len(mesh.faces) == 0:
        return gt
    if ranges is None:
        def ranges(c2w, width, height, fov_rad, fov_axis):
            return range_image(mesh, c2w, width, height, fov_rad, fov_axis)
    if train_depth:
        gt.train_depth_file = write_train_depth(
            writer, ranges(sensor.camera_to_world, sensor.width, sensor.height, sensor.fov_rad, sensor.fov_axis))
    if test_cameras is not None and len(test_cameras):
        tw, th = test_size
        # no progress bar: the 139 views take ~0.3 s; `import tqdm` alone is 0.04-0.08 CPU-s of a 128 x 128 run
        depths = np.stack([ranges(c2w, tw, th, test_fov_rad, "x") for c2w in test_cameras])
        gt.test_views = write_test_views(writer, test_cameras, depths, test_fov_rad)
    if export_mesh:
        gt.mesh_file = write_mesh(writer, mesh)
    return gt


def object_meshes(vertices, faces, owner, names, labelled: dict | None = None) -> dict:
    """{label: (PlainMesh, [part names])} of the scene's objects from its triangles and their owners
    (owner: part index per face, names: part names; labelled: {label: [part names]} or None)."""
    owner = np.asarray(owner)
    faces = np.asarray(faces)
    tri = np.asarray(vertices, np.float64)[faces]
    bounds = {}
    for i, n in enumerate(names):
        t = tri[owner == i].reshape(-1, 3)
        if len(t):
            lo, hi = t.min(axis=0), t.max(axis=0)
            if n in bounds:
                lo, hi = np.minimum(lo, bounds[n][0]), np.maximum(hi, bounds[n][1])
            bounds[n] = (lo, hi)
    out = {}
    for label, parts in label_parts(bounds, labelled).items():
        sel = np.isin(owner, [i for i, n in enumerate(names) if n in parts])
        if sel.any():
            out[label] = (PlainMesh.compact(vertices, faces[sel]), sorted(parts))
    return out


def room_mesh(triangles, objects: dict):
    """The scene's triangles that belong to no object (the room), for placing test views inside it."""
    vertices, faces, owner, names = triangles
    in_objects = {p for _, parts in objects.values() for p in parts}
    keep = ~np.isin(np.asarray(owner), [i for i, n in enumerate(names) if n in in_objects])
    if not keep.any():
        return None
    return PlainMesh.compact(vertices, np.asarray(faces)[keep])


def write_objects(writer, objects: dict) -> list:
    """One PLY per labelled object -> the manifest's ground_truth.objects entries."""
    out, used = [], set()
    for label, (m, parts) in sorted(objects.items()):
        stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", label).strip("_") or "object"
        while stem in used:
            stem += "_"
        used.add(stem)
        rel = f"{OBJECTS_DIR}/{stem}.ply"
        m.export(str(writer.path(rel)), file_type="ply")
        out.append(GroundTruthObject(name=label, mesh_file=rel, parts=list(parts)))
    return out


def test_cameras_for(mesh, sensor, cfg, objects: dict, room=None):
    """(valid test cameras, trajectory name, number dropped): the scene-aware views or the paper's preset."""
    trajectory = getattr(cfg, "test_view_trajectory", "scene")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if trajectory == "paper":
            cams = test_view_cameras(cfg.test_views_dolly, cfg.test_views_orbit)
            valid, report = check_test_views(mesh, cams)
            cams = cams[valid]
        else:
            cams, report = scene_test_view_cameras(
                mesh, [m for m, _ in objects.values()], sensor.camera_to_world,
                SceneViewSettings(dolly=cfg.test_views_dolly, orbit=cfg.test_views_orbit), room_mesh=room)
    for w in caught:
        print(f"ground truth: warning: {w.message}")
    return cams, trajectory, int(report["n_invalid"])


def write_ground_truth(writer, mesh, sensor, cfg, objects: dict | None = None, room=None,
                       ranges=None) -> GroundTruth:
    """What a simulation config asks for (train depth, test views, mesh, labelled objects).

    objects: {label: (mesh, [part names])} (object_meshes); room: the GT without the objects (room_mesh);
    ranges: see render_ground_truth.
    """
    objects = objects or {}
    n_views = cfg.test_views_dolly + cfg.test_views_orbit
    cams, trajectory, n_invalid = (test_cameras_for(mesh, sensor, cfg, objects, room) if n_views > 0
                                   and mesh is not None and len(mesh.faces) else (None, None, 0))
    res = cfg.test_view_resolution
    gt = render_ground_truth(writer, mesh, sensor, train_depth=cfg.train_depth, test_cameras=cams,
                             test_size=(res, res), export_mesh=cfg.gt_mesh, ranges=ranges)
    if gt.test_views is not None:
        gt.test_views.trajectory, gt.test_views.n_invalid = trajectory, n_invalid
    if cfg.gt_mesh and gt.mesh_file is not None:
        gt.objects = write_objects(writer, objects)
    return gt
