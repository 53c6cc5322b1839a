"""The one ground-truth writer (no bpy here): mesh, train-view range depth, test-view depths.

Depths come from Embree ray casting of the ground-truth mesh
(`analytic.range_image`), not from Cycles: one ray per pixel, exact range along
the pixel-centre ray (Cycles' Depth pass is planar depth), and the paper's 139
test views cost about a second instead of 139 renders. The simulator, the
analytic dataset builder and the PlatoNeRF-layout import all write through here,
so the file names below are the only ones a dataset holds.
"""

from __future__ import annotations

import math

import numpy as np

from .analytic import range_image
from .dataset.schema import GroundTruth, GroundTruthViews
from .frames import paper_test_view_cameras

MESH_FILE = "ground_truth/mesh.ply"
TRAIN_DEPTH_FILE = "ground_truth/train_depth.exr"
TEST_DEPTH_FILE = "ground_truth/test_depth.exr"
#: the paper's test views are square 90-degree views (contract/data/platonerf_cave.json)
TEST_VIEW_FOV_RAD = math.pi / 2


def scene_mesh(vertices: np.ndarray, faces: np.ndarray):
    """A trimesh of the world-frame triangles (not merged or repaired: exactly what was rendered)."""
    import trimesh

    return trimesh.Trimesh(np.asarray(vertices, np.float64), np.asarray(faces, np.int64), process=False)


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
                        export_mesh: bool = True) -> GroundTruth:
    """Ray-cast `mesh` for the train view and `test_cameras`, write what is asked, describe it."""
    gt = GroundTruth()
    if mesh is None or len(mesh.faces) == 0:
        return gt
    if train_depth:
        gt.train_depth_file = write_train_depth(
            writer, range_image(mesh, sensor.camera_to_world, sensor.width, sensor.height, sensor.fov_rad,
                                sensor.fov_axis))
    if test_cameras is not None and len(test_cameras):
        tw, th = test_size
        depths = np.stack([range_image(mesh, c2w, tw, th, test_fov_rad, "x") for c2w in test_cameras])
        gt.test_views = write_test_views(writer, test_cameras, depths, test_fov_rad)
    if export_mesh:
        gt.mesh_file = write_mesh(writer, mesh)
    return gt


def write_ground_truth(writer, mesh, sensor, cfg) -> GroundTruth:
    """What a simulation config asks for (train depth, the paper's test views, mesh)."""
    n_views = cfg.test_views_dolly + cfg.test_views_orbit
    cams = test_view_cameras(cfg.test_views_dolly, cfg.test_views_orbit) if n_views > 0 else None
    res = cfg.test_view_resolution
    return render_ground_truth(writer, mesh, sensor, train_depth=cfg.train_depth, test_cameras=cams,
                               test_size=(res, res), export_mesh=cfg.gt_mesh)
