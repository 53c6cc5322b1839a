"""Unit conversions, in one place (round-trip tested in tests/torch_recon/contract/test_units.py).

Inside the code: metres for lengths and optical path, radians for angles.
People type picoseconds and degrees; those are converted here and nowhere else.
"""

from __future__ import annotations

import math

import numpy as np

SPEED_OF_LIGHT_M_PER_S = 299_792_458.0
#: metres of optical path per picosecond (light travel)
METRES_PER_PS = SPEED_OF_LIGHT_M_PER_S * 1e-12

#: relative tolerance when a bin width is given both in ps and in metres
#: (the paper rounds 128 ps to 0.0384 m: 0.07 % off)
BIN_WIDTH_REL_TOL = 2e-3


def ps_to_m(ps):
    """Optical path (m) travelled by light in `ps` picoseconds."""
    return ps * METRES_PER_PS


def m_to_ps(m):
    """Time (ps) light needs for `m` metres of optical path."""
    return m / METRES_PER_PS


def deg_to_rad(deg):
    return deg * (math.pi / 180.0)


def rad_to_deg(rad):
    return rad * (180.0 / math.pi)


def fwhm_to_sigma(fwhm):
    """Standard deviation of a Gaussian with full width at half maximum `fwhm`."""
    return fwhm / (2.0 * math.sqrt(2.0 * math.log(2.0)))


def sigma_to_fwhm(sigma):
    return sigma * (2.0 * math.sqrt(2.0 * math.log(2.0)))


def bin_widths_consistent(bin_width_m: float, bin_width_ps: float) -> bool:
    """True when a bin width given in metres and in ps describe the same bin."""
    expected = ps_to_m(bin_width_ps)
    return bool(np.isfinite(bin_width_m) and abs(bin_width_m - expected) <= BIN_WIDTH_REL_TOL * expected)


def format_bytes(n: float) -> str:
    """A memory or file size for a message: '3.2 GB', '870 MB' (decimal units)."""
    for unit, scale in (("PB", 1e15), ("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{int(n)} bytes"


#: largest sensor side (pixels) any stage accepts; 16x the paper's 512 (Cycles' own limit is 65536)
MAX_SENSOR_SIDE = 8192
#: largest single dense transient (float32 pixels x bins) a stage accepts: no machine this runs on holds more
MAX_TRANSIENT_BYTES = 64e9


def transient_size_problem(width: int, height: int, bins: int) -> str | None:
    """Why a width x height x bins sensor cannot be held (with the estimate), or None when it can."""
    if max(width, height) > MAX_SENSOR_SIDE:
        return (f"{width} x {height} pixels is larger than the {MAX_SENSOR_SIDE} pixels per side supported "
                f"(one dense transient would need {format_bytes(4.0 * width * height * bins)})")
    need = 4.0 * width * height * bins
    if need > MAX_TRANSIENT_BYTES:
        return (f"{width} x {height} pixels x {bins} bins need {format_bytes(need)} per dense transient "
                f"(float32), more than the {format_bytes(MAX_TRANSIENT_BYTES)} supported")
    return None
