"""Flat faces of the hidden hull move to their voxel layer's centre (recon/hull_flat.py; session 14)."""

from __future__ import annotations

import numpy as np
import pytest

from torch_recon.contract.errors import SettingsError
from torch_recon.mesh_export import InwardSmoothing, mesh_from_volume
from torch_recon.recon.config import FitConfig, override
from torch_recon.recon.hull_flat import flat_patch_voxels


def _slab_volume(n=16):
    """A binary occupied block (1 m grid steps): x 3..8, y and z 3..12 (a 10 x 10 face at +x)."""
    v = np.zeros((n, n, n), np.float32)
    v[3:9, 3:13, 3:13] = 1.0
    return v


def test_flat_patches_are_the_large_coplanar_faces_only():
    occ = np.zeros((16, 16, 16), bool)
    occ[3:9, 3:13, 3:13] = True                 # faces of 6 x 10 and 10 x 10 voxels
    occ[9, 5, 5] = True                         # a one-voxel step on the +x face
    free = ~occ
    flat = flat_patch_voxels(occ, free, 15)
    assert flat[8, 8, 8] and flat[3, 8, 8]       # the +x and -x faces' layers
    assert not flat[9, 5, 5]                     # the step: a patch of 1 (+x) and 4 side faces of 1
    assert not flat[5, 8, 8]                     # inside
    assert not flat_patch_voxels(occ, free, 200).any()


def test_the_flat_face_moves_inward_by_the_offset_where_smoothing_alone_leaves_it():
    vol = _slab_volume()
    hull = vol > 0
    hull[4:8, 4:12, 4:12] = False                # the outer layer only
    free = vol == 0
    kw = dict(min_island_fraction=0, smooth_iterations=0)
    plain, _ = mesh_from_volume(vol, (0, 0, 0), (15, 15, 15), 0.5, inward=InwardSmoothing(hull, 0.5, 10), **kw)
    flat, _ = mesh_from_volume(vol, (0, 0, 0), (15, 15, 15), 0.5,
                               inward=InwardSmoothing(hull, 0.5, 10, flat_patch_voxels(hull, free, 15), 0.25), **kw)
    mid = lambda m: m.vertices[(np.abs(m.vertices[:, 1] - 7.5) < 1.6) & (np.abs(m.vertices[:, 2] - 7.5) < 1.6)
                               & (m.vertices[:, 0] > 8)]
    assert np.all(mid(plain)[:, 0] > 8.44)                        # the smoothing leaves the flat run (about)
    assert np.all(mid(flat)[:, 0] < 8.27)                         # the offset moves it a quarter voxel in
    assert np.all(mid(flat)[:, 0] > 8.2)
    assert np.all(np.isfinite(flat.vertices))


def test_flat_centre_setting_is_range_checked():
    assert override(FitConfig(mode="fast"), ["fast.mesh_hull_flat_centre_voxels=0.25"]).fast.mesh_hull_flat_centre_voxels == 0.25
    with pytest.raises(SettingsError, match="fast.mesh_hull_flat_centre_voxels"):
        override(FitConfig(mode="fast"), ["fast.mesh_hull_flat_centre_voxels=0.8"])
    with pytest.raises(SettingsError, match="fast.mesh_hull_flat_patch_faces"):
        override(FitConfig(mode="fast"), ["fast.mesh_hull_flat_patch_faces=0"])
