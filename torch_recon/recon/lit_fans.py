"""The hidden hull's boundary voxels as a share of space the spots' light swept (session 16, issue 11).

Whole-voxel carving takes a voxel that any lit segment crosses and keeps one that the segments, about a voxel
apart, pass beside: the hull's boundary is dented where a segment clips a voxel's corner and bumped where the
light swept between two segments. The light itself is continuous: each spot lights a fan of lines to the
surfaces it reaches, sampled by the pixels. A point is inside spot l's fan when, among the spot's pairs (lit or
shadowed) seen from l, the direction nearest to the point's is a lit pair's (within that pair's own spacing to
its nearest neighbour: beyond, no pixel saw where the line goes) whose surface lies beyond the point (less the
segments' offset). The share of a boundary voxel's sub-points inside no fan is its occupancy, fed to marching
cubes (`fast.mesh_hull_lit_fan`), as session 15's oracle hull did with the true geometry (blob F@2cm 0.709 by
voxel centre -> 0.717 by share).

Only the shrinkable hull (`hull_subvoxel.shrinkable_hull`: no measured surface, thin part, silhouette or shadow's
edge beside it) less its flat patches (`hull_flat`) and the lit-carved, not camera-free voxels next to it change.
A carved voxel's occupancy is capped (`CARVED_MAX`): its sub-points outside every fan are unlit, not object
(organic-occluded, against the true blob: 0.31 of those voxels' sub-points lie in no fan, 0.14 inside the object),
and uncapped they moved faces up to a voxel out (F@2cm 0.808 -> 0.798). A hull voxel keeps at least `HULL_MIN`.
Measured: docs/reconstruction.md "The hidden hull's boundary by the share of the lit fans" (session 16).
"""

from __future__ import annotations

import numpy as np
import torch

#: sub-points per axis of a voxel (4^3 at the centres of its 4 x 4 x 4 sub-cells)
SUBPOINTS = 4
#: a point's direction counts as the nearest pair's within this many times that pair's spacing to its neighbour
FAN_SPACINGS = 1.0
#: a hull voxel's occupancy is at least this: a one-voxel wall the light passes on both sides stays a sheet
#: (without: thin-structures lamp hidden R 0.827 -> 0.764; leaving one-voxel-thick hull out instead cost
#: organic-occluded most of its gain, 0.790 -> 0.784)
HULL_MIN = 0.55
#: a carved voxel's occupancy is at most this (its face moves at most 0.5 / (1 - 0.4) - 0.5 = 0.33 voxel out)
CARVED_MAX = 0.4


def in_lit_fans(spot_points, lit, shadowed, points, spacings: float = FAN_SPACINGS) -> np.ndarray:
    """bool (M,): `points` (M, 3) inside some spot's lit fan. lit, shadowed: segments (origins at the surface,
    unit directions towards the spot, near, far; `hull_subvoxel.carving_segments`), each belonging to the spot its
    far end lies at; the light swept from its spot out to `far` (the surface less the segments' offset)."""
    spots = np.asarray(spot_points, np.float64)
    points = np.asarray(points, np.float64)
    out = np.zeros(len(points), bool)
    if len(points) == 0:
        return out
    from scipy.spatial import cKDTree

    groups, nearest_spot = [], cKDTree(spots)
    for is_lit, (x, d, near, far) in ((True, lit), (False, shadowed)):
        x, d, near, far = (np.asarray(t.detach().cpu(), np.float64) for t in (x, d, near, far))
        spot = nearest_spot.query(x + d * (near + far)[:, None])[1] if len(x) else np.zeros(0, int)   # its far end
        groups.append((spot, -d, np.where(is_lit, far, 0.0), np.full(len(x), is_lit)))
    spot, u, reach, is_lit = (np.concatenate(g) for g in zip(*groups))
    for k in np.unique(spot[is_lit]):
        mine = spot == k
        if mine.sum() < 2:
            continue
        tree = cKDTree(u[mine])
        own = tree.query(u[mine], k=2)[0][:, 1]      # each pair's spacing to its nearest neighbour
        todo = np.nonzero(~out)[0]                   # (a point another fan holds is settled)
        v = points[todo] - spots[k]
        dist = np.linalg.norm(v, axis=1)
        gap, i = tree.query(v / np.maximum(dist, 1e-12)[:, None], distance_upper_bound=spacings * float(own.max()))
        hit = np.isfinite(gap)
        todo, gap, i, dist = todo[hit], gap[hit], i[hit], dist[hit]
        out[todo] = is_lit[mine][i] & (gap <= spacings * own[i]) & (dist < reach[mine][i])
    return out


def sub_points(cells: np.ndarray, bbox_min, voxel: float, n: int = SUBPOINTS) -> np.ndarray:
    """(K * n^3, 3) world points: the centres of the n^3 sub-cells of each voxel (K, 3) of `cells` (indices)."""
    g = (np.arange(n) + 0.5) / n
    sub = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    return ((cells[:, None, :] + sub[None]).reshape(-1, 3)) * voxel + np.asarray(bbox_min, np.float64)


def hull_occupancy(model, inward, flat=None) -> None:
    """Set `inward.occupancy` (mesh_export `InwardSmoothing`): the shrinkable hull's voxels (`inward.movable`) and
    the lit-carved, not camera-free voxels next to them, each with the share of its sub-points inside no lit fan
    (hull ones at least HULL_MIN, carved ones at most CARVED_MAX). flat: optional bool (nx, ny, nz), `hull_flat`'s
    patches, left out with their carved neighbours (their faces move by the light's gap; a carved neighbour raised
    moved dark-room's box +x face back out, hidden R 0.882 -> 0.844)."""
    from .fields import next_to
    from .hull_subvoxel import camera_free, carving_segments

    box = model.grid.box
    free = (model._start_raw <= model.fc.raw_free + 1e-3).cpu()
    kept = torch.zeros(box.shape, dtype=torch.bool) if flat is None else torch.as_tensor(flat)
    hull = torch.as_tensor(inward.movable) & ~kept
    if not bool(hull.any()):
        return
    carved = next_to(hull) & ~next_to(kept) & free & model.evidence.lit_crossed.cpu() & ~camera_free(model, box).cpu()
    cells = np.stack(np.nonzero((hull | carved).numpy()), 1)
    pts = sub_points(cells, box.bbox_min.cpu().numpy(), box.voxel)
    lit = in_lit_fans(model.data.spot_points.cpu().numpy(), carving_segments(model, lit=True),
                      carving_segments(model, lit=False), pts)
    share = 1.0 - lit.reshape(len(cells), -1).mean(1)
    share = np.where(hull.numpy()[tuple(cells.T)], np.maximum(share, HULL_MIN), np.minimum(share, CARVED_MAX))
    inward.occupancy = (cells, share.astype(np.float32))


def with_occupancy(volume: np.ndarray, cells: np.ndarray, share: np.ndarray, movable: np.ndarray) -> np.ndarray:
    """A copy of the mesh field `volume` with voxels `cells` (K, 3) set to `share` (K,) of the way from its free
    value (its minimum) to its occupied one (its maximum), where they are `movable` hull or saturated free."""
    lo, hi = float(volume.min()), float(volume.max())
    if not np.all(np.isfinite(share)):
        raise ValueError("lit-fan occupancy is not finite")
    at = tuple(np.asarray(cells, np.int64).T)
    ok = np.asarray(movable, bool)[at] | (volume[at] <= lo + 1e-4 * max(hi - lo, 1e-12))
    out = volume.copy()
    out[tuple(a[ok] for a in at)] = lo + np.clip(share[ok], 0.0, 1.0) * (hi - lo)
    return out
