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
    return restored & (cluster_sizes(restored) >= min_voxels)


def cluster_sizes(mask: torch.Tensor) -> torch.Tensor:
    """Per voxel (nx, ny, nz) long, the size of its 26-connected cluster in `mask` (0 outside it)."""
    from scipy.ndimage import label as connected

    parts, n = connected(mask.cpu().numpy(), structure=[[[1] * 3] * 3] * 3)
    parts = torch.as_tensor(parts).long()
    size = torch.bincount(parts.reshape(-1), minlength=n + 1)
    size[0] = 0
    return size[parts].to(mask.device)


def shared_blockers(box, picked: torch.Tensor, paths, score: torch.Tensor, min_cluster: int) -> torch.Tensor:
    """Second pass of `voxel_evidence.explain_shadows`: a segment whose pick lies in a cluster of at least
    `min_cluster` restored voxels takes instead, among the first pass's picks on its own path, the one most segments
    picked (ties: the higher ranking). paths: per chunk (flat (R, n) voxel of each sample, cand (R, n) candidates)."""
    n = int(score.numel())
    first = torch.zeros(n, dtype=torch.bool, device=picked.device)
    first[picked] = True
    votes = torch.bincount(picked, minlength=n).float()
    big = cluster_sizes(first.reshape(box.shape)).reshape(-1) >= min_cluster
    rank = votes + score.clamp(min=0) / (float(score.clamp(min=0).max()) + 1.0)
    out, k = [], 0
    for flat, cand in paths:
        own = picked[k:k + flat.shape[0]]
        k += flat.shape[0]
        shared = cand & first[flat]
        sc = torch.where(shared, rank[flat], torch.full_like(rank[flat], -1.0))
        best, j = sc.max(1)
        alt = flat.gather(1, j[:, None]).squeeze(1)
        out.append(torch.where(big[own] & (best >= 0), alt, own))
    return torch.cat(out)


class MeasuredSurfacePoints:
    """Where the sensor measured a surface (the pixels' visible points and the thin parts' points): a shadowed
    segment's blocker ranks by shadowed / lit crossings divided by 1 + (its marching sample's distance to the nearest
    such point) / `scale` (m). A leg the carving took fills only part of its voxels; lit rays graze the rest, and the
    voxel beside the leg, in the leg's own shadow, outranked it (session 17: cave-chair's fins beside its legs, 83
    restored voxels more than 3.2 cm from any true surface); the leg's voxels hold its measured points, the one
    beside it does not. Where nothing was measured near the segment (a hidden part) every candidate is far from them
    alike and the ratio decides."""

    def __init__(self, points: torch.Tensor, scale: float):
        from scipy.spatial import cKDTree

        pts = points[torch.isfinite(points).all(1)].detach().cpu().double().numpy()
        self.tree = cKDTree(pts) if len(pts) else None
        self.scale = float(scale)

    def rank(self, score, cand, origins, dirs, near, far, step):
        """`score` (R, n) of the segments' marching samples (`segment_crossings.marching_cells`' (R, n) of segments
        origins + dirs t, t from `near` to `far` at `step`) divided where `cand` by 1 + distance / scale."""
        if self.tree is None or not bool(cand.any()):
            return score
        from .segment_crossings import marching_midpoints

        k = torch.arange(score.shape[1], device=score.device, dtype=near.dtype)
        _, t = marching_midpoints(near, far, step, k)
        pos = origins[:, None] + dirs[:, None] * t[..., None]
        dist, _ = self.tree.query(pos[cand].detach().cpu().double().numpy())
        dist = torch.as_tensor(dist, dtype=score.dtype, device=score.device)
        return score.masked_scatter(cand, score[cand] / (1.0 + dist / self.scale))
