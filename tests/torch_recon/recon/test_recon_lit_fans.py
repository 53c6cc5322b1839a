"""The hidden hull's boundary voxels as the share of space no spot's lit fan swept (`fast.mesh_hull_lit_fan`,
session 16; recon/lit_fans.py)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torch_recon.contract.errors import SettingsError
from torch_recon.recon.config import FitConfig, override
from torch_recon.recon.lit_fans import CARVED_MAX, HULL_MIN, in_lit_fans, sub_points, with_occupancy

SPOT = np.array([0.0, 0.0, 2.0])
OFF = 0.05


def _fan(shadowed_x=(0.3, 0.6), step=0.1):
    """Segments from the floor z = 0 (x, y in [-1, 1], `step` apart) to SPOT: lit, except x in `shadowed_x`."""
    g = np.arange(-1.0, 1.0 + 1e-9, step)
    x = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    x = np.c_[x, np.zeros(len(x))]
    v = SPOT - x
    length = np.linalg.norm(v, axis=1)
    d = v / length[:, None]
    shade = (x[:, 0] > shadowed_x[0]) & (x[:, 0] < shadowed_x[1])

    def seg(m):
        t = lambda a: torch.as_tensor(a[m])     # noqa: E731
        return t(x), t(d), torch.full((int(m.sum()),), OFF, dtype=torch.float64), t(length - OFF)
    return seg(~shade), seg(shade)


def test_the_fan_holds_the_space_between_lit_segments_not_beyond_the_surface_nor_in_the_shadow():
    lit, shadowed = _fan()
    on_line = lambda fx, fy, t: SPOT + t * (np.array([fx, fy, 0.0]) - SPOT)     # noqa: E731 (floor point fx, fy)
    pts = np.array([on_line(-0.45, 0.05, 0.5),      # between four lit pixels' lines, half-way down: swept
                    on_line(0.0, 0.0, 0.9),         # on a lit line, near the floor: swept
                    on_line(0.45, 0.05, 0.5),       # in the shadowed pixels' directions: not
                    on_line(-0.45, 0.05, 1.2),      # below the floor, beyond the surface: not
                    on_line(3.0, 0.0, 0.5)])        # towards no pixel at all: not
    assert in_lit_fans(SPOT[None], lit, shadowed, pts).tolist() == [True, True, False, False, False]


def test_sub_points_are_the_sub_cell_centres():
    p = sub_points(np.array([[1, 0, 2]]), (0.0, 0.0, 0.0), 2.0, n=2)
    assert p.shape == (8, 3)
    assert np.allclose(p.min(0), [2.5, 0.5, 4.5]) and np.allclose(p.max(0), [3.5, 1.5, 5.5])


def test_occupancy_enters_the_field_only_on_movable_or_saturated_free_voxels():
    vol = np.full((4, 4, 4), -1.0, np.float32)
    vol[1:3, 1:3, 1:3] = 1.0
    vol[0, 0, 0] = 0.2                                # a ramp (a measured surface): never changed
    movable = np.zeros(vol.shape, bool)
    movable[1, 1, 1] = True
    cells = np.array([[1, 1, 1], [2, 2, 2], [3, 3, 3], [0, 0, 0]])
    out = with_occupancy(vol, cells, np.array([0.25, 0.25, 0.4, 0.9]), movable)
    assert out[1, 1, 1] == pytest.approx(-0.5) and out[3, 3, 3] == pytest.approx(-0.2)
    assert out[2, 2, 2] == 1.0 and out[0, 0, 0] == pytest.approx(0.2)       # not movable; not saturated
    assert vol[1, 1, 1] == 1.0                        # a copy
    with pytest.raises(ValueError, match="not finite"):
        with_occupancy(vol, cells, np.array([np.nan, 0, 0, 0]), movable)


def test_the_fitted_box_scene_places_its_hull_boundary_between_voxel_faces():
    """Box on a floor (32 px, 56 voxels): with `fast.mesh_hull_lit_fan` the hull's boundary voxels get shares
    strictly between whole voxels (hull ones at least HULL_MIN, carved ones at most CARVED_MAX), and the mesh is
    finite."""
    from tests.support.recon_fixtures import box_floor_measurements
    from tests.torch_recon.recon.test_recon_fit import small_config
    from tests.torch_recon.recon.test_recon_freeze import _meta
    from torch_recon.mesh_export import mesh_from_volume
    from torch_recon.recon.data import build_ray_data
    from torch_recon.recon.models import FastModel

    meas = box_floor_measurements(32)
    cfg = small_config(steps=1)
    cfg.fast.resolution = 56
    cfg.fast.mesh_hull_lit_fan = True
    model = FastModel(build_ray_data(meas), cfg, _meta(meas))
    box = model.grid.box
    vol, level = model.surface_volume()
    inward = model.mesh_inward(vol, level)
    cells, share = inward.occupancy
    assert len(cells) > 20 and np.all((share >= 0) & (share <= 1))
    assert np.any((share > 0.05) & (share < 0.95))    # sub-voxel: neither whole voxel
    hull = inward.movable[tuple(cells.T)]
    assert np.all(share[hull] >= HULL_MIN) and np.all(share[~hull] <= CARVED_MAX)
    lo = box.bbox_min.numpy() + 0.5 * box.voxel
    hi = lo + (np.array(box.shape) - 1) * box.voxel
    mesh, _ = mesh_from_volume(vol, lo, hi, level, smooth_iterations=10, inward=inward, min_island_fraction=0)
    assert len(mesh.faces) > 100 and np.all(np.isfinite(mesh.vertices))


def test_lit_fan_is_opt_in_and_needs_the_shrinkable_hull():
    assert not FitConfig(mode="fast").fast.mesh_hull_lit_fan
    assert override(FitConfig(mode="fast"), ["fast.mesh_hull_lit_fan=true"]).fast.mesh_hull_lit_fan
    assert override(FitConfig(mode="fast"), ["fast.mesh_hull_lit_fan=true",          # the flat patches get fans too
                                             "fast.mesh_hull_flat_approach=false"]).fast.mesh_hull_lit_fan
    with pytest.raises(SettingsError, match="fast.mesh_hull_lit_fan"):
        override(FitConfig(mode="fast"), ["fast.mesh_hull_lit_fan=true", "fast.mesh_hull_shrink_voxels=0"])
