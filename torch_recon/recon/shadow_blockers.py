"""Which carved voxel a shadowed segment gets back (`voxel_evidence.explain_shadows`): one next to what stayed occupied.

A shadowed segment whose voxels were all lit-carved crosses a part the carving took (a 1 cm lamp-shade wall
or a chair leg grazed by lit rays inside its 3.2 cm voxel). The part's carved voxels touch what stayed of it
(its uncarved voxels, a part under a pixel wide, a seen face); the lit inside of a hollow part (light enters
the lamp shade through its open top and bottom) touches nothing, and the shadowed / lit crossing ratio alone
put blockers there (session 12: a cross of lumps and a lid inside the shade, 5-15 cm from any surface).
"""

from __future__ import annotations

import torch

#: evidence labels (`voxel_evidence.evidence_grid`) that are free space: 2 seen through by the sensor, 3 lit-carved
FREE_LABELS = (2, 3)


def occupied_neighbours(label: torch.Tensor) -> torch.Tensor:
    """Per voxel (nx, ny, nz) float, how many of its 26 neighbours are not free space (outside the box: free)."""
    solid = torch.ones_like(label, dtype=torch.float32)
    for v in FREE_LABELS:
        solid = solid.masked_fill(label == v, 0.0)
    cube = torch.nn.functional.avg_pool3d(solid[None, None], 3, 1, 1, count_include_pad=True)[0, 0] * 27.0
    return (cube - solid).round()


def blocker_weight(label: torch.Tensor, power: float) -> torch.Tensor | None:
    """Flat multiplier of a restorable voxel's ranking: (1 + occupied 26-neighbours) ^ `power`; None for 0."""
    if power <= 0:
        return None
    return (1.0 + occupied_neighbours(label)).pow(power).reshape(-1)


def restored_runs(restored: torch.Tensor, min_voxels: int) -> torch.Tensor:
    """The restored blockers (nx, ny, nz bool) in a connected run (26-neighbours) of at least `min_voxels`: a part's
    column the shadows put back, not a lone voxel (a speck the mesh's island cleanup should still drop)."""
    from scipy.ndimage import label as connected

    parts, n = connected(restored.cpu().numpy(), structure=[[[1] * 3] * 3] * 3)
    if n == 0:
        return torch.zeros_like(restored)
    size = torch.bincount(torch.as_tensor(parts).reshape(-1), minlength=n + 1)
    size[0] = 0
    return (size[torch.as_tensor(parts).long()] >= min_voxels).to(restored.device)
