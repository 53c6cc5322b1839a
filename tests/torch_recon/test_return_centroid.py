"""The sub-bin path of a return wider than the pulse (a pixel that sees a surface at a grazing angle): its
intensity centroid (first_bounce.centroid_offset) against the 3-bin Gaussian fit (subbin_offset)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torch_recon.first_bounce import CENTROID_HALF_WIDTH, SubBinLUT, centroid_offset, gaussian_bin_profile, subbin_offset

SIGMA = 128.0 / 2.355 / 128.0     # the benchmark datasets' pulse: FWHM 128 ps in 128 ps bins


def _return(paths_bins, weights, n=2 * CENTROID_HALF_WIDTH + 1):
    """Bin values (bins -W..W) of a pixel whose footprint holds surface points at `paths_bins` (offsets from
    bin 0's centre) with irradiance `weights`: each point's Gaussian pulse, bin-integrated, summed."""
    w = n // 2
    prof = gaussian_bin_profile(np.asarray(paths_bins), SIGMA, taps=w)      # (points, n)
    return (np.asarray(weights)[:, None] * prof).sum(0)


def _window(values):
    """The window centred on the maximum bin, as matched_filter passes it."""
    w = len(values) // 2
    k = int(np.argmax(values))
    out = np.zeros(len(values))
    lo, hi = max(k - w, 0), min(k + w + 1, len(values))
    out[lo - (k - w):hi - (k - w)] = values[lo:hi]
    return torch.tensor(out[None]), k - w


@pytest.mark.parametrize("centre", [-0.3, 0.0, 0.2, 0.45])
def test_a_narrow_return_centroid_is_within_a_fiftieth_of_a_bin(centre):
    win, shift = _window(_return([centre], [1.0]))
    off = float(centroid_offset(win, 0.05, torch)[0]) + shift
    assert abs(off - centre) < 0.02


@pytest.mark.parametrize("tilt", [-0.6, 0.0, 0.6])
def test_a_flat_topped_return_centroid_is_the_footprints_mean_path(tilt):
    """cave-chair's floor beside the back wall: one pixel spans 5 bins of path; the irradiance tips the flat
    top. The centroid lands on the irradiance-weighted mean path; the 3-bin fit on wherever the top is highest."""
    paths = np.linspace(-2.5, 2.5, 201) + 0.3
    weights = 1.0 + tilt * (paths - paths.mean()) / 5.0
    truth = float(np.sum(paths * weights) / np.sum(weights))
    values = _return(paths, weights)
    win, shift = _window(values)
    off = float(centroid_offset(win, 0.05, torch)[0]) + shift
    assert abs(off - truth) < 0.03
    if tilt:    # the 3-bin Gaussian fit follows the tilt past the mean path by more than 0.5 bin
        w = CENTROID_HALF_WIDTH
        three = win[:, w - 1:w + 2]
        lut = SubBinLUT(SIGMA)
        off3 = float(subbin_offset(three[:, 0], three[:, 1], three[:, 2], "lut", lut, torch)[0]) + shift
        assert abs(off3 - truth) > 0.5


def test_the_centroid_stops_at_a_valley_before_a_second_return():
    """A thin part in front of a wall: two returns 5 bins apart; each one's centroid is its own."""
    values = _return([-2.5, 2.5], [1.0, 0.6])
    win, shift = _window(values)
    assert abs(float(centroid_offset(win, 0.05, torch)[0]) + shift - (-2.5)) < 0.02
    # the weaker one, centred on its own maximum
    k = int(np.argmax(np.where(np.arange(len(values)) > len(values) // 2, values, 0)))
    w = CENTROID_HALF_WIDTH
    padded = np.concatenate([np.zeros(w), values, np.zeros(w)])
    win2 = torch.tensor(padded[k:k + 2 * w + 1][None])
    assert abs(float(centroid_offset(win2, 0.05, torch)[0]) + k - w - 2.5) < 0.02


def test_an_empty_window_has_no_offset():
    assert float(centroid_offset(torch.zeros(1, 2 * CENTROID_HALF_WIDTH + 1), 0.05, torch)[0]) == 0.0


def test_the_valley_rule_parts_two_returns_that_overlap():
    """Two returns 2.6 bins apart (the second at half the first): the bins between them never fall below 5 % of
    the peak, only the valley (below half of it, rising again) parts them."""
    values = _return([-1.3, 1.3], [1.0, 0.5])
    win, shift = _window(values)
    assert abs(float(centroid_offset(win, 0.05, torch)[0]) + shift - (-1.3)) < 0.1


def test_a_background_left_in_pulls_the_centroid_and_the_filter_takes_it_off():
    """matched_filter subtracts the background from the window before the centroid: with 6 % of the peak left
    in every bin the centroid of a return 0.3 bin off its maximum bin's centre moved to about 0.18."""
    values = _return([0.3], [1.0])
    win, _ = _window(values)
    with_floor = win + 0.06 * win.max()
    assert abs(float(centroid_offset(with_floor, 0.05, torch)[0]) - 0.3) > 0.05
    assert abs(float(centroid_offset((with_floor - 0.06 * win.max()).clamp_min(0), 0.05, torch)[0]) - 0.3) < 0.02


def test_no_return_above_the_background_has_no_offset():
    win = torch.zeros(1, 2 * CENTROID_HALF_WIDTH + 1)
    win[0, 2] = 3.0                  # a stray count far from an empty maximum bin
    assert float(centroid_offset(win, 0.05, torch)[0]) == 0.0
