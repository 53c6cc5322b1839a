"""The spot advisor's voxel classes and the marches over them (issue 11; split from spot_advice.py).

Every voxel of a fast fit's grid is FREE, SOLID (a measured surface, a blocker, a completed plane), HULL
(shadow hull no lit segment bounds) or FACE (a hidden back face next to a measured surface). The advisor
scores a candidate spot by marching its segments through these classes (`segment_values`), checks that the
laser reaches a point (`laser_reaches`) and finds where laser directions beyond the view land
(`landing_points`). See spot_advice.py for the model.
"""

from __future__ import annotations

import math

import torch

from .fields import GridBox, dilate_cube
from .init import in_view, objects_measured_points
from .segment_crossings import marching_cells
from .spot_geometry import back_facing_free
from .visible_surface_init import coarse_sensor_seen_free, visible_surface
from .voxel_evidence import HULL as UNCARVED, SURFACE, configured_evidence_grid

#: voxel classes along a segment (FACE: a hidden back face next to a measured surface, see voxel_classes)
FREE, HULL, SOLID, FACE = 0, 1, 2, 3
#: hull voxels this close (voxels, cube) to a measured surface voxel count as that surface
SURFACE_BAND_VOXELS = 2



def voxel_classes(data, box: GridBox, opacity, level, fast: dict, meta: dict, offset_m: float,
                  back_faces: bool = False, surface=None) -> torch.Tensor:
    """Flat (x-major) class per voxel: HULL (shadow hull in the measured space, crossed by no lit segment,
    still occupied after training, more than SURFACE_BAND_VOXELS from a measured surface), FACE (such a voxel
    within the band that bounds free space on its side away from the sensor: `back_facing_free`; with
    `back_faces`), SOLID (every other occupied voxel: measured surfaces, blockers, the completed planes) or
    FREE. offset_m: the fit's secondary ray offset (FastModel.offset_for); surface: `visible_surface(data, box)` when
    already computed."""
    import dataclasses

    from .fast_config import FastConfig
    known = {f.name for f in dataclasses.fields(FastConfig)}
    cfg = FastConfig(**{k: v for k, v in fast.items() if k in known})
    # labelled as the fit's start field on its final grid (a coarse sensor's seen-free space included; blockers
    # ranked by the same objects' measured points)
    seen = coarse_sensor_seen_free(data, box, cfg, meta)
    surface = visible_surface(data, box) if surface is None else surface
    measured = objects_measured_points(data, box, cfg, surface)
    label = configured_evidence_grid(data, box, cfg, offset_m, seen_free=seen, measured_points=measured,
                                     surface=surface)[0].label
    view = in_view(data, box, meta["camera_to_world"], meta["fov_rad"], meta["fov_axis"])
    occupied = torch.as_tensor(opacity >= level, device=label.device)
    cls = torch.full(box.shape, FREE, dtype=torch.int8, device=label.device)
    cls[occupied] = SOLID
    # hidden voxels next to a measured surface are the surface's own thickness (a wall seen at a grazing angle
    # has voxels no pixel's point lands in): solid, not unbounded space
    band = dilate_cube((label == SURFACE).float(), SURFACE_BAND_VOXELS) > 0
    hidden = occupied & (label == UNCARVED) & view
    cls[hidden & ~band] = HULL
    if back_faces:  # ... but where such a voxel bounds free space on its side away from the sensor it is the back
        # face of a part (a table top's underside, a box's far side): only light grazing it places that face
        c2w = meta["camera_to_world"]
        cls[hidden & band & back_facing_free(occupied, box, c2w)] = FACE
    return cls.reshape(-1)


def segment_values(box, cls, hull_index, n_hull, origins, ends, off, step, prior, device):
    """Per target voxel (HULL or FACE, compact index), the best lit probability (1 - prior)^n over the
    segments origins -> ends that cross it with no SOLID voxel on the way (n: HULL voxels crossed; a FACE
    voxel is passed unattenuated). The first and last `off` of each segment are skipped (its own surfaces)."""
    v = ends - origins
    length = torch.linalg.vector_norm(v, dim=-1)
    good = length > 2 * off
    o, d, length = origins[good], v[good] / length[good, None], length[good]
    values = torch.zeros(n_hull, device=device)
    if len(o) == 0:
        return values
    near = torch.full_like(length, off)
    log_lit = math.log1p(-prior) * step / box.voxel     # per hull sample (step / voxel of a voxel)
    for rays, flat, keep in marching_cells(box, o, d, near, length - off, step):
        c = cls[flat.where(keep, 0.0).long()]
        hull = keep & (c == HULL)
        clear = ~(keep & (c == SOLID)).any(1)
        p = torch.exp(hull.sum(1).float() * log_lit) * clear
        sel = (hull | (keep & (c == FACE))) & clear[:, None]
        idx = hull_index[flat[sel].long()]
        values.scatter_reduce_(0, idx, p[:, None].expand_as(sel)[sel], "amax")
    return values


def laser_reaches(box, cls, laser, points, off, step):
    """Whether the laser's ray from `laser` to each point (N, 3) crosses no occupied voxel before it."""
    v = points - laser
    length = torch.linalg.vector_norm(v, dim=-1).clamp(min=1e-9)
    ok = torch.ones(len(points), dtype=torch.bool, device=points.device)
    far = (length - off).clamp(min=0)
    for rays, flat, keep in marching_cells(box, laser.expand_as(points).contiguous(), v / length[:, None],
                                            torch.zeros_like(length), far, step):
        c = cls[flat.where(keep, 0.0).long()]
        ok[rays] = ~(keep & (c != FREE)).any(1)
    return ok


def landing_points(box, cls, laser, dirs, step):
    """Where laser rays (unit dirs (N, 3)) first enter a SOLID voxel (NaN: a HULL voxel first, or none)."""
    from .sampler import ray_box

    org = laser.expand_as(dirs).contiguous()
    near, far = ray_box(org, dirs, box.bbox_min, box.bbox_max)
    near = near.clamp(min=0)
    out = torch.full_like(dirs, float("nan"))
    for rays, flat, keep in marching_cells(box, org, dirs, near, far, step):
        c = cls[flat.where(keep, 0.0).long()]
        hit = keep & (c != FREE)
        first = torch.where(hit.any(1), hit.float().argmax(1), torch.full_like(rays, -1))
        solid = (first >= 0) & (c.gather(1, first.clamp(min=0)[:, None]).squeeze(1) == SOLID)
        t = near[rays] + first.float() * step
        pts = org[rays] + dirs[rays] * t[:, None]
        out[rays[solid]] = pts[solid]
    return out
