"""Shadow hull that no measurement needs: trimmed from the free side (fast start, recon/init.py `initial_grid`).

The start keeps every voxel in the sensor's view that no camera ray and no lit secondary ray crosses
(BF Lidar's shadow hull: every shadowed ray stays blocked). Where no shadowed ray crosses a hull voxel
either, nothing measured needs it: it is a lump that only the rays' coverage left (cave-chair: 469 of the
478 hull-boundary voxels more than 1.5 voxels from any true surface had no shadowed crossing; of the
319 within a voxel of the chair, none). Such voxels are emptied when connected to measured free space
through voxels like them, up to `depth_voxels` deep; the visible-surface band (where the measured depth
places the surface) is never trimmed, so the space behind walls and objects' interiors stay closed.

A prior for the hull that shadowed rays do cross but no measurement bounds (opt-in, `init._hull_prior`):
a part's hull outside the convex closure of the voxels a measured surface or a shadow's edge places
(`outside_convex_closure`, `sole_blockers`), or thinner than a ball (`opening`), is emptied while every
shadowed segment stays blocked (`keep_blocked`). Measured in docs/reconstruction.md ("A prior for the space
no measurement bounds").
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from .segment_crossings import marching_cells
from .fields import dilate_cube


def unneeded_hull(free: torch.Tensor, hull: torch.Tensor, shadow_count: torch.Tensor, surface_band: torch.Tensor,
                  depth_voxels: int) -> torch.Tensor:
    """Hull voxels (bool, (nx, ny, nz)) to empty: in `hull`, crossed by no shadowed ray, outside `surface_band`,
    reachable from `free` in at most `depth_voxels` steps (26-neighbourhood) through such voxels."""
    can = hull & (shadow_count == 0) & ~surface_band
    reach = free.clone()
    for _ in range(max(0, int(depth_voxels))):
        grown = dilate_cube(reach.float(), 1) > 0
        new = grown & can & ~reach
        if not bool(new.any()):
            break
        reach |= new
    return reach & can


def _ball(radius: int) -> torch.Tensor:
    r = int(radius)
    g = torch.arange(-r, r + 1, dtype=torch.float32)
    d2 = g[:, None, None] ** 2 + g[None, :, None] ** 2 + g[None, None, :] ** 2
    return (d2 <= r * r + 1e-6).float()


def opening(solid: torch.Tensor, radius: int) -> torch.Tensor:
    """Morphological opening (bool (nx, ny, nz)) of `solid` by a ball of `radius` voxels: the union of all the
    balls that fit inside it. Beyond the box counts as solid (the box cuts the hull, it does not bound it)."""
    ball = _ball(radius)[None, None]
    r, full = int(radius), float(ball.sum())
    x = F.pad(solid[None, None].float(), (r,) * 6, value=1.0)
    core = (F.conv3d(x, ball) > full - 0.5).float()
    grown = F.conv3d(F.pad(core, (r,) * 6, value=0.0), ball) > 0.5
    return grown[0, 0] & solid


def unblocked_segments(box, blocker: torch.Tensor, origins, dirs, near, far, step) -> torch.Tensor:
    """Per segment (bool (R,)): no marching sample lies in a `blocker` voxel (flat bool)."""
    hit = torch.zeros(origins.shape[0], dtype=torch.bool, device=origins.device)
    for rays, flat, keep in marching_cells(box, origins, dirs, near, far, step):
        flat = flat.where(keep, 0.0).long()
        hit[rays] = (keep & blocker[flat]).any(1)
    return ~hit


def sole_blockers(box, solid_flat: torch.Tensor, segments, step, max_samples: int = 3, min_segments: int = 1
                  ) -> torch.Tensor:
    """Voxels (flat bool) that are all a shadowed segment crosses of `solid_flat`, where it crosses at most
    `max_samples` marching samples of it, for at least `min_segments` segments: the segments graze the shadow
    caster there (the shadow's edge), so the caster certainly reaches that voxel (one segment may be a wrong
    shadow label)."""
    n_all = solid_flat.numel()
    count = torch.zeros(n_all + 1, dtype=torch.long, device=solid_flat.device)
    for _, flat, keep in marching_cells(box, *segments, step):
        flat = flat.where(keep, 0.0).long()
        inside = keep & solid_flat[flat]
        n = inside.sum(1)
        few = (n > 0) & (n <= max_samples)
        # one count per segment and voxel: the first sample of a run of samples in the same voxel
        f, ins = flat[few], inside[few]
        first = ins & torch.cat([torch.ones_like(ins[:, :1]), f[:, 1:] != f[:, :-1]], 1)
        count += torch.bincount(f.masked_fill(~first, n_all).reshape(-1), minlength=n_all + 1)
    return count[:n_all] >= min_segments


def outside_convex_closure(parts: torch.Tensor, anchors: torch.Tensor, margin: float = 0.0) -> torch.Tensor:
    """Voxels (bool (nx, ny, nz)) of `parts` more than `margin` voxels outside the convex hull of the `anchors`
    voxels (whole voxels, their corners) of their own 26-connected component of `parts`; components with
    anchors spanning no volume are left whole."""
    import numpy as np
    from scipy import ndimage
    from scipy.spatial import ConvexHull, QhullError
    comp, n = ndimage.label(parts.cpu().numpy(), structure=np.ones((3, 3, 3), bool))
    anc = anchors.cpu().numpy()
    out = np.zeros(comp.shape, bool)
    corners = np.array([[i, j, k] for i in (-.5, .5) for j in (-.5, .5) for k in (-.5, .5)])
    for c, sl in enumerate(ndimage.find_objects(comp), start=1):
        sub = comp[sl] == c
        a = np.argwhere(sub & anc[sl])
        if len(a) < 4:
            continue
        try:
            hull = ConvexHull((a[:, None, :] + corners[None]).reshape(-1, 3))
        except QhullError:
            continue
        v = np.argwhere(sub)
        outside = (v @ hull.equations[:, :3].T + hull.equations[:, 3] > margin + 1e-6).any(1)
        o = np.zeros(sub.shape, bool)
        o[tuple(v[outside].T)] = True
        out[sl] |= o
    return torch.as_tensor(out, device=parts.device)


def keep_blocked(box, solid: torch.Tensor, removed: torch.Tensor, segments, step) -> torch.Tensor:
    """`removed` less the voxels along every shadowed segment that `solid` blocked and `solid` less `removed`
    would not: the prior never clears a measured shadow."""
    flat_solid, flat_removed = solid.reshape(-1), removed.reshape(-1).clone()
    lost = (unblocked_segments(box, flat_solid & ~flat_removed, *segments, step)
            & ~unblocked_segments(box, flat_solid, *segments, step))
    if bool(lost.any()):
        o, d, n, f = (t[lost] for t in segments)
        keep_back = torch.zeros_like(flat_removed)
        for _, flat, keep in marching_cells(box, o, d, n, f, step):
            flat = flat.where(keep, 0.0).long()
            keep_back[flat[keep & flat_removed[flat]]] = True
        flat_removed &= ~keep_back
    return flat_removed.reshape(solid.shape)
