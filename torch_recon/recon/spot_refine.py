"""Local refinement of advised laser spots (recon/spot_advice.py; session 14, issue 11).

The greedy choice picks each spot from spread-out candidates about 0.4 m apart (300 on a room's walls), so
the spot that grazes a table from just under its plane is rarely among them (session 13: one spot moved 5 cm
lifted thin-structures' table coverage from 0.44 to 0.81). Refinement moves each chosen spot to the best of
the sensor-visible points near it, scored by the same objective as the greedy choice given all other spots
(the expected hull voxels the whole capture covers), a spot at a time in choice order, repeated while a
sweep still moves one (hill climbing: a spot may travel further than one radius). Deterministic: the points
near a spot are thinned by `select_diverse_spots` with the advisor's seeded generator.
"""

from __future__ import annotations

import torch

from ..contract.spots import select_diverse_spots

#: at most this many nearby points are scored per spot and sweep (spread-out ones when more lie near)
NEARBY_POINTS = 24
#: sweeps over the chosen spots at most (each stops early when no spot moved)
SWEEPS = 3


def covered_total(existing: torch.Tensor, values: list) -> float:
    """The objective: expected hull voxels covered by the existing spots and `values` (per spot, per voxel)."""
    cov = existing
    for v in values:
        cov = torch.maximum(cov, v)
    return float(cov.sum())


def refine_spots(spot_idx: list, values: list, existing: torch.Tensor, points: torch.Tensor, usable,
                 values_of, radius_m: float, rng) -> tuple[list, list, int]:
    """Move each chosen spot (an index into `points` (P, 3), the sensor-visible points; None: a spot beyond
    the view, kept) to the best of the usable points within `radius_m`, given the others' values.
    usable(indices) -> bool mask (the laser reaches them, their paths fit the sensor's range);
    values_of(indices) -> (N, n_hull) values. Returns (indices, values, spots moved)."""
    idx, vals = list(spot_idx), list(values)
    moved = set()
    for _ in range(SWEEPS):
        changed = False
        for i, centre in enumerate(idx):
            if centre is None:
                continue
            others = existing
            for j, v in enumerate(vals):
                if j != i:
                    others = torch.maximum(others, v)
            near = torch.nonzero(torch.linalg.vector_norm(points - points[centre], dim=1) <= radius_m).squeeze(1)
            near = near[near != centre]
            if len(near) == 0:
                continue
            near = near[usable(near)]
            if len(near) > NEARBY_POINTS:   # spread-out ones, seeded (the one diversity rule)
                keep = select_diverse_spots(points[near].cpu().numpy(), None, NEARBY_POINTS, rng)
                near = near[torch.as_tensor(keep, device=near.device)]
            if len(near) == 0:
                continue
            cand = values_of(near)
            score = torch.maximum(cand, others).sum(1)
            best = int(torch.argmax(score))
            # a strict, relative margin: ties and float noise never move a spot
            if float(score[best]) > float(torch.maximum(vals[i], others).sum()) * (1 + 1e-6) + 1e-6:
                idx[i], vals[i] = int(near[best]), cand[best]
                moved.add(i)
                changed = True
        if not changed:
            break
    return idx, vals, len(moved)
