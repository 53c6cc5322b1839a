"""Voxels training leaves alone: the fast model's raw-density gradient masks (out of models.py, session 20).

Each mask comes from its own setting; `masked_gradient` (the hook on the grid's raw density) applies them all:
- measured voxels (`fast.freeze_measured`, `measured_trainable`): what the sensor measured directly;
- frozen voxels (`frozen_voxels`): round the laser spots (`fast.freeze_spot_radius_voxels`) and along the room's
  concave edges (`fast.freeze_plane_edges_voxels`, `plane_edge_voxels`);
- thin parts (`fast.thin_part_training`, `thin_part_mask`): 'frozen' whole, or kept from eroding ('grow').
Adam's step follows the sign of its masked gradient, so a zeroed direction never moves.
"""

from __future__ import annotations

import numpy as np
import torch

from .fields import dilate_cube
from .thin_parts import thin_part_signed_distance, thin_part_voxels


def measured_trainable(model, raw):
    """Voxels (raw layout (1, 1, nz, ny, nx), bool) the optimiser may change, or None (all).

    Frozen with `fast.freeze_measured`: what the sensor measured directly (known free space: seen
    through by the sensor or crossed by a lit secondary ray; and the visible-surface ramp, dilated by
    `fast.freeze_dilate_voxels` so the occupied voxel behind the surface that the marching-cubes
    crossing interpolates to stays too). Left to the shadow loss: the hidden hull, the restored
    blockers and the unmeasured space outside the view. Also the anchor prior's mask (`fast.anchor_weight`)."""
    fc = model.fc
    if not (fc.freeze_measured or fc.anchor_weight > 0):
        return None
    with torch.no_grad():
        ramp = (raw > fc.raw_free + 1e-3) & (raw < fc.raw_occupied - 1e-3)
        r = int(fc.freeze_dilate_voxels)
        if r >= 1:
            ramp = dilate_cube(ramp.float(), r) > 0        # max_pool3d(., 2 r + 1, 1, r)
        free = model.free.permute(2, 1, 0)[None, None].to(raw.device)
        return ~(ramp | free)


def thin_part_mask(model, box):
    """The voxels (raw layout, bool) holding a thin part's point that `fast.thin_part_training` keeps from eroding,
    or None ('free'). A part a voxel wide has no neighbour to prop it up: the camera and lit rays passing it (they
    see past a part under a pixel wide) lower it below the surface in a few dozen steps, and a pole or a leg breaks
    where one voxel of its column goes."""
    fc, points = model.fc, model.thin_points(box)
    if fc.thin_part_training == "free" or points is None:
        return None
    if fc.thin_part_radius_voxels > 0:     # the tube's whole ramp: it holds the part's place
        vox = torch.isfinite(thin_part_signed_distance(model.data, box, fc.thin_part_radius_voxels * box.voxel,
                                                       fc.thin_part_edges, fc.thin_part_centre, points))
    else:
        vox = thin_part_voxels(model.data, box, fc.thin_part_edges, fc.thin_part_centre, points)
    return vox.permute(2, 1, 0)[None, None].to(model.device)


def frozen_voxels(model, box):
    """Flat raw-layout indices of the voxels training leaves at their start value, or None (none): those within
    `fast.freeze_spot_radius_voxels` of a laser spot (every secondary ray of a spot leaves through them: their
    transmittance gradient, summed over all of the spot's pixels, dents the spot's own measured surface, 1-1.5 cm
    at 3 cm voxels, session 18) and those along the room's concave edges (`fast.freeze_plane_edges_voxels`:
    training specked the grid's rounded edge, session 19; the model's cached `room_planes`)."""
    fc, data = model.fc, model.data
    near = torch.zeros(box.shape, dtype=torch.bool)
    if fc.freeze_spot_radius_voxels > 0 and len(data.spot_points):
        near = box.near_points(data.spot_points, fc.freeze_spot_radius_voxels * box.voxel).cpu()
    if fc.freeze_plane_edges_voxels > 0:
        points, normals = model.visible_surface(box)
        near |= plane_edge_voxels(box, model.room_planes(box), points, fc.freeze_plane_edges_voxels * box.voxel,
                                  normals)
    if not near.any():
        return None
    return torch.nonzero(near.permute(2, 1, 0).reshape(-1)).reshape(-1).to(model.device)


#: a measured point is one of a plane's own (an edge's side) within half a voxel of it and with its image normal within
#: this many degrees of the plane's: a curved wall's RANSAC facets (planes 11-30 degrees apart) pass through the wall
#: beyond their own patches, where the wall's normal is another facet's (session 21)
EDGE_SIDE_NORMAL_DEG = 10.0
#: ... and within this many freeze radii of the edge voxel
EDGE_SIDE_REACH = 2.0


def plane_edge_voxels(box, planes: list, points, radius_m: float, normals=None) -> torch.Tensor:
    """bool (nx, ny, nz): voxels whose centre lies within `radius_m` of two non-parallel `planes`
    (`unobserved.Plane`: a concave edge of the room) and of the measured `points` (N, 3): the edge is seen there.
    With `normals` (N, 3, the points' image normals) the edge needs points of each of its two planes within
    radius_m (`EDGE_SIDE_NORMAL_DEG`): without that, the lines where a curved wall's facet planes cross the wall
    counted as edges, and their frozen voxels kept the start field's bumps in a dotted line (curved-wall, s. 21)."""
    from scipy.spatial import cKDTree
    out = torch.zeros(box.shape, dtype=torch.bool)
    if len(planes) < 2 or len(points) == 0:
        return out
    points = np.asarray(points, np.float64)
    c = box.centres().double().cpu().numpy().reshape(-1, 3)
    near = np.stack([np.abs(p.signed_distance(c)) <= radius_m for p in planes])     # (P, V)
    own = []
    if normals is not None:
        cos_side = np.cos(np.radians(EDGE_SIDE_NORMAL_DEG))
        n = np.asarray(normals, np.float64)
        own = [points[(np.abs(p.signed_distance(points)) <= 0.5 * float(box.voxel)) & (n @ p.normal >= cos_side)]
               for p in planes]
    trees = {}

    def within(k, idx, r):      # voxels idx with a point of plane k (k None: any measured point) within r
        pts = points if k is None else own[k]
        if len(pts) == 0:
            return np.zeros(len(idx), bool)
        if k not in trees:
            trees[k] = cKDTree(pts)
        return np.isfinite(trees[k].query(c[idx], distance_upper_bound=r)[0])

    edge = np.zeros(len(c), bool)
    for i in range(len(planes)):
        for j in range(i + 1, len(planes)):
            if abs(float(planes[i].normal @ planes[j].normal)) >= 0.9:
                continue
            idx = np.nonzero(near[i] & near[j] & ~edge)[0]
            if len(idx):
                seen = within(None, idx, radius_m)
                if own:     # each side's own points, EDGE_SIDE_REACH radii (pixel rays meet a far wall 6-12 cm apart)
                    reach = EDGE_SIDE_REACH * radius_m
                    seen &= within(i, idx, reach) & within(j, idx, reach)
                edge[idx[seen]] = True
    return torch.from_numpy(edge.reshape(box.shape))


def masks_gradient(model) -> bool:
    """Whether any mask is set, so the model's grid needs the `masked_gradient` hook."""
    return ((model.trainable is not None and model.fc.freeze_measured) or model.thin_parts is not None
            or model.frozen_voxels is not None)


def masked_gradient(model, g):
    """The raw-density gradient the optimiser sees: zero on frozen measured voxels (`fast.freeze_measured`),
    on the frozen voxels (`frozen_voxels`) and on thin parts (`fast.thin_part_training`: all of it when 'frozen',
    the part pushing them down when 'grow'). The caller's gradient is left alone."""
    caller = g      # copied once, before the first in-place change
    if model.trainable is not None and model.fc.freeze_measured:
        # the mask cast once per mask, not every step (2.8 -> 0.9 ms per step on 128^3 voxels, session 20)
        cast = model._trainable_cast
        if cast is None or cast[0] is not model.trainable or cast[1].dtype != g.dtype or cast[1].device != g.device:
            cast = model._trainable_cast = (model.trainable, model.trainable.to(g.device, g.dtype))
        g = g * cast[1]
    if model.frozen_voxels is not None:
        g = g.clone() if g is caller else g
        g.view(-1).index_fill_(0, model.frozen_voxels.to(g.device), 0.0)
    if model.thin_parts is not None:
        # the same values as g.masked_fill(stop, 0.0), at the thin parts' few voxels instead of the whole grid
        # (4.1 -> 1.4 ms per step on 128^3 voxels, session 17)
        if model._thin_index is None or model._thin_index[0] is not model.thin_parts:
            model._thin_index = (model.thin_parts, torch.nonzero(model.thin_parts.reshape(-1)).reshape(-1))
        idx = model._thin_index[1].to(g.device)
        g = g.clone() if g is caller else g
        flat = g.view(-1)
        if model.fc.thin_part_training == "frozen":
            flat.index_fill_(0, idx, 0.0)
        else:
            vals = flat[idx]
            flat[idx] = torch.where(vals > 0, torch.zeros_like(vals), vals)
    return g
