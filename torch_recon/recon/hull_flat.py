"""Flat faces of the hidden hull: the outer voxel layer's centre, not its outer side (session 14, issue 11).

A flat object face that no lit segment runs along (dark-room's box +x face: the spots' light reaches it head-on or
not at all, and the sensor does not see it) is bounded only by whole voxels: the hull keeps the voxel layer the
face lies in, and marching cubes puts the face at that layer's outer side, 0 to 1 voxel outside the true plane
(dark-room: 0.75 voxel, 2.4 cm, recall@2cm of that face 0.62). The inward smoothing (`fast.mesh_hull_shrink_voxels`)
cuts staircases but leaves flat runs, so the vertices of large coplanar patches of the shrinkable hull move inward
along their normal by `fast.mesh_hull_flat_centre_voxels` first. Small patches are the staircases of curved or
oblique hulls, whose faces grazing light erodes (organic-occluded's blob: its true surface lies in the carved
voxel beyond the face more often than not): they are left to the smoothing.
"""

from __future__ import annotations

import numpy as np


def flat_patch_voxels(hull, free, min_faces: int) -> np.ndarray:
    """(nx, ny, nz) bool: `hull` voxels with a face towards a `free` 6-neighbour that belongs to a patch of at least
    `min_faces` such faces in one plane (same direction, same layer, joined across edges in the plane)."""
    from scipy.ndimage import label
    hull, free = np.asarray(hull, bool), np.asarray(free, bool)
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
