"""A pixel part covered by a thin part holds two returns: the earlier one bounds the pixel's free space
(matched_filter `first_return_bin`, visible_depth `nearest`)."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from torch_recon.measurements import Measurements, SpotMeasurement  # noqa: E402
from torch_recon.matched_filter import first_return_bin  # noqa: E402
from torch_recon.visible_depth import fuse_visible_depth  # noqa: E402


def _pulse(n, centre, height):
    return height * np.exp(-0.5 * ((np.arange(n) - centre) / 0.8) ** 2)


def test_the_earliest_significant_return_is_found_not_the_strongest():
    n = 60
    rows = np.stack([
        _pulse(n, 10, 3.0) + _pulse(n, 30, 10.0),    # a leg (weaker) in front of the floor
        _pulse(n, 10, 0.3) + _pulse(n, 30, 10.0),    # 3 %: below the 10 % fraction, the floor alone
        _pulse(n, 30, 10.0),                          # one surface
        _pulse(n, 12, 10.0) + _pulse(n, 30, 4.0),    # the strongest is the earliest
    ])
    corr = torch.as_tensor(rows)
    k = first_return_bin(corr, corr.max(1).values, torch.zeros(len(rows), dtype=corr.dtype), 0.1)
    assert k.tolist() == [10, 30, 30, 12]
    # a background rate lifts the threshold: a return 5 % over a background of 2 per bin is not significant
    k = first_return_bin(corr + 2.0, corr.max(1).values + 2.0, torch.full((len(rows),), 2.0, dtype=corr.dtype), 0.5)
    assert k.tolist() == [30, 30, 30, 12]


def _two_surface_measurements(early_spots):
    """Two pixels looking along +y from the origin at a wall 3 m away; a thin part 2 m away fills part of
    pixel 0 (its earliest return, seen by the spots `early_spots`) and none of pixel 1."""
    u = np.array([[[0.0, 1.0, 0.0], [0.05, 1.0, 0.0]]])
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    c = np.zeros(3)
    spots = []
    for k, l in enumerate(([-1.0, 2.5, 0.5], [1.0, 2.5, -0.5], [0.5, 2.8, 1.0])):
        l = np.asarray(l)
        path = lambda t: np.linalg.norm(l) + np.linalg.norm(c + t[:, None] * u[0] - l, axis=-1) + t  # noqa: E731
        far, near = path(np.array([3.0, 3.0 / u[0, 1, 1]])), path(np.array([2.0, 2.0 / u[0, 1, 1]]))
        first = np.array([near[0] if k in early_spots else far[0], far[1]])
        ones = np.ones((1, 2), bool)
        spots.append(SpotMeasurement(spot_id=k, first_bounce=l, laser_direction=l / np.linalg.norm(l),
                                     path_length=far[None].astype(np.float32), signal=ones,
                                     shadow_confidence=ones.astype(np.float32), shadow=~ones, excluded=~ones,
                                     first_return_path=first[None].astype(np.float32)))
    return Measurements(width=2, height=1, fov_rad=0.5, fov_axis="x", camera_to_world=np.eye(4),
                        laser_origin=c, bin_width_m=0.01, shadow_threshold=0.15, spots=spots, ray_directions=u)


def test_nearest_depth_is_the_thin_part_that_two_spots_see_not_one_stray_peak():
    fused = fuse_visible_depth(_two_surface_measurements(early_spots=(0, 1)))
    assert fused.depth[0, 0] == pytest.approx(3.0, abs=1e-4)        # the strongest returns: the wall
    assert fused.nearest[0, 0] == pytest.approx(2.0, abs=1e-4)      # the part in front
    assert fused.nearest[0, 1] == pytest.approx(fused.depth[0, 1], abs=1e-6)
    one = fuse_visible_depth(_two_surface_measurements(early_spots=(0,)))
    assert one.nearest[0, 0] == pytest.approx(3.0, abs=1e-4)        # one spot's early peak is not enough


def test_coarse_bins_scatter_of_the_spots_ranges_makes_no_nearer_surface():
    """1024 ps bins: each spot's sub-bin path errs by a few cm, so its range does too; with no earlier
    return in any spot the nearest surface is the depth itself (the second smallest of the scattered
    ranges put a 'thin part' in front of every pixel: rings of spurious surface over the room)."""
    m = _two_surface_measurements(early_spots=())
    for k, s in enumerate(m.spots):
        err = np.float32((-0.06, -0.03, 0.09)[k])     # cm of path: quantisation-sized errors
        s.path_length = s.path_length + err
        s.first_return_path = s.first_return_path + err
    fused = fuse_visible_depth(m, inlier_m=0.3)
    np.testing.assert_allclose(fused.nearest, fused.depth, atol=1e-6)
    # and a part in front that two spots see is still found
    m2 = _two_surface_measurements(early_spots=(0, 1))
    for k, s in enumerate(m2.spots):
        err = np.float32((-0.06, -0.03, 0.09)[k])
        s.path_length, s.first_return_path = s.path_length + err, s.first_return_path + err
    f2 = fuse_visible_depth(m2, inlier_m=0.3)
    assert f2.nearest[0, 0] == pytest.approx(2.0, abs=0.08)      # the earlier peaks carry their own sub-bin error
    assert f2.nearest[0, 1] == pytest.approx(f2.depth[0, 1], abs=1e-6)


def test_nearest_depth_survives_a_save_and_load(tmp_path):
    m = _two_surface_measurements(early_spots=(0, 1))
    fused = fuse_visible_depth(m)
    m.visible_depth, m.visible_confidence, m.nearest_depth = fused.depth, fused.confidence, fused.nearest
    back = Measurements.load(m.save(tmp_path / "m.npz"))
    np.testing.assert_array_equal(back.nearest_depth, m.nearest_depth)
    np.testing.assert_array_equal(back.spots[0].first_return_path, m.spots[0].first_return_path)


def test_a_first_return_fraction_outside_0_1_is_refused():
    from torch_recon.contract.errors import PreprocessError
    from torch_recon.preprocess import PreprocessSettings

    with pytest.raises(PreprocessError, match="first_return_fraction"):
        PreprocessSettings(first_return_fraction=1.5).validate()


def test_with_photon_counts_a_stray_photon_before_the_return_is_no_earlier_surface():
    n = 60
    one_photon = np.zeros(n)
    one_photon[10] = 1.0                            # one photon, 20 % of a 5-photon return: not a surface
    rows = np.stack([one_photon + _pulse(n, 30, 5.0), _pulse(n, 10, 12.0) + _pulse(n, 30, 40.0)])
    corr = torch.as_tensor(rows)
    noise = torch.full((2,), 4.0 * np.sqrt(0.3), dtype=corr.dtype)
    k = first_return_bin(corr, corr.max(1).values, torch.zeros(2, dtype=corr.dtype), 0.1, noise)
    assert k.tolist() == [30, 10]
    assert first_return_bin(corr, corr.max(1).values, torch.zeros(2, dtype=corr.dtype), 0.1).tolist() == [10, 10]
