"""Surface placement of the fast mode's mesh: the shadow hull's binary boundary inset, the level shift."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torch_recon.recon.models import binary_boundary_inset

LEVEL, HALF = 0.94, 3.06


def _crossing(column):
    """Where the linear interpolation of a 1-D profile crosses LEVEL (in voxel centres' index units)."""
    c = np.asarray(column, np.float64)
    i = int(np.flatnonzero((c[:-1] < LEVEL) & (c[1:] >= LEVEL))[0])
    return i + (LEVEL - c[i]) / (c[i + 1] - c[i])


def _step_volume():
    """x < 3 free (saturated), x >= 3 occupied (saturated), on a (7, 3, 3) grid."""
    v = torch.full((7, 3, 3), LEVEL - HALF)
    v[3:] = LEVEL + HALF
    return v


@pytest.mark.parametrize("inset", [0.1, 0.25, 0.4])
def test_binary_boundary_crossing_moves_inset_voxels_inside(inset):
    v = _step_volume()
    assert _crossing(v[:, 1, 1]) == pytest.approx(2.5)
    out = binary_boundary_inset(v, LEVEL, HALF, inset)
    assert _crossing(out[:, 1, 1]) == pytest.approx(2.5 + inset)
    assert torch.equal(out[4:], v[4:]) and torch.equal(out[:3], v[:3])   # interior and free space untouched
    assert torch.equal(v, _step_volume())                                 # the input is not modified


def test_ramp_voxels_keep_their_values():
    """A measured surface (unsaturated ramp values) is not a binary boundary: nothing changes there."""
    v = torch.full((7, 3, 3), LEVEL - HALF)
    v[2] = LEVEL - 1.0
    v[3] = LEVEL + 2.0
    v[4:] = LEVEL + HALF
    out = binary_boundary_inset(v, LEVEL, HALF, 0.3)
    assert torch.equal(out, v)


def test_one_voxel_part_keeps_its_thickness_less_twice_the_inset():
    v = torch.full((7, 3, 3), LEVEL - HALF)
    v[3] = LEVEL + HALF
    out = binary_boundary_inset(v, LEVEL, HALF, 0.25)[:, 1, 1].numpy()
    near = _crossing(out)
    far = 6 - _crossing(out[::-1])
    assert far - near == pytest.approx(1.0 - 2 * 0.25)


def test_surface_placement_settings_are_range_checked():
    from torch_recon.contract.errors import SettingsError
    from torch_recon.recon.config import FitConfig, override

    with pytest.raises(SettingsError, match="fast.mesh_hull_inset_voxels"):
        override(FitConfig(), ["fast.mesh_hull_inset_voxels=0.5"])
    with pytest.raises(SettingsError, match="fast.mesh_level_shift_voxels"):
        override(FitConfig(), ["fast.mesh_level_shift_voxels=0.6"])
