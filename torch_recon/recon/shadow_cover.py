"""The fewest carved voxels that block every unexplained shadowed segment (`voxel_evidence.explain_shadows`, `fast.explain_pick`
'cover').

Per segment, the carved voxel with the most shadowed and fewest lit crossings (shadow / (lit + 1)) puts a blocker
wherever each segment alone ranks one best. Inside a hollow part (the lamp shade: four 1 cm walls, open top and
bottom, lit through the openings) that is often the interior: its voxels are lit less than the wall voxels, which
lit rays graze from outside, and every segment crossing the shade crosses the interior too (session 13: 203 of
875 restored voxels of thin-structures more than 5 cm from any surface, a cross of lumps and a lid inside the
shade). A blocker is shared: the wall voxel that one segment needs is crossed by the other segments that wall
shadows, while an interior voxel picked for one segment explains few others. So the blockers are chosen together,
greedily: each time the carved voxel crossed by the most still-unblocked segments, divided by (lit crossings + 1)
^ `lit_power`, until every segment is blocked.
"""

from __future__ import annotations

import heapq

import numpy as np
import torch

from .fields import next_to


def greedy_cover(segment: torch.Tensor, voxel: torch.Tensor, lit_count: torch.Tensor, lit_power: float,
                 weight: torch.Tensor | None = None) -> torch.Tensor:
    """Flat voxel indices (sorted) that block every segment: segment / voxel (M,) long are the (segment, carved
    voxel it crosses) pairs (repeats allowed); lit_count (flat) the voxels' lit crossings; weight (flat, > 0) an
    optional multiplier of a voxel's gain. Ties go to the lower flat index (deterministic)."""
    if segment.numel() == 0:
        return torch.zeros(0, dtype=torch.long, device=voxel.device)
    n = int(lit_count.numel())
    key = torch.unique(segment.long() * n + voxel.long()).cpu().numpy()
    seg, vox = key // n, key % n
    vids, vinv = np.unique(vox, return_inverse=True)
    order = np.argsort(vinv, kind="stable")
    starts = np.searchsorted(vinv[order], np.arange(len(vids) + 1))
    segs_of = seg[order]
    factor = (lit_count.detach().cpu().double().numpy()[vids] + 1.0) ** -float(lit_power)
    if weight is not None:
        factor = factor * weight.detach().cpu().double().numpy()[vids]
    _, seg_id = np.unique(segs_of, return_inverse=True)
    covered = np.zeros(int(seg_id.max()) + 1, dtype=bool)
    heap = [(-(starts[i + 1] - starts[i]) * factor[i], i) for i in range(len(vids))]
    heapq.heapify(heap)
    picked, left = [], len(covered)
    while left and heap:
        _, i = heapq.heappop(heap)
        mine = seg_id[starts[i]:starts[i + 1]]
        open_ = mine[~covered[mine]]
        gain = len(open_) * factor[i]
        if gain <= 0:
            continue
        if heap and gain < -heap[0][0]:     # gains only fall: re-queue with the current one (lazy greedy)
            heapq.heappush(heap, (-gain, i))
            continue
        picked.append(vids[i])
        covered[open_] = True
        left -= len(open_)
    return torch.as_tensor(np.sort(np.asarray(picked, dtype=np.int64)), device=voxel.device)


def best_near_cover(segment: torch.Tensor, voxel: torch.Tensor, score: torch.Tensor, cover: torch.Tensor,
                    shape) -> torch.Tensor:
    """Flat voxel indices (unique): each segment's best-scored candidate among those at or next to (6-neighbours) a
    voxel of the shared cover (`greedy_cover`): the blocker stays the segment's own, on the part the cover found."""
    near = torch.zeros(int(score.numel()), dtype=torch.bool, device=voxel.device)
    near[cover] = True
    near = (near.reshape(shape) | next_to(near.reshape(shape))).reshape(-1)     # the cover and its 6-neighbours
    ok = near[voxel]
    seg, vox = segment[ok].long(), voxel[ok].long()
    sc = score[vox].double()
    best = torch.full((int(segment.max()) + 1,), -1.0, dtype=torch.float64, device=voxel.device)
    best.scatter_reduce_(0, seg, sc, reduce="amax")
    win = sc >= best[seg]
    # ties: the lowest flat index per segment
    first = torch.full_like(best, float(score.numel()))
    first.scatter_reduce_(0, seg[win], vox[win].double(), reduce="amin")
    return torch.unique(first[torch.unique(seg)].long())
