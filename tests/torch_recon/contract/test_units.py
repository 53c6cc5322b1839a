import math

import numpy as np
import pytest

from torch_recon.contract import units


def test_paper_bin_width():
    # the paper: 128 ps bins = 0.0384 m of optical path (rounded)
    assert units.ps_to_m(128.0) == pytest.approx(0.0384, rel=1e-3)
    assert units.bin_widths_consistent(0.0384, 128.0)
    assert not units.bin_widths_consistent(0.0384, 256.0)
    assert not units.bin_widths_consistent(float("nan"), 128.0)


@pytest.mark.parametrize("x", [0.0, 1e-6, 1.0, 128.0, 1e6])
def test_round_trips(x):
    assert units.m_to_ps(units.ps_to_m(x)) == pytest.approx(x, rel=1e-12, abs=1e-15)
    assert units.rad_to_deg(units.deg_to_rad(x)) == pytest.approx(x, rel=1e-12, abs=1e-15)
    assert units.sigma_to_fwhm(units.fwhm_to_sigma(x)) == pytest.approx(x, rel=1e-12, abs=1e-15)


def test_fwhm_sigma():
    sigma = units.fwhm_to_sigma(1.0)
    # a Gaussian is at half its peak at +-FWHM/2
    assert math.exp(-0.5 * (0.5 / sigma) ** 2) == pytest.approx(0.5)


def test_vectorised():
    a = np.array([1.0, 2.0, 3.0])
    np.testing.assert_allclose(units.m_to_ps(units.ps_to_m(a)), a)
