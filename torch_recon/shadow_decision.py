"""Shadow or lit, per spot and pixel, from the matched filter's output and the photon counts.

The normalised matched-filter confidence (the PlatoNeRF rule, `preprocess`) says whether a pixel's
transient holds a pulse-shaped return; it cannot see how many photons arrive. Two decisions here use
the counts (numpy on (H, W) images of one spot; the statistics are Poisson when the transient holds
integer photon counts, `photon_counting`):
- `partial_shadow_mask`: a lit pixel receiving under `partial_shadow_ratio` of what its same-surface lit
  neighbours receive is covered in part by a thin shadow (a leg about one pixel wide): shadow.
- `significant_return`: a pixel whose peak holds no more photons than the ambient background would
  often give has no return, however pulse-like its few photons look (shadow, or unlabelled below).
- `unsupported_shadow_mask`: a dark pixel next to lit ones whose darkness a lit pixel that dim would
  often produce (Poisson likelihood ratio below 1 / `shadow_false_alarm`): unlabelled, neither lit nor
  shadow (the reconstructor neither carves through it nor builds along it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .contract.dataset.transient import Transient


@dataclass
class FilterOutput:
    confidence: np.ndarray   # (H, W) max of the normalised matched filter, in [0, 1]
    amplitude: np.ndarray    # (H, W) raw matched-filter maximum
    path: np.ndarray         # (H, W) sub-bin two-bounce path (m) at the filter peak
    counts: np.ndarray       # (H, W) gated photons less the background estimate (>= 0)
    variance: np.ndarray     # (H, W) their Poisson variance: all gated photons
    background: np.ndarray   # (H, W) the background estimate: photons the gate holds without a return
    first_path: np.ndarray | None = None  # (H, W) sub-bin path (m) of the earliest significant return
    peak_counts: np.ndarray | None = None  # (H, W) photons in the pulse's support bins at the filter peak
    support_bins: int = 1    # how many bins that support spans
    gate_bins: int = 1       # bins the filter searched per pixel (the peak is the best of this many)


def _shifted(a: np.ndarray, dy: int, dx: int, fill) -> np.ndarray:
    """b[r, c] = a[r + dy, c + dx], `fill` outside the image."""
    h, w = a.shape
    out = np.full_like(a, fill)
    out[max(-dy, 0):h - max(dy, 0), max(-dx, 0):w - max(dx, 0)] = \
        a[max(dy, 0):h - max(-dy, 0), max(dx, 0):w - max(-dx, 0)]
    return out


def photon_counting(tr: Transient, settings) -> bool:
    """Whether the transient holds photon counts (Poisson statistics apply) or expected values."""
    if settings.photon_statistics != "auto":
        return settings.photon_statistics == "poisson"
    w = tr.window
    return bool(np.array_equal(w, np.round(w)))


#: the background rate is pooled over (2 r + 1)^2 pixels: at 0.1 photons per bin a 32-bin gate holds 3 photons
BACKGROUND_POOL_RADIUS = 2


def pooled_background(off_sum, off_bins, gate_bins: int, radius: int = BACKGROUND_POOL_RADIUS) -> np.ndarray:
    """(H, W) background photons per gate: the photons outside each pixel's return (`off_sum`, over `off_bins`
    bins) summed over its (2 radius + 1)^2 neighbourhood, as a rate per bin, times `gate_bins`. Ambient light
    varies slowly across the image; one pixel's gate alone is too short to measure a low rate (a zero
    estimate would let any stray photon count as a return)."""
    from scipy.ndimage import uniform_filter
    size = 2 * radius + 1
    n = uniform_filter(np.asarray(off_sum, np.float64), size, mode="nearest")
    b = uniform_filter(np.asarray(off_bins, np.float64), size, mode="nearest")
    return (np.where(b > 0, n / np.maximum(b, 1e-30), 0.0) * gate_bins).astype(np.float32)


def significant_return(mf: FilterOutput, alpha: float) -> np.ndarray:
    """(H, W) bool: the filter peak holds more photons than the background would give, at false-alarm `alpha`.

    The normalised matched filter (the PlatoNeRF rule) measures a return's shape, not whether there is one:
    under ambient light a shadowed pixel's stray photons, once the background is taken off, can look like a
    pulse (in a 32-bin gate most did: shadow recall 0.04 at 1 photon per pixel per bin). With a background
    rate b per bin, the n photons in the pulse's L support bins at the peak are a return only when
    P(Poisson(b L) >= n) < alpha / G, the peak being the best of G positions (Bonferroni). Where no
    background is estimated (none recorded, or a gate too narrow to measure it), every peak passes.
    """
    from scipy.special import gammainc
    b = np.asarray(mf.background, np.float64)
    n = np.asarray(mf.peak_counts, np.float64)
    lam = b / max(mf.gate_bins, 1) * mf.support_bins
    with np.errstate(invalid="ignore"):
        p = np.where(n >= 1, gammainc(np.maximum(n, 1.0), lam), 1.0)     # P(Poisson(lam) >= n)
    return (b <= 0) | (p * max(mf.gate_bins, 1) < alpha)


def unsupported_shadow_mask(mf: FilterOutput, lit, excluded, alpha: float) -> np.ndarray:
    """Dark pixels whose darkness is no evidence of shadow: Poisson likelihood ratio below 1 / alpha.

    A pixel without a return is a shadow only if the light it would receive lit, lam (the mean photons of
    its lit 3 x 3 neighbours), would rarely give so few photons: with n gated photons and a background
    of B, log LR(shadow : lit) = lam - n log(1 + lam / B) (B = 0: lam if n = 0, else -inf). A dim surface
    (a dark wall, grazing light) whose lit pixels hold 1-2 photons gives zero photons often (e^-2 = 14 %):
    those zeros are left unlabelled (neither lit nor shadow), not called shadows. Pixels inside a shadow
    (no lit neighbour) are not touched.
    """
    lit = np.asarray(lit, bool)
    c = np.where(lit, mf.counts, 0.0).astype(np.float64)
    total, n_lit = np.zeros_like(c), np.zeros_like(c)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy or dx:
                total += _shifted(c, dy, dx, 0.0)
                n_lit += _shifted(lit.astype(np.float64), dy, dx, 0.0)
    lam = total / np.maximum(n_lit, 1.0)
    n = np.asarray(mf.variance, np.float64)          # all gated photons of the pixel
    b = np.asarray(mf.background, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        llr = np.where(b > 0, lam - n * np.log1p(lam / np.maximum(b, 1e-30)), np.where(n > 0, -np.inf, lam))
    dark = ~lit & ~np.asarray(excluded, bool)
    return dark & (n_lit > 0) & (llr < math.log(1.0 / alpha))


def partial_shadow_mask(counts, variance, path, lit, excluded, bin_width_m, settings,
                        poisson: bool = True, ratio: float | None = None) -> np.ndarray:
    """Lit pixels that a thin shadow (a leg's, about one pixel wide) covers in part.

    The normalised matched filter is blind to them: its confidence does not depend on how many photons
    arrive. Such a pixel receives a fraction of what its unshadowed neighbours on the same surface receive
    (two-bounce shading varies slowly across 1-2 pixels), while a pixel on a plain surface lies between
    its neighbours. For each of 4 directions and neighbour pairs at (1, 1), (1, 2), (2, 1) pixels on either
    side, both lit and within `same_surface_bins` of the pixel's path, the dimmer of the two is a lower
    bound of what the pixel would receive lit, E (the largest over pairs). At the rim of a shadow (one
    side dark, `partial_shadow_edges`) the bound is the near lit neighbour s1 (`partial_shadow_rim`
    'near'), or its trend extrapolated to the pixel, min(s1, 2 s1 - s2) ('trend': shading that falls
    steeply towards a depth or attached-shadow edge is no cast shadow, but neither is a rim whose s1 is
    itself partly shadowed, as where a shadow's edge crosses pixels at a slant: 'trend' calls lit most
    rim pixels under half lit there).
    The pixel is a partial shadow when counts < ratio E by more than `partial_shadow_z` Poisson standard
    deviations of the difference (variance: the pixel's gated photons, at least ratio E, + ratio^2 that of
    the neighbour; without `poisson`, i.e. expected values rather than counts, any deficit counts).
    Depth edges (the other side another surface) and pixels without lit neighbours never qualify.
    """
    ratio = settings.partial_shadow_ratio if ratio is None else ratio
    best, best_var = lit_neighbour_bound(counts, variance, path, lit, excluded, bin_width_m, settings)
    s = np.where(np.asarray(lit, bool), counts, 0.0).astype(np.float32)
    deficit = ratio * best - s
    if not poisson:
        return lit & (deficit > 0)
    # Poisson variance of the pixel at the decision boundary (at least ratio E photons) and of E
    var = np.maximum(np.asarray(variance, np.float32), ratio * best) + ratio * ratio * best_var
    return lit & (deficit > 0) & (deficit > settings.partial_shadow_z * np.sqrt(var))


def lit_neighbour_bound(counts, variance, path, lit, excluded, bin_width_m, settings):
    """E (H, W): a lower bound of the photons a lit pixel would receive unshadowed, from its same-surface lit
    neighbours (`partial_shadow_mask`); 0 where no pair qualifies. Also the variance of the neighbour giving E."""
    tol = settings.same_surface_bins * bin_width_m
    lit = np.asarray(lit, bool)
    s = np.where(lit, counts, 0.0).astype(np.float32)
    v = np.asarray(variance, np.float32)
    p = np.where(lit, path, np.nan).astype(np.float32)
    dark = ~lit & ~np.asarray(excluded, bool)
    best, best_var = np.zeros_like(s), np.zeros_like(s)
    with np.errstate(invalid="ignore"):
        for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
            # neighbours k steps along the direction: photons, same surface (1 and 2 tolerances), variance, dark
            nb = {}
            for k in (-2, -1, 1, 2):
                dp = np.abs(_shifted(p, k * dy, k * dx, np.nan) - p)
                nb[k] = (_shifted(s, k * dy, k * dx, 0.0), dp <= tol, _shifted(v, k * dy, k * dx, 0.0),
                         _shifted(dark, k * dy, k * dx, False), dp <= 2 * tol)
            cands = [(np.where(nb[-a][1] & nb[b][1], np.minimum(nb[-a][0], nb[b][0]), 0.0),
                      np.where(nb[-a][0] <= nb[b][0], nb[-a][2], nb[b][2])) for a, b in ((1, 1), (1, 2), (2, 1))]
            if settings.partial_shadow_edges:
                for near, far, other in ((-1, -2, 1), (1, 2, -1)):
                    sn, okn, vn, _, _ = nb[near]
                    rim = okn & nb[other][3] & nb[far][4]
                    bound = sn if settings.partial_shadow_rim == "near" else np.minimum(sn, 2 * sn - nb[far][0])
                    cands.append((np.where(rim, bound, 0.0), vn))
            for e, ev in cands:
                take = e > best
                best, best_var = np.where(take, e, best), np.where(take, ev, best_var)
    return best, best_var
