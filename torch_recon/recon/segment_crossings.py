"""Voxels crossed by ray segments (the fast start's evidence, its hull trims and the mesh's hull placement).

A segment is marched at fixed steps from `near` to `far`; each marching sample (interval midpoint) falls in one
voxel. Camera rays c -> x and secondary segments x -> l (`pair_segments`) are counted this way.
"""

from __future__ import annotations

import numpy as np
import torch

from .data import RayData, own_ranges
from .fields import GridBox


def marching_cells(box: GridBox, origins, dirs, near, far, step, chunk_samples: int = 1 << 20,
                    core: float = 0.5, positions: bool = False):
    """The voxels of the fixed-step marching samples (interval midpoints, as `marching_intervals`) of each
    segment, chunk by chunk: yields (rays, flat, keep): the segments' indices (R,), the flat x-major voxel
    index of every sample (R, n; float, arbitrary where not counted) and whether it counts (inside the
    box, non-empty interval, within `core` voxel of the voxel centre on every axis). positions: the tuples
    end with the samples' place inside their voxel too, (R, n, 3) in [0, 1) voxels from its low corner.

    Segments are taken longest first so that a chunk pads its rays only to its own longest one, and
    the axes are done one at a time on contiguous arrays: every sample and voxel is the same as with
    one global padding and (R, n, 3) arrays, at about a third of the time."""
    nx, ny, nz = box.shape
    span = (far - near).clamp(min=0)
    n_all = max(1, int(float(span.max()) / step) + 1)
    order = torch.argsort(span, descending=True, stable=True)
    wide = nx * ny * nz >= 1 << 24          # flat index exact in float32 below 2^24
    k_all = torch.arange(n_all, device=near.device, dtype=near.dtype)
    i = 0
    while i < len(order):
        # samples past floor(span / step) + 1 lie beyond the segment's end (t0 >= far): leave them out
        n = min(n_all, int(float(span[order[i]]) / step) + 2)
        rays = order[i:i + max(1, chunk_samples // n)]
        i += len(rays)
        keep, mid = marching_midpoints(near[rays], far[rays], step, k_all[:n])
        o, d = origins[rays], dirs[rays]
        flat, inside = None, []
        for axis, (size, stride) in enumerate(((nx, 1), (ny, ny), (nz, nz))):
            q = d[:, axis, None] * mid           # the sample's coordinate in voxel units
            q = q.add_(o[:, axis, None]).sub_(box.bbox_min[axis]).div_(box.voxel)
            f = torch.floor(q)
            keep &= (f >= 0) & (f < size)
            if core < 0.5:
                keep &= (q - f - 0.5).abs() <= core
            if positions:
                inside.append(q - f)
            if wide:
                f = f.double()
            flat = f if flat is None else flat.mul_(stride).add_(f)
        yield (rays, flat, keep, torch.stack(inside, -1)) if positions else (rays, flat, keep)


def marching_midpoints(near, far, step, k):
    """The marching samples of segments (R,) from `near` to `far` at `step`, sample numbers `k` (n,): whether each
    interval is non-empty (R, n) and its midpoint's distance along the segment (R, n; `marching_cells`' samples)."""
    fr = far[:, None]
    t0 = near[:, None] + k * step
    t1 = torch.minimum(t0 + step, fr)
    t0 = torch.minimum(t0, fr)
    return t1 > t0, 0.5 * (t0 + t1)


def accumulate_crossings(box: GridBox, origins, dirs, near, far, step, counts, chunk_samples=1 << 20, core: float = 0.5):
    """Add 1 to `counts` (flat, x-major) for every marching sample of each segment inside the box whose
    position lies within `core` voxel of the voxel centre on every axis (0.5: anywhere in the voxel;
    smaller: a segment that only clips a corner of a partly filled voxel does not count)."""
    if origins.shape[0] == 0:
        return
    n = counts.numel()
    for _, flat, keep in marching_cells(box, origins, dirs, near, far, step, chunk_samples, core):
        # samples that do not count go to one extra bin (cheaper than selecting the others)
        counts += torch.bincount(flat.masked_fill_(~keep, n).long().reshape(-1), minlength=n + 1)[:n]


def segment_counts(data: RayData, box: GridBox, mask, off, step, core, own_range=None):
    """Per-voxel count of marching samples of the secondary segments x -> l of the pairs in `mask`."""
    counts = torch.zeros(int(np.prod(box.shape)), dtype=torch.long, device=data.pixel_dirs.device)
    accumulate_crossings(box, *pair_segments(data, mask, off, own_range), step, counts, core=core)
    return counts


def pair_segments(data: RayData, mask, off, own_range=None):
    """Secondary segments x -> l of the pairs in `mask` (finite visible depth, longer than 2 `off`):
    origins, unit directions, near, far. own_range: bool (N,), pairs whose x is where their own path puts the
    surface on the pixel ray instead of the pixel's visible point (`data.unexplained_lit`: their light came from
    another surface in the pixel); left out where that range does not exist."""
    pairs = torch.nonzero(mask & torch.isfinite(data.visible_depth[data.pair_pixel]), as_tuple=False).squeeze(1)
    depth = data.visible_depth[data.pair_pixel[pairs]]
    if own_range is not None and bool(own_range[pairs].any()):
        sel = own_range[pairs]
        depth = depth.clone()
        depth[sel] = own_ranges(data, pairs[sel])
        ok = torch.isfinite(depth)
        pairs, depth = pairs[ok], depth[ok]
    px = data.pair_pixel[pairs]
    x = data.sensor_origin + data.pixel_dirs[px] * depth[:, None]
    v = data.spot_points[data.pair_spot[pairs]] - x
    length = torch.linalg.vector_norm(v, dim=-1)
    good = length > 2 * off
    return x[good], v[good] / length[good, None], torch.full_like(length[good], off), length[good] - off



def spot_crossings(data: RayData, box: GridBox, mask, off, step, core=0.5):
    """Per voxel (flat), the number of distinct spots with at least one secondary segment of `mask` crossing it."""
    n = int(np.prod(box.shape))
    spots = torch.zeros(n, dtype=torch.long, device=data.pixel_dirs.device)
    for k in torch.unique(data.pair_spot[mask]).tolist():
        spots += segment_counts(data, box, mask & (data.pair_spot == k), off, step, core) > 0
    return spots

