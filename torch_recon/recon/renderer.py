"""Volume rendering: weights, expected depth, transmittance of a segment.

Quadrature over intervals: alpha_i = 1 - exp(-sigma_i delta_i), T_i = exp(-sum_{j<i} sigma_j delta_j),
w_i = T_i alpha_i, expected depth = sum w_i t_i (t_i the interval midpoint), and the transmittance of
the whole segment exp(-sum sigma_i delta_i). Sums of optical depth instead of products of (1 - alpha)
keep it exact and free of log(0).
"""

from __future__ import annotations

import weakref
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


#: samples per block of the sparse pass: a block whose cells (the box spanned by its first and last sample's
#: cells) hold no occupied voxel is dropped whole; 8 samples = 4 voxels at the default step
SAMPLE_BLOCK = 8


def occupied_ahead(occupancy: torch.Tensor, k: int) -> torch.Tensor:
    """(nx, ny, nz) bool: an occupied voxel lies in the k x k x k voxels from this one towards +x, +y, +z (the
    box of a block whose lowest cell is here and which spans at most k cells per axis: one look-up per block)."""
    out = occupancy.clone()
    for axis in range(3):
        grown = out.clone()
        for shift in range(1, min(k, out.shape[axis])):
            n = out.shape[axis] - shift
            grown.narrow(axis, 0, n).logical_or_(out.narrow(axis, shift, n))
        out = grown
    return out


_last_ahead = (None, -1, 0, None)      # (weak reference to an occupancy grid, its version, k, occupied_ahead)


def _occupied_ahead_of(occupancy: torch.Tensor, k: int) -> torch.Tensor:
    """`occupied_ahead` of the grid the last call was given, built again only for another grid, another k or after
    an in-place change (a model refreshes its occupancy every few dozen steps and renders it a few hundred times)."""
    global _last_ahead
    ref, version, k_last, table = _last_ahead
    if ref is None or ref() is not occupancy or version != occupancy._version or k != k_last:
        table = occupied_ahead(occupancy, k)
        _last_ahead = (weakref.ref(occupancy), occupancy._version, k, table)
    return table


def render_pruned(grid, occupancy, origins, dirs, near, far, step: float, tau_grid=None,
                  stop_tau: float = 12.0) -> RenderOut:
    """March a density grid at a fixed step, evaluating it only in occupied cells (others: sigma = 0).

    Two passes (nerfacc style): a pass without autograd finds the occupied samples and, given
    `tau_grid` (per-voxel optical depth of one step, refreshed with the occupancy), drops the samples
    behind an optical depth of `stop_tau` (transmittance < 1e-5: early ray termination); density,
    optical depth and compositing then run on the packed survivors only. `weights` is returned
    packed (K,) with the per-sample ray index in `RenderOut.ray_index`.

    The first pass looks at blocks of SAMPLE_BLOCK samples before single samples: a sample's cell index
    is monotone along the ray (every float step of its computation is), so the cells of a block's samples
    lie in the box of its first and last sample's cells; a block with no occupied voxel in the k x k x k voxels
    from its box's lowest corner (k: the widest box of the call; `occupied_ahead`) or that lies outside
    [near, far] has no sample to keep. The samples kept are exactly those of testing every sample.
    """
    r = origins.shape[0]
    box = grid.box
    nx, ny, nz = box.shape
    with torch.no_grad():
        near_d = near.detach()
        bn, bf = ray_box(origins.detach(), dirs.detach(), box.bbox_min, box.bbox_max)
        lo = torch.maximum(near_d, bn)
        hi = torch.minimum(far.detach(), bf)
        span = float((hi - near_d).clamp(min=0.0).max()) if r else 0.0
        n = max(1, int(span / step) + 1)
        start = (origins.detach() - box.bbox_min) / box.voxel      # grid coordinates: start + heading * t
        heading = dirs.detach() / box.voxel
        upper = torch.tensor([nx - 1, ny - 1, nz - 1], device=origins.device)

        def cells(origin, direction, tm):
            """The voxel (..., 3) of the samples at t = tm (the dense march's arithmetic, clamped to the box)."""
            return torch.minimum((origin + direction * tm[..., None]).long().clamp_(min=0), upper)

        # blocks (R, n_blocks): t grows along a block, so it meets [near, far] unless it ends before near or
        # starts after far, and its samples' cells lie in the box of its first and last sample's cells
        first = torch.arange(0, n, SAMPLE_BLOCK, device=origins.device, dtype=origins.dtype)
        last = torch.clamp(first + (SAMPLE_BLOCK - 1), max=n - 1)
        t_first = near_d[:, None] + (first + 0.5) * step      # the same grid of t as the grad pass below
        t_last = near_d[:, None] + (last + 0.5) * step
        live = (t_last + 0.5 * step > lo[:, None]) & (t_first - 0.5 * step < hi[:, None])
        if occupancy is not None:
            c0 = cells(start[:, None, :], heading[:, None, :], t_first)
            c1 = cells(start[:, None, :], heading[:, None, :], t_last)
            corner = torch.minimum(c0, c1)
            k = int((torch.maximum(c0, c1) - corner).max()) + 1 if corner.numel() else 1    # 5 at the default step
            ahead = _occupied_ahead_of(occupancy, k).reshape(-1)
            live &= ahead.index_select(0, ((corner[..., 0] * ny + corner[..., 1]) * nz + corner[..., 2]).reshape(-1)
                                       ).reshape(live.shape)
        ray_b, block = torch.nonzero(live, as_tuple=True)      # row-major: by ray, then along it
        k_id = (block[:, None] * SAMPLE_BLOCK + torch.arange(SAMPLE_BLOCK, device=origins.device)).reshape(-1)
        ray_c = ray_b.repeat_interleave(SAMPLE_BLOCK)
        ok = k_id < n
        ray_c, k_id = ray_c[ok], k_id[ok]
        tm = near_d.index_select(0, ray_c) + (k_id.to(origins.dtype) + 0.5) * step
        keep = (tm + 0.5 * step > lo.index_select(0, ray_c)) & (tm - 0.5 * step < hi.index_select(0, ray_c))
        gi = cells(start.index_select(0, ray_c), heading.index_select(0, ray_c), tm)
        flat = (gi[:, 0] * ny + gi[:, 1]) * nz + gi[:, 2]
        if occupancy is not None:
            keep &= occupancy.reshape(-1).index_select(0, flat)
        if tau_grid is not None:
            # the optical depth before each sample, summed along its ray in the (ray, sample) layout of a
            # dense march (the same sums, in the same order, as testing every sample)
            tau_est = torch.where(keep, tau_grid.reshape(-1).index_select(0, flat), torch.zeros((), device=flat.device))
            at = ray_c * n + k_id
            dense = torch.zeros(r * n, dtype=tau_est.dtype, device=tau_est.device).index_copy_(0, at, tau_est)
            before = torch.cumsum(dense.reshape(r, n), 1).reshape(-1).index_select(0, at) - tau_est
            keep &= before < stop_tau
        ray_id, s_id = ray_c[keep], k_id[keep]
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
