"""Ground truth for a simulated dataset (no bpy here): mesh, labelled objects, train-view and test-view depths.

Depths come from Embree ray casting of the exported ground-truth mesh
(torch_recon.analytic.range_image), not from Cycles: one ray per pixel, exact
range along the pixel-centre ray (Cycles' Depth pass is planar depth), and the
139 test views cost about a second instead of 139 renders.

Objects (torch_recon.contract.scene_objects decides which parts are objects): one PLY per object under
ground_truth/objects/, listed in the manifest's ground_truth.objects. Test views: the scene-aware dolly +
orbit around those objects (torch_recon.contract.test_views), or the paper's preset; cameras that are not in
free space are dropped with a warning and counted (ground_truth.test_views.n_invalid).
"""

from __future__ import annotations

import math
import re
import warnings

import numpy as np

from torch_recon.analytic import range_image
from torch_recon.contract.scene_objects import label_parts
from torch_recon.contract.test_views import SceneViewSettings, check_test_views, scene_test_view_cameras
from torch_recon.dataset.schema import GroundTruth, GroundTruthObject, GroundTruthViews
from torch_recon.frames import paper_test_view_cameras

MESH_FILE = "ground_truth/mesh.ply"
OBJECTS_DIR = "ground_truth/objects"
TRAIN_DEPTH_FILE = "ground_truth/train_depth.exr"
TEST_DEPTH_FILE = "ground_truth/test_depths.exr"


def scene_mesh(vertices: np.ndarray, faces: np.ndarray):
    """A trimesh of the world-frame triangles (not merged or repaired: exactly what was rendered)."""
    import trimesh

    return trimesh.Trimesh(np.asarray(vertices, np.float64), np.asarray(faces, np.int64), process=False)


def object_meshes(vertices, faces, owner, names, labelled: dict | None = None) -> dict:
    """{label: (trimesh, [part names])} of the scene's objects from its triangles and their owners."""
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
        idx = [i for i, n in enumerate(names) if n in parts]
        sel = np.isin(owner, idx)
        if sel.any():
            out[label] = (scene_mesh(vertices, faces[sel]).copy(), sorted(parts))
            out[label][0].remove_unreferenced_vertices()
    return out


def test_view_cameras(dolly: int, orbit: int) -> np.ndarray:
    return paper_test_view_cameras(dolly_count=dolly, orbit_count=orbit)


def _file_label(label: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", label).strip("_") or "object"


def write_ground_truth(writer, mesh, sensor, cfg, objects: dict | None = None, room_mesh=None) -> GroundTruth:
    """Write what `cfg` asks for (train depth, test views, mesh, objects) and describe it.

    objects: {label: (trimesh, [part names])} (see object_meshes); room_mesh: the GT without the objects.
    """
    gt = GroundTruth()
    if mesh is None or len(mesh.faces) == 0:
        return gt
    objects = objects or {}
    if cfg.train_depth:
        depth = range_image(mesh, sensor.camera_to_world, sensor.width, sensor.height, sensor.fov_rad,
                            sensor.fov_axis)
        gt.train_depth_file = writer.write_depth(TRAIN_DEPTH_FILE, depth)
    n_views = cfg.test_views_dolly + cfg.test_views_orbit
    if n_views > 0:
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
                    SceneViewSettings(dolly=cfg.test_views_dolly, orbit=cfg.test_views_orbit), room_mesh=room_mesh)
        for w in caught:
            print(f"simulate: warning: {w.message}")
        if len(cams):
            res = cfg.test_view_resolution
            fov = math.pi / 2
            depths = np.stack([range_image(mesh, c2w, res, res, fov, "x") for c2w in cams])
            rel = writer.write_depth(TEST_DEPTH_FILE, depths)
            gt.test_views = GroundTruthViews(width=res, height=res, fov_rad=fov, fov_axis="x",
                                             camera_to_world=[c.tolist() for c in cams], depth_file=rel,
                                             trajectory=trajectory, n_invalid=int(report["n_invalid"]))
    if cfg.gt_mesh:
        mesh.export(str(writer.path(MESH_FILE)), file_type="ply")
        gt.mesh_file = MESH_FILE
        used = set()
        for label, (m, parts) in sorted(objects.items()):
            stem = _file_label(label)
            while stem in used:
                stem += "_"
            used.add(stem)
            rel = f"{OBJECTS_DIR}/{stem}.ply"
            m.export(str(writer.path(rel)), file_type="ply")
            gt.objects.append(GroundTruthObject(name=label, mesh_file=rel, parts=list(parts)))
    return gt


def room_mesh(triangles, objects: dict):
    """The scene's triangles that belong to no object (the room), for placing test views inside it."""
    vertices, faces, owner, names = triangles
    in_objects = {p for _, parts in objects.values() for p in parts}
    idx = [i for i, n in enumerate(names) if n in in_objects]
    keep = ~np.isin(np.asarray(owner), idx)
    if not keep.any():
        return None
    m = scene_mesh(vertices, np.asarray(faces)[keep]).copy()
    m.remove_unreferenced_vertices()
    return m
