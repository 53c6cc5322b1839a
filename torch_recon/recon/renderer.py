"""Volume rendering: weights, expected depth, transmittance of a segment.

Quadrature over intervals: alpha_i = 1 - exp(-sigma_i delta_i), T_i = exp(-sum_{j<i} sigma_j delta_j),
w_i = T_i alpha_i, expected depth = sum w_i t_i (t_i the interval midpoint), and the transmittance of
the whole segment exp(-sum sigma_i delta_i). Sums of optical depth instead of products of (1 - alpha)
keep it exact and free of log(0).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .sampler import ray_box



@dataclass
class RenderOut:
    weights: torch.Tensor       # (R, S)
    depth: torch.Tensor         # (R,) expected termination distance (no background term)
    opacity: torch.Tensor       # (R,) sum of weights = 1 - transmittance
    transmittance: torch.Tensor  # (R,) exp(-optical depth of the whole segment)


def composite(sigma: torch.Tensor, t0: torch.Tensor, t1: torch.Tensor) -> RenderOut:
    delta = (t1 - t0).clamp(min=0.0)
    tau = sigma.clamp(min=0.0) * delta
    cum = torch.cumsum(tau, -1)
    trans_before = torch.exp(-(cum - tau))
    alpha = 1.0 - torch.exp(-tau)
    w = trans_before * alpha
    depth = (w * 0.5 * (t0 + t1)).sum(-1)
    total = cum[:, -1] if cum.shape[-1] else sigma.new_zeros(sigma.shape[0])
    return RenderOut(weights=w, depth=depth, opacity=w.sum(-1), transmittance=torch.exp(-total))


def sample_points(origins, dirs, t0, t1):
    return origins[:, None, :] + dirs[:, None, :] * (0.5 * (t0 + t1))[..., None]


def render_field(field, origins, dirs, t0, t1) -> RenderOut:
    """Evaluate `field` at every interval midpoint and composite."""
    pts = sample_points(origins, dirs, t0, t1)
    return composite(field(pts), t0, t1)


def render_pruned(grid, occupancy, origins, dirs, near, far, step: float, tau_grid=None,
                  stop_tau: float = 12.0) -> RenderOut:
    """March a density grid at a fixed step, evaluating it only in occupied cells (others: sigma = 0).

    Two passes (nerfacc style): a pass without autograd finds the occupied samples and, given
    `tau_grid` (per-voxel optical depth of one step, refreshed with the occupancy), drops the samples
    behind an optical depth of `stop_tau` (transmittance < 1e-5: early ray termination); density,
    optical depth and compositing then run on the packed survivors only. `weights` is returned
    packed (K,) with the per-sample ray index in `RenderOut.ray_index`.
    """
    r = origins.shape[0]
    box = grid.box
    nx, ny, nz = box.shape
    with torch.no_grad():
        bn, bf = ray_box(origins.detach(), dirs.detach(), box.bbox_min, box.bbox_max)
        lo = torch.maximum(near.detach(), bn)
        hi = torch.minimum(far.detach(), bf)
        span = float((hi - near.detach()).clamp(min=0.0).max()) if r else 0.0
        n = max(1, int(span / step) + 1)
        k = torch.arange(n, device=origins.device, dtype=origins.dtype)
        tm = near.detach()[:, None] + (k + 0.5) * step       # the same grid of t as the grad pass below
        keep = (tm + 0.5 * step > lo[:, None]) & (tm - 0.5 * step < hi[:, None])
        g = ((origins.detach() - box.bbox_min) / box.voxel)[:, None, :] \
            + (dirs.detach() / box.voxel)[:, None, :] * tm[..., None]
        gi = g.long()
        gi = torch.minimum(gi.clamp_(min=0), torch.tensor([nx - 1, ny - 1, nz - 1], device=g.device))
        flat = (gi[..., 0] * ny + gi[..., 1]) * nz + gi[..., 2]
        if occupancy is not None:
            keep &= occupancy.reshape(-1)[flat]
        if tau_grid is not None:
            tau_est = torch.where(keep, tau_grid.reshape(-1)[flat], torch.zeros((), device=g.device))
            keep &= (torch.cumsum(tau_est, 1) - tau_est) < stop_tau
        ray_id, s_id = torch.nonzero(keep, as_tuple=True)
    t0 = near[ray_id] + s_id.to(near.dtype) * step
    t1 = torch.minimum(t0 + step, far[ray_id])
    tmid = 0.5 * (t0 + t1)
    pts = origins[ray_id] + dirs[ray_id] * tmid[:, None]
    tau = grid(pts) * (t1 - t0).clamp(min=0.0)
    return composite_packed(tau, tmid, ray_id, r)


def composite_packed(tau: torch.Tensor, tmid: torch.Tensor, ray_id: torch.Tensor, n_rays: int) -> RenderOut:
    """Compositing over packed samples sorted by ray (tau = sigma * delta per sample)."""
    cs = torch.cumsum(tau.double(), 0)
    counts = torch.bincount(ray_id, minlength=n_rays)
    starts = torch.cumsum(counts, 0) - counts
    excl = cs - tau.double()
    before = (excl - excl[starts[ray_id]]).float() if ray_id.numel() else tau
    w = torch.exp(-before) * (1.0 - torch.exp(-tau))
    zeros = tau.new_zeros(n_rays)
    depth = zeros.index_add(0, ray_id, w * tmid)
    opacity = zeros.index_add(0, ray_id, w)
    total = zeros.index_add(0, ray_id, tau)
    out = RenderOut(weights=w, depth=depth, opacity=opacity, transmittance=torch.exp(-total))
    out.ray_index = ray_id
    return out


def secondary_rays(x: torch.Tensor, l: torch.Tensor, offset: float):
    """Secondary rays x -> l: origins, unit directions, near, far and a mask of non-degenerate ones.

    A segment shorter than twice `offset` (the spot lies on the pixel's own surface, or x == l) has
    nothing to occlude it: near = far, so its transmittance is exactly 1.
    """
    v = l - x
    length = torch.linalg.vector_norm(v, dim=-1)
    ok = length > 2.0 * offset + 1e-6
    dirs = v / length.clamp(min=1e-6)[:, None]
    near = torch.full_like(length, offset)
    far = torch.where(ok, length - offset, near)
    return x, dirs, near, far, ok, length
