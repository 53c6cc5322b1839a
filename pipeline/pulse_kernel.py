"""The laser pulse's weights over the time bins (numpy only, no bpy).

A Gaussian pulse (FWHM from the sensor) centred at an optical path is integrated over each bin it
overlaps: erf differences, truncated at +-PULSE_SUPPORT_SIGMAS and renormalised, so the weights of one
sample sum to exactly 1; 'box' puts the sample in its one bin. Used by the two-bounce binning
(`transient_binning`) and by spot planning's predicted transients.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import erf

from torch_recon.contract.units import fwhm_to_sigma, ps_to_m

#: the Gaussian pulse is truncated at this many standard deviations (mass outside: 6e-5)
PULSE_SUPPORT_SIGMAS = 4.0
#: rows of PulseKernel.tabulated_weights' table over a sample's position within a bin
TABLE_STEPS = 4096


class PulseKernel:
    """Bin weights of a unit laser pulse centred at arbitrary optical paths."""

    def __init__(self, sensor):
        self.start_m = float(sensor.start_m)
        self.bin_width_m = float(sensor.bin_width_m)
        self.bins = int(sensor.bins)
        self.shape = sensor.pulse.shape
        if self.shape not in ("gaussian", "box"):
            raise ValueError(f"sensor.pulse.shape: expected 'gaussian' or 'box', got {self.shape!r}")
        if not (self.bin_width_m > 0 and math.isfinite(self.bin_width_m)):
            raise ValueError(f"sensor.bin_width_m: expected a positive number, got {self.bin_width_m!r}")
        if self.bins < 1:
            raise ValueError(f"sensor.bins: expected at least 1 bin, got {self.bins}")
        self.sigma_m = fwhm_to_sigma(ps_to_m(float(sensor.pulse.fwhm_ps)))
        if self.shape == "gaussian" and not self.sigma_m > 0:
            raise ValueError(f"sensor.pulse.fwhm_ps: expected a positive width, got {sensor.pulse.fwhm_ps!r}")
        half = PULSE_SUPPORT_SIGMAS * self.sigma_m
        # a support of length 2*half starting anywhere inside a bin touches at most this many bins
        self.support_bins = 1 if self.shape == "box" else int(math.ceil(2 * half / self.bin_width_m)) + 1

    @property
    def end_m(self) -> float:
        return self.start_m + self.bins * self.bin_width_m

    def weights(self, path_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """First bin index (N,) int64 and weights (N, K) float64 of bins first .. first+K-1.

        Bin indices may fall outside [0, bins); callers drop those (pulse tails past the range).
        """
        u = (np.asarray(path_m, np.float64) - self.start_m) / self.bin_width_m  # continuous bin coordinate
        if self.shape == "box":
            return np.floor(u).astype(np.int64), np.ones((len(u), 1))
        half_bins = PULSE_SUPPORT_SIGMAS * self.sigma_m / self.bin_width_m
        first = np.floor(u - half_bins).astype(np.int64)
        edges = first[:, None] + np.arange(self.support_bins + 1)[None, :]  # bin edges, in bins
        z = (edges - u[:, None]) * (self.bin_width_m / (self.sigma_m * math.sqrt(2.0)))
        cdf = erf(z)                                  # 2 * CDF - 1; differences give 2 * mass
        w = np.diff(cdf, axis=1)
        total = cdf[:, -1] - cdf[:, 0]                # >= 2 * (1 - 6e-5) by construction
        w /= total[:, None]
        return first, w

    def weight_table(self):
        """(TABLE_STEPS + 1, K) weights of a sample at position phi = row / TABLE_STEPS within its first bin
        (the erf differences of weights(); rows sum to 1); None for the box pulse."""
        if self.shape == "box":
            return None
        if getattr(self, "_table", None) is None:
            half_bins = PULSE_SUPPORT_SIGMAS * self.sigma_m / self.bin_width_m
            phi = np.arange(TABLE_STEPS + 1) / TABLE_STEPS
            # a sample at u = first + half_bins + phi: the erf differences of weights(), phi up to 1 inclusive
            edges = np.arange(self.support_bins + 1)[None, :] - (half_bins + phi)[:, None]
            cdf = erf(edges * (self.bin_width_m / (self.sigma_m * math.sqrt(2.0))))
            self._table = np.diff(cdf, axis=1) / (cdf[:, -1] - cdf[:, 0])[:, None]
        return self._table

    def tabulated_weights(self, path_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """weights() from a table over the sample's position within its first bin: the nearest of
        TABLE_STEPS exact rows (the path rounded to 1/TABLE_STEPS bin, 9 um for 3.84 cm bins; rows
        sum to 1 exactly): a gather instead of K + 1 erf per sample."""
        u = (np.asarray(path_m, np.float64) - self.start_m) / self.bin_width_m
        if self.shape == "box":
            return np.floor(u).astype(np.int64), np.ones((len(u), 1))
        v = u - PULSE_SUPPORT_SIGMAS * self.sigma_m / self.bin_width_m
        first = np.floor(v).astype(np.int64)
        i = np.minimum(((v - first) * TABLE_STEPS + 0.5).astype(np.int64), TABLE_STEPS)
        return first, self.weight_table()[i]
