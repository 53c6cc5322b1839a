"""Where to evaluate the density along rays: uniform / stratified, importance (coarse -> fine), marching.

Samples are intervals [t0, t1) along a ray (nerfacc style): the point is the interval midpoint and
the interval length is the delta of the quadrature. Rays are (origins (R, 3), unit dirs (R, 3)) with
per-ray near/far (R,).
"""

from __future__ import annotations

import torch

EPS = 1e-9


def ray_box(origins: torch.Tensor, dirs: torch.Tensor, bbox_min: torch.Tensor, bbox_max: torch.Tensor):
    """Entry and exit distances of rays through an axis-aligned box (slab test); exit <= entry: a miss."""
    safe = torch.where(dirs.abs() < EPS, torch.full_like(dirs, EPS), dirs)
    inv = 1.0 / safe
    t0 = (bbox_min - origins) * inv
    t1 = (bbox_max - origins) * inv
    near = torch.minimum(t0, t1).amax(-1).clamp(min=0.0)
    far = torch.maximum(t0, t1).amin(-1)
    return near, far


def uniform_intervals(near: torch.Tensor, far: torch.Tensor, n: int, stratified: bool = False,
                      generator: torch.Generator | None = None):
    """n intervals per ray between near and far: (t0, t1), each (R, n).

    Deterministic: equal cells. Stratified: the cell edges stay, the sample point moves (t is drawn
    uniformly inside each cell and the interval is centred on it, clipped to the cell's neighbours).
    """
    u = torch.linspace(0.0, 1.0, n + 1, device=near.device)
    span = (far - near).clamp(min=0.0)[:, None]
    edges = near[:, None] + span * u
    if not stratified:
        return edges[:, :-1], edges[:, 1:]
    r = torch.rand(edges.shape[0], n, device=near.device, generator=generator)
    t = edges[:, :-1] + (edges[:, 1:] - edges[:, :-1]) * r
    return _intervals_around(t, near, far)


def _intervals_around(t: torch.Tensor, near: torch.Tensor, far: torch.Tensor):
    """Sorted sample positions (R, n) -> intervals whose edges are the midpoints between samples."""
    mids = 0.5 * (t[:, 1:] + t[:, :-1])
    t0 = torch.cat([near[:, None].expand(-1, 1), mids], -1)
    t1 = torch.cat([mids, far[:, None].expand(-1, 1)], -1)
    return t0, t1


def importance_positions(t0: torch.Tensor, t1: torch.Tensor, weights: torch.Tensor, n: int,
                         deterministic: bool = True, generator: torch.Generator | None = None):
    """n positions per ray drawn from the piecewise-constant pdf of `weights` over the intervals (inverse CDF)."""
    w = weights.detach() + 1e-5                      # keep every interval reachable (no zero pdf)
    pdf = w / w.sum(-1, keepdim=True)
    cdf = torch.cat([torch.zeros_like(pdf[:, :1]), torch.cumsum(pdf, -1)], -1).clamp(max=1.0)
    edges = torch.cat([t0[:, :1], t1], -1).detach()
    if deterministic:
        u = torch.linspace(0.0, 1.0, n + 2, device=w.device)[1:-1].expand(w.shape[0], n).contiguous()
    else:
        u = torch.rand(w.shape[0], n, device=w.device, generator=generator)
    idx = torch.searchsorted(cdf, u, right=True).clamp(1, cdf.shape[-1] - 1)
    c_lo, c_hi = cdf.gather(-1, idx - 1), cdf.gather(-1, idx)
    e_lo, e_hi = edges.gather(-1, idx - 1), edges.gather(-1, idx)
    frac = (u - c_lo) / (c_hi - c_lo).clamp(min=1e-12)
    return e_lo + frac * (e_hi - e_lo)


def merged_intervals(t0: torch.Tensor, t1: torch.Tensor, extra: torch.Tensor, near: torch.Tensor,
                     far: torch.Tensor):
    """Coarse sample midpoints plus extra positions, sorted, as intervals (PlatoNeRF's fine pass)."""
    t = torch.sort(torch.cat([0.5 * (t0 + t1), extra], -1), -1).values
    return _intervals_around(t, near, far)


def marching_intervals(near: torch.Tensor, far: torch.Tensor, step: float, max_samples: int | None = None):
    """Fixed-step intervals from near to far (the last one clipped; empty ones have t1 == t0)."""
    span = float((far - near).clamp(min=0.0).max()) if near.numel() else 0.0
    n = max(1, int(span / step) + 1)
    if max_samples is not None:
        n = min(n, max_samples)
    k = torch.arange(n, device=near.device, dtype=near.dtype)
    t0 = near[:, None] + k * step
    t1 = torch.minimum(t0 + step, far[:, None])
    t0 = torch.minimum(t0, far[:, None])
    return t0, t1
