"""Ground truth for a simulated dataset (no bpy here): mesh, train-view range depth, test-view depths.

Depths come from Embree ray casting of the exported ground-truth mesh
(torch_recon.analytic.range_image), not from Cycles: one ray per pixel, exact
range along the pixel-centre ray (Cycles' Depth pass is planar depth), and the
paper's 139 test views cost about a second instead of 139 renders.
"""

from __future__ import annotations

import math

import numpy as np

from torch_recon.analytic import range_image
from torch_recon.dataset.schema import GroundTruth, GroundTruthViews
from torch_recon.frames import paper_test_view_cameras

MESH_FILE = "ground_truth/mesh.ply"
TRAIN_DEPTH_FILE = "ground_truth/train_depth.exr"
TEST_DEPTH_FILE = "ground_truth/test_depths.exr"


def scene_mesh(vertices: np.ndarray, faces: np.ndarray):
    """A trimesh of the world-frame triangles (not merged or repaired: exactly what was rendered)."""
    import trimesh

    return trimesh.Trimesh(np.asarray(vertices, np.float64), np.asarray(faces, np.int64), process=False)


def test_view_cameras(dolly: int, orbit: int) -> np.ndarray:
    return paper_test_view_cameras(dolly_count=dolly, orbit_count=orbit)


def write_ground_truth(writer, mesh, sensor, cfg) -> GroundTruth:
    """Write what `cfg` asks for (train depth, test views, mesh) and describe it."""
    gt = GroundTruth()
    if mesh is None or len(mesh.faces) == 0:
        return gt
    if cfg.train_depth:
        depth = range_image(mesh, sensor.camera_to_world, sensor.width, sensor.height, sensor.fov_rad,
                            sensor.fov_axis)
        gt.train_depth_file = writer.write_depth(TRAIN_DEPTH_FILE, depth)
    n_views = cfg.test_views_dolly + cfg.test_views_orbit
    if n_views > 0:
        cams = test_view_cameras(cfg.test_views_dolly, cfg.test_views_orbit)
        res = cfg.test_view_resolution
        fov = math.pi / 2
        depths = np.stack([range_image(mesh, c2w, res, res, fov, "x") for c2w in cams])
        rel = writer.write_depth(TEST_DEPTH_FILE, depths)
        gt.test_views = GroundTruthViews(width=res, height=res, fov_rad=fov, fov_axis="x",
                                         camera_to_world=[c.tolist() for c in cams], depth_file=rel)
    if cfg.gt_mesh:
        mesh.export(str(writer.path(MESH_FILE)), file_type="ply")
        gt.mesh_file = MESH_FILE
    return gt
