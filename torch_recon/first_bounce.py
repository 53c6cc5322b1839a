"""The first-bounce return and sub-bin peaks (step 1 and 5 of torch_recon/preprocess.py's docstring).

find_first_bounce locates l_k, the point the laser hits, from the brightest return along the laser
ray and measures the pulse there. A spot outside the sensor's view (a laser scanning a wider field than
the camera sees) has no first-bounce return: fit_out_of_view_spot fits its range along the known laser
direction to its two-bounce arrival times at pixels whose depth the in-view spots measured.
The sub-bin peak model (a bin-integrated Gaussian whose width is
fitted to that pulse) refines both the first-bounce path and every two-bounce peak.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .contract.dataset.transient import Transient
from .contract.errors import PreprocessError
from .contract.frames import focal_length_px

if TYPE_CHECKING:
    from .preprocess import PreprocessSettings


def _torch():
    import torch
    return torch


# ---------------------------------------------------------------- sub-bin peak

def gaussian_bin_profile(offset_bins, sigma_bins, taps: int = 1):
    """Bin-integrated unit Gaussian centred `offset_bins` from bin 0's centre: values at bins -taps..taps.

    offset and sigma broadcast against each other; the result has one more (last) axis.
    """
    from scipy.special import erf
    j = np.arange(-taps, taps + 1)
    off = np.asarray(offset_bins, np.float64)[..., None]
    s = np.maximum(np.asarray(sigma_bins, np.float64), 1e-3)[..., None] * math.sqrt(2.0)
    return 0.5 * (erf((j + 0.5 - off) / s) - erf((j - 0.5 - off) / s))


def fit_pulse_sigma(samples: np.ndarray) -> float:
    """Width (bins) of the bin-integrated Gaussian best matching a peak's 2t+1 bins (any sub-bin offset)."""
    y = np.asarray(samples, np.float64)
    y = y / max(y.sum(), 1e-30)
    sig = np.linspace(0.05, 4.0, 160)
    off = np.linspace(-0.5, 0.5, 101)
    m = gaussian_bin_profile(off[:, None], sig[None, :], taps=len(y) // 2)     # (offsets, sigmas, taps)
    m = m / np.maximum(m.sum(axis=-1, keepdims=True), 1e-30)
    err = ((m - y) ** 2).sum(axis=-1).min(axis=0)
    return float(sig[int(np.argmin(err))])


class SubBinLUT:
    """Inverse of the 3-bin ratio r(offset) = (x+ - x-) / (x- + x0 + x+) of a bin-integrated Gaussian."""

    def __init__(self, sigma_bins: float, n: int = 2001):
        off = np.linspace(-0.5, 0.5, n)
        p = gaussian_bin_profile(off, sigma_bins)
        r = (p[:, 2] - p[:, 0]) / np.maximum(p.sum(axis=1), 1e-30)
        self.r, self.off = np.maximum.accumulate(r), off   # monotone (flat only at numerical limits)
        self.sigma_bins = sigma_bins

    def __call__(self, r, torch):
        rt = torch.as_tensor(self.r, dtype=r.dtype, device=r.device)
        ot = torch.as_tensor(self.off, dtype=r.dtype, device=r.device)
        i = torch.searchsorted(rt, r.contiguous()).clamp(1, len(self.r) - 1)
        r0, r1 = rt[i - 1], rt[i]
        f = ((r - r0) / (r1 - r0).clamp_min(1e-12)).clamp(0, 1)
        return ot[i - 1] + f * (ot[i] - ot[i - 1])


def subbin_offset(xm, x0, xp, method: str, lut: SubBinLUT | None, torch):
    """Offset (bins, in [-0.5, 0.5]) of a peak from the centre of its maximum bin x0."""
    if method == "none":
        return torch.zeros_like(x0)
    if method == "lut":
        return lut((xp - xm) / (xm + x0 + xp).clamp_min(1e-30), torch)
    if method == "gaussian":
        lm, l0, lp = (torch.log(v.clamp_min(1e-30)) for v in (xm, x0, xp))
        den = lm - 2 * l0 + lp
    else:
        lm, l0, lp = xm, x0, xp
        den = xm - 2 * x0 + xp
    off = torch.where(den < -1e-30, 0.5 * (lm - lp) / den.clamp(max=-1e-30), torch.zeros_like(x0))
    return off.clamp(-0.5, 0.5)


#: bins either side of a return's maximum that its centroid may reach (a grazing pixel's return at 128 x 128
#: spans about 5 bins; 8 leaves room without reaching a second surface's return that a valley does not part)
CENTROID_HALF_WIDTH = 8


def centroid_offset(win, fraction: float, torch):
    """Offset (bins) of a return's intensity centroid from the centre of its maximum bin, the middle column of
    `win` (N, 2 W + 1). The return: the bins outward from the maximum while they stay above `fraction` x the
    maximum and do not rise again out of a valley below half of it (the next surface's return), plus the one bin
    beyond each end (its tail: without it a cut Gaussian's centroid errs by up to 0.03 bin).

    Why not the 3-bin Gaussian fit (`refine`): a pixel that sees a surface at a grazing angle spans a range of
    paths several pulse widths long (cave-chair's floor beside the back wall: a flat top 5 bins wide), and the
    fit on its 3 top bins finds wherever the irradiance gradient tips the flat top (per spot -4 to -17 mm), while
    the centroid is the footprint's mean path (within 1 mm of the pixel centre's path there)."""
    w = win.shape[1] // 2
    peak = win[:, w:w + 1]

    def run(side):   # (N, W + 1) from the maximum outward
        ok = side >= fraction * peak
        ok[:, 1:] &= ~((side[:, 1:] > side[:, :-1]) & (side[:, :-1] < 0.5 * peak))
        keep = torch.cumprod(ok.to(win.dtype), dim=1)
        tail = torch.zeros_like(keep)   # the first bin past the run, if it still falls
        tail[:, 1:] = keep[:, :-1] * (1 - keep[:, 1:]) * (side[:, 1:] <= side[:, :-1]).to(win.dtype)
        return keep + tail

    right, left = run(win[:, w:]), run(win[:, :w + 1].flip(1))
    mask = torch.cat([left.flip(1)[:, :w], right], dim=1)
    offs = torch.arange(-w, w + 1, dtype=win.dtype, device=win.device)
    mass = (win * mask).sum(dim=1)
    ok = (mass > 0) & (peak[:, 0] > 0)      # no return left above the background: no offset
    return torch.where(ok, (win * mask * offs).sum(dim=1) / mass.clamp_min(1e-30), torch.zeros_like(mass))


# ---------------------------------------------------------------- first bounce

@dataclass
class FirstBounce:
    point: np.ndarray       # l
    distance: float         # |l - o|
    path_m: float           # P1 = |l - o| + |l - c|
    pixel: tuple            # (row, col)
    pulse: np.ndarray       # (2h + 1,) unit sum
    pulse_sigma_bins: float
    peak_bin: int
    range_fit: dict | None = None   # out-of-view spots: how the range was fitted (fit_out_of_view_spot)


def _read_bins(tr: Transient, rows, cols, bins):
    """Values of pixels (rows, cols) at absolute bins (0 outside each pixel's window)."""
    j = bins - tr.start_bin[rows, cols]
    ok = (j >= 0) & (j < tr.window_bins)
    out = np.zeros(len(rows), np.float64)
    out[ok] = tr.window[rows[ok], cols[ok], j[ok]]
    return out


def _pixel_dense(tr: Transient, row, col) -> np.ndarray:
    out = np.zeros(tr.bins, np.float64)
    s = int(tr.start_bin[row, col])
    out[s:s + tr.window_bins] = tr.window[row, col]
    return out


def _laser_ray_samples(sensor, ld):
    """Samples o + d ld of the laser ray: d, their pixel (row, col), first-bounce bin, and which the sensor sees."""
    c2w = np.asarray(sensor.camera_to_world, np.float64)
    c, o = c2w[:3, 3], np.asarray(sensor.laser_origin, np.float64)
    w, h, bw = sensor.width, sensor.height, sensor.bin_width_m
    f = focal_length_px(w, h, sensor.fov_rad, sensor.fov_axis)
    d_max = 0.5 * (sensor.end_m + np.linalg.norm(o - c))
    n = int(min(200_000, max(256, math.ceil(d_max / (0.25 * bw)))))
    d = np.linspace(1e-3, d_max, n)
    pts = o + d[:, None] * ld
    path = d + np.linalg.norm(pts - c, axis=1)
    pc = (pts - c) @ c2w[:3, :3]               # camera frame: looks down -Z
    front = pc[:, 2] < -1e-9
    z = np.where(front, -pc[:, 2], 1.0)
    col = np.floor(0.5 * w + f * pc[:, 0] / z).astype(np.int64)
    row = np.floor(0.5 * h - f * pc[:, 1] / z).astype(np.int64)
    kb = np.floor((path - sensor.start_m) / bw).astype(np.int64)
    ok = front & (col >= 0) & (col < w) & (row >= 0) & (row < h) & (kb >= 0) & (kb < sensor.bins)
    return d, row, col, kb, ok


def laser_ray_seen(sensor, laser_direction) -> bool:
    """Whether any point of the laser ray within the histogram range projects into the image (else the
    spot is out of view: no first-bounce return can be recorded; see fit_out_of_view_spot)."""
    ld = np.asarray(laser_direction, np.float64)
    return bool(_laser_ray_samples(sensor, ld / np.linalg.norm(ld))[4].any())


def find_first_bounce(tr: Transient, sensor, laser_direction, spot_id, settings: PreprocessSettings,
                      method: str | None = None) -> FirstBounce:
    """Locate l_k from the brightest return along the laser ray (see the module docstring)."""
    c2w = np.asarray(sensor.camera_to_world, np.float64)
    c, o = c2w[:3, 3], np.asarray(sensor.laser_origin, np.float64)
    ld = np.asarray(laser_direction, np.float64)
    ld = ld / np.linalg.norm(ld)
    w, h, bw = sensor.width, sensor.height, sensor.bin_width_m
    q = o - c
    _, row, col, kb, ok = _laser_ray_samples(sensor, ld)
    if not ok.any():
        raise PreprocessError(f"spot {spot_id}: the laser ray never crosses the sensor's view within the "
                              f"histogram range; no first bounce can be seen")
    row, col, kb = row[ok], col[ok], kb[ok]
    # the 3 x 3 pixels around each projection, +-1 bin: a spot on a pixel border (the paper's targets
    # land exactly on pixel edges at 512 x 512) or rounding must not hide the return
    best_v, best_r, best_c = np.full(len(row), -1.0), row.copy(), col.copy()
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            rr, cc = np.clip(row + dr, 0, h - 1), np.clip(col + dc, 0, w - 1)
            v = np.max([_read_bins(tr, rr, cc, np.clip(kb + s, 0, sensor.bins - 1)) for s in (-1, 0, 1)], axis=0)
            better = v > best_v
            best_v[better], best_r[better], best_c[better] = v[better], rr[better], cc[better]
    i = int(np.argmax(best_v))
    r0, c0 = int(best_r[i]), int(best_c[i])
    x = _pixel_dense(tr, r0, c0)
    lo, hi = max(int(kb[i]) - 2, 0), min(int(kb[i]) + 3, sensor.bins)
    k1 = lo + int(np.argmax(x[lo:hi]))
    floor = float(np.median(x))
    # noise floor: the spread of the rest of the histogram, plus a tiny absolute floor
    rest = np.delete(x, np.arange(max(k1 - 3, 0), min(k1 + 4, len(x))))
    noise = float(np.std(rest)) if rest.size else 0.0
    weak = x[k1] <= floor + settings.min_first_bounce_snr * max(noise, 1e-12 * max(x[k1], 1e-30))
    if weak or x[k1] <= 0 or x[k1] < x.max():
        raise PreprocessError(f"spot {spot_id}: no first-bounce return along the laser ray (brightest sample "
                              f"{x[k1]:.3g} at pixel row {r0} col {c0} does not stand out of the background "
                              f"{floor:.3g} +- {noise:.3g}); is the laser spot outside the view or too dim?")
    hw = settings.pulse_half_width_bins
    taps = np.arange(k1 - hw, k1 + hw + 1)
    inside = (taps >= 0) & (taps < len(x))
    pulse = np.zeros(2 * hw + 1)
    pulse[inside] = x[taps[inside]]
    pulse = np.clip(pulse - floor, 0.0, None)
    pulse /= pulse.sum()
    sigma = fit_pulse_sigma(pulse[hw - 2:hw + 3]) if hw >= 2 else 0.05
    torch = _torch()
    method = method or settings.refine
    lut = SubBinLUT(sigma) if method == "lut" else None
    xm, x0, xp = (torch.tensor([x[k] if 0 <= k < len(x) else 0.0]) for k in (k1 - 1, k1, k1 + 1))
    off = float(subbin_offset(xm, x0, xp, method, lut, torch)[0])
    p1 = sensor.start_m + (k1 + 0.5 + off) * bw
    den = 2.0 * (p1 + float(q @ ld))
    if den <= 1e-9 or p1 * p1 <= q @ q:
        raise PreprocessError(f"spot {spot_id}: first-bounce path {p1:.4f} m is shorter than the laser-sensor "
                              f"baseline {np.linalg.norm(q):.4f} m")
    dist = (p1 * p1 - float(q @ q)) / den
    return FirstBounce(point=o + dist * ld, distance=dist, path_m=p1, pixel=(r0, c0), pulse=pulse,
                       pulse_sigma_bins=sigma, peak_bin=k1)


# ---------------------------------------------------------------- out-of-view spot

#: fewest lit pixels of known depth an out-of-view spot's range fit accepts
MIN_RANGE_FIT_PIXELS = 50


def fit_out_of_view_spot(sensor, laser_direction, spot_id, path, points, reference: FirstBounce,
                         tolerance_m: float | None = None, max_grid_pixels: int = 4000, seed: int = 0) -> FirstBounce:
    """l = o + d ld of a spot the sensor cannot see, from its two-bounce arrival times.

    path (H, W): the spot's measured two-bounce optical path (NaN where no peak); points (H, W, 3): the
    visible surface point of each pixel, measured with the in-view spots (NaN unknown). Each pixel gives
    t = d + |o + d ld - x| + |x - c|, one equation in the single unknown d (closed form per pixel:
    d = (R^2 - |q|^2) / (2 (R + q.ld)), R = t - |x - c|, q = o - x). The robust fit: a grid over d scored
    by the truncated squared residual (max_grid_pixels seeded pixels), then scipy's least_squares with
    a soft-L1 loss over all pixels. `reference`: an in-view spot's first bounce, whose pulse is the
    laser's. tolerance_m: inlier residual (default one bin)."""
    from scipy.optimize import least_squares

    c = np.asarray(sensor.camera_to_world, np.float64)[:3, 3]
    o = np.asarray(sensor.laser_origin, np.float64)
    ld = np.asarray(laser_direction, np.float64)
    ld = ld / np.linalg.norm(ld)
    tol = float(tolerance_m if tolerance_m is not None else sensor.bin_width_m)
    t = np.asarray(path, np.float64).reshape(-1)
    x = np.asarray(points, np.float64).reshape(-1, 3)
    ok = np.isfinite(t) & np.all(np.isfinite(x), axis=1)
    if ok.sum() < MIN_RANGE_FIT_PIXELS:
        raise PreprocessError(f"spot {spot_id}: the laser spot is outside the sensor's view and only {int(ok.sum())} "
                              f"of its lit pixels have a depth measured by an in-view spot (need at least "
                              f"{MIN_RANGE_FIT_PIXELS}); aim it where more of its light reaches the visible scene")
    t, x = t[ok], x[ok]
    b = t - np.linalg.norm(x - c, axis=1)             # d + |o + d ld - x|

    def residual(d, xs, bs):     # d: scalar or (G, 1) against pixels (N,) / (1, N)
        d = np.asarray(d, np.float64)[..., None]
        return d[..., 0] + np.linalg.norm(o + d * ld - xs, axis=-1) - bs

    rng = np.random.default_rng(seed)
    sub = rng.choice(len(t), max_grid_pixels, replace=False) if len(t) > max_grid_pixels else np.arange(len(t))
    grid = np.arange(0.0, max(float(b.max()), tol), 0.25 * tol)
    cost = np.zeros(len(grid))
    for i in range(0, len(grid), 256):      # (256 d values, pixels) per block
        r = residual(grid[i:i + 256, None], x[sub][None], b[sub][None])
        cost[i:i + 256] = np.minimum(r * r, tol * tol).sum(axis=1)
    d0 = float(grid[int(np.argmin(cost))])
    fit = least_squares(lambda v: residual(v[0], x, b), [d0], loss="soft_l1", f_scale=0.25 * tol,
                        bounds=([max(d0 - 2 * tol, 0.0)], [d0 + 2 * tol]))
    d = float(fit.x[0])
    res = residual(d, x, b)
    inl = np.abs(res) <= tol
    l = o + d * ld
    p1 = d + float(np.linalg.norm(l - c))
    if inl.sum() < MIN_RANGE_FIT_PIXELS:
        raise PreprocessError(f"spot {spot_id}: out of view; its two-bounce arrival times fit no single range along "
                              f"the laser ray ({int(inl.sum())} of {len(t)} pixels within {tol:.3f} m of the best "
                              f"range {d:.3f} m)")
    stats = {"pixels": int(len(t)), "inliers": int(inl.sum()), "rms_m": float(np.sqrt(np.mean(res[inl] ** 2))),
             "tolerance_m": tol}
    return FirstBounce(point=l, distance=d, path_m=p1, pixel=None, pulse=reference.pulse,
                       pulse_sigma_bins=reference.pulse_sigma_bins,
                       peak_bin=int(math.floor((p1 - sensor.start_m) / sensor.bin_width_m)), range_fit=stats)
