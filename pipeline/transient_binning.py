"""Bin two-bounce radiance into time bins by optical path (numpy only, no bpy).

The Blender side renders, per spot, the sensor view lit only by the laser spot l
and hands over S sub-pixel samples per pixel: world position x and two-bounce
radiance. Each sample lands at the optical path

    D = |l - o| + |x - l| + |c - x|     (o laser origin, c sensor centre; metres)

and carries radiance / S, so a pixel spanning a depth edge spreads over the bins
of both depths. The laser pulse is applied per sample, not by convolving the cube
(`pulse_kernel.PulseKernel`: each sample's weights over the bins sum to exactly 1).
The first-bounce return (path |l - o| + |c - l|) goes to the pixel that sees l.

Speed: within one sub-pixel sample index s every pixel appears once, so for each
(s, pulse bin j) the flat indices pixel * T + bin are unique and a plain fancy-index
`+=` scatter is exact. Work is S x K vectorised scatters over the lit samples
(K = bins the pulse covers, ~5 for the paper's 128 ps pulse and bins); memory is
the float32 output cube plus O(H W K) temporaries.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from pipeline.pulse_kernel import PULSE_SUPPORT_SIGMAS, TABLE_STEPS, PulseKernel

#: samples per chunk of bin_windows (bounds its temporaries to ~BIN_CHUNK x K x 20 bytes)
BIN_CHUNK = 1 << 16
#: sub-samples of one pixel up to this many bins apart are summed in a local window first
FAST_SPREAD_BINS = 3
#: below this many pixels per thread, threads cost more than they save
MIN_PIXELS_PER_THREAD = 16384


def optical_path(x, first_bounce, laser_origin, sensor_centre) -> np.ndarray:
    """Two-bounce optical path |l - o| + |x - l| + |c - x| (m) for points x (..., 3), float64."""
    x = np.asarray(x, np.float64)
    l, o, c = (np.asarray(v, np.float64).reshape(3) for v in (first_bounce, laser_origin, sensor_centre))
    return np.linalg.norm(l - o) + np.linalg.norm(x - l, axis=-1) + np.linalg.norm(c - x, axis=-1)


def first_bounce_path(first_bounce, laser_origin, sensor_centre) -> float:
    """Optical path of the first-bounce return: |l - o| + |c - l| (2 |l - o| for a co-located laser)."""
    l, o, c = (np.asarray(v, np.float64).reshape(3) for v in (first_bounce, laser_origin, sensor_centre))
    return float(np.linalg.norm(l - o) + np.linalg.norm(c - l))


def expected_return_path(sub_positions, sub_valid, first_bounce, laser_origin, sensor_centre) -> np.ndarray:
    """Per-pixel two-bounce path (H, W) float32 where the return would be if the pixel is lit.

    Mean over the pixel's valid sub-samples, from geometry only (shadowed pixels get a path
    too, so a time gate sits at the same place for lit and shadowed pixels). NaN where no
    sample sees a surface; `sensor_model.apply_sensor` then falls back to the strongest window.
    """
    pos = np.asarray(sub_positions)
    valid = np.asarray(sub_valid, bool)
    if pos.ndim != 4 or pos.shape[-1] != 3 or valid.shape != pos.shape[:3]:
        raise ValueError(f"expected sub_positions (S, H, W, 3) and sub_valid (S, H, W), "
                         f"got {pos.shape} and {valid.shape}")
    total = np.zeros(pos.shape[1:3])
    count = np.zeros(pos.shape[1:3])
    for s in range(pos.shape[0]):
        with np.errstate(invalid="ignore", over="ignore"):
            p = optical_path(pos[s], first_bounce, laser_origin, sensor_centre)
        v = valid[s] & np.isfinite(p)          # a non-finite position gives a non-finite path
        total += np.where(v, p, 0.0)
        count += v
    out = np.full(total.shape, np.nan, np.float32)
    np.divide(total, count, out=out, where=count > 0, casting="unsafe")
    return out


def _range_error(paths: np.ndarray, kernel: PulseKernel, what: str) -> ValueError:
    lo, hi = float(paths.min()), float(paths.max())
    need_bins = int(math.ceil((hi - kernel.start_m) / kernel.bin_width_m)) + 1
    return ValueError(
        f"{len(paths)} {what} have optical paths outside the bin range "
        f"[start_m, start_m + bins * bin_width_m) = [{kernel.start_m:.4f}, {kernel.end_m:.4f}) m "
        f"(paths span {lo:.4f} .. {hi:.4f} m): "
        + (f"raise 'bins' to at least {need_bins}" if hi >= kernel.end_m else "")
        + (" and " if hi >= kernel.end_m and lo < kernel.start_m else "")
        + (f"lower 'start_m' to at most {max(lo, 0.0):.4f} m" if lo < kernel.start_m else ""))


def _deposit(flat: np.ndarray, pixels: np.ndarray, paths: np.ndarray, amps: np.ndarray, kernel: PulseKernel):
    """flat (P, T) float32 += amp * pulse(path) for each (pixel, path, amp); pixels must be unique."""
    if len(pixels):
        first, w = kernel.weights(paths)
        _deposit_weights(flat, pixels, first, w, amps)


def _deposit_samples(flat: np.ndarray, samples: list, kernel: PulseKernel):
    """Add every sub-pixel sample (pixels, paths, amps) of one spot into flat (P, T) float32.

    Fast path: most pixels' samples fall within a few bins of each other, so they are summed
    in a small local window (P', L) first (cache friendly) and written to the big cube in
    one pass. Pixels spanning more bins (depth edges) or touching the range ends take the
    direct scatter.
    """
    p, t = flat.shape
    k_sup = kernel.support_bins
    width = k_sup + FAST_SPREAD_BINS
    big = np.iinfo(np.int64).max // 4          # sentinel; hi - lo cannot overflow
    lo = np.full(p, big, np.int64)
    hi = np.full(p, -big, np.int64)
    pulses = []
    for pix, paths, amps in samples:
        first, w = kernel.weights(paths)
        lo[pix] = np.minimum(lo[pix], first)     # pix unique within one sample index
        hi[pix] = np.maximum(hi[pix], first)
        pulses.append((pix, first, w, amps))
    lit = lo != big
    fast = lit & (hi - lo <= FAST_SPREAD_BINS) & (lo >= 0) & (lo + width <= t)
    row_of = np.full(p, -1, np.int64)
    fast_pix = np.flatnonzero(fast)
    row_of[fast_pix] = np.arange(len(fast_pix))
    local = np.zeros(len(fast_pix) * width, np.float32)
    for pix, first, w, amps in pulses:
        sel = fast[pix]
        if sel.any():
            base = row_of[pix[sel]] * width + (first[sel] - lo[pix[sel]])
            vals = amps[sel, None] * w[sel]
            for j in range(w.shape[1]):
                local[base + j] += vals[:, j].astype(np.float32)
        if not sel.all():
            slow = ~sel
            _deposit_weights(flat, pix[slow], first[slow], w[slow], amps[slow])
    if len(fast_pix):
        idx = (fast_pix * t + lo[fast_pix])[:, None] + np.arange(width)[None, :]
        flat.reshape(-1)[idx] += local.reshape(-1, width)


def _deposit_threaded(flat: np.ndarray, samples: list, kernel: PulseKernel, threads: int | None):
    """_deposit_samples over disjoint pixel blocks in threads (numpy releases the GIL in its loops).

    Each pixel is handled by one thread in the same order as unthreaded: identical bytes.
    """
    n = min(2, os.cpu_count() or 1) if threads is None else max(1, int(threads))
    p = flat.shape[0]
    if n == 1 or p < 2 * MIN_PIXELS_PER_THREAD:
        _deposit_samples(flat, samples, kernel)
        return
    bounds = np.linspace(0, p, n + 1).astype(np.int64)

    def block(b):
        p0, p1 = int(bounds[b]), int(bounds[b + 1])
        part = []
        for pix, paths, amps in samples:                 # pix ascending (flatnonzero)
            i0, i1 = np.searchsorted(pix, [p0, p1])
            part.append((pix[i0:i1] - p0, paths[i0:i1], amps[i0:i1]))
        _deposit_samples(flat[p0:p1], part, kernel)      # a contiguous row block: a view

    with ThreadPoolExecutor(max_workers=n) as pool:
        list(pool.map(block, range(n)))


def _deposit_weights(flat, pixels, first, w, amps):
    t = flat.shape[1]
    flat_1d = flat.reshape(-1)
    base = pixels.astype(np.int64) * t
    for j in range(w.shape[1]):
        k = first + j
        ok = (k >= 0) & (k < t)
        if ok.any():
            flat_1d[base[ok] + k[ok]] += (amps[ok] * w[ok, j]).astype(np.float32)


def bin_two_bounce(sub_positions, sub_radiance, sub_valid, first_bounce, laser_origin, sensor_centre, sensor,
                   first_bounce_pixel=None, first_bounce_radiance=0.0, *, out_of_range="raise",
                   out: np.ndarray | None = None, accumulate: bool = False,
                   threads: int | None = None) -> np.ndarray:
    """Expected transient (H, W, T) float32 of one spot (units of the input radiance per pixel).

    sub_positions (S, H, W, 3) world positions of S sub-pixel samples, sub_radiance (S, H, W)
    two-bounce radiance, sub_valid (S, H, W) whether the sample sees a surface. Each sample
    contributes radiance / S, so a pixel's total equals its mean sub-sample radiance.
    first_bounce_pixel (row, col) receives first_bounce_radiance at the first-bounce path.
    Lit samples (valid, radiance > 0) whose path lies outside [start_m, end_m) raise a
    ValueError naming 'bins' / 'start_m' (out_of_range="raise"), or are dropped ("drop";
    use count_out_of_range to report them). Pulse tails past the range are always cut.
    `out`: a C-contiguous float32 (H, W, T) array to overwrite and return; reusing one across
    spots saves the page faults of a fresh 400 MB cube (0.3-1 s per spot at 512x512x391).
    accumulate=True adds into `out` instead of overwriting it (e.g. third-bounce light sources
    summed into the spot's cube with no second cube).
    threads: worker threads over disjoint pixel blocks (default: up to 2 on a multi-core CPU);
    the result is bit-identical for any thread count.
    """
    if accumulate and out is None:
        raise ValueError("accumulate=True needs an `out` array to add into")
    if out_of_range not in ("raise", "drop"):
        raise ValueError(f"out_of_range: expected 'raise' or 'drop', got {out_of_range!r}")
    pos = np.asarray(sub_positions)
    rad = np.asarray(sub_radiance)
    valid = np.asarray(sub_valid, bool)
    if rad.ndim != 3 or pos.shape != rad.shape + (3,) or valid.shape != rad.shape:
        raise ValueError(f"expected sub_positions (S, H, W, 3), sub_radiance (S, H, W) and sub_valid (S, H, W); "
                         f"got {pos.shape}, {rad.shape}, {valid.shape}")
    n_sub, h, w = rad.shape
    if n_sub < 1:
        raise ValueError("expected at least one sub-pixel sample (S >= 1)")
    if (h, w) != (sensor.height, sensor.width):
        raise ValueError(f"radiance is {h}x{w} (HxW) but the sensor is {sensor.height}x{sensor.width}")
    kernel = PulseKernel(sensor)
    lit = valid & (rad != 0)
    lit_rad = rad[lit]
    if not np.all(np.isfinite(lit_rad)) or np.any(lit_rad < 0):
        raise ValueError("sub_radiance: expected finite radiance >= 0 at valid samples "
                         f"({int((~np.isfinite(lit_rad)).sum())} non-finite, {int((lit_rad < 0).sum())} negative)")
    if not np.all(np.isfinite(pos[lit])):
        raise ValueError("sub_positions: non-finite world position at a lit sample")
    fb_amp = float(first_bounce_radiance)
    if not (math.isfinite(fb_amp) and fb_amp >= 0):
        raise ValueError(f"first_bounce_radiance: expected a finite value >= 0, got {first_bounce_radiance!r}")

    if out is None:
        cube = np.zeros((h * w, kernel.bins), np.float32)
    else:
        if out.shape != (h, w, kernel.bins) or out.dtype != np.float32 or not out.flags.c_contiguous:
            raise ValueError(f"out: expected a C-contiguous float32 array of shape {(h, w, kernel.bins)}, "
                             f"got {out.dtype} {out.shape}")
        cube = out.reshape(h * w, kernel.bins)
        if not accumulate:
            cube.fill(0.0)
    paths_per_s = []
    for s in range(n_sub):
        pix = np.flatnonzero(lit[s])
        paths = optical_path(pos[s].reshape(-1, 3)[pix], first_bounce, laser_origin, sensor_centre)
        outside = (paths < kernel.start_m) | (paths >= kernel.end_m)
        if outside.any():
            if out_of_range == "raise":
                raise _range_error(paths[outside], kernel, "lit two-bounce samples")
            pix, paths = pix[~outside], paths[~outside]
        paths_per_s.append((pix, paths))
    samples = [(pix, paths, rad[s].reshape(-1)[pix].astype(np.float64) / n_sub)
               for s, (pix, paths) in enumerate(paths_per_s)]
    _deposit_threaded(cube, samples, kernel, threads)

    if first_bounce_pixel is not None and fb_amp > 0:
        row, col = (int(v) for v in first_bounce_pixel)
        if not (0 <= row < h and 0 <= col < w):
            raise ValueError(f"first_bounce_pixel {(row, col)} lies outside the {h}x{w} image")
        p1 = np.array([first_bounce_path(first_bounce, laser_origin, sensor_centre)])
        if not kernel.start_m <= p1[0] < kernel.end_m:
            if out_of_range == "raise":
                raise _range_error(p1, kernel, "first-bounce return(s)")
        else:
            _deposit(cube, np.array([row * w + col]), p1, np.array([fb_amp]), kernel)
    return cube.reshape(h, w, kernel.bins) if out is None else out


def count_out_of_range(sub_positions, sub_radiance, sub_valid, first_bounce, laser_origin, sensor_centre,
                       sensor) -> int:
    """Number of lit samples whose two-bounce path lies outside the sensor's bin range."""
    kernel = PulseKernel(sensor)
    rad = np.asarray(sub_radiance)
    lit = np.asarray(sub_valid, bool) & (rad != 0)
    paths = optical_path(np.asarray(sub_positions)[lit], first_bounce, laser_origin, sensor_centre)
    return int(np.count_nonzero((paths < kernel.start_m) | (paths >= kernel.end_m)))


def bin_windows(pixels, paths, amps, n_pixels: int, sensor, window_bins: int, *, out_of_range="raise"):
    """Samples (pixel, path, amplitude) straight into per-pixel windows: (start (P,), window (P, G), needed).

    The sparse form of bin_two_bounce (no (H, W, T) cube): pixel q keeps bins start[q] ..
    start[q] + G - 1, start[q] = its first bin with signal (clipped to T - G; 0 without signal),
    the layout apply_sensor produces. Samples may repeat pixels (bincount sums them) and carry
    any weight (radiance / samples of that pixel). `needed` is the largest per-pixel extent of
    signal in bins; when it exceeds G the window is too short and the caller must widen it.
    Lit samples outside the bin range raise a ValueError naming 'bins' (out_of_range="raise")
    or are dropped ("drop"); pulse tails past the range are cut.
    """
    kernel = PulseKernel(sensor)
    t, g = kernel.bins, int(window_bins)
    pixels = np.asarray(pixels, np.int64)
    paths = np.asarray(paths, np.float64)
    amps = np.asarray(amps, np.float64)
    keep = amps > 0
    outside = keep & ((paths < kernel.start_m) | (paths >= kernel.end_m))
    if outside.any():
        if out_of_range == "raise":
            raise _range_error(paths[outside], kernel, "lit samples")
        keep &= ~outside
    if not keep.all():               # callers usually pass lit samples only: no copies then
        pixels, paths, amps = pixels[keep], paths[keep], amps[keep]
    start = np.zeros(n_pixels, np.int64)
    # stored bins-first (G, P) and handed out as its (P, G) transpose: the EXR writer stores one channel
    # per window bin, so it then writes rows of this buffer with no (P, G) -> (G, P) copy (0.2 s per
    # 512 x 512 spot)
    bins_first = np.zeros((g, n_pixels), np.float32)
    window = bins_first.T
    if not len(pixels):
        return start, window, 0
    k_sup = kernel.support_bins
    # each sample's first pulse bin and table row, as tabulated_weights() computes them
    v = (paths - kernel.start_m) / kernel.bin_width_m
    if kernel.shape != "box":
        v -= PULSE_SUPPORT_SIGMAS * kernel.sigma_m / kernel.bin_width_m
    first = np.floor(v).astype(np.int64)
    lo = np.full(n_pixels, t, np.int64)
    hi = np.full(n_pixels, -1, np.int64)
    np.minimum.at(lo, pixels, np.maximum(first, 0))
    np.maximum.at(hi, pixels, np.minimum(first + k_sup - 1, t - 1))
    has = hi >= 0
    start[has] = np.minimum(lo[has], max(t - g, 0))
    needed = int((hi[has] - start[has]).max()) + 1
    if needed > g:
        return start, window, needed
    flat = bins_first.reshape(-1)
    table = kernel.weight_table()
    # taps-first (K, TABLE_STEPS + 1): each chunk's weights come out (K, N), one contiguous row per tap for add.at
    taps32 = None if table is None else np.ascontiguousarray(table.T, np.float32)
    amps32 = amps.astype(np.float32)
    for a in range(0, len(paths), BIN_CHUNK):      # bounded temporaries (N x K per chunk)
        b = slice(a, a + BIN_CHUNK)
        f = first[b]
        q = f - start[pixels[b]]
        q *= n_pixels
        q += pixels[b]                              # flat index of each sample's first tap in bins_first
        if taps32 is None:                          # box pulse: one bin
            w = amps32[None, b]
        else:
            row = v[b] - f                          # the table row: round((v - first) * TABLE_STEPS), in place
            row *= TABLE_STEPS
            row += 0.5
            row = row.astype(np.intp)
            np.minimum(row, TABLE_STEPS, out=row)
            w = taps32.take(row, axis=1)
            w *= amps32[None, b]
        cut = f.min() < 0 or f.max() + k_sup > t    # pulse tails past the range
        for j in range(w.shape[0]):                 # one tap at a time: no (N, K) index array
            if cut:
                ok = (f + j >= 0) & (f + j < t)
                np.add.at(flat, q[ok] + j * n_pixels, w[j, ok])
            else:
                np.add.at(flat, q + j * n_pixels, w[j])
    return start, window, needed
