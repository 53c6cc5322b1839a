"""The hidden hull's faces on a plane bounding the observation go onto it (`fast.mesh_plane_snap_voxels`, session 19;
recon/hull_planes.py)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from torch_recon.contract.errors import SettingsError
from torch_recon.recon.config import FitConfig, override
from torch_recon.recon.hull_planes import snap_to_planes

N = 24                      # grid points per axis over [-1.2, 1.2]
LO = np.full(3, -1.2)
SPACING = np.full(3, 2.4 / (N - 1))
VOXEL = float(SPACING[0])
FLOOR = (np.array([[0.0, 0.0, 1.0]]), np.array([0.0]))     # z = 0, facing up (the free side)


def _floor(height, k=41):
    """A heightfield mesh over [-1, 1]^2, z = height(x, y), faces up."""
    g = np.linspace(-1.0, 1.0, k)
    x, y = np.meshgrid(g, g, indexing="ij")
    v = np.stack([x.ravel(), y.ravel(), height(x, y).ravel()], 1)
    i = np.arange(k * k).reshape(k, k)
    a, b, c, d = i[:-1, :-1].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel(), i[:-1, 1:].ravel()
    m = trimesh.Trimesh(v, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]), process=False)
    assert np.all(m.vertex_normals[:, 2] > 0)
    return m


def test_furrows_in_the_hidden_floor_go_onto_the_plane_placed_and_far_vertices_stay():
    furrow = lambda x, y: (x > 0.2) & (x < 0.6)                                            # noqa: E731
    m = _floor(lambda x, y: np.where(furrow(x, y), -0.6 * VOXEL, 0.0)
               + np.where(x < -0.5, -0.6 * VOXEL, 0.0)                                      # a dent the sensor placed
               + np.where((y > 0.5) & (x > 0.2) & (x < 0.6), -1.5 * VOXEL, 0.0))           # deeper than the reach
    v0 = m.vertices.copy()
    placed = np.zeros((N, N, N), bool)
    placed[: int(np.rint((-0.5 - LO[0]) / VOXEL)) - 1] = True                              # x < -0.5: measured
    snap_to_planes(m, placed, LO, SPACING, *FLOOR, max_m=VOXEL)
    z = m.vertices[:, 2]
    shallow = furrow(v0[:, 0], v0[:, 1]) & (v0[:, 1] < 0.45)
    assert shallow.any() and np.abs(z[shallow]).max() < 1e-9                                # on the plane
    assert np.all(z[v0[:, 0] < -0.6] == v0[v0[:, 0] < -0.6, 2])                             # placed: unmoved
    deep = v0[:, 2] < -1.2 * VOXEL
    assert deep.any() and np.all(z[deep] == v0[deep, 2])                                    # beyond the reach
    assert np.allclose(m.vertices[:, :2], v0[:, :2])                                        # along the normal only


def test_a_face_at_an_angle_to_the_plane_stays():
    m = _floor(lambda x, y: 0.02 + 1.2 * (x - 0.0))                 # a 50 degree slope crossing the floor's band
    v0 = m.vertices.copy()
    snap_to_planes(m, np.zeros((N, N, N), bool), LO, SPACING, *FLOOR, max_m=VOXEL)
    assert np.array_equal(m.vertices, v0)


def test_the_fitted_box_scene_fills_the_plane_fields_and_keeps_the_mesh_finite():
    """Box on a floor (32 px, 56 voxels): the default export hands the floor's bounding plane to the mesh; the
    vertices that move go onto one of the planes."""
    from tests.support.recon_fixtures import box_floor_measurements
    from tests.torch_recon.recon.test_recon_fit import small_config
    from tests.torch_recon.recon.test_recon_freeze import _meta
    from torch_recon.mesh_export import mesh_from_volume
    from torch_recon.recon.data import build_ray_data
    from torch_recon.recon.models import FastModel

    meas = box_floor_measurements(32)
    cfg = small_config(steps=1)
    cfg.fast.resolution = 56
    assert cfg.fast.mesh_plane_snap_voxels > 0                       # the default
    meshes = {}
    for snap in (0.0, cfg.fast.mesh_plane_snap_voxels):
        cfg.fast.mesh_plane_snap_voxels = snap
        model = FastModel(build_ray_data(meas), cfg, _meta(meas))
        box = model.grid.box
        vol, level = model.surface_volume()
        inward = model.mesh_inward(vol, level)
        lo = box.bbox_min.numpy() + 0.5 * box.voxel
        hi = lo + (np.array(box.shape) - 1) * box.voxel
        meshes[snap], _ = mesh_from_volume(vol, lo, hi, level, smooth_iterations=10, inward=inward,
                                           min_island_fraction=0)
    assert inward.plane_snap_m == pytest.approx(snap * box.voxel) and len(inward.plane_offsets) >= 1
    assert inward.placed.shape == tuple(box.shape) and inward.placed.any()
    a, b = meshes[0.0], meshes[snap]
    assert len(a.vertices) == len(b.vertices) and np.all(np.isfinite(b.vertices))
    moved = np.linalg.norm(b.vertices - a.vertices, axis=1) > 1e-9
    assert moved.any()
    d = np.abs(b.vertices[moved] @ inward.plane_normals.T - inward.plane_offsets).min(1)
    assert np.all(d < 1e-6)


def test_plane_snap_is_range_checked():
    assert FitConfig(mode="fast").fast.mesh_plane_snap_voxels == 1.0
    for bad in (["fast.mesh_plane_snap_voxels=-1"], ["fast.mesh_plane_snap_voxels=3"], ["fast.mesh_plane_snap_voxels=nan"]):
        with pytest.raises(SettingsError, match="fast.mesh_plane_snap_voxels"):
            override(FitConfig(mode="fast"), bad)


def test_a_vertex_whose_snap_would_fold_a_face_over_stays():
    """A hidden floor vertex 0.05 m below the floor's plane with a steep sliver face rising from it to 0.02 m below
    the plane (its other vertices face sideways, so they do not move): snapped up, the vertex passes them and the
    sliver turns inside out (its normal by ~135 degrees). The vertex stays; the flat faces round it still go up,
    and without the sliver the vertex snaps (the old code snapped it regardless; session 20)."""
    ring = np.stack([np.cos(np.linspace(0, 2 * np.pi, 9)[:-1]), np.sin(np.linspace(0, 2 * np.pi, 9)[:-1]),
                     np.full(8, -0.05)], 1)
    sliver = np.array([[0.01, -0.005, -0.02], [0.01, 0.005, -0.02]])
    verts = np.concatenate([[[0.0, 0.0, -0.05]], ring, sliver])
    fan = [[0, 1 + i, 1 + (i + 1) % 8] for i in range(8)]                # faces up
    placed = np.zeros((N, N, N), bool)

    def snapped(faces):
        m = trimesh.Trimesh(verts.copy(), np.array(faces), process=False)
        before = m.face_normals.copy()
        snap_to_planes(m, placed, LO, SPACING, *FLOOR, max_m=VOXEL)
        return m, (m.face_normals * before).sum(1)

    alone, _ = snapped(fan)
    assert abs(alone.vertices[0, 2]) < 1e-12 and np.abs(alone.vertices[1:9, 2]).max() < 1e-12
    m, turn = snapped(fan + [[0, 10, 9]])
    assert m.face_normals[8, 0] > 0.9                                     # the sliver still faces +x (old: -0.89)
    assert turn.min() > 0.0                                               # no face folded
    assert m.vertices[0, 2] == -0.05 and np.abs(m.vertices[1:9, 2]).max() < 1e-12
    assert np.array_equal(m.vertices[9:], sliver)
