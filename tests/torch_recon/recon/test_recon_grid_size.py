"""The fast grid is no finer than the sensor's pixels resolve (recon/grid_size.py)."""

from __future__ import annotations

import dataclasses

import pytest

pytest.importorskip("torch")

from tests.support.recon_fixtures import box_floor_measurements  # noqa: E402
from torch_recon.contract.errors import SettingsError  # noqa: E402
from torch_recon.recon import FitConfig  # noqa: E402
from torch_recon.recon.data import build_ray_data  # noqa: E402
from torch_recon.recon.grid_size import describe, sensor_grid, sensor_grid_resolution  # noqa: E402


@pytest.fixture(scope="module")
def coarse_and_fine():
    return build_ray_data(box_floor_measurements(16)), build_ray_data(box_floor_measurements(64))


def test_the_cap_follows_the_pixel_footprint(coarse_and_fine):
    coarse, fine = coarse_and_fine
    a, b = sensor_grid_resolution(coarse, 1.5), sensor_grid_resolution(fine, 1.5)
    assert 15 < a < 40 and 3.5 < b / a < 4.5          # 4 x the pixels: about 4 x the voxels
    assert sensor_grid_resolution(coarse, 3.0) == pytest.approx(2 * a, abs=1)


def test_a_coarse_sensor_gets_a_coarser_grid_and_the_log_says_so(coarse_and_fine):
    coarse, fine = coarse_and_fine
    cfg = FitConfig(mode="fast")
    capped, note = sensor_grid(coarse, cfg)
    assert capped.fast.resolution == sensor_grid_resolution(coarse, cfg.fast.max_voxels_per_pixel) < 128
    assert capped.fast.coarse_resolution == round(64 * capped.fast.resolution / 128)
    assert note["requested"] == 128 and "16 x 16 px" in describe(note) and "max_voxels_per_pixel" in describe(note)
    assert cfg.fast.resolution == 128                   # the caller's config is not changed
    # a grid the sensor resolves, the cap switched off, or the other mode: unchanged
    small = dataclasses.replace(cfg, fast=dataclasses.replace(cfg.fast, resolution=16))
    assert sensor_grid(coarse, small) == (small, None)
    off = dataclasses.replace(cfg, fast=dataclasses.replace(cfg.fast, max_voxels_per_pixel=0.0))
    assert sensor_grid(coarse, off) == (off, None)
    assert sensor_grid(coarse, FitConfig(mode="platonerf"))[1] is None


def test_a_negative_or_infinite_cap_is_refused():
    for bad in (-1.0, float("inf"), float("nan")):
        with pytest.raises(SettingsError, match="fast.max_voxels_per_pixel"):
            FitConfig.from_dict({"fast": {"max_voxels_per_pixel": bad}})
