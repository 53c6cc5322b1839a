"""Taubin passes of the mesh vertices no camera ray places (`fast.mesh_unplaced_taubin_iterations`, session 17;
recon/hull_unplaced.py)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from torch_recon.contract.errors import SettingsError
from torch_recon.recon.config import FitConfig, override
from torch_recon.recon.hull_unplaced import unplaced_taubin

N = 24                      # grid points per axis over [-1.2, 1.2]
LO = np.full(3, -1.2)
SPACING = np.full(3, 2.4 / (N - 1))


def _lumpy_sphere(seed=0):
    """A unit icosphere with its vertices moved radially by up to 6 cm (seeded): lumps a few faces wide."""
    m = trimesh.creation.icosphere(subdivisions=4)
    rng = np.random.default_rng(seed)
    bump = 1.0 + 0.06 * rng.uniform(-1, 1, len(m.vertices))
    m.vertices = m.vertices * bump[:, None]
    return m


def _normal_consistency(m):
    """mean |n_face . radial| (1: a smooth sphere)."""
    c = m.triangles_center
    return float(np.abs((m.face_normals * c / np.linalg.norm(c, axis=1, keepdims=True)).sum(1)).mean())


def _cells(points):
    return tuple(np.clip(np.rint((points - LO) / SPACING).astype(int), 0, N - 1).T)


def test_unplaced_vertices_are_smoothed_placed_ones_stay_and_moves_are_bounded():
    m = _lumpy_sphere()
    v0 = m.vertices.copy()
    before = _normal_consistency(m)
    placed = np.zeros((N, N, N), bool)
    placed[:, :, : N // 4] = True            # the lowest quarter of the grid: a measured surface
    camera_free = np.zeros_like(placed)
    max_move = 0.05
    unplaced_taubin(m, placed, camera_free, LO, SPACING, 30, max_move)
    move = np.linalg.norm(m.vertices - v0, axis=1)
    assert _normal_consistency(m) > before + 0.01                 # the lumps are smoothed
    assert move.max() <= max_move + 1e-9                           # within the cap
    low = v0[:, 2] < LO[2] + (N // 4 - 1.5) * SPACING[2]           # vertices well inside the placed voxels
    assert low.any() and np.all(move[low] == 0.0)
    r0, r1 = np.linalg.norm(v0, axis=1), np.linalg.norm(m.vertices, axis=1)
    assert abs(r1.mean() - r0.mean()) < 0.01                       # Taubin: neither shrinks nor grows the sphere


def test_no_vertex_enters_camera_free_space():
    m = _lumpy_sphere(1)
    v0 = m.vertices.copy()
    placed = np.zeros((N, N, N), bool)
    camera_free = np.zeros_like(placed)
    camera_free[_cells(v0 * 0.9)] = True     # the space just inside the lumps: the sensor saw it empty
    camera_free[_cells(v0)] = False          # (each vertex starts outside it)
    unplaced_taubin(m, placed, camera_free, LO, SPACING, 30, 0.05)
    assert not camera_free[_cells(m.vertices)].any()
    assert np.any(np.linalg.norm(m.vertices - v0, axis=1) > 1e-4)   # the others still move


def test_the_fitted_box_scene_smooths_only_what_the_sensor_did_not_place():
    """Box on a floor (32 px, 56 voxels): the export fills the unplaced-vertex fields; the visible floor's vertices
    (on its measured ramp) do not move, some hidden ones do, the mesh stays finite."""
    from tests.support.recon_fixtures import box_floor_measurements
    from tests.torch_recon.recon.test_recon_fit import small_config
    from tests.torch_recon.recon.test_recon_freeze import _meta
    from torch_recon.mesh_export import mesh_from_volume
    from torch_recon.recon.data import build_ray_data
    from torch_recon.recon.models import FastModel

    meas = box_floor_measurements(32)
    cfg = small_config(steps=1)
    cfg.fast.resolution = 56
    box_vol = {}
    for iterations in (0, 30):
        cfg.fast.mesh_unplaced_taubin_iterations = iterations
        model = FastModel(build_ray_data(meas), cfg, _meta(meas))
        box = model.grid.box
        vol, level = model.surface_volume()
        inward = model.mesh_inward(vol, level)
        assert inward.unplaced_iterations == iterations
        lo = box.bbox_min.numpy() + 0.5 * box.voxel
        hi = lo + (np.array(box.shape) - 1) * box.voxel
        box_vol[iterations], _ = mesh_from_volume(vol, lo, hi, level, smooth_iterations=10, inward=inward,
                                                  min_island_fraction=0)
    assert inward.placed.shape == inward.camera_free.shape == tuple(box.shape) and inward.placed.any()
    a, b = box_vol[0], box_vol[30]
    assert len(a.vertices) == len(b.vertices) and np.all(np.isfinite(b.vertices))
    move = np.linalg.norm(b.vertices - a.vertices, axis=1)
    assert move.max() <= cfg.fast.mesh_unplaced_max_voxels * box.voxel + 1e-6
    assert np.any(move > 1e-4) and np.any(move == 0.0)


def test_unplaced_taubin_is_opt_in_and_range_checked():
    fc = FitConfig(mode="fast").fast
    assert fc.mesh_unplaced_taubin_iterations == 0
    assert override(FitConfig(mode="fast"), ["fast.mesh_unplaced_taubin_iterations=30"]).fast.mesh_unplaced_taubin_iterations == 30
    for bad in (["fast.mesh_unplaced_taubin_iterations=-1"], ["fast.mesh_unplaced_max_voxels=0"],
                ["fast.mesh_unplaced_max_voxels=nan"],
                ["fast.mesh_unplaced_taubin_iterations=30", "fast.mesh_hull_shrink_voxels=0"]):
        with pytest.raises(SettingsError, match="fast.mesh_unplaced_"):
            override(FitConfig(mode="fast"), bad)
