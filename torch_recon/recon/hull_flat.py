"""Flat faces of the hidden hull: inside their outer voxel layer, not at its outer side (sessions 14-15, issue 11).

A flat object face that no lit segment runs along (dark-room's box +x face: the spots' light reaches it head-on or
not at all, and the sensor does not see it) is bounded only by whole voxels: the hull keeps the voxel layer the
face lies in, and marching cubes puts the face at that layer's outer side, 0 to 1 voxel outside the true plane
(dark-room: 0.75 voxel, 2.4 cm, recall@2cm of that face 0.62). The inward smoothing (`fast.mesh_hull_shrink_voxels`)
cuts staircases but leaves flat runs, so the vertices of large coplanar patches of the shrinkable hull move inward
along their normal first. Small patches are the staircases of curved or oblique hulls, whose faces grazing light
erodes (organic-occluded's blob: its true surface lies in the carved voxel beyond the face more often than not):
they are left to the smoothing.

`fast.mesh_hull_flat_approach` (session 15) moves them by what the light says (session 14's fixed quarter voxel
moved outside-fov's eroded column face beyond 2 cm; removed in session 15): the lit segments came within d voxel of the face in the carved voxel beyond it (`light_approach`), so the object's plane lies
between that nearest approach and the hull layer's inner side; the face goes to that gap's middle, (1 - d) / 2 voxel
in (`flat_face_offsets`). An eroded face (the light passed close: outside-fov's column) barely moves; one no light
came near (dark-room's box +x) goes to its layer's centre.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from .fields import GridBox, dilate_cube
from .sampler import ray_box
from .segment_crossings import marching_cells

#: the lit segments are marched this finely (voxels) near the flat faces: each approach is known to half of it
APPROACH_STEP_VOXELS = 0.1


def flat_patch_voxels(hull, free, min_faces: int) -> np.ndarray:
    """(nx, ny, nz) bool: `hull` voxels with a face towards a `free` 6-neighbour that belongs to a patch of at least
    `min_faces` such faces in one plane (same direction, same layer, joined across edges in the plane)."""
    hull, free = np.asarray(hull, bool), np.asarray(free, bool)
    out = np.zeros(hull.shape, bool)
    if not hull.any():
        return out
    at = np.nonzero(hull)       # labelled on the hull's bounding box and one voxel around (the free neighbours)
    box = tuple(slice(max(int(a.min()) - 1, 0), int(a.max()) + 2) for a in at)
    out[box] = _flat_patch_voxels(hull[box], free[box], min_faces)
    return out


def _flat_patch_voxels(hull, free, min_faces: int) -> np.ndarray:
    from scipy.ndimage import label
    out = np.zeros(hull.shape, bool)
    for axis in range(3):
        # in-plane 4-connectivity: neighbours along the two other axes
        st = np.zeros((3, 3, 3), bool)
        st[1, 1, 1] = True
        for other in range(3):
            if other != axis:
                for t in (0, 2):
                    idx = [1, 1, 1]
                    idx[other] = t
                    st[tuple(idx)] = True
        for shift in (-1, 1):
            beyond = np.zeros_like(free)     # beyond[v] = free[v + shift along axis]
            dst, src = [slice(None)] * 3, [slice(None)] * 3
            dst[axis], src[axis] = (slice(0, -1), slice(1, None)) if shift > 0 else (slice(1, None), slice(0, -1))
            beyond[tuple(dst)] = free[tuple(src)]
            faces = hull & beyond
            lab, _ = label(faces, structure=st)
            size = np.bincount(lab.ravel())
            size[0] = 0
            out |= size[lab] >= min_faces
    return out


def light_approach(box, origins, dirs, near, far, cells, chunk_samples: int = 1 << 20) -> torch.Tensor:
    """(M, 6) float for the M voxels of `cells` (bool (nx, ny, nz); x-major order, as `torch.nonzero`): the segments'
    nearest approach (voxels, of their marching samples inside the voxel, every APPROACH_STEP_VOXELS) to each of
    its faces (-x, +x, -y, +y, -z, +z); inf where no sample falls in it. Only the segments' stretch through the
    cells' bounding box is marched, at one-voxel steps first: every stretch of a segment inside a cell belongs to
    an interval whose midpoint lies in the cell or a 26-neighbour, and only those intervals are marched finely."""
    nx, ny, nz = box.shape
    cells = cells.to(origins.device)
    m = int(cells.sum())
    best = torch.full((m, 6), float("inf"), device=origins.device)
    if m == 0 or origins.shape[0] == 0:
        return best
    where = torch.nonzero(cells)
    lo = box.bbox_min + (where.amin(0) - 1).to(box.bbox_min.dtype) * box.voxel
    hi = box.bbox_min + (where.amax(0) + 2).to(box.bbox_min.dtype) * box.voxel
    enter, leave = ray_box(origins, dirs, lo, hi)
    near, far = torch.maximum(near, enter), torch.minimum(far, leave)
    seg = torch.nonzero(far > near).squeeze(1)
    origins, dirs, near, far = origins[seg], dirs[seg], near[seg], far[seg]
    index = torch.full((nx * ny * nz,), -1, dtype=torch.long, device=origins.device)
    index[cells.reshape(-1)] = torch.arange(m, device=origins.device)
    # the coarse midpoints may lie up to half a voxel outside the grid: marched on the grid with one voxel around
    around = dilate_cube(F.pad(cells.float(), (1,) * 6), 1).reshape(-1) > 0
    wide = GridBox.exact(box.bbox_min - box.voxel, box.voxel, [nx + 2, ny + 2, nz + 2])
    coarse, fine = box.voxel, APPROACH_STEP_VOXELS * box.voxel
    for rays, flat, keep in marching_cells(wide, origins, dirs, near, far, coarse, chunk_samples):
        r, k = torch.nonzero(keep & around[flat.where(keep, 0).long()], as_tuple=True)
        if r.numel() == 0:
            continue
        seg = rays[r]
        t0 = near[seg] + k.to(near.dtype) * coarse
        for _, flat2, keep2, pos in marching_cells(box, origins[seg], dirs[seg], t0, torch.minimum(t0 + coarse, far[seg]),
                                                   fine, chunk_samples, positions=True):
            j = index[flat2.where(keep2, 0).long()]
            ok = keep2 & (j >= 0)
            p = pos[ok]
            dist = torch.stack([p[:, 0], 1 - p[:, 0], p[:, 1], 1 - p[:, 1], p[:, 2], 1 - p[:, 2]], 1)
            best.scatter_reduce_(0, j[ok][:, None].expand(-1, 6), dist, reduce="amin")
    return best


def flat_face_offsets(flat, free, cells, approach, voxel: float) -> np.ndarray:
    """(nx, ny, nz, 6) float32 (m): for each face (-x, +x, -y, +y, -z, +z) of a `flat` voxel towards a `free`
    6-neighbour among `cells` (bool, whose `approach` (M, 6) voxels `light_approach` gives), how far that face's mesh
    vertices move inward: to the middle between the light's nearest approach d (the neighbour's, to its face
    towards this voxel) and the flat voxel's inner side, (1 - d) / 2 voxel; 0 where no light reached the neighbour
    (d > 1) and on every other face."""
    flat, free, cells = np.asarray(flat, bool), np.asarray(free, bool), np.asarray(cells, bool)
    d = np.asarray(approach, np.float64)
    shape = np.array(flat.shape)
    cell_flat = np.ravel_multi_index(np.nonzero(cells), flat.shape)      # sorted: `approach`'s row order
    out = np.zeros(flat.shape + (6,), np.float32)
    at = np.stack(np.nonzero(flat), 1)
    for axis in range(3):
        for side in (0, 1):     # the -axis (0) or +axis (1) face of the flat voxel
            nb = at.copy()
            nb[:, axis] += 2 * side - 1
            ok = np.all((nb >= 0) & (nb < shape), 1)
            v, nb = at[ok], nb[ok]
            ok = free[tuple(nb.T)] & cells[tuple(nb.T)]
            v, nb = v[ok], nb[ok]
            row = np.searchsorted(cell_flat, np.ravel_multi_index(tuple(nb.T), flat.shape))
            gap = d[row, 2 * axis + 1 - side]      # the neighbour's face towards this voxel
            ok = gap <= 1.0
            out[tuple(v[ok].T) + (2 * axis + side,)] = 0.5 * (1.0 - gap[ok]) * voxel
    return out


def flat_patches_inward(model, inward) -> np.ndarray:
    """Set how far the faces of the flat patches of a fast model's `mesh_export.InwardSmoothing` `inward` (its
    `movable` hull) first move (`face_offsets_m`; `fast.mesh_hull_flat_approach`: the light's gap, marched on the
    start field's lit segments). Returns the flat patches' voxels (bool (nx, ny, nz))."""
    from .hull_subvoxel import carving_segments

    fc, box = model.fc, model.grid.box
    free = (model._start_raw <= fc.raw_free + 1e-3).cpu().numpy()
    flat = flat_patch_voxels(inward.movable, free, fc.mesh_hull_flat_patch_faces)
    if not flat.any():        # (cave-chair: its hull's faces are small or beside the light)
        return flat
    cells = (dilate_cube(torch.as_tensor(flat).float(), 1) > 0) & torch.as_tensor(free)
    approach = light_approach(box, *carving_segments(model, lit=True), cells.to(box.bbox_min.device))
    inward.face_offsets_m = flat_face_offsets(flat, free, cells.numpy(), approach.cpu().numpy(), box.voxel)
    return flat
