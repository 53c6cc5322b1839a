"""A lit pair whose path disagrees with its pixel's visible point got its light from another surface in the
pixel (a depth edge): it carves from where its own path puts the surface, and training leaves it out
(recon/data.py `unexplained_lit`, recon/segment_crossings.py `pair_segments`, `fast.lit_path_tolerance_voxels`)."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from torch_recon.contract.errors import SettingsError  # noqa: E402
from torch_recon.recon.config import FitConfig, override  # noqa: E402
from torch_recon.recon.data import RayData, lit_path_tolerance, unexplained_lit, without_lit  # noqa: E402
from torch_recon.recon.fields import GridBox  # noqa: E402
from torch_recon.recon.segment_crossings import pair_segments  # noqa: E402
from torch_recon.recon.voxel_evidence import evidence_grid  # noqa: E402

C = np.array([0.5, 0.5, 2.0])
TOP = np.array([0.5, 0.5, 0.6])     # what the pixel's depth sees: a block's top edge
FLOOR = np.array([0.5, 0.5, 0.0])   # ... and the floor behind it, in the same pixel
L_ABOVE = np.array([0.0, 0.5, 1.0])  # lights the top
L_BELOW = np.array([1.0, 0.5, 0.5])  # below the top's plane: lights only the floor


def _edge_pixel():
    """One pixel looking straight down at the top; spot 0 lights the top (its path goes through the top), spot 1
    only the floor behind it in the same pixel (its path goes through the floor, about 1.2 m longer)."""
    path = lambda x, l: np.linalg.norm(x - C) + np.linalg.norm(l - x) + np.linalg.norm(l - C)  # noqa: E731
    spots = np.stack([L_ABOVE, L_BELOW])
    f = lambda a, dt=torch.float32: torch.as_tensor(np.asarray(a), dtype=dt)  # noqa: E731
    return RayData(sensor_origin=f(C), laser_origin=f(C), pixel_dirs=f([[0.0, 0.0, -1.0]]), spot_points=f(spots),
                   laser_to_spot=f(np.linalg.norm(spots - C, axis=1)), pair_pixel=f([0, 0], torch.long),
                   pair_spot=f([0, 1], torch.long), path=f([path(TOP, L_ABOVE), path(FLOOR, L_BELOW)]),
                   lit=f([True, True], torch.bool), shadowed=f([False, False], torch.bool),
                   visible_depth=f([np.linalg.norm(TOP - C)]), height=1, width=1, bin_width_m=0.04)


def test_the_pair_lit_through_another_surface_is_unexplained():
    data = _edge_pixel()
    assert unexplained_lit(data, 0.05).tolist() == [False, True]
    assert not unexplained_lit(data, 2.0).any()


def test_its_segment_starts_where_its_own_path_puts_the_surface():
    data = _edge_pixel()
    origins, dirs, near, far = pair_segments(data, data.lit, 0.01, own_range=unexplained_lit(data, 0.05))
    np.testing.assert_allclose(origins.numpy(), [TOP, FLOOR], atol=1e-4)
    np.testing.assert_allclose((origins + dirs * (far + 0.01)[:, None]).numpy(), [L_ABOVE, L_BELOW], atol=1e-4)


def test_it_no_longer_carves_the_block_under_the_top():
    data = _edge_pixel()
    box = GridBox([0.0, 0.0, 0.0], [1.2, 1.2, 2.2], 44)      # 5 cm voxels
    under_top = box.cell_index(torch.tensor([[0.8, 0.5, 0.545]]))[0][0].tolist()   # on the segment top -> L_BELOW
    above_floor = box.cell_index(torch.tensor([[0.8, 0.5, 0.3]]))[0][0].tolist()   # on the segment floor -> L_BELOW
    old = evidence_grid(data, box)[0].label
    new = evidence_grid(data, box, lit_path_tolerance_m=0.05)[0].label
    assert old[tuple(under_top)] == 3 and new[tuple(under_top)] != 3
    assert new[tuple(above_floor)] == 3


def test_training_leaves_it_out_and_the_tolerance_is_at_least_half_a_bin():
    data = _edge_pixel()
    kept = without_lit(data, unexplained_lit(data, 0.05))
    assert kept.lit.tolist() == [True, False] and not kept.shadowed.any()
    assert torch.isnan(kept.path[1]) and data.lit.all()      # the original is untouched
    assert lit_path_tolerance(data, 0.032, 1.0) == pytest.approx(0.032)
    assert lit_path_tolerance(data, 0.01, 1.0) == pytest.approx(0.02)     # half of the 4 cm bin
    assert lit_path_tolerance(data, 0.032, 0.0) == 0.0


def test_a_negative_tolerance_is_refused():
    with pytest.raises(SettingsError, match="fast.lit_path_tolerance_voxels"):
        override(FitConfig(), ["fast.lit_path_tolerance_voxels=-1"])
