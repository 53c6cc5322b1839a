"""Surface placement of the fast mode's mesh: the shadow hull's binary boundary inset, the level shift."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torch_recon.recon.hull_subvoxel import binary_boundary_inset

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


def _slab(thickness):
    """Saturated free on a (9, 3, 3) grid with an occupied slab x = 3 .. 3 + thickness - 1."""
    v = torch.full((9, 3, 3), LEVEL - HALF)
    v[3:3 + thickness] = LEVEL + HALF
    return v


def _thickness(column):
    return (8 - _crossing(column[::-1])) - _crossing(column)


@pytest.mark.parametrize("thickness, thinned", [(1, False), (2, True), (3, False)])
def test_inset_only_across_slabs_of_the_given_thickness(thickness, thinned):
    """max 2, min 2: a wall a voxel fraction thick straddling two voxels is pulled in from both faces; a one-voxel
    run (a leg, a restored blocker: the part at its centre) and a thick hull keep their faces."""
    out = binary_boundary_inset(_slab(thickness), LEVEL, HALF, 0.3, max_thickness_voxels=2, min_thickness_voxels=2)
    got = _thickness(out[:, 1, 1].numpy())
    assert got == pytest.approx(thickness - 0.6 if thinned else thickness)


def test_inset_leaves_voxels_next_to_a_measured_surface_and_kept_ones():
    """A voxel next to a measured surface's outer ramp (unsaturated, below the level) is not lowered: that
    surface's crossing would move; its neighbour in the slab is. A kept voxel (a thin part) is never lowered."""
    v = _slab(2)
    v[3, 0, 1] = LEVEL - 1.0                 # a measured surface's ramp beside voxel (3, 1, 1)
    out = binary_boundary_inset(v, LEVEL, HALF, 0.3, max_thickness_voxels=2, min_thickness_voxels=2)
    assert out[3, 1, 1] == v[3, 1, 1]
    assert out[4, 1, 1] < v[4, 1, 1]
    keep = torch.zeros(v.shape, dtype=torch.bool)
    keep[3:5] = True
    out = binary_boundary_inset(_slab(2), LEVEL, HALF, 0.3, max_thickness_voxels=2, keep=keep)
    assert torch.equal(out, _slab(2))


def test_surface_placement_settings_are_range_checked():
    from torch_recon.contract.errors import SettingsError
    from torch_recon.recon.config import FitConfig, override

    with pytest.raises(SettingsError, match="fast.mesh_hull_inset_voxels"):
        override(FitConfig(), ["fast.mesh_hull_inset_voxels=0.5"])
    with pytest.raises(SettingsError, match="fast.mesh_level_shift_voxels"):
        override(FitConfig(), ["fast.mesh_level_shift_voxels=0.6"])
    with pytest.raises(SettingsError, match="fast.mesh_hull_inset_min_voxels"):
        override(FitConfig(), ["fast.mesh_hull_inset_max_voxels=2", "fast.mesh_hull_inset_min_voxels=3"])


def test_fast_model_surface_volume_applies_the_settings():
    """The fast model's mesh field: the level moves by shift x surface_slope; the inset lowers only saturated
    occupied voxels next to saturated free ones. The shift is off by default, the inset on (2-voxel hull runs)."""
    from tests.support.recon_fixtures import box_floor_measurements
    from tests.torch_recon.recon.test_recon_fit import small_config
    from tests.torch_recon.recon.test_recon_freeze import _meta
    from torch_recon.recon.data import build_ray_data
    from torch_recon.recon.models import FastModel

    meas = box_floor_measurements(32)
    cfg = small_config(steps=1)
    assert cfg.fast.mesh_level_shift_voxels == 0 and cfg.fast.mesh_hull_inset_voxels == 0.35
    cfg.fast.mesh_hull_inset_voxels, cfg.fast.mesh_hull_inset_max_voxels, cfg.fast.mesh_hull_inset_min_voxels = 0.0, 0, 1
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
