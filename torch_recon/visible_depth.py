"""Visible depth in closed form: each (spot, pixel) path length is an ellipsoid; intersect the pixel ray.

Derivation. Pixel ray x = c + t u (|u| = 1, t > 0: range along the ray). The
two-bounce path is D = |l - o| + |x - l| + |x - c| = |l - o| + |x - l| + t, so
with D' = D - |l - o| (the ellipsoid's major axis, foci l and c):
    |c - l + t u|^2 = (D' - t)^2
    |c - l|^2 + 2 t u.(c - l) + t^2 = D'^2 - 2 D' t + t^2
    t = (D'^2 - |c - l|^2) / (2 (D' - u.(l - c))).
A real ellipsoid needs D' > |c - l|; then the denominator is >= D' - |l - c| > 0
and D' - t = |D' u - (l - c)|^2 / (2 (D' - u.(l - c))) >= 0, so the squared
equation has no spurious root. The denominator vanishes only for the pixel
looking straight at l with D' = |l - c| (every point of the segment c -> l has
the same path): such pixels are the 'parallel' ones preprocessing excludes, and
here any denominator below `min_denominator` gives NaN.

Precision. dt/dD' = (2 D' M - N) / (2 M^2) with N, M the numerator and the
denominator above: a bin of path error moves t by that much. Spots are fused
per pixel by the median, then the estimates within `inlier_m` of it are
averaged with weights 1 / (dt/dD')^2 (better-conditioned spots count more).
Confidence = inliers / spots that measured the pixel (lit or shadow).

Nearest depth. A pixel partly covered by a thin part (a leg narrower than the pixel) holds two returns
per spot; the strongest (above) usually is the surface behind. Each spot's earliest significant return
(`first_return_path`) gives a range the same way; the nearest surface of the pixel is the second
smallest of them (two spots must see it: one spot's stray early peak does not count), never beyond
the depth. Camera rays are free only up to it. A range within the spots' own scatter of the depth
(`SCATTER_FACTOR` x the 90th percentile of |spot range - fused depth| over the image) counts as the depth:
with coarse bins each spot's sub-bin path errs by up to half a bin (1024 ps: range scatter 2.6 cm mean,
5.4 cm p90 on cave-chair), and the second smallest of 16 scattered ranges put a "nearest surface" 5-15 cm
in front of almost every pixel (a thin part everywhere: spurious surface 18 % of the mesh). At 128 ps the
scatter is 3 mm (p90), below anything the fit resolves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .contract.errors import MeasurementsError


#: a spot's earliest range counts as a surface in front of the depth only beyond this x the spots' range scatter
SCATTER_FACTOR = 2.0


@dataclass
class VisibleDepth:
    depth: np.ndarray        # (H, W) float32 range along the pixel ray; NaN where unknown
    confidence: np.ndarray   # (H, W) float32 in [0, 1]
    count: np.ndarray        # (H, W) int: spots giving a valid estimate
    per_spot: np.ndarray | None = None  # (S, H, W) per-spot estimates (NaN: none)
    nearest: np.ndarray | None = None   # (H, W) float32 range of the nearest surface in the pixel (<= depth)


def ellipsoid_range(path, first_bounce, laser_origin, sensor_origin, dirs, min_denominator=1e-6):
    """Range t along unit rays `dirs` (..., 3) for two-bounce paths `path` (...) (torch tensors).

    NaN where the path is NaN, the ellipsoid is degenerate (D' <= |c - l|) or the
    denominator is below `min_denominator` (metres). Also returns dt/dD'.
    """
    import torch
    l = torch.as_tensor(first_bounce, dtype=dirs.dtype, device=dirs.device)
    o = torch.as_tensor(laser_origin, dtype=dirs.dtype, device=dirs.device)
    c = torch.as_tensor(sensor_origin, dtype=dirs.dtype, device=dirs.device)
    dp = path - torch.linalg.norm(l - o)
    lc = l - c
    n = dp * dp - (lc * lc).sum()
    m = dp - (dirs * lc).sum(-1)
    ok = torch.isfinite(dp) & (dp > torch.linalg.norm(lc)) & (m > min_denominator)
    ms = torch.where(ok, m, torch.ones_like(m))
    t = torch.where(ok, n / (2 * ms), torch.full_like(m, float("nan")))
    dt = torch.where(ok, (2 * dp * ms - n) / (2 * ms * ms), torch.full_like(m, float("nan")))
    return t, dt


def fuse_visible_depth(meas, device="cpu", inlier_m: float | None = None, keep_per_spot: bool = False,
                       dtype=None) -> VisibleDepth:
    """Fuse the per-spot closed-form ranges of a Measurements into one depth map and confidence."""
    import torch

    dtype = dtype or torch.float64
    dirs = meas.pixel_directions()
    dirs = torch.as_tensor(dirs, dtype=dtype, device=device)
    c = np.asarray(meas.camera_to_world, np.float64)[:3, 3]
    inlier_m = meas.bin_width_m if inlier_m is None else inlier_m
    ts, ws, measured, firsts = [], [], [], []
    for s in meas.spots:
        path = torch.as_tensor(np.where(s.signal, s.path_length, np.nan), dtype=dtype, device=device)
        t, dt = ellipsoid_range(path, s.first_bounce, meas.laser_origin, c, dirs)
        ts.append(t)
        if s.first_return_path is not None:
            p1 = torch.as_tensor(np.where(s.signal, s.first_return_path, np.nan), dtype=dtype, device=device)
            firsts.append(ellipsoid_range(p1, s.first_bounce, meas.laser_origin, c, dirs)[0])
        ws.append(1.0 / (dt * dt).clamp_min(1e-6))
        measured.append(torch.as_tensor(~np.asarray(s.excluded, bool), device=device))
    t = torch.stack(ts)                                    # (S, H, W)
    w = torch.stack(ws)
    med = torch.nanmedian(t, dim=0).values                 # NaN where no spot has an estimate
    inl = torch.isfinite(t) & ((t - med).abs() <= inlier_m)
    wi = torch.where(inl, w, torch.zeros_like(w))
    wsum = wi.sum(0)
    depth = torch.where(wsum > 0, (wi * torch.nan_to_num(t)).sum(0) / wsum.clamp_min(1e-30),
                        torch.full_like(med, float("nan")))
    n_meas = torch.stack(measured).sum(0)
    n_inl = inl.sum(0)
    conf = torch.where(n_meas > 0, n_inl.to(dtype) / n_meas.clamp_min(1).to(dtype), torch.zeros_like(med))
    nearest = None
    if len(firsts) == len(ts) and len(ts) >= 2:
        t1 = torch.stack(firsts)
        # ranges within the spots' scatter of the depth are the depth (not a surface in front of it)
        dev = (t - depth).abs()
        dev = dev[torch.isfinite(dev)]
        if dev.numel():
            tol = SCATTER_FACTOR * float(torch.quantile(dev[:: max(1, dev.numel() // 100_000)], 0.9))
            t1 = torch.where(t1 >= depth - tol, depth.expand_as(t1), t1)
        second = torch.kthvalue(torch.where(torch.isfinite(t1), t1, torch.full_like(t1, float("inf"))), 2, dim=0).values
        nearest = torch.where(torch.isfinite(depth), torch.fmin(second, depth), depth).to(torch.float32).cpu().numpy()
    return VisibleDepth(depth=depth.to(torch.float32).cpu().numpy(), confidence=conf.to(torch.float32).cpu().numpy(),
                        count=torch.isfinite(t).sum(0).cpu().numpy(),
                        per_spot=t.to(torch.float32).cpu().numpy() if keep_per_spot else None, nearest=nearest)


def visible_points(meas, depth=None, min_confidence: float = 0.0) -> np.ndarray:
    """World points (N, 3) of pixels with a finite fused depth (and confidence >= min_confidence)."""
    depth = meas.visible_depth if depth is None else depth
    if depth is None:
        raise MeasurementsError("measurements carry no visible depth; run preprocess with compute_visible_depth")
    d = meas.pixel_directions()
    o = np.broadcast_to(meas.sensor_origin, d.shape)
    ok = np.isfinite(depth)
    if meas.visible_confidence is not None:
        ok &= meas.visible_confidence >= min_confidence
    return (o[ok] + d[ok] * depth[ok, None]).astype(np.float64)
