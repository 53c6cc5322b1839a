"""NeRF-style point quadrature and hierarchical sampling, as PlatoNeRF's published code does it.

Unlike the interval sampler of the fast mode (sampler.py / renderer.py), samples here are points z_i
along the ray; each carries the gap to the next point and the last one a gap of 1e10, so whatever
transmittance is left at the end of the ray lands on the last sample (nerf-pytorch's convention,
which PlatoNeRF keeps). Written for this project after reading the authors' code; no code copied.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

LAST_GAP = 1e10      # the last sample's gap: it absorbs all remaining transmittance
PDF_FLOOR = 1e-5     # added to the coarse weights before inverting the CDF (every bin reachable)


@dataclass
class PointRender:
    depth: torch.Tensor          # (R,) sum of w_i z_i (no normalisation; the last sample takes the rest)
    opacity: torch.Tensor        # (R,) sum of weights
    transmittance: torch.Tensor  # (R,) exp(-optical depth of all samples but the last two)
    weights: torch.Tensor        # (R, S)
    z: torch.Tensor              # (R, S) sample distances


def stratified_depths(near: torch.Tensor, far: torch.Tensor, n: int, perturb: bool,
                      generator: torch.Generator | None = None) -> torch.Tensor:
    """n distances per ray from near to far (both included); with `perturb` each one is drawn
    uniformly between the midpoints to its neighbours (the first from near, the last up to far)."""
    s = torch.linspace(0.0, 1.0, n, device=near.device)
    z = near[:, None] * (1.0 - s) + far[:, None] * s
    if not perturb:
        return z
    mids = 0.5 * (z[:, 1:] + z[:, :-1])
    lo = torch.cat([z[:, :1], mids], -1)
    hi = torch.cat([mids, z[:, -1:]], -1)
    r = torch.rand(z.shape, device=z.device, generator=generator)
    return lo + (hi - lo) * r


def composite_points(sigma: torch.Tensor, z: torch.Tensor) -> PointRender:
    """alpha_i = 1 - exp(-sigma_i gap_i), w_i = T_i alpha_i with T_i = exp(-sum_{j<i} sigma_j gap_j).

    Optical depths are summed (exclusive cumulative sum) rather than (1 - alpha) multiplied: the same
    values without the authors' +1e-10 guard, and no loss of T to the huge last gap in float32.
    `transmittance` is T at the second-to-last sample, as the authors read the secondary ray's
    visibility (the last two samples sit at the light spot's surface).
    """
    gap = torch.cat([z[:, 1:] - z[:, :-1], torch.full_like(z[:, :1], LAST_GAP)], -1)
    tau = sigma * gap
    before = torch.cat([torch.zeros_like(tau[:, :1]), torch.cumsum(tau[:, :-1], -1)], -1)
    w = torch.exp(-before) * (1.0 - torch.exp(-tau))
    trans = torch.exp(-before[:, -2]) if z.shape[1] >= 2 else torch.ones_like(z[:, 0])
    return PointRender(depth=(w * z).sum(-1), opacity=w.sum(-1), transmittance=trans, weights=w, z=z)


def importance_depths(z: torch.Tensor, weights: torch.Tensor, n: int, perturb: bool,
                      generator: torch.Generator | None = None) -> torch.Tensor:
    """n distances drawn from the coarse weights (inverse CDF), no gradient.

    Bins are the midpoints between the coarse samples, weighted by the inner samples' weights (the
    first and last coarse samples have no bin of their own). Deterministic (evaluation): n evenly
    spaced quantiles including 0 and 1.
    """
    with torch.no_grad():
        bins = 0.5 * (z[:, 1:] + z[:, :-1])                      # (R, S-1)
        w = weights[:, 1:-1] + PDF_FLOOR                          # (R, S-2)
        pdf = w / w.sum(-1, keepdim=True)
        cdf = torch.cat([torch.zeros_like(pdf[:, :1]), torch.cumsum(pdf, -1)], -1)  # (R, S-1)
        if perturb:
            u = torch.rand(z.shape[0], n, device=z.device, generator=generator)
        else:
            u = torch.linspace(0.0, 1.0, n, device=z.device).expand(z.shape[0], n).contiguous()
        hi = torch.searchsorted(cdf, u, right=True)
        lo = (hi - 1).clamp(min=0)
        hi = hi.clamp(max=cdf.shape[-1] - 1)
        c_lo, c_hi = cdf.gather(-1, lo), cdf.gather(-1, hi)
        b_lo, b_hi = bins.gather(-1, lo), bins.gather(-1, hi)
        span = c_hi - c_lo
        span = torch.where(span < PDF_FLOOR, torch.ones_like(span), span)
        return b_lo + (u - c_lo) / span * (b_hi - b_lo)


def render_hierarchical(coarse_field, fine_field, origins, dirs, near, far, n_coarse: int, n_fine: int,
                        perturb: bool, generator: torch.Generator | None = None):
    """(fine, coarse) PointRender: n_coarse stratified samples through the coarse field, then the
    fine field on those samples plus n_fine drawn from the coarse weights, sorted."""
    z = stratified_depths(near, far, n_coarse, perturb, generator)
    coarse = composite_points(coarse_field(origins[:, None] + dirs[:, None] * z[..., None]), z)
    extra = importance_depths(z, coarse.weights, n_fine, perturb, generator)
    zf = torch.sort(torch.cat([z, extra], -1), -1).values
    fine = composite_points(fine_field(origins[:, None] + dirs[:, None] * zf[..., None]), zf)
    return fine, coarse
