"""Shadow hull that no measurement needs: trimmed from the free side (fast start, recon/init.py `initial_grid`).

The start keeps every voxel in the sensor's view that no camera ray and no lit secondary ray crosses
(BF Lidar's shadow hull: every shadowed ray stays blocked). Where no shadowed ray crosses a hull voxel
either, nothing measured needs it: it is a lump that only the rays' coverage left (cave-chair: 469 of the
478 hull-boundary voxels more than 1.5 voxels from any true surface had no shadowed crossing; of the
319 within a voxel of the chair, none). Such voxels are emptied when connected to measured free space
through voxels like them, up to `depth_voxels` deep; the visible-surface band (where the measured depth
places the surface) is never trimmed, so the space behind walls and objects' interiors stay closed.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F


def unneeded_hull(free: torch.Tensor, hull: torch.Tensor, shadow_count: torch.Tensor, surface_band: torch.Tensor,
                  depth_voxels: int) -> torch.Tensor:
    """Hull voxels (bool, (nx, ny, nz)) to empty: in `hull`, crossed by no shadowed ray, outside `surface_band`,
    reachable from `free` in at most `depth_voxels` steps (26-neighbourhood) through such voxels."""
    can = hull & (shadow_count == 0) & ~surface_band
    reach = free.clone()
    for _ in range(max(0, int(depth_voxels))):
        grown = F.max_pool3d(reach[None, None].float(), 3, 1, 1)[0, 0] > 0
        new = grown & can & ~reach
        if not bool(new.any()):
            break
        reach |= new
    return reach & can
