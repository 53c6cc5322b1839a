"""SPAD sensor model: expected transient -> stored transient (numpy only, no bpy).

Input: the expected two-bounce transient of one spot, (H, W, T), in any radiance unit
(from transient_binning.bin_two_bounce). Each stage is switched by the NoiseSpec:

1. Photon scaling (photons_per_pixel > 0): one factor for the whole spot so that the
   brightest pixel's total expected signal equals photons_per_pixel photons (the
   first-bounce pixel, far brighter, is left out of that maximum when given).
   photons_per_pixel == 0 keeps the input values unscaled.
2. Background: a constant rate per pixel per bin, in photons,
       b = ambient_per_bin * wavelength_filter_factor [* ambient_scale(pixel)] + dark_counts_per_bin
   (the band-pass filter passes a fraction of the ambient light; dark counts pass regardless).
3. Time gate (sensor.time_gate): keep only window_bins bins per pixel, centred on the
   expected return path when given (also for shadowed pixels, which is what makes the gate a
   gate), else on the pixel's strongest window of expected signal. Gating keeps signal and
   W/T of the background: the signal-to-background ratio improves by about T / W.
4. Without a gate, empty bins are not stored: with no background, each pixel keeps the smallest
   window (one length G for all pixels, a start per pixel) holding all its non-zero expected
   bins; with a background every bin has counts and the layout is dense.
5. Poisson sampling (photon_counts): counts ~ Poisson(rate), drawn only for the stored bins
   (bins outside the window are discarded anyway and bins are independent, so this is the same
   distribution), as signal + background parts (see _poisson_counts), pixel chunk by pixel
   chunk from the one rng: same seed, same bytes.

A dataset has one layout for all spots: when non-gated spots need different window lengths,
widen each to the largest with `widen_window` (exact: the added bins are zero in expectation).
"""

from __future__ import annotations

import math

import numpy as np

from torch_recon.contract.dataset import NoiseSpec, SensorSpec, Transient, TransientLayout

#: pixels per processing chunk (bounds temporaries to ~CHUNK_PIXELS * T * 8 bytes)
CHUNK_PIXELS = 16384
FLOAT16_MAX = float(np.finfo(np.float16).max)


def background_rate(noise: NoiseSpec, ambient_scale=None):
    """Background photons per pixel per bin: a float, or (H, W) with a per-pixel ambient_scale."""
    ambient = noise.ambient_per_bin * noise.wavelength_filter_factor
    if ambient_scale is None:
        return float(ambient + noise.dark_counts_per_bin)
    return (ambient * np.asarray(ambient_scale, np.float64) + noise.dark_counts_per_bin).astype(np.float64)


def photon_scale(pixel_totals: np.ndarray, noise: NoiseSpec, first_bounce_pixel=None) -> float:
    """Factor from input units to expected photons: photons_per_pixel / brightest pixel total."""
    if noise.photons_per_pixel <= 0:
        return 1.0
    all_totals = np.asarray(pixel_totals, np.float64)
    totals = all_totals
    if first_bounce_pixel is not None:
        totals = all_totals.copy()
        totals[int(first_bounce_pixel[0]), int(first_bounce_pixel[1])] = 0.0
    brightest = float(totals.max()) if totals.size else 0.0
    if brightest <= 0:
        # no visible pixel gets two-bounce light (the spot lights only hidden surfaces):
        # budget the first-bounce return instead, so it is not scaled away
        brightest = float(all_totals.max()) if all_totals.size else 0.0
    return noise.photons_per_pixel / brightest if brightest > 0 else 1.0


def gate_starts(expected_path, sensor: SensorSpec, window_bins: int) -> np.ndarray:
    """First bin (H, W) of a window_bins-long gate centred on each pixel's expected path (m).

    -1 where the path is not finite (no surface): the caller uses the strongest window there.
    """
    path = np.asarray(expected_path, np.float64)
    u = (path - sensor.start_m) / sensor.bin_width_m          # continuous bin coordinate
    ok = np.isfinite(u)
    start = np.full(path.shape, -1, np.int64)
    start[ok] = np.clip(np.floor(u[ok] - 0.5 * window_bins + 0.5), 0, sensor.bins - window_bins)
    return start


def _strongest_starts(block: np.ndarray, g: int) -> np.ndarray:
    """First bin of the g consecutive bins with the most expected signal, per row of (n, T)."""
    csum = np.zeros((block.shape[0], block.shape[1] + 1))
    np.cumsum(block, axis=1, dtype=np.float64, out=csum[:, 1:])
    return np.argmax(csum[:, g:] - csum[:, :-g], axis=1)


def _nonzero_extent(flat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First and last non-zero bin per pixel of (P, T); (0, -1) for an all-zero pixel."""
    p, t = flat.shape
    first = np.zeros(p, np.int64)
    last = np.full(p, -1, np.int64)
    for a in range(0, p, CHUNK_PIXELS):
        nz = flat[a:a + CHUNK_PIXELS] != 0
        anyz = nz.any(axis=1)
        first[a:a + CHUNK_PIXELS] = np.where(anyz, np.argmax(nz, axis=1), 0)
        last[a:a + CHUNK_PIXELS] = np.where(anyz, t - 1 - np.argmax(nz[:, ::-1], axis=1), -1)
    return first, last


def _poisson_counts(expected: np.ndarray, scale: float, background: np.ndarray, rng: np.random.Generator,
                    out: np.ndarray) -> np.ndarray:
    """Counts (n, g) float32 ~ Poisson(expected * scale + background) per bin, independent bins.

    Drawn as the sum of two independent Poisson parts (same distribution, much faster): the
    signal only where its rate is non-zero, and the flat background of each pixel as a Poisson
    total Poisson(b * g) spread uniformly over its g bins (splitting a Poisson process).
    """
    n, g = expected.shape
    nz = expected > 0
    draws = None
    if nz.any():
        try:
            draws = rng.poisson(expected[nz].astype(np.float64) * scale)
        except ValueError as exc:
            raise ValueError(f"photons_per_pixel: Poisson sampling failed ({exc}); lower photons_per_pixel"
                             ) from None
    out.fill(0.0)                   # only now: out may be expected itself (apply_sensor_windows in_place)
    if draws is not None:
        out[nz] = draws
    if np.any(background > 0):
        totals = rng.poisson(background * g)
        pixel = np.repeat(np.arange(n), totals)
        where = pixel * g + rng.integers(0, g, pixel.size)
        np.add.at(out.reshape(-1), where, np.float32(1.0))
    return out


def _check_expected(expected: np.ndarray, sensor: SensorSpec) -> float:
    """Shape, finiteness, sign; returns the largest value."""
    if expected.ndim != 3 or expected.shape != (sensor.height, sensor.width, sensor.bins):
        raise ValueError(f"expected transient: expected shape (H, W, T) = "
                         f"{(sensor.height, sensor.width, sensor.bins)} from the sensor, got {expected.shape}")
    if expected.size:
        lo, hi = float(expected.min()), float(expected.max())   # min/max propagate NaN
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise ValueError("expected transient: contains NaN or inf")
        if lo < 0:
            raise ValueError(f"expected transient: negative expected value {lo}")
        return hi
    return 0.0


def apply_sensor(expected, sensor: SensorSpec, noise: NoiseSpec, rng: np.random.Generator, expected_path=None, *,
                 first_bounce_pixel=None, ambient_scale=None, sample_type: str = "float32",
                 return_info: bool = False):
    """Expected transient (H, W, T) -> (Transient, TransientLayout) [, info dict with return_info].

    expected_path (H, W) metres or None: centre of the time gate per pixel (NaN: no surface).
    first_bounce_pixel (row, col): excluded from the photon budget's brightest pixel.
    ambient_scale (H, W) >= 0: per-pixel multiplier of the ambient rate (e.g. an ambient render).
    sample_type 'float16': values are rounded to float16 (what the dataset file will hold) and
    a count above 65504 raises. Output is float32, finite and >= 0 for any valid input.
    """
    expected = np.asarray(expected)
    peak = _check_expected(expected, sensor)
    if sample_type not in ("float32", "float16"):
        raise ValueError(f"sample_type: expected 'float32' or 'float16', got {sample_type!r}")
    h, w, t = expected.shape
    flat = expected.reshape(h * w, t)

    scale = photon_scale(flat.sum(axis=1, dtype=np.float64).reshape(h, w), noise, first_bounce_pixel)
    if ambient_scale is not None:
        ambient_scale = np.asarray(ambient_scale, np.float64)
        if ambient_scale.shape != (h, w) or not np.all(np.isfinite(ambient_scale)) or np.any(ambient_scale < 0):
            raise ValueError(f"ambient_scale: expected finite values >= 0 of shape {(h, w)}")
    bg = background_rate(noise, ambient_scale)
    bg_flat = np.broadcast_to(np.asarray(bg, np.float64), (h, w)).reshape(-1)
    has_bg = bool(np.any(bg_flat > 0))

    gate = sensor.time_gate
    if gate.enabled:
        g = int(gate.window_bins)
        if not 1 <= g <= t:
            raise ValueError(f"time_gate.window_bins: expected 1..{t} (bins), got {g}")
        if expected_path is None:
            start = np.full(h * w, -1, np.int64)
        else:
            if np.shape(expected_path) != (h, w):
                raise ValueError(f"expected_path: expected shape {(h, w)}, got {np.shape(expected_path)}")
            start = gate_starts(expected_path, sensor, g).reshape(-1)
    elif has_bg:
        g, start = t, np.zeros(h * w, np.int64)
    else:
        first, last = _nonzero_extent(flat)
        g = max(int((last - first).max()) + 1, 1) if flat.size else 1
        start = np.clip(first, 0, t - g)

    if not peak * scale + float(bg_flat.max(initial=0.0)) <= np.finfo(np.float32).max:
        raise ValueError("photons_per_pixel: the scaled transient overflows float32 (is the first-bounce pixel "
                         "far brighter than the budgeted two-bounce pixel?); lower photons_per_pixel")
    window = np.empty((h * w, g), np.float32)
    offsets = np.arange(g)
    for a in range(0, h * w, CHUNK_PIXELS):
        b = min(a + CHUNK_PIXELS, h * w)
        block = flat[a:b]
        st = start[a:b]
        need = st < 0
        if need.any():                       # gate without a known path: strongest window
            st[need] = _strongest_starts(block[need], g)
        vals = block if g == t else np.take_along_axis(block, st[:, None] + offsets[None, :], axis=1)
        _detect(vals, scale, bg_flat[a:b], noise, rng, out=window[a:b])
    window = _stored_as(window, sample_type)

    tr = Transient(start.reshape(h, w), window.reshape(h, w, g), t)
    layout = TransientLayout(kind="dense" if g == t else "windowed", window_bins=g, sample_type=sample_type)
    if not return_info:
        return tr, layout
    info = {"photon_scale": float(scale), "background_per_bin": float(np.mean(bg_flat)) if bg_flat.size else 0.0,
            "gated": bool(gate.enabled), "window_bins": g, "layout_kind": layout.kind,
            "photon_counts": bool(noise.photon_counts)}
    return tr, layout, info


def _detect(vals, scale: float, bg, noise: NoiseSpec, rng, *, out) -> None:
    """One chunk of pixels' expected values (N, G) -> detected samples in `out`: Poisson counts, or the
    scaled expectation plus the background rate bg (N,) per bin (None: no background)."""
    if noise.photon_counts:
        _poisson_counts(vals, scale, np.zeros(len(vals)) if bg is None else bg, rng, out=out)
    else:
        np.multiply(vals, scale, out=out, casting="unsafe")
        if bg is not None:
            out += bg[:, None]


def _stored_as(window: np.ndarray, sample_type: str) -> np.ndarray:
    """The samples rounded to the stored sample type (float16 keeps float32 arrays; refuses overflow)."""
    if sample_type != "float16":
        return window
    peak = float(window.max()) if window.size else 0.0
    if peak > FLOAT16_MAX:
        raise ValueError(f"sample_type float16: a value of {peak:.0f} exceeds the float16 maximum "
                         f"{FLOAT16_MAX:.0f}; lower photons_per_pixel or store float32")
    return window.astype(np.float16).astype(np.float32)


def widen_window(tr: Transient, window_bins: int) -> Transient:
    """The same transient stored with a longer window (>= its own), for one layout across spots.

    Exact when the old windows hold every non-zero bin (true for apply_sensor's non-gated output).
    """
    g_new, g_old, t = int(window_bins), tr.window_bins, tr.bins
    if not g_old <= g_new <= t:
        raise ValueError(f"window_bins: expected {g_old}..{t}, got {window_bins}")
    if g_new == g_old:
        return tr
    start = np.minimum(tr.start_bin, t - g_new)          # new window still covers the old one
    h, w = tr.shape
    out = np.zeros((h, w, g_new), np.float32)
    idx = (tr.start_bin - start)[..., None] + np.arange(g_old)
    np.put_along_axis(out, idx, tr.window, axis=2)
    return Transient(start, out, t)


def apply_sensor_windows(start, window, sensor: SensorSpec, noise: NoiseSpec, rng: np.random.Generator, *,
                         first_bounce_pixel=None, sample_type: str = "float32", in_place: bool = False):
    """apply_sensor for an expected transient already in windows (transient_binning.bin_windows).

    Only stages 1 and 5 apply (no background, no time gate: the caller expands to a dense cube
    for those), so the windows are the stored layout: the same result as apply_sensor on the
    dense cube followed by widen_window to G, without ever building the cube.
    start (H, W) first bin per pixel, window (H, W, G) expected values >= 0; in_place: the detected
    samples overwrite window (a float32 array the caller gives up: one window less in memory).
    """
    start = np.asarray(start, np.int64)
    window = np.asarray(window, np.float32)
    h, w, g = window.shape
    t = sensor.bins
    if sensor.time_gate.enabled or np.any(np.asarray(background_rate(noise)) > 0):
        raise ValueError("apply_sensor_windows: a time gate or background needs apply_sensor on the dense cube")
    if (h, w) != (sensor.height, sensor.width) or start.shape != (h, w) or not 1 <= g <= t:
        raise ValueError(f"expected start (H, W) and window (H, W, G<= {t}) of the {sensor.height}x{sensor.width} "
                         f"sensor, got {start.shape} and {window.shape}")
    hi = 0.0
    if window.size:
        lo, hi = float(window.min()), float(window.max())
        if not (math.isfinite(lo) and math.isfinite(hi)) or lo < 0:
            raise ValueError("expected transient: contains NaN, inf or negative values")
    if sample_type not in ("float32", "float16"):
        raise ValueError(f"sample_type: expected 'float32' or 'float16', got {sample_type!r}")
    flat = window.reshape(h * w, g)
    scale = photon_scale(flat.sum(axis=1, dtype=np.float64).reshape(h, w), noise, first_bounce_pixel)
    if not max(hi, 0.0) * scale <= np.finfo(np.float32).max:
        raise ValueError("photons_per_pixel: the scaled transient overflows float32; lower photons_per_pixel")
    out = flat if in_place and window.dtype == np.float32 else np.empty_like(flat)
    if noise.photon_counts:
        for a in range(0, h * w, CHUNK_PIXELS):          # chunks bound the Poisson draws' temporaries
            b = min(a + CHUNK_PIXELS, h * w)
            _detect(flat[a:b], scale, None, noise, rng, out=out[a:b])
    else:                                               # one pass in memory order (windows may be bins-first)
        _detect(flat, scale, None, noise, rng, out=out)
    out = _stored_as(out, sample_type)
    tr = Transient(start, out.reshape(h, w, g), t)
    return tr, TransientLayout(kind="dense" if g == t else "windowed", window_bins=g, sample_type=sample_type)
