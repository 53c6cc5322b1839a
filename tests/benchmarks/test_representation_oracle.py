"""The representation suite's oracle builder: the true signed distance on the fit's grid, exported through
the fit's path, on hand-made scenes with known answers (a box: found; a rod thinner than a voxel: lost)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("torch")
trimesh = pytest.importorskip("trimesh")

from benchmarks.oracle_grid import SolidPart, export_oracle, oracle_signed_distance  # noqa: E402
from torch_recon.evaluation.objects import ObjectMetricSettings, object_surface_metrics  # noqa: E402
from torch_recon.recon.config import FitConfig  # noqa: E402
from torch_recon.recon.fields import GridBox  # noqa: E402


def _box(lo, hi):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return trimesh.creation.box(extents=hi - lo, transform=trimesh.transformations.translation_matrix((lo + hi) / 2))


#: a block beside the object: the scene keeps a surface when a thin object vanishes from the grid
BLOCK = _box((0.25, 0.25, -0.4), (0.45, 0.45, -0.2))


def _scored(obj, resolution, tmp_path):
    """Object metrics of the oracle mesh of `obj` (beside BLOCK) in a 1 m box, the oracle's signed
    distance and the box."""
    box = GridBox(np.full(3, -0.5), np.full(3, 0.5), resolution)
    parts = [SolidPart(obj, "object"), SolidPart(BLOCK, "object")]
    sd = oracle_signed_distance(parts, box.bbox_min.numpy(), box.voxel, box.shape)
    _, mesh = export_oracle(sd, box, FitConfig(), tmp_path / f"r{resolution}" / "mesh")
    m = object_surface_metrics(mesh, trimesh.util.concatenate([obj, BLOCK]), [("obj", obj)],
                               settings=ObjectMetricSettings(gt_samples_per_object=2000, recon_samples_per_m2=4000))
    return m["objects"]["obj"], sd, box


def test_a_box_is_found_at_a_fine_grid(tmp_path):
    obj = _box((-0.2, -0.15, -0.1), (0.2, 0.15, 0.1))
    res, sd, box = _scored(obj, 80, tmp_path)                    # 1.25 cm voxels
    assert res["fscore@2cm"] > 0.97 and res["fscore@1cm"] > 0.9
    centre = tuple(int(np.floor((0.0 + 0.5) / box.voxel)) for _ in range(3))
    assert sd[centre] > 0 and sd[0, 0, 0] < 0                     # inside solid, far outside empty


def test_a_rod_thinner_than_a_voxel_loses_recall(tmp_path):
    obj = _box((-0.006, -0.006, -0.3), (0.006, 0.006, 0.3))      # 1.2 cm rod, 3.3 cm voxels
    coarse, _, _ = _scored(obj, 30, tmp_path)
    fine, _, _ = _scored(obj, 160, tmp_path)                      # 0.6 cm voxels
    assert coarse["recall@2cm"] < 0.5 < fine["recall@2cm"]


def test_behind_a_room_wall_is_solid():
    """A 2 cm wall slab facing the sensor: the space behind it is solid (the fit continues the wall's
    plane), not a 2 cm sheet with empty space behind; the room in front stays empty."""
    wall = _box((-0.5, 0.3, -0.5), (0.5, 0.32, 0.5))
    sensor = np.array([0.0, -0.4, 0.0])
    facing = ((sensor - wall.triangles_center) * wall.face_normals).sum(1) > 1e-6
    part = SolidPart(wall.submesh([np.flatnonzero(facing)], append=True), "room")
    box = GridBox(np.full(3, -0.5), np.full(3, 0.5), 50)           # 2 cm voxels
    sd = oracle_signed_distance([part], box.bbox_min.numpy(), box.voxel, box.shape, sensor_origin=sensor)
    y = box.bbox_min[1].item() + (np.arange(box.shape[1]) + 0.5) * box.voxel
    column = sd[25, :, 25]
    assert np.all(column[y > 0.33] > 0) and np.all(column[y < 0.29] < 0)
    near = np.abs(y - 0.3) < 0.02                                  # exact distance next to the wall's face
    np.testing.assert_allclose(column[near], y[near] - 0.3, atol=1e-5)
