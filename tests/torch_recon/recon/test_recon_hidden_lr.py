"""fast.hidden_lr_scale: the voxels no direct measurement fixed take larger optimiser steps."""

from __future__ import annotations

import pytest
import torch

from tests.support.recon_fixtures import box_floor_measurements
from tests.torch_recon.recon.test_recon_fit import small_config
from tests.torch_recon.recon.test_recon_freeze import _meta

from torch_recon.recon.data import build_ray_data
from torch_recon.recon.models import FastModel


@pytest.fixture(scope="module")
def meas():
    return box_floor_measurements(32)


def _one_step(meas, scale):
    cfg = small_config(steps=10)
    cfg.fast.hidden_lr_scale = scale
    data = build_ray_data(meas)
    model = FastModel(data, cfg, _meta(meas))
    raw0 = model.grid.raw.detach().clone()
    gen = torch.Generator().manual_seed(0)
    idx = data.sample(1024, gen, lit_only=False)
    loss, _ = model.loss(idx, 5, 10, gen)      # after the warm-up: the shadow loss reaches the hidden hull
    model.optimizer.zero_grad(set_to_none=True)
    loss.backward()
    model.optimizer.step()
    return model, raw0, model.grid.raw.detach() - raw0


def test_hidden_voxels_step_scale_times_further_measured_ones_the_same(meas):
    base, raw0, d1 = _one_step(meas, 1.0)
    model, raw0b, d4 = _one_step(meas, 4.0)
    assert base.step_scale is None and torch.equal(raw0, raw0b)
    measured = model._measured(raw0)
    hidden = ~measured
    assert torch.equal(model.step_scale[hidden], torch.full_like(model.step_scale[hidden], 4.0))
    moved = hidden & (d1.abs() > 1e-6)
    assert moved.sum() > 10 and (measured & (d1.abs() > 1e-6)).sum() > 10
    torch.testing.assert_close(d4[moved], 4.0 * d1[moved], rtol=1e-4, atol=1e-6)
    torch.testing.assert_close(d4[measured], d1[measured], rtol=1e-4, atol=1e-6)


def test_hidden_lr_scale_survives_a_checkpoint(meas):
    model, _, _ = _one_step(meas, 3.0)
    st = model.state_dict()
    other, _, _ = _one_step(meas, 1.0)
    other.load_state_dict(st)
    assert torch.equal(other.step_scale, model.step_scale)


def test_hidden_lr_scale_must_be_positive():
    from torch_recon.contract.errors import SettingsError
    from torch_recon.recon.config import FitConfig, override

    with pytest.raises(SettingsError, match="fast.hidden_lr_scale"):
        override(FitConfig(), ["fast.hidden_lr_scale=0"])
