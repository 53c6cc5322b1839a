"""Transients -> measurements: first bounce, pulse, time gate, matched filter, sub-bin peaks.

Vectorised torch on CPU or CUDA (`device`); each spot is processed in chunks of
image rows so a dense 512 x 512 x 391 cube never needs more than one extra copy
of a chunk. Windowed transients (start bin + G bins per pixel) are used as they
are: the matched filter runs over the G stored bins only.

Per spot k (paths in metres of optical path, bin centres start_m + (j + 0.5) w):
1. First bounce l_k: the laser ray o + d * ld is sampled in d; each sample is
   projected into the image and the transient of that pixel is read at the
   sample's first-bounce path P(d) = d + |o + d ld - c|. The brightest sample
   names the pixel seeing l_k; its sub-bin peak P1 gives d in closed form:
   (P1 - d)^2 = |q + d ld|^2, q = o - c  ->  d = (P1^2 - |q|^2) / (2 (P1 + q.ld)).
2. Pulse: that pixel's transient around P1, background (median) removed, unit sum.
3. Time gate: two-bounce paths are >= P1 (triangle inequality), so bins before
   P1 - (pulse half width) are ignored, as are bins beyond `gate_max_m`.
4. Matched filter (as the PlatoNeRF code): correlate each pixel with the unit-sum
   pulse, divide by the pixel's (gated) sum; the maximum is the shadow confidence.
   Below `shadow_threshold` -> shadow, otherwise the pixel saw l_k (signal).
   Then the photon counts (torch_recon.shadow_decision): a lit pixel far dimmer than its
   same-surface lit neighbours is partly covered by a thin shadow -> shadow; a dark pixel whose
   darkness is no evidence of shadow under Poisson statistics -> unlabelled (neither).
5. Sub-bin peak: at the raw maximum next to the matched-filter peak, the 3-bin
   ratio r = (x+ - x-) / (x- + x0 + x+) is inverted through a lookup table built
   from a Gaussian pulse model whose width is fitted to the first-bounce return
   ('lut', exact for noise-free Gaussian pulses); 'gaussian' (log-parabola) and
   'parabola' fits are available for comparison.
6. 'Parallel' pixels (the PlatoNeRF filter): pixels whose ray is within
   asin(parallel_sin) of the direction c -> l_k see the first-bounce return
   (and its blur) instead of a two-bounce one; they are marked `excluded`.
Steps 1 and 5 (first bounce, sub-bin peaks) live in torch_recon/first_bounce.py.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import asdict, dataclass

import numpy as np

from .contract.dataset.transient import Transient
from .contract.frames import camera_ray_directions
from .contract.errors import PreprocessError
from .first_bounce import (FirstBounce, SubBinLUT, find_first_bounce, fit_out_of_view_spot, fit_pulse_sigma,
                           laser_ray_seen, subbin_offset)
from .measurements import Measurements, SpotMeasurement
from .shadow_decision import (FilterOutput, partial_shadow_mask, photon_counting, pooled_background,
                              significant_return, unsupported_shadow_mask)


@dataclass
class PreprocessSettings:
    shadow_threshold: float = 0.15     # matched-filter confidence below this -> shadow (paper: 0.15)
    parallel_sin: float = 0.05         # exclude pixels within asin(this) of the ray c -> l (paper: 0.05)
    refine: str = "lut"                # sub-bin peak: 'lut' | 'gaussian' | 'parabola' | 'none'
    pulse_half_width_bins: int = 3     # pulse template = 2 h + 1 bins around the first-bounce peak
    gate_max_m: float | None = None    # ignore returns beyond this optical path (None: end of histogram)
    background: str = "none"           # 'median': subtract each pixel's median before the filter
    first_bounce_tolerance_m: float = 0.05  # warn when l differs this much from a recorded first bounce
    min_first_bounce_snr: float = 5.0  # first-bounce peak must exceed this x the pixel's median (+ floor)
    partial_shadow_ratio: float = 0.5  # lit pixel with under this x the photons of same-surface lit pixels on
                                       # both sides (within 2 px): a thin shadow covers part of it (0: off)
    partial_unlabel_ratio: float = 0.0  # under this (> partial_shadow_ratio) x the neighbours' photons: partly
                                       # shadowed, left unlabelled (neither lit nor shadow); 0: off
    partial_shadow_z: float = 2.0      # ... and the deficit exceeds this many Poisson standard deviations
    partial_shadow_edges: bool = True  # also the rim of a shadow: dimmer than ratio x the lit side
    partial_shadow_rim: str = "near"   # the rim's bound: 'near' = the nearest lit pixel's photons, 'trend' =
                                       # the lit side extrapolated, min(s1, 2 s1 - s2) (session 8; shadow_decision)
    first_return_fraction: float = 0.1  # a pixel's earliest return counts when its filtered peak exceeds this x
                                       # the strongest one's (above background): a thin part in front of a wall
                                       # fills part of the pixel and returns first (0: off)
    photon_statistics: str = "auto"    # 'poisson': values are photon counts; 'none': expected values (no
                                       # counting noise); 'auto': 'poisson' when every stored value is an integer
    shadow_false_alarm: float = 0.05  # a dark pixel next to lit ones is a shadow only where a lit pixel
                                      # that dark has a Poisson probability below this (else unlabelled; 0: off)
    return_false_alarm: float = 1e-3  # photon counts over a background: a pixel is lit only where its peak's
                                      # photons would come from the background alone with a probability below
                                      # this (shadow_decision.significant_return; 0: off)
    same_surface_bins: float = 2.0     # neighbours count as the same surface within this many bins of path
    chunk_elements: int = 1 << 20      # bins per chunk: 4 MB tensors stay in the allocator's heap (1 << 24:
                                       # 64 MB ones were mapped afresh each time, 10.7 of 27 CPU-s at 512 px in page faults)
    compute_visible_depth: bool = True

    SETTINGS_META = {"refine": {"choices": ("lut", "gaussian", "parabola", "none")},
                     "background": {"choices": ("none", "median")},
                     "partial_shadow_rim": {"choices": ("near", "trend")},
                     "photon_statistics": {"choices": ("auto", "poisson", "none")}, "shadow_threshold": {"range": (0.0, 1.0)},
                     "gate_max_m": {"unit": "m"}}

    def validate(self):
        if not 0.0 <= self.shadow_threshold <= 1.0:
            raise PreprocessError(f"shadow_threshold must be in [0, 1], got {self.shadow_threshold}")
        if not 0.0 <= self.parallel_sin < 1.0:
            raise PreprocessError(f"parallel_sin must be in [0, 1), got {self.parallel_sin}")
        if self.refine not in ("lut", "gaussian", "parabola", "none"):
            raise PreprocessError(f"refine must be 'lut', 'gaussian', 'parabola' or 'none', got {self.refine!r}")
        if self.background not in ("none", "median"):
            raise PreprocessError(f"background must be 'none' or 'median', got {self.background!r}")
        if self.partial_shadow_rim not in ("near", "trend"):
            raise PreprocessError(f"partial_shadow_rim must be 'near' or 'trend', got {self.partial_shadow_rim!r}")
        if not 0.0 <= self.partial_shadow_ratio < 1.0:
            raise PreprocessError(f"partial_shadow_ratio must be in [0, 1), got {self.partial_shadow_ratio}")
        if self.photon_statistics not in ("auto", "poisson", "none"):
            raise PreprocessError(f"photon_statistics must be 'auto', 'poisson' or 'none', got {self.photon_statistics!r}")
        if not 0.0 <= self.shadow_false_alarm < 1.0:
            raise PreprocessError(f"shadow_false_alarm must be in [0, 1), got {self.shadow_false_alarm}")
        if not 0.0 <= self.return_false_alarm < 1.0:
            raise PreprocessError(f"return_false_alarm must be in [0, 1), got {self.return_false_alarm}")
        if not 0.0 <= self.first_return_fraction < 1.0:
            raise PreprocessError(f"first_return_fraction must be in [0, 1), got {self.first_return_fraction}")
        if not 0.0 <= self.partial_unlabel_ratio < 1.0:
            raise PreprocessError(f"partial_unlabel_ratio must be in [0, 1), got {self.partial_unlabel_ratio}")
        if not (self.partial_shadow_z >= 0 and self.same_surface_bins > 0):
            raise PreprocessError("partial_shadow_z must be >= 0 and same_surface_bins > 0")
        if self.pulse_half_width_bins < 1:
            raise PreprocessError("pulse_half_width_bins must be >= 1")


def _torch():
    import torch
    return torch


# ---------------------------------------------------------------- input checks

def check_transient(tr: Transient, sensor, spot_id) -> None:
    """Refuse a transient that does not fit the sensor: shape, bins, NaN/inf, negatives, all zero."""
    where = f"spot {spot_id}"
    if tr.bins != sensor.bins:
        raise PreprocessError(f"{where}: transient has {tr.bins} bins, the manifest says sensor.bins={sensor.bins}")
    if tuple(tr.shape) != (sensor.height, sensor.width):
        raise PreprocessError(f"{where}: transient is {tr.shape[0]}x{tr.shape[1]} pixels, the manifest says "
                              f"{sensor.height}x{sensor.width} (sensor.height x sensor.width)")
    w = tr.window
    lo, hi = (float(w.min()), float(w.max())) if w.size else (0.0, 0.0)   # min is NaN if any value is
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise PreprocessError(f"{where}: transient has {int((~np.isfinite(w)).sum())} NaN or infinite value(s)")
    if lo < 0:
        raise PreprocessError(f"{where}: transient has {int((w < 0).sum())} negative count(s)")
    if hi == 0:
        raise PreprocessError(f"{where}: transient is all zeros (no return at all; laser off or hits nothing?)")


# ---------------------------------------------------------------- per spot

def world_pixel_directions(sensor) -> np.ndarray:
    c2w = np.asarray(sensor.camera_to_world, np.float64)
    return camera_ray_directions(sensor.width, sensor.height, sensor.fov_rad, sensor.fov_axis) @ c2w[:3, :3].T


def parallel_mask(dirs: np.ndarray, c, l, parallel_sin: float) -> np.ndarray:
    """Pixels looking (almost) along c -> l, where the first-bounce return swamps the two-bounce one."""
    e = np.asarray(l, np.float64) - np.asarray(c, np.float64)
    e /= max(np.linalg.norm(e), 1e-12)
    sin = np.linalg.norm(np.cross(dirs, e), axis=-1)
    return (sin < parallel_sin) & ((dirs @ e) > 0)


MIN_BACKGROUND_BINS = 24   # gates at least this wide (3 blocks of 8 bins) give each pixel's background rate


def matched_filter_spot(tr: Transient, sensor, fb: FirstBounce, settings: PreprocessSettings, device="cpu",
                        counting: bool = False):
    """Per-pixel confidence, raw matched-filter amplitude and sub-bin two-bounce path for one spot."""
    torch = _torch()
    h, w, g = tr.window.shape
    bw = sensor.bin_width_m
    hw = settings.pulse_half_width_bins
    gate_lo = max(fb.peak_bin - hw, 0)
    gate_hi = sensor.bins if settings.gate_max_m is None else \
        int(np.clip(math.ceil((settings.gate_max_m - sensor.start_m) / bw), 1, sensor.bins))
    if gate_hi <= gate_lo:
        raise PreprocessError(f"gate_max_m={settings.gate_max_m} ends before the first-bounce return "
                              f"({fb.path_m:.3f} m)")
    pulse = torch.as_tensor(fb.pulse, dtype=torch.float32, device=device)
    # taps below 1e-3 of the peak change the confidence by < 0.1 % and cost a full pass each
    taps = [(j, float(pulse[j])) for j in range(len(fb.pulse)) if fb.pulse[j] >= 1e-3 * fb.pulse.max()]
    tap_sum = sum(pj for _, pj in taps)
    support = [j for j, pj in taps if pj >= RETURN_SUPPORT_FRACTION * fb.pulse.max()]
    lut = SubBinLUT(fb.pulse_sigma_bins) if settings.refine == "lut" else None
    dense = tr.is_dense
    rows_per_chunk = max(1, settings.chunk_elements // max(w * g, 1))
    conf = np.zeros((h, w), np.float32)
    amp = np.zeros((h, w), np.float32)
    counts = np.zeros((h, w), np.float32)
    variance = np.zeros((h, w), np.float32)
    background = np.zeros((h, w), np.float32)
    path = np.full((h, w), np.nan, np.float32)
    first = np.full((h, w), np.nan, np.float32)
    peak_n = np.zeros((h, w), np.float32)
    off_sum, off_bins = np.zeros((h, w), np.float32), np.zeros((h, w), np.float32)
    if dense:   # centres stop h bins before the end, so the padded view below needs no copy
        gate_hi = min(gate_hi, sensor.bins - hw)
        if gate_hi <= gate_lo:
            raise PreprocessError(f"the histogram ends right after the first-bounce return ({fb.path_m:.3f} m)")
    for r0 in range(0, h, rows_per_chunk):
        r1 = min(h, r0 + rows_per_chunk)
        x = torch.from_numpy(np.ascontiguousarray(tr.window[r0:r1])).to(device).reshape(-1, g)
        if dense:
            a = gate_lo - hw
            xp = x[:, max(a, 0):gate_hi + hw]          # a view: the gate plus h bins either side
            if a < 0:
                xp = torch.nn.functional.pad(xp, (-a, 0))
            base = torch.full((x.shape[0],), gate_lo, dtype=torch.int64, device=device)
        else:
            base = torch.from_numpy(tr.start_bin[r0:r1].reshape(-1)).to(device)
            absb = base[:, None] + torch.arange(g, device=device)
            xp = torch.nn.functional.pad(x * ((absb >= gate_lo) & (absb < gate_hi)), (hw, hw))
        # expected values: the median is the background. Photon counts keep their values (clamping x - median
        # at 0 leaves the positive half of the noise: in a 32-bin gate a few stray photons then look like a
        # pulse to the normalised filter); their background is estimated below and taken off the sums.
        subtract = settings.background == "median" and counting
        if settings.background == "median" and not counting:
            xp = (xp - xp[:, hw:xp.shape[1] - hw].median(dim=1, keepdim=True).values).clamp_min(0)
            if dense and a < 0:
                xp[:, :-a] = 0
        gg = xp.shape[1] - 2 * hw
        total = xp[:, hw:hw + gg].sum(dim=1)
        # correlation with a short pulse: a few shifted multiply-adds beat conv1d and FFT here
        (j0, p0), rest = taps[0], taps[1:]
        corr = xp[:, j0:j0 + gg] * p0
        for j, pj in rest:
            corr.add_(xp[:, j:j + gg], alpha=pj)
        m, k = corr.max(dim=1)
        # photons of the two-bounce return: the gated sum less the background. Photon counts: the background
        # rate is what the gate holds outside the pulse template at the peak (pooled over neighbouring pixels
        # after this loop: at 0.1 photons per bin a 32-bin gate often holds none); expected values: the median
        # of a wide gate's 8-bin block means (a return fills one or two blocks); a narrow window holds no
        # background (the simulator stores only non-zero bins when there is none). Poisson: variance = all.
        if counting:
            idx = k[:, None] + torch.arange(2 * hw + 1, device=device)
            in_gate = (idx >= hw) & (idx < hw + gg)
            off_n = total - (torch.gather(xp, 1, idx) * in_gate).sum(dim=1)
            off_b = (gg - in_gate.sum(dim=1)).to(total.dtype)
            bg = off_n / off_b.clamp_min(1) * gg       # this pixel's own estimate: sub-bin and earliest return
            off_sum[r0:r1] = off_n.reshape(r1 - r0, w).cpu().numpy()
            off_bins[r0:r1] = off_b.reshape(r1 - r0, w).cpu().numpy()
        elif gg >= MIN_BACKGROUND_BINS and settings.background != "median":
            nb = gg // 8
            blocks = xp[:, hw:hw + 8 * nb].reshape(-1, nb, 8).mean(dim=2)
            bg = blocks.median(dim=1).values * gg
        else:
            bg = torch.zeros_like(total)
        c = torch.where(total > 0, m / total.clamp_min(1e-30), torch.zeros_like(m))
        # photons in the pulse's main bins at the filter peak: the return's significance (shadow_decision)
        peak_n[r0:r1] = sum(xp[:, j:j + gg].gather(1, k[:, None])[:, 0] for j in support).reshape(r1 - r0, w).cpu().numpy()

        def peak_path(k):
            # the raw maximum next to the filter peak k, then its sub-bin offset from 3 bins
            idx = k[:, None] + hw + torch.arange(-1, 2, device=device)
            kk = (k + torch.gather(xp, 1, idx).argmax(dim=1) - 1).clamp(0, gg - 1)
            three = torch.gather(xp, 1, kk[:, None] + hw + torch.arange(-1, 2, device=device))
            if subtract:
                three = (three - (bg / gg)[:, None]).clamp_min(0)
            off = subbin_offset(three[:, 0], three[:, 1], three[:, 2], settings.refine, lut, torch)
            return sensor.start_m + (base + kk).to(torch.float64) * bw + (0.5 + off.to(torch.float64)) * bw

        p = peak_path(k)
        p1 = p
        if settings.first_return_fraction > 0:
            # photon counts: the earlier peak must also stand out of the counting noise (a stray photon is none)
            noise = (FIRST_RETURN_Z * torch.sqrt(torch.clamp(bg / gg, min=1.0) * sum(pj * pj for _, pj in taps))
                     if counting else None)
            k1 = first_return_bin(corr, m, bg / gg, settings.first_return_fraction, noise)
            p1 = torch.where(k1 == k, p, peak_path(k1))
        conf[r0:r1] = c.reshape(r1 - r0, w).cpu().numpy()
        amp[r0:r1] = m.reshape(r1 - r0, w).cpu().numpy()
        counts[r0:r1] = (total - bg).clamp_min(0).reshape(r1 - r0, w).cpu().numpy()
        variance[r0:r1] = total.reshape(r1 - r0, w).cpu().numpy()
        background[r0:r1] = bg.reshape(r1 - r0, w).cpu().numpy()
        path[r0:r1] = p.reshape(r1 - r0, w).to(torch.float32).cpu().numpy()
        first[r0:r1] = p1.reshape(r1 - r0, w).to(torch.float32).cpu().numpy()
    if counting:        # the background pooled over neighbouring pixels; with 'median' taken off the filter's sums
        background = pooled_background(off_sum, off_bins, int(gg))
        counts = np.maximum(variance - background, 0.0).astype(np.float32)
        if subtract:
            sig_total = variance - background
            conf = np.where(sig_total > 0, (amp - background / gg * tap_sum) / np.maximum(sig_total, 1e-30), 0.0)
    return FilterOutput(np.clip(conf, 0.0, 1.0).astype(np.float32), amp, path, counts, variance, background, first,
                        peak_counts=peak_n, support_bins=len(support), gate_bins=int(gg))


#: the pulse's main bins (the return's significance test counts their photons): taps >= this x the peak tap
RETURN_SUPPORT_FRACTION = 0.1


#: standard deviations of the filtered counting noise an earliest return must exceed (photon counts)
FIRST_RETURN_Z = 4.0


def first_return_bin(corr, peak, background_per_bin, fraction: float, noise=None):
    """Per row of the matched filter's output `corr` (R, G): the earliest local maximum whose height above
    the background rate exceeds `fraction` x the strongest one's (`peak`, (R,)).

    A pixel half covered by a thin part (a 2 cm leg in front of the floor) holds two returns: the part's,
    earlier (along one ray the two-bounce path t + |c + t u - l| grows with the range t), and the floor's,
    often stronger. The strongest names the visible depth; the earliest bounds the pixel's free space.
    Rows without such a maximum keep the strongest's bin. `noise` (R,): with photon counts, the height above
    the background must also exceed it."""
    import torch
    thr = background_per_bin + fraction * (peak - background_per_bin)
    if noise is not None:
        thr = torch.maximum(thr, background_per_bin + noise)
    nxt = torch.cat([corr[:, 1:], torch.full_like(corr[:, :1], -float("inf"))], 1)
    cand = (corr >= thr[:, None]) & (corr >= nxt) & (corr > background_per_bin[:, None])
    return torch.where(cand.any(1), cand.to(torch.uint8).argmax(1), corr.argmax(1))


def process_spot(tr: Transient, sensor, spot, settings: PreprocessSettings, device="cpu", dirs=None,
                 recorded_first_bounce=None, fb: FirstBounce | None = None) -> SpotMeasurement:
    """One spot's measurements; `fb` given: its first bounce is already known (an out-of-view spot's fit)."""
    settings.validate()
    check_transient(tr, sensor, spot.id)
    if fb is None:
        fb = find_first_bounce(tr, sensor, spot.laser_direction, spot.id, settings)
    rec = recorded_first_bounce if recorded_first_bounce is not None else getattr(spot, "first_bounce", None)
    if rec is not None:
        err = float(np.linalg.norm(fb.point - np.asarray(rec, np.float64)))
        if err > settings.first_bounce_tolerance_m:
            warnings.warn(f"spot {spot.id}: first bounce estimated from the transient {np.round(fb.point, 4).tolist()} "
                          f"is {err:.4f} m from the recorded one {np.round(rec, 4).tolist()} "
                          f"(tolerance {settings.first_bounce_tolerance_m} m)", stacklevel=2)
    counting = photon_counting(tr, settings)     # expected values: no counting noise, a dark pixel is dark
    mf = matched_filter_spot(tr, sensor, fb, settings, device, counting)
    conf, amp, path = mf.confidence, mf.amplitude, mf.path
    if dirs is None:
        dirs = world_pixel_directions(sensor)
    c = np.asarray(sensor.camera_to_world, np.float64)[:3, 3]
    excluded = parallel_mask(dirs, c, fb.point, settings.parallel_sin)
    if fb.pixel is not None:
        excluded[fb.pixel] = True
    signal = (conf >= settings.shadow_threshold) & ~excluded
    if counting and settings.return_false_alarm > 0:        # under ambient light: a return must outnumber it
        signal &= significant_return(mf, settings.return_false_alarm)
    # darkness is judged against the lit pixels of the matched filter, before partial shadows join the dark
    unlabelled = unsupported_shadow_mask(mf, signal, excluded, settings.shadow_false_alarm) \
        if counting and settings.shadow_false_alarm > 0 else np.zeros_like(signal)
    if settings.partial_shadow_ratio > 0:
        lit = signal
        part = lambda ratio: partial_shadow_mask(mf.counts, mf.variance, path, lit, excluded, sensor.bin_width_m,  # noqa: E731
                                                 settings, poisson=counting, ratio=ratio)
        signal = lit & ~part(settings.partial_shadow_ratio)
        if settings.partial_unlabel_ratio > settings.partial_shadow_ratio:
            dim = signal & part(settings.partial_unlabel_ratio)     # partly shadowed: neither carve nor build
            signal, unlabelled = signal & ~dim, unlabelled | dim
    path = np.where(signal, path, np.nan).astype(np.float32)
    first = None if mf.first_path is None else np.where(signal, np.fmin(mf.first_path, path), np.nan).astype(np.float32)
    ld = np.asarray(spot.laser_direction, np.float64)
    return SpotMeasurement(
        spot_id=int(spot.id), first_bounce=fb.point.astype(np.float64), laser_direction=ld / np.linalg.norm(ld),
        path_length=path, signal=signal, shadow_confidence=conf.astype(np.float32),
        shadow=(~signal) & ~excluded & ~unlabelled, excluded=excluded, first_bounce_pixel=fb.pixel,
        pulse=fb.pulse.astype(np.float32), first_bounce_path_m=float(fb.path_m), amplitude=amp,
        first_bounce_recorded=None if rec is None else np.asarray(rec, np.float64), first_return_path=first)


def preprocess(sensor, spot_transients, settings: PreprocessSettings | None = None, device="cpu",
               progress: bool = False) -> Measurements:
    """(Spot, Transient) pairs -> Measurements (with the fused closed-form visible depth)."""
    settings = settings or PreprocessSettings()
    settings.validate()
    dirs = world_pixel_directions(sensor)
    items = list(spot_transients) if not hasattr(spot_transients, "__len__") else spot_transients
    it = items
    if progress:
        from tqdm import tqdm
        it = tqdm(items, desc="preprocess", unit="spot")
    spots, out_of_view = [], []
    for i, (s, tr) in enumerate(it):   # out-of-view spots wait for the depth the in-view ones measure
        if laser_ray_seen(sensor, s.laser_direction):
            spots.append((i, process_spot(tr, sensor, s, settings, device, dirs)))
        else:       # a lazily read dataset reads it again later: a 512^2 cube per spot is 400 MB
            out_of_view.append((i, s, None if isinstance(items, _LazySpots) else tr))
        del tr
    if out_of_view:
        read = items.dataset.read_transient if isinstance(items, _LazySpots) else None
        spots += _out_of_view_spots(sensor, [m for _, m in spots], out_of_view, settings, device, dirs, read)
    spots = [m for _, m in sorted(spots, key=lambda im: im[0])]
    if not spots:
        raise PreprocessError("no enabled spots to preprocess")
    m = Measurements(width=sensor.width, height=sensor.height, fov_rad=float(sensor.fov_rad),
                     fov_axis=sensor.fov_axis, camera_to_world=np.asarray(sensor.camera_to_world, np.float64),
                     laser_origin=np.asarray(sensor.laser_origin, np.float64), bin_width_m=float(sensor.bin_width_m),
                     shadow_threshold=float(settings.shadow_threshold), spots=spots,
                     settings=asdict(settings))
    if settings.compute_visible_depth:
        from .visible_depth import fuse_visible_depth
        fused = fuse_visible_depth(m, device=device)
        m.visible_depth, m.visible_confidence, m.nearest_depth = fused.depth, fused.confidence, fused.nearest
    return m


def _out_of_view_spots(sensor, spots, out_of_view, settings, device, dirs, read_transient=None) -> list:
    """[(index, SpotMeasurement)] of the out-of-view (index, spot, transient) triples, each located by its
    two-bounce arrival times at pixels whose depth the in-view `spots` measured
    (first_bounce.fit_out_of_view_spot; the laser's pulse is an in-view spot's)."""
    if not spots:
        ids = ", ".join(str(s.id) for _, s, _ in out_of_view)
        raise PreprocessError(f"every spot ({ids}) lies outside the sensor's view: at least one spot inside the view "
                              f"is needed (its first bounce is measured; out-of-view spots are located from the "
                              f"depth it gives)")
    from .visible_depth import fuse_visible_depth     # only scenes with out-of-view spots need it
    fused = fuse_visible_depth(Measurements(
        width=sensor.width, height=sensor.height, fov_rad=float(sensor.fov_rad), fov_axis=sensor.fov_axis,
        camera_to_world=np.asarray(sensor.camera_to_world, np.float64),
        laser_origin=np.asarray(sensor.laser_origin, np.float64), bin_width_m=float(sensor.bin_width_m),
        shadow_threshold=float(settings.shadow_threshold), spots=spots), device=device)
    c = np.asarray(sensor.camera_to_world, np.float64)[:3, 3]
    points = c + dirs * np.asarray(fused.depth, np.float64)[..., None]
    pulse = np.asarray(spots[0].pulse, np.float64)
    h = len(pulse) // 2
    # peak_bin 0: the first pass is ungated (l, hence the earliest two-bounce path, is still unknown)
    ungated = FirstBounce(point=spots[0].first_bounce, distance=0.0, path_m=float(sensor.start_m), pixel=None,
                          pulse=pulse, pulse_sigma_bins=fit_pulse_sigma(pulse[h - 2:h + 3]) if h >= 2 else 0.05,
                          peak_bin=0)
    out = []
    for i, s, tr in out_of_view:
        tr = tr if tr is not None else read_transient(s.id)
        check_transient(tr, sensor, s.id)
        mf = matched_filter_spot(tr, sensor, ungated, settings, device)
        path = np.where(mf.confidence >= settings.shadow_threshold, mf.path, np.nan)
        fb = fit_out_of_view_spot(sensor, s.laser_direction, s.id, path, points, ungated)
        out.append((i, process_spot(tr, sensor, s, settings, device, dirs, fb=fb)))
    return out


class _LazySpots:
    """Reads one spot's transient at a time (a 512^2 x 391 cube is 400 MB)."""

    def __init__(self, dataset):
        self.dataset = dataset
        self.spots = dataset.manifest.enabled_spots

    def __len__(self):
        return len(self.spots)

    def __iter__(self):
        for s in self.spots:
            yield s, self.dataset.read_transient(s.id)


def measurements_from_dataset(dataset, settings: PreprocessSettings | None = None, device="cpu") -> Measurements:
    """A measurements-kind dataset (no transients): its stored per-pixel paths and masks as Measurements."""
    settings = settings or PreprocessSettings()
    settings.validate()
    s = dataset.sensor
    rays = dataset.ray_directions()
    dirs = rays if rays is not None else world_pixel_directions(s)
    c = np.asarray(s.camera_to_world, np.float64)[:3, 3]
    spots = []
    for sp in dataset.manifest.enabled_spots:
        d = dataset.read_spot_measurement(sp.id)
        l = np.asarray(sp.first_bounce, np.float64)
        excluded = ~d["valid"] | parallel_mask(dirs, c, l, settings.parallel_sin)
        signal = d["lit"] & ~excluded
        ld = np.asarray(sp.laser_direction, np.float64)
        spots.append(SpotMeasurement(
            spot_id=int(sp.id), first_bounce=l, laser_direction=ld / np.linalg.norm(ld),
            path_length=np.where(signal, d["path_m"], np.nan).astype(np.float32), signal=signal,
            shadow_confidence=signal.astype(np.float32), shadow=~signal & ~excluded, excluded=excluded,
            first_bounce_recorded=l))
    if not spots:
        raise PreprocessError(f"{dataset.root}: no enabled spots")
    m = Measurements(width=s.width, height=s.height, fov_rad=float(s.fov_rad), fov_axis=s.fov_axis,
                     camera_to_world=np.asarray(s.camera_to_world, np.float64),
                     laser_origin=np.asarray(s.laser_origin, np.float64), bin_width_m=float(s.bin_width_m),
                     shadow_threshold=float(settings.shadow_threshold), spots=spots,
                     settings={**asdict(settings), "source": "measurements dataset"}, ray_directions=rays)
    if settings.compute_visible_depth:
        from .visible_depth import fuse_visible_depth
        fused = fuse_visible_depth(m, device=device)
        m.visible_depth, m.visible_confidence, m.nearest_depth = fused.depth, fused.confidence, fused.nearest
    return m


def preprocess_dataset(dataset, settings: PreprocessSettings | None = None, device="cpu",
                       progress: bool = False) -> Measurements:
    """Preprocess every enabled spot of a loaded Dataset (transients read one at a time).

    A measurements-kind dataset (schema 1.1, e.g. an imported real capture) already holds what
    preprocessing extracts; it is read as it is (no matched filter, no first-bounce search)."""
    if dataset.manifest.kind == "measurements":
        return measurements_from_dataset(dataset, settings, device)
    try:
        return preprocess(dataset.sensor, _LazySpots(dataset), settings, device, progress)
    except PreprocessError as exc:
        raise PreprocessError(f"{dataset.root}: {exc}") from None
