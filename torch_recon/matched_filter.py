"""Steps 2 to 5 of preprocessing (torch_recon/preprocess.py's docstring) for one spot: the time gate, the
matched filter with the first-bounce pulse (shadow confidence), each pixel's background and two-bounce photons,
and the sub-bin paths of its strongest and earliest returns. Shadow decisions from these: shadow_decision.py."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from .contract.dataset.transient import Transient
from .contract.errors import PreprocessError
from .first_bounce import CENTROID_HALF_WIDTH, FirstBounce, SubBinLUT, centroid_offset, subbin_offset
from .shadow_decision import FilterOutput, pooled_background

if TYPE_CHECKING:
    from .preprocess import PreprocessSettings


MIN_BACKGROUND_BINS = 24   # gates at least this wide (3 blocks of 8 bins) give each pixel's background rate


def matched_filter_spot(tr: Transient, sensor, fb: FirstBounce, settings: PreprocessSettings, device="cpu",
                        counting: bool = False):
    """Per-pixel confidence, raw matched-filter amplitude and sub-bin two-bounce path for one spot."""
    import torch
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
            if settings.return_centroid_fraction > 0:
                cw = CENTROID_HALF_WIDTH
                at = kk[:, None] + hw + torch.arange(-cw, cw + 1, device=device)
                inside = (at >= 0) & (at < xp.shape[1])
                win = torch.gather(xp, 1, at.clamp(0, xp.shape[1] - 1)) * inside
                # the background off every bin (0 where none was estimated): left in, every bin above the
                # threshold joins the return and pulls its centroid to the window's middle
                win = (win - (bg / gg)[:, None]).clamp_min(0)
                off = centroid_offset(win, settings.return_centroid_fraction, torch)
            else:
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
