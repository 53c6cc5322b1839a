"""The hidden hull's bounded inward smoothing (recon/hull_subvoxel.py, mesh_export.inward_smoothing; session 13)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torch_recon.contract.errors import SettingsError
from torch_recon.mesh_export import inward_smoothing, mesh_from_volume
from torch_recon.recon.config import FitConfig, override
from torch_recon.recon.hull_subvoxel import hull_voxels


def _cube_volume(n=12, lo=3, hi=9):
    """A binary occupied cube on an (n, n, n) grid (1 m grid steps)."""
    v = np.zeros((n, n, n), np.float32)
    v[lo:hi, lo:hi, lo:hi] = 1.0
    return v


def test_inward_smoothing_cuts_convex_steps_bounded_and_only_inward():
    mesh, _ = mesh_from_volume(_cube_volume(), (0, 0, 0), (11, 11, 11), 0.5, min_island_fraction=0)
    start = mesh.vertices.copy()
    normals = mesh.vertex_normals.copy()
    movable = start[:, 0] > 5.5                  # the half of the cube at +x moves, the rest stays
    volume = mesh.volume
    inward_smoothing(mesh, movable, 0.3, 10)
    moved = mesh.vertices - start
    assert np.allclose(moved[~movable], 0.0)
    assert np.linalg.norm(moved, axis=1).max() <= 0.3 + 1e-9
    assert np.linalg.norm(moved[movable], axis=1).max() > 0.1         # the cube's edges and corners are cut
    assert (np.einsum("ij,ij->i", moved, normals) <= 1e-9).all()     # never outward
    assert mesh.volume < volume


def test_inward_smoothing_through_the_exporter_only_where_movable():
    vol = _cube_volume()
    plain, _ = mesh_from_volume(vol, (0, 0, 0), (11, 11, 11), 0.5, min_island_fraction=0)
    none, _ = mesh_from_volume(vol, (0, 0, 0), (11, 11, 11), 0.5, min_island_fraction=0,
                               inward=(np.zeros(vol.shape, bool), 0.4, 10))
    assert np.allclose(plain.vertices, none.vertices)
    cut, _ = mesh_from_volume(vol, (0, 0, 0), (11, 11, 11), 0.5, min_island_fraction=0,
                              inward=(vol > 0, 0.4, 10))
    assert cut.volume < plain.volume - 1.0 and np.all(np.isfinite(cut.vertices))


def test_restored_blockers_and_ramps_are_not_hull():
    """(7, 3, 3) start field: hull x >= 3 (raw 4), free x < 3 (raw -10)."""
    start = torch.full((7, 3, 3), -10.0)
    start[3:] = 4.0
    lit = torch.zeros(start.shape, dtype=torch.long)
    assert bool(hull_voxels(start, -10.0, 4.0, lit)[3].all())
    assert not bool(hull_voxels(start, -10.0, 4.0, lit)[4:].any())        # the boundary layer only
    lit[3, 0] = 1                                           # a carved voxel put back (a lit segment crossed it)
    start[2, 2] = 1.0                                       # a measured surface's ramp next to the hull
    hull = hull_voxels(start, -10.0, 4.0, lit)
    assert not bool(hull[3, 0].any()) and not bool(hull[3, 2].any()) and bool(hull[3, 1].all())


@pytest.mark.parametrize("key,bad", [("mesh_hull_shrink_voxels", "0.6"), ("mesh_hull_shrink_voxels", "-0.1"),
                                     ("mesh_hull_shrink_graze_samples", "-1")])
def test_shrink_settings_refused_on_one_line(key, bad):
    with pytest.raises(SettingsError, match=f"fast.{key}"):
        override(FitConfig(mode="fast"), [f"fast.{key}={bad}"])
    assert override(FitConfig(mode="fast"), ["fast.mesh_hull_shrink_voxels=0.5"]).fast.mesh_hull_shrink_voxels == 0.5
