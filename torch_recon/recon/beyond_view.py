"""Space beside the camera's view that only out-of-view laser spots measure (fast start, `init.initial_grid`).

A laser spot outside the camera's view (`first_bounce.fit_out_of_view_spot` places it) lights the room from
beside the sensor; its secondary segments x -> l cross space the camera never sees. There the start holds the
shadow hull where the segments of at least two such spots cross (`init.in_view`) and completes the rest as
empty. The mesh exporter reports only faces toward known free space, so the hull's faces toward that
completed space were dropped as a cut at the edge of the measured space, and test cameras beside an object
outside the view looked through it (outside-fov: the column's faces toward the sensor).
But where a shadowed segment leaves the hull towards its spot, light from the spot travelled up to the hull:
that is the lit side of the shadow caster, and its faces are reported (`lit_side_of_hull`). And that light
stopped at the first run of hull it met: hull further along the segment, past free space, is not needed by it;
hull beside the view that no shadowed segment needs is emptied from free space inward (`unneeded_beside_view`:
outside-fov's slab of shadow volume over the unseen floor). Measured in docs/reconstruction.md ("Beside the view").
"""

from __future__ import annotations

import numpy as np
import torch

from .data import RayData
from .fields import GridBox, dilate_cube
from .segment_crossings import marching_cells, pair_segments


def _camera_basis(data: RayData):
    """Forward, right, up unit vectors and the half extents (tan) of the pinhole image, from the pixel rays."""
    d = data.pixel_dirs.double().reshape(data.height, data.width, 3)
    h, w = data.height, data.width
    fwd = d[(h - 1) // 2:h // 2 + 1, (w - 1) // 2:w // 2 + 1].reshape(-1, 3).mean(0)
    fwd = fwd / torch.linalg.vector_norm(fwd)
    right = d[:, -1].mean(0) - d[:, 0].mean(0)
    right = right - (right @ fwd) * fwd
    right = right / torch.linalg.vector_norm(right)
    up = torch.linalg.cross(right, fwd)
    if float((d[0].mean(0) - d[-1].mean(0)) @ up) < 0:     # row 0 at the top
        up = -up
    t = d / (d @ fwd)[..., None]
    # pixel centres span the image minus half a pixel on each side
    half_u = float((t @ right).abs().max()) * w / max(w - 1, 1)
    half_v = float((t @ up).abs().max()) * h / max(h - 1, 1)
    return fwd, right, up, half_u, half_v


def in_camera_view(data: RayData, points: torch.Tensor) -> torch.Tensor:
    """Points (..., 3) in front of the sensor whose ray falls into the image (bool (...))."""
    fwd, right, up, hu, hv = _camera_basis(data)
    q = points.double() - data.sensor_origin.double()
    z = q @ fwd
    zs = torch.where(z > 0, z, torch.ones_like(z))
    return (z > 0) & ((q @ right / zs).abs() <= hu) & ((q @ up / zs).abs() <= hv)


def out_of_view_spots(data: RayData) -> torch.Tensor:
    """Indices (long) of the spots the camera does not see (the laser's direction is known; their position
    comes from the two-bounce times, `first_bounce.fit_out_of_view_spot`)."""
    return torch.nonzero(~in_camera_view(data, data.spot_points)).reshape(-1)


def _shadowed_samples(data: RayData, box: GridBox, flat_hull: torch.Tensor, spots: torch.Tensor, off: float,
                      step: float, chunk_samples: int):
    """Per chunk of the `spots`' shadowed segments, samples ordered from x to the spot: (voxel index (long,
    0 where outside the box), inside the box, inside the hull)."""

    seg = pair_segments(data, data.shadowed & torch.isin(data.pair_spot, spots), off)
    if seg[0].shape[0] == 0:
        return
    for _, flat, keep in marching_cells(box, *seg, step, chunk_samples):
        flat = flat.where(keep, 0.0).long()
        yield flat, keep, keep & flat_hull[flat]


def lit_side_of_hull(data: RayData, box: GridBox, hull: torch.Tensor, spots: torch.Tensor, off: float, step: float,
                     chunk_samples: int = 1 << 20) -> torch.Tensor:
    """Voxels (nx, ny, nz) bool not in `hull` where a shadowed segment of one of the `spots` last passes before it
    enters `hull` on its way from the spot: the light reached them and stopped at the hull, so the hull's
    surface faces them (the lit side of a shadow caster)."""
    out = torch.zeros(int(np.prod(box.shape)), dtype=torch.bool, device=hull.device)
    flat_hull = hull.reshape(-1)
    for flat, keep, inside in _shadowed_samples(data, box, flat_hull, spots, off, step, chunk_samples):
        n = flat.shape[1]
        order = torch.arange(n, device=flat.device).expand_as(flat)
        last = torch.where(inside, order, torch.full_like(order, -1)).amax(1)     # the hull sample nearest the spot
        nxt = (last + 1).clamp(max=n - 1)
        ok = (last >= 0) & (last + 1 < n)
        cell, k = flat.gather(1, nxt[:, None])[:, 0], keep.gather(1, nxt[:, None])[:, 0]
        ok &= k & ~flat_hull[cell]
        out[cell[ok]] = True
    # the face between the hull and that voxel may lie a voxel aside of the sample (diagonal steps)
    return (dilate_cube(out.reshape(box.shape).float(), 1) > 0) & ~hull




def first_blockers(data: RayData, box: GridBox, hull: torch.Tensor, spots: torch.Tensor, off: float, step: float,
                   chunk_samples: int = 1 << 20) -> torch.Tensor:
    """Voxels of `hull` (bool (nx, ny, nz)) in the first run of hull voxels that a shadowed segment of the `spots`
    meets coming from its spot: the light stopped there; hull further along the segment (past free space)
    is not needed by it."""
    out = torch.zeros(int(np.prod(box.shape)), dtype=torch.bool, device=hull.device)
    for flat, keep, inside in _shadowed_samples(data, box, hull.reshape(-1), spots, off, step, chunk_samples):
        order = torch.arange(flat.shape[1], device=flat.device).expand_as(flat)
        last = torch.where(inside, order, torch.full_like(order, -1)).amax(1, keepdim=True)
        gap = torch.where(keep & ~inside & (order < last), order, torch.full_like(order, -1)).amax(1, keepdim=True)
        run = inside & (order > gap) & (order <= last)
        out[flat[run]] = True
    return out.reshape(box.shape)


def unneeded_beside_view(data: RayData, box: GridBox, free: torch.Tensor, hull: torch.Tensor, spots: torch.Tensor,
                         off: float, step: float, depth_voxels: int) -> torch.Tensor:
    """Hull voxels outside the camera's view (bool (nx, ny, nz)) to empty: in no shadowed segment's first run of
    hull from its spot (`first_blockers`), reachable from `free` through such voxels within `depth_voxels`
    (`hull_trim.unneeded_hull`). hull: the occupied voxels of the measured space (in and beside the view)."""
    from .hull_trim import unneeded_hull

    beside = hull & ~in_camera_view(data, box.centres()).to(hull.device)
    if len(spots) == 0 or depth_voxels <= 0 or not bool(beside.any()):
        return torch.zeros_like(free)
    needed = first_blockers(data, box, hull, spots, off, step)
    return unneeded_hull(free, beside, needed.long(), torch.zeros_like(free), depth_voxels)
