"""Sub-voxel free-space evidence for the fast start (recon/init.py `evidence_grid`).

A ray carves every voxel it crosses, so a part narrower than a voxel (a 2 cm chair leg in a 3.2 cm voxel)
is carved wherever a camera ray or a lit secondary ray passes beside it inside its voxel. The same rays
marched through a grid `factor` times finer leave the leg's own sub-voxels uncarved: a voxel carved on
the coarse grid that keeps an uncarved sub-voxel is only partly free. A shadowed segment that every
coarse voxel lets through but that crosses such an uncarved sub-voxel is blocked there, so its
blocker is put back in that voxel (not in the best-scoring voxel anywhere along the segment).
"""

from __future__ import annotations

import numpy as np
import torch

from .fields import GridBox


def finer_box(box: GridBox, factor: int) -> GridBox:
    """The same box cut `factor` times finer on every axis (sub-voxel (i, j, k) lies in voxel (i, j, k) // factor)."""
    return GridBox.exact(box.bbox_min, box.voxel / factor, tuple(factor * n for n in box.shape))


def pool_any(fine: torch.Tensor, factor: int) -> torch.Tensor:
    """Per coarse voxel (nx, ny, nz): whether any of its factor^3 sub-voxels of `fine` (bool, fine shape) is set."""
    nx, ny, nz = (n // factor for n in fine.shape)
    return fine.reshape(nx, factor, ny, factor, nz, factor).any(5).any(3).any(1)


def upsample(coarse: torch.Tensor, factor: int) -> torch.Tensor:
    """Each coarse voxel's value repeated over its factor^3 sub-voxels (nearest)."""
    return coarse.repeat_interleave(factor, 0).repeat_interleave(factor, 1).repeat_interleave(factor, 2)


def uncarved_subvoxels(box: GridBox, factor: int, camera_rays, lit_segments, step_voxels: float,
                       surface_points=None, accumulate=None) -> torch.Tensor:
    """Sub-voxels (fine shape, bool) no camera ray before its surface margin and no lit segment crosses.

    camera_rays / lit_segments: (origins, dirs, near, far) as marched on the coarse grid (the segment ends
    stay where the coarse pass put them, so a sub-voxel is carved only by what carves its voxel)."""
    fine = finer_box(box, factor)
    n = int(np.prod(fine.shape))
    dev = camera_rays[0].device
    counts = torch.zeros(n, dtype=torch.long, device=dev)
    step = step_voxels * fine.voxel
    for rays in (camera_rays, lit_segments):
        accumulate(fine, *rays, step, counts)
    keep = counts == 0
    if surface_points is not None and len(surface_points):
        idx, inside = fine.cell_index(surface_points)
        flat = (idx[:, 0] * fine.shape[1] + idx[:, 1]) * fine.shape[2] + idx[:, 2]
        keep[flat[inside]] = True
    return keep.reshape(fine.shape)
