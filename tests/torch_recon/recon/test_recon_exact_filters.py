"""Faster grid filters with the same values (issue 11's speed, session 17): the cube dilation by neighbour maxima
(max_pool3d's values), the thin parts' gradient mask at their own voxels (masked_fill's values)."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from torch_recon.recon.fields import dilate_cube


def _same(a: torch.Tensor, b: torch.Tensor) -> bool:
    return (a.shape == b.shape and torch.equal(a.isnan(), b.isnan())
            and torch.equal(torch.nan_to_num(a, nan=0.0), torch.nan_to_num(b, nan=0.0)))


@pytest.mark.parametrize("r", [0, 1, 2, 3])
def test_cube_dilation_is_max_pool3d_on_any_values(r):
    """Real values of either sign, NaNs, thin and one-voxel axes, the raw layout (1, 1, nz, ny, nx) too."""
    gen = torch.Generator().manual_seed(10 + r)
    for shape in ((9, 14, 11), (1, 5, 2), (3, 1, 1), (1, 1, 6, 7, 8)):
        x = torch.randn(shape, generator=gen) * 3.0
        x.view(-1)[torch.randint(0, x.numel(), (3,), generator=gen)] = float("nan")
        x5 = x if x.dim() == 5 else x[None, None]
        ref, ref_min = F.max_pool3d(x5, 2 * r + 1, 1, r), -F.max_pool3d(-x5, 2 * r + 1, 1, r)
        if x.dim() == 3:
            ref, ref_min = ref[0, 0], ref_min[0, 0]
        got = dilate_cube(x, r)
        assert _same(got, ref), (shape, r)
        assert _same(-dilate_cube(-x, r), ref_min)     # the occupancy's minimum
        assert got.data_ptr() != x.data_ptr()


@pytest.mark.parametrize("training", ["frozen", "grow"])
def test_thin_part_gradient_mask_is_masked_fill(training):
    from tests.support.recon_fixtures import box_floor_measurements
    from tests.torch_recon.recon.test_recon_fit import small_config
    from tests.torch_recon.recon.test_recon_freeze import _meta
    from torch_recon.recon.data import build_ray_data
    from torch_recon.recon.freeze_masks import masked_gradient
    from torch_recon.recon.models import FastModel

    meas = box_floor_measurements(32)
    cfg = small_config(steps=1)
    cfg.fast.thin_part_training = training
    cfg.fast.freeze_spot_radius_voxels = 0.0       # this mask alone (test_recon_freeze.py has the spots')
    cfg.fast.freeze_plane_edges_voxels = 0.0
    model = FastModel(build_ray_data(meas), cfg, _meta(meas))
    gen = torch.Generator().manual_seed(4)
    model.thin_parts = torch.rand(model.grid.raw.shape, generator=gen) > 0.9       # any mask, many voxels
    g = torch.randn(model.grid.raw.shape, generator=gen)
    g.view(-1)[:50] = float("nan")
    g.view(-1)[50:100] = -0.0
    stop = model.thin_parts if training == "frozen" else model.thin_parts & (g > 0)
    ref = g.masked_fill(stop, 0.0)
    got = masked_gradient(model, g)
    assert _same(got, ref) and torch.equal(torch.signbit(got), torch.signbit(ref))
    assert not torch.equal(torch.nan_to_num(g), torch.nan_to_num(got))      # the caller's gradient is left alone
    model.thin_parts = model.thin_parts.clone()         # a new mask (a resumed fit): its own voxels
    model.thin_parts.view(-1)[:500] = True
    stop = model.thin_parts if training == "frozen" else model.thin_parts & (g > 0)
    assert _same(masked_gradient(model, g), g.masked_fill(stop, 0.0))


def test_measured_gradient_mask_is_cast_once_and_follows_a_new_mask():
    """`fast.freeze_measured`'s mask: the same values as `g * trainable` every step, cast once per mask (not per
    step), and a new mask (the fine level's, a resumed fit's) used from its first step."""
    from tests.support.recon_fixtures import box_floor_measurements
    from tests.torch_recon.recon.test_recon_fit import small_config
    from tests.torch_recon.recon.test_recon_freeze import _meta
    from torch_recon.recon.data import build_ray_data
    from torch_recon.recon.freeze_masks import masked_gradient
    from torch_recon.recon.models import FastModel

    meas = box_floor_measurements(32)
    cfg = small_config(steps=1)
    cfg.fast.freeze_measured = True
    cfg.fast.freeze_spot_radius_voxels = 0.0
    cfg.fast.freeze_plane_edges_voxels = 0.0
    model = FastModel(build_ray_data(meas), cfg, _meta(meas))
    model.thin_parts = model.frozen_voxels = None                   # this mask alone
    gen = torch.Generator().manual_seed(5)
    model.trainable = torch.rand(model.grid.raw.shape, generator=gen) > 0.5
    g = torch.randn(model.grid.raw.shape, generator=gen)
    assert _same(masked_gradient(model, g), g * model.trainable.float())
    cast = model._trainable_cast[1]
    masked_gradient(model, g)
    assert model._trainable_cast[1] is cast                         # the cast is kept between steps
    model.trainable = ~model.trainable                              # a new mask: used at once
    assert _same(masked_gradient(model, g), g * model.trainable.float())
