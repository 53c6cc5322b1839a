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


def test_fast_model_surface_volume_applies_the_settings():
    """The fast model's mesh field: the level moves by shift x surface_slope; the inset lowers only saturated
    occupied voxels next to saturated free ones; both off by default."""
    from tests.support.recon_fixtures import box_floor_measurements
    from tests.torch_recon.recon.test_recon_fit import small_config
    from tests.torch_recon.recon.test_recon_freeze import _meta
    from torch_recon.recon.data import build_ray_data
    from torch_recon.recon.models import FastModel

    meas = box_floor_measurements(32)
    cfg = small_config(steps=1)
    assert cfg.fast.mesh_level_shift_voxels == 0 and cfg.fast.mesh_hull_inset_voxels == 0
    model = FastModel(build_ray_data(meas), cfg, _meta(meas))
    vol0, level0 = model.surface_volume()
    cfg.fast.mesh_level_shift_voxels = 0.1
    _, level1 = model.surface_volume()
    assert level1 == pytest.approx(level0 + 0.1 * cfg.fast.surface_slope)
    cfg.fast.mesh_level_shift_voxels = 0.0
    cfg.fast.mesh_hull_inset_voxels = 0.3
    vol2, level2 = model.surface_volume()
    assert level2 == level0
    changed = vol2 != vol0
    assert changed.any() and np.all(vol0[changed] == vol0.max()) and np.all(vol2[changed] < vol0.max())
