"""Fast-mode initialisation: a density grid from the closed-form visible depth and shadow carving.

Evidence, voxel by voxel (priority top to bottom):
1. the voxel holding a visible surface point x = c + d u (closed-form depth d): occupied; so is the voxel
   holding a pixel's nearest surface where its strongest return lies behind it (a leg under a pixel wide in
   front of the floor: `thin_part_points`), and the voxels joining it to its neighbours' at the same range;
2. crossed by a camera ray before its visible surface (before its nearest surface): free;
3. crossed by at least `carve_min_lit` lit secondary rays x -> l: free (shadow carving; a pair whose path
   disagrees with its pixel's depth carves from where its own path puts the surface, `unexplained_lit`);
4. otherwise, inside the sensor's view (hidden from the sensor and never lit through): occupied, the
   shadow hull of BF Lidar; outside the view (no measurement reaches it): the planes bounding the
   observation continue there (`unobserved.py`). Hull voxels no shadowed ray crosses, connected to measured
   free space, start empty (`hull_trim.py`, `fast.trim_hull_voxels`): no measurement needs them.
Near visible surfaces the raw density is a ramp in the point-to-plane signed distance to the measured
surface (normals from the depth image), so planar walls start planar at sub-voxel accuracy.
Which voxels are known free (2 and 3) is kept: the mesh exporter reports only surfaces that face
measured free space (`free_evidence`) or completed empty space next to a completed plane.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..contract.errors import UnconstrainedMeasurementsError
from .data import RayData, lit_path_tolerance, own_ranges, pixel_angle, unexplained_lit
from .fields import DensityGrid, GridBox
from .sampler import ray_box
from .shadow_blockers import blocker_weight
from .thin_parts import thin_part_signed_distance, thin_part_voxels
from .visible_surface_init import dilate_cube, surface_offset, surface_signed_distance, visible_surface


def scene_bbox(data: RayData, margin_m: float, quantile: float = 0.001):
    """Robust extent of the observed surface points, the spots and the sensor, grown by `margin_m`.

    The sensor is inside: the space between it and the surfaces was measured (free); the unseen
    parts of a room next to the sensor stay empty (nothing is reported there).
    """
    pts = data.scene_points()
    if len(pts) < 2:
        raise UnconstrainedMeasurementsError("measurements: no visible depth and no spots: cannot bound the scene "
                                             "(expected at least two measured points)")
    lo = np.quantile(pts, quantile, axis=0) - margin_m
    hi = np.quantile(pts, 1.0 - quantile, axis=0) + margin_m
    must = np.concatenate([pts[-len(data.spot_points):], data.sensor_origin.cpu().numpy()[None]], 0)
    lo = np.minimum(lo, must.min(0) - margin_m)
    hi = np.maximum(hi, must.max(0) + margin_m)
    return lo.astype(np.float32), hi.astype(np.float32)


def grid_bbox(data: RayData, resolution: int, margin_voxels: float):
    """The fast fit's box corners (lo, hi): `scene_bbox` grown by `margin_voxels` voxels of a grid with
    `resolution` voxels along the longest side of the ungrown box (fast.resolution and bbox_margin_voxels)."""
    lo, hi = scene_bbox(data, 0.0)
    voxel = float(np.max(hi - lo)) / resolution
    return scene_bbox(data, margin_voxels * voxel)


def marching_cells(box: GridBox, origins, dirs, near, far, step, chunk_samples: int = 1 << 20,
                    core: float = 0.5):
    """The voxels of the fixed-step marching samples (interval midpoints, as `marching_intervals`) of each
    segment, chunk by chunk: yields (rays, flat, keep): the segments' indices (R,), the flat x-major voxel
    index of every sample (R, n; float, arbitrary where not counted) and whether it counts (inside the
    box, non-empty interval, within `core` voxel of the voxel centre on every axis).

    Segments are taken longest first so that a chunk pads its rays only to its own longest one, and
    the axes are done one at a time on contiguous arrays: every sample and voxel is the same as with
    one global padding and (R, n, 3) arrays, at about a third of the time."""
    nx, ny, nz = box.shape
    span = (far - near).clamp(min=0)
    n_all = max(1, int(float(span.max()) / step) + 1)
    order = torch.argsort(span, descending=True, stable=True)
    wide = nx * ny * nz >= 1 << 24          # flat index exact in float32 below 2^24
    k_all = torch.arange(n_all, device=near.device, dtype=near.dtype)
    i = 0
    while i < len(order):
        # samples past floor(span / step) + 1 lie beyond the segment's end (t0 >= far): leave them out
        n = min(n_all, int(float(span[order[i]]) / step) + 2)
        rays = order[i:i + max(1, chunk_samples // n)]
        i += len(rays)
        nr, fr = near[rays, None], far[rays, None]
        t0 = nr + k_all[:n] * step
        t1 = torch.minimum(t0 + step, fr)
        t0 = torch.minimum(t0, fr)
        keep = t1 > t0
        mid = 0.5 * (t0 + t1)
        o, d = origins[rays], dirs[rays]
        flat = None
        for axis, (size, stride) in enumerate(((nx, 1), (ny, ny), (nz, nz))):
            q = d[:, axis, None] * mid           # the sample's coordinate in voxel units
            q = q.add_(o[:, axis, None]).sub_(box.bbox_min[axis]).div_(box.voxel)
            f = torch.floor(q)
            keep &= (f >= 0) & (f < size)
            if core < 0.5:
                keep &= (q - f - 0.5).abs() <= core
            if wide:
                f = f.double()
            flat = f if flat is None else flat.mul_(stride).add_(f)
        yield rays, flat, keep


def accumulate_crossings(box: GridBox, origins, dirs, near, far, step, counts, chunk_samples=1 << 20, core: float = 0.5):
    """Add 1 to `counts` (flat, x-major) for every marching sample of each segment inside the box whose
    position lies within `core` voxel of the voxel centre on every axis (0.5: anywhere in the voxel;
    smaller: a segment that only clips a corner of a partly filled voxel does not count)."""
    if origins.shape[0] == 0:
        return
    n = counts.numel()
    for _, flat, keep in marching_cells(box, origins, dirs, near, far, step, chunk_samples, core):
        # samples that do not count go to one extra bin (cheaper than selecting the others)
        counts += torch.bincount(flat.masked_fill_(~keep, n).long().reshape(-1), minlength=n + 1)[:n]


def segment_counts(data: RayData, box: GridBox, mask, off, step, core, own_range=None):
    """Per-voxel count of marching samples of the secondary segments x -> l of the pairs in `mask`."""
    counts = torch.zeros(int(np.prod(box.shape)), dtype=torch.long, device=data.pixel_dirs.device)
    accumulate_crossings(box, *pair_segments(data, mask, off, own_range), step, counts, core=core)
    return counts


def pair_segments(data: RayData, mask, off, own_range=None):
    """Secondary segments x -> l of the pairs in `mask` (finite visible depth, longer than 2 `off`):
    origins, unit directions, near, far. own_range: bool (N,), pairs whose x is where their own path puts the
    surface on the pixel ray instead of the pixel's visible point (`data.unexplained_lit`: their light came from
    another surface in the pixel); left out where that range does not exist."""
    pairs = torch.nonzero(mask & torch.isfinite(data.visible_depth[data.pair_pixel]), as_tuple=False).squeeze(1)
    depth = data.visible_depth[data.pair_pixel[pairs]]
    if own_range is not None and bool(own_range[pairs].any()):
        sel = own_range[pairs]
        depth = depth.clone()
        depth[sel] = own_ranges(data, pairs[sel])
        ok = torch.isfinite(depth)
        pairs, depth = pairs[ok], depth[ok]
    px = data.pair_pixel[pairs]
    x = data.sensor_origin + data.pixel_dirs[px] * depth[:, None]
    v = data.spot_points[data.pair_spot[pairs]] - x
    length = torch.linalg.vector_norm(v, dim=-1)
    good = length > 2 * off
    return x[good], v[good] / length[good, None], torch.full_like(length[good], off), length[good] - off


#: evidence label of a carved voxel put back because a shadowed segment needs a blocker there
RESTORED = 4
#: evidence label of the nearest surface of a pixel whose strongest return lies behind (a part under a pixel wide)
NEAREST = 6


def explain_shadows(box: GridBox, label: torch.Tensor, free_count, shadow_count, origins, dirs, near, far, step,
                    restorable=(3,), chunk_samples: int = 1 << 20, score=None, lead: float = 0.0,
                    weight=None, cover_lit_power: float | None = None, near_cover: bool = False) -> int:
    """Make every shadowed segment blocked (in place on the flat `label`): a shadowed segment whose voxels
    were all carved free gets back the carved voxel along it with the most shadowed and fewest free
    crossings (shadow / (lit + 1)). Carving through whole voxels takes thin parts
    (a chair leg about one voxel wide) with it wherever a lit ray grazes their voxel; the shadows the part
    casts cross it and put it back. `score` (flat, float): another ranking of the candidates (higher wins)
    in place of that ratio. `lead` (m): candidates are also looked for this far before each segment's
    `near` (nearer its surface point x), where only a carved voxel counts: a point on a part seen by the
    sensor is shadowed by the part itself (its own voxel and the next), inside the offset the segments
    skip next to x; without the lead the blocker lands on the first voxel past the offset, beside the
    part. `weight` (flat, float > 0): multiplies the ranking (`shadow_blockers.blocker_weight`).
    cover_lit_power: not None: the segments' blockers are chosen together, the fewest that block them all
    (`shadow_cover.greedy_cover`; `score` unused). Returns the number of voxels restored."""
    if origins.shape[0] == 0:
        return 0
    if score is None:
        score = shadow_count.float() / (free_count.float() + 1.0)
    if weight is not None:
        score = score * weight
    can = torch.zeros(8, dtype=torch.bool, device=label.device)
    can[list(restorable)] = True
    lead = min(max(float(lead), 0.0), float(near.min()))
    picked, pairs = [], []
    for rays, flat, keep in marching_cells(box, origins, dirs, near - lead, far, step, chunk_samples):
        flat = flat.where(keep, 0.0).long()
        lab = label[flat]
        past = torch.arange(flat.shape[1], device=flat.device)[None] * step >= lead - 1e-6
        blocked = (keep & past & (lab != 2) & (lab != 3)).any(1)
        cand = keep & can[lab.long()] & ~blocked[:, None]
        if cover_lit_power is not None:
            pairs.append((rays[:, None].expand_as(flat)[cand], flat[cand]))
            continue
        sc = torch.where(cand, score[flat], torch.full_like(flat, -1, dtype=score.dtype))
        best, j = sc.max(1)
        ok = best >= 0
        picked.append(flat[ok].gather(1, j[ok, None]).squeeze(1))
    if cover_lit_power is not None:
        from .shadow_cover import best_near_cover, greedy_cover
        seg_, vox_ = torch.cat([p[0] for p in pairs]), torch.cat([p[1] for p in pairs])
        picked = greedy_cover(seg_, vox_, free_count, cover_lit_power, weight)
        if near_cover:
            picked = best_near_cover(seg_, vox_, score, picked, box.shape)
    else:
        picked = torch.unique(torch.cat(picked))
    label[picked] = RESTORED
    return int(picked.numel())


def spot_crossings(data: RayData, box: GridBox, mask, off, step, core=0.5):
    """Per voxel (flat), the number of distinct spots with at least one secondary segment of `mask` crossing it."""
    n = int(np.prod(box.shape))
    spots = torch.zeros(n, dtype=torch.long, device=data.pixel_dirs.device)
    for k in torch.unique(data.pair_spot[mask]).tolist():
        spots += segment_counts(data, box, mask & (data.pair_spot == k), off, step, core) > 0
    return spots


def far_pixel_spacing(data: RayData) -> float | None:
    """Distance (m) between neighbouring pixel rays at the far surfaces (the 95th percentile visible depth);
    None without a visible depth."""
    d = data.visible_depth[torch.isfinite(data.visible_depth)]
    if d.numel() == 0:
        return None
    ang = pixel_angle(data) or 1.0
    return max(ang * float(torch.quantile(d, 0.95)), 1e-6)


def _pixel_stride(data: RayData, voxel: float, spacing_voxels: float = 1.0) -> int:
    """Pixel stride keeping neighbouring carving rays within `spacing_voxels` of each other out to the
    far surfaces (the 95th percentile depth): finer images carve with a subset of their pixels."""
    footprint = far_pixel_spacing(data)
    return 1 if footprint is None else max(1, int(spacing_voxels * voxel / footprint))


def carving_pixel_mask(data: RayData, box: GridBox, spacing_voxels: float) -> torch.Tensor:
    """Pixels (bool (H W,)) whose rays carve (`_pixel_stride` in rows and columns)."""
    stride = _pixel_stride(data, box.voxel, spacing_voxels)
    m = torch.zeros(data.height, data.width, dtype=torch.bool, device=data.pixel_dirs.device)
    m[::stride, ::stride] = True
    return m.reshape(-1)


def evidence_grid(data: RayData, box: GridBox, surface_margin_voxels: float = 1.0, carve_min_lit: int = 1,
                  secondary_offset_m: float = 0.0, step_voxels: float = 0.5, carve_core: float = 0.5,
                  count_shadow: bool = False, carve_spacing_voxels: float = 1.0, explain_shadow_rays: bool = False,
                  explain_camera_free: bool = False, explain_score: str = "ratio", nearest_free: bool = False,
                  nearest_surface: bool = False, seen_free=None, thin_part_edges: bool = True,
                  thin_part_centre: str = "off", explain_lead_voxels: float = 0.0, thin_points=None,
                  lit_path_tolerance_m: float = 0.0, explain_neighbour_power: float = 0.0,
                  explain_cover_lit_power: float | None = None, explain_near_cover: bool = False):
    """Per-voxel labels (nx, ny, nz) int8: 1 surface, 2 camera-free, 3 lit-free, 0 hidden, 4 restored
    blocker of a shadowed segment (with `explain_shadow_rays`), 6 a part under a pixel wide (with
    `nearest_surface`: `thin_part_points`); and the count of shadowed secondary segments through each voxel
    (with `count_shadow`). With `nearest_free` a camera ray is free only up to its pixel's nearest depth.
    seen_free: optional bool (nx, ny, nz), voxels the pixels' footprints saw through (camera-free as well).
    thin_points: `thin_parts.thin_part_cloud` of these settings when already computed.
    lit_path_tolerance_m > 0: a lit pair whose path disagrees with its pixel's visible point by more carves from
    where its own path puts the surface on the pixel ray (`unexplained_lit`).
    explain_neighbour_power > 0: a restored blocker is looked for next to what stayed occupied (`blocker_weight`).
    explain_cover_lit_power: not None: the blockers are chosen together (`shadow_cover.greedy_cover`)."""
    dev = data.pixel_dirs.device
    n = int(np.prod(box.shape))
    step = step_voxels * box.voxel
    stride = _pixel_stride(data, box.voxel, carve_spacing_voxels)
    rows = torch.arange(0, data.height, stride, device=dev)
    cols = torch.arange(0, data.width, stride, device=dev)
    sub = (rows[:, None] * data.width + cols[None, :]).reshape(-1)
    d = data.visible_depth[sub]
    if nearest_free and data.nearest_depth is not None:    # a thin part in the pixel: free only up to it
        d = torch.fmin(data.nearest_depth[sub], d)
    ok = torch.isfinite(d)
    sub, d = sub[ok], d[ok]
    c = data.sensor_origin
    dirs = data.pixel_dirs[sub]
    org = c.expand_as(dirs).contiguous()
    near, _ = ray_box(org, dirs, box.bbox_min, box.bbox_max)
    free_end = d - surface_margin_voxels * box.voxel
    cam_free = torch.zeros(n, dtype=torch.long, device=dev)
    accumulate_crossings(box, org, dirs, near, torch.maximum(free_end, near), step, cam_free)
    if seen_free is not None:   # between the pixel rays (visible_surface_init.seen_free)
        cam_free += seen_free.reshape(-1).to(cam_free.device).long()
    surface = torch.zeros(n, dtype=torch.long, device=dev)
    x_all = c + data.pixel_dirs * data.visible_depth[:, None]
    okx = torch.isfinite(data.visible_depth)
    idx, inside = box.cell_index(x_all[okx])
    flat = (idx[:, 0] * box.shape[1] + idx[:, 1]) * box.shape[2] + idx[:, 2]
    surface += torch.bincount(flat[inside], minlength=n)
    nearest = torch.zeros(n, dtype=torch.bool, device=dev)
    if nearest_surface and data.nearest_depth is not None:
        # the nearest surface of a pixel whose strongest return lies behind it: a part thinner than the pixel
        nearest = thin_part_voxels(data, box, thin_part_edges, thin_part_centre, thin_points).reshape(-1)
    # shadow carving: lit pairs on the carving pixels only; shadowed pairs count occluder evidence
    on_sub = torch.zeros(data.height * data.width, dtype=torch.bool, device=dev)
    on_sub[sub] = True
    off = max(secondary_offset_m, surface_margin_voxels * box.voxel)
    own = unexplained_lit(data, lit_path_tolerance_m) if lit_path_tolerance_m > 0 else None
    lit_count = segment_counts(data, box, data.lit & on_sub[data.pair_pixel], off, step, carve_core, own)
    consistent = explain_shadow_rays and bool(data.shadowed.any())
    shadow_count = (segment_counts(data, box, data.shadowed & on_sub[data.pair_pixel], off, step, 0.5)
                    if count_shadow or consistent else torch.zeros_like(lit_count))
    label = torch.zeros(n, dtype=torch.int8, device=dev)
    label[lit_count >= max(1, carve_min_lit)] = 3
    label[cam_free > 0] = 2
    label[surface > 0] = 1
    label[nearest & (surface == 0)] = NEAREST
    if consistent:
        seg = pair_segments(data, data.shadowed & on_sub[data.pair_pixel], off)
        score = None
        if explain_score == "spots":    # distinct spots whose shadows cross a voxel, over distinct lit spots
            sh = data.shadowed & on_sub[data.pair_pixel]
            score = (spot_crossings(data, box, sh, off, step).float()
                     / (spot_crossings(data, box, data.lit & on_sub[data.pair_pixel], off, step, carve_core) + 1.0))
        lead = explain_lead_voxels * box.voxel
        weight = blocker_weight(label.reshape(box.shape), explain_neighbour_power)
        if explain_camera_free:     # a part thinner than a pixel: the pixel ray saw past it
            explain_shadows(box, label, lit_count + cam_free, shadow_count, *seg, step, restorable=(2, 3),
                            score=score, lead=lead, weight=weight, cover_lit_power=explain_cover_lit_power,
                            near_cover=explain_near_cover)
        else:
            explain_shadows(box, label, lit_count, shadow_count, *seg, step, score=score, lead=lead, weight=weight,
                            cover_lit_power=explain_cover_lit_power, near_cover=explain_near_cover)
    return label.reshape(box.shape), shadow_count.reshape(box.shape)


def _hull_prior(data: RayData, box: GridBox, cfg, label, free, view, sd, shell, off):
    """Free space and the hull voxels a scene-independent prior empties (`fast.hull_opening_voxels`: thinner
    than a ball; `fast.hull_closure`: outside the convex hull of the voxels a shadow's edge or a measured surface
    places, per connected part), every measured shadow staying blocked (hull_trim.py)."""
    from .hull_trim import keep_blocked, opening, outside_convex_closure, sole_blockers
    solid = ~free
    band = torch.isfinite(sd) if sd is not None else dilate_cube((label == 1).float(), 2) > 0
    removable = (label == 0) & solid & ~band & (shell < -0.5 * box.voxel)
    removable = removable if view is None else removable & view
    on_sub = carving_pixel_mask(data, box, cfg.carve_spacing_voxels)
    segs = pair_segments(data, data.shadowed & on_sub[data.pair_pixel], off)
    step = cfg.step_voxels * box.voxel
    removed = torch.zeros_like(solid)
    if cfg.hull_opening_voxels > 0:
        removed |= removable & ~opening(solid, cfg.hull_opening_voxels)
    if cfg.hull_closure == "convex":
        parts = solid & (shell < -1.5 * box.voxel)    # not the floor or a wall under an object
        parts = parts if view is None else parts & view
        placed = (label == 1) | (label == RESTORED) | (label == NEAREST)     # a measured surface or blocker
        anchors = (parts & placed) | (sole_blockers(box, solid.reshape(-1), segs, step,
                                                        min_segments=cfg.hull_closure_min_segments,
                                                        max_samples=cfg.hull_closure_graze_samples).reshape(solid.shape)
                                          & parts)
        outside = removable & outside_convex_closure(parts, anchors, cfg.hull_closure_margin_voxels)
        # ... and the layer of hull between it and the floor or wall it stood on (parts leave that layer out)
        removed |= outside | (removable & ~parts & (dilate_cube(outside.float(), 1) > 0))
    removed = keep_blocked(box, solid, removed, segs, step) if bool(removed.any()) else removed
    return free | removed, removed


def fov_xy(width: int, height: int, fov_rad: float, fov_axis: str):
    if fov_axis == "x":
        return fov_rad, 2.0 * math.atan(math.tan(0.5 * fov_rad) * height / width)
    return 2.0 * math.atan(math.tan(0.5 * fov_rad) * width / height), fov_rad


#: spots whose secondary rays must cross a voxel outside the camera's view for it to count as measured
MIN_SPOTS_BEYOND_VIEW = 2


def configured_evidence_grid(data: RayData, box: GridBox, cfg, secondary_offset_m: float, seen_free=None,
                             count_shadow: bool = False, thin_points=None):
    """`evidence_grid` with a FastConfig's settings: the one place that maps the settings onto its arguments
    (the start field and the spot advisor both label voxels this way)."""
    return evidence_grid(data, box, cfg.surface_margin_voxels, cfg.carve_min_lit, secondary_offset_m,
                         cfg.step_voxels, cfg.carve_core, carve_spacing_voxels=cfg.carve_spacing_voxels,
                         count_shadow=count_shadow, explain_shadow_rays=cfg.explain_shadows,
                         explain_camera_free=cfg.explain_camera_free, explain_score=cfg.explain_score,
                         nearest_free=cfg.nearest_free, nearest_surface=cfg.nearest_surface,
                         seen_free=seen_free, thin_part_edges=cfg.thin_part_edges,
                         thin_part_centre=cfg.thin_part_centre, explain_lead_voxels=cfg.explain_lead_voxels,
                         thin_points=thin_points,
                         lit_path_tolerance_m=lit_path_tolerance(data, box.voxel, cfg.lit_path_tolerance_voxels),
                         explain_neighbour_power=cfg.explain_neighbour_power,
                         explain_cover_lit_power=cfg.explain_cover_lit_power if cfg.explain_pick != "segment" else None,
                         explain_near_cover=cfg.explain_pick == "near_cover")


def in_view(data: RayData, box: GridBox, camera_to_world, fov_rad: float, fov_axis: str) -> torch.Tensor:
    """Voxels (nx, ny, nz) bool some measurement reaches: the centre projects into the sensor image (camera
    rays; and the secondary rays of spots inside the view, which stay in the convex view), or a secondary
    segment x -> l (lit or shadowed) of a spot outside the view crosses the voxel (a laser scanning a wider
    field than the camera sees: its light passes objects beside the sensor) from at least two spots: one
    spot's shadow bounds a blocker's direction, not its depth (a one-view silhouette; inside the view the
    camera rays bound it), so space only one spot reaches stays unobserved."""
    from ..contract.frames import project_points

    def projects(pts, front_only=False):
        col, row, depth = project_points(camera_to_world, data.width, data.height, fov_rad, pts, fov_axis)
        col, row = np.nan_to_num(col, nan=-1.0), np.nan_to_num(row, nan=-1.0)
        return (col >= 0) & (col < data.width) & (row >= 0) & (row < data.height) & ((depth > 0) | (not front_only))

    ok = torch.as_tensor(projects(box.centres().reshape(-1, 3).cpu().numpy()), device=data.pixel_dirs.device)
    outside = ~torch.as_tensor(projects(data.spot_points.cpu().numpy().reshape(-1, 3), True), device=ok.device)
    beyond = torch.nonzero(outside).reshape(-1)
    if len(beyond):
        pairs = (data.lit | data.shadowed) & torch.isin(data.pair_spot, beyond)
        ok |= spot_crossings(data, box, pairs, 0.0, 0.5 * box.voxel) >= MIN_SPOTS_BEYOND_VIEW
    return ok.reshape(box.shape)


def initial_grid(data: RayData, box: GridBox, cfg, secondary_offset_m: float = 0.0, view=None, surface=None,
                 seen_free=None, thin_points=None, restored_out: list | None = None):
    """The fast mode's starting field (cfg: FastConfig) and the voxels the mesh may face (nx, ny, nz) bool.

    Known free (seen through by the sensor or crossed by a lit secondary ray): empty. Everything else
    in the sensor's view (`view`, bool (nx, ny, nz)) is occupied (the shadow hull: every shadowed ray
    stays blocked, every lit ray stays clear). Outside the view nothing was measured: with
    `cfg.complete_unobserved` the planes bounding the observation continue there (`unobserved.py`),
    otherwise it stays empty. The mesh exporter reports only surfaces facing known free space or the
    completed empty space next to a completed plane (the second result). Near visible surfaces a
    linear ramp in the point-to-plane signed distance puts the surface at the measured depth to a
    fraction of a voxel (trilinear interpolation keeps a linear ramp linear); behind a visible surface
    a lit voxel stays free (thin parts keep their thickness), and so does a voxel the sensor saw through
    (beside an object's silhouette, where the plane of its face would extend).
    surface: `visible_surface(data, box)` (points, normals) when already computed; thin_points likewise
    `thin_parts.thin_part_cloud` (the model's frozen thin-part mask uses the same points).
    restored_out: a list that gets the restored blockers (label 4, nx, ny, nz bool) appended, for the mesh.
    """
    from .beyond_view import lit_side_of_hull, out_of_view_spots, unneeded_beside_view
    from .unobserved import bounding_planes, on_planes, shell_signed_distance

    label, shadow_count = configured_evidence_grid(data, box, cfg, secondary_offset_m, seen_free,
                                                   count_shadow=cfg.trim_hull_voxels > 0, thin_points=thin_points)
    free = (label == 2) | (label == 3)
    if restored_out is not None:
        restored_out.append(label == RESTORED)
    dev = data.pixel_dirs.device
    surface = visible_surface(data, box) if surface is None else surface
    planes = (bounding_planes(*surface, data.sensor_origin.cpu().numpy(), data.spot_points.cpu().numpy(),
                              cfg.plane_tolerance_voxels * box.voxel, cfg.plane_min_support)
              if (cfg.complete_unobserved and view is not None) or cfg.trim_hull_voxels > 0
              or cfg.surface_concave_corners == "planes" else [])
    corners = cfg.surface_concave_corners
    sd = (surface_signed_distance(data, box, cfg.surface_half_width_voxels, surface=surface,
                                  concave_corners=corners != "off",
                                  corner_points=(on_planes(*surface, planes, cfg.plane_tolerance_voxels * box.voxel)
                                                 if corners == "planes" else None)).to(dev)
          if cfg.surface_slope > 0 else None)
    shell = None
    if (cfg.complete_unobserved and view is not None) or cfg.trim_hull_voxels > 0:
        shell = shell_signed_distance(box.centres().double(), planes).float().to(dev)
    trimmed = None
    if cfg.trim_hull_voxels > 0:
        from .hull_trim import unneeded_hull
        band = torch.isfinite(sd) if sd is not None else dilate_cube((label == 1).float(), 2) > 0
        hull = (label == 0) & (shell < -0.5 * box.voxel)     # never through a wall, floor or ceiling plane
        hull = hull if view is None else hull & view
        trimmed = unneeded_hull(free, hull, shadow_count, band, cfg.trim_hull_voxels)
        free = free | trimmed
    beyond = out_of_view_spots(data) if view is not None else torch.zeros(0, dtype=torch.long)
    off = max(secondary_offset_m, cfg.surface_margin_voxels * box.voxel)     # as evidence_grid's secondary rays
    if len(beyond) and cfg.trim_hull_voxels > 0:    # shadow hull beside the view no light stopped at (beyond_view.py)
        excess = unneeded_beside_view(data, box, free, ~free & view, beyond, off, cfg.step_voxels * box.voxel,
                                      cfg.trim_hull_voxels)
        free, trimmed = free | excess, excess if trimmed is None else trimmed | excess
    if (cfg.hull_opening_voxels > 0 or cfg.hull_closure != "off") and shell is not None:
        free, thin = _hull_prior(data, box, cfg, label, free, view, sd, shell, off)     # hull_trim.py
        trimmed = thin if trimmed is None else trimmed | thin
    occupied = ~free if view is None else ~free & view
    raw = torch.where(occupied, torch.tensor(cfg.raw_occupied, device=dev), torch.tensor(cfg.raw_free, device=dev))
    b = surface_offset(cfg.density_scale, box.voxel, max(cfg.surface_slope, 1e-3))
    ramp = lambda sd: ((cfg.surface_slope * sd / box.voxel + b) if cfg.surface_slope > 0  # noqa: E731
                       else torch.where(sd > 0, cfg.raw_occupied, cfg.raw_free)).clamp(cfg.raw_free, cfg.raw_occupied)
    mesh_free = free
    if trimmed is not None:
        # where a trimmed lump met a wall the sensor did not see, the wall's plane places its surface
        wall = (dilate_cube(trimmed.float(), 2) > 0) & ~free & (shell.abs() < 2 * box.voxel)
        raw = torch.where(wall, ramp(shell), raw)
    if cfg.complete_unobserved and view is not None:
        unobserved = ~free & ~view
        raw = torch.where(unobserved, ramp(shell), raw)
        # completed empty space counts as free for the mesh only next to a completed plane: the shadow
        # hull's boundary at the edge of the view stays unreported
        mesh_free = free | (unobserved & (shell < 0) & (shell > -cfg.plane_free_band_voxels * box.voxel))
        if len(beyond):     # ... and the lit side of the hull beside the view (beyond_view.py)
            mesh_free = mesh_free | lit_side_of_hull(data, box, occupied, beyond, off, cfg.step_voxels * box.voxel)
    if sd is not None:
        # a voxel the sensor saw through lies in front of every measured surface: a face's plane, extended past
        # the object's silhouette, must not fill it (at 512 px it fattened resolved legs and chair backs)
        near = (torch.isfinite(sd) & ((label != 3) | (sd <= 0.5 * box.voxel)) & ((label != 2) | (sd <= 0))
                & (label != RESTORED) & (label != NEAREST))
        raw = torch.where(near, ramp(sd), raw)
    if cfg.thin_part_raw != cfg.raw_occupied:
        raw = torch.where(label == NEAREST, torch.tensor(cfg.thin_part_raw, device=dev), raw)
    if cfg.thin_part_half_width_voxels > 0:
        # a part under a pixel wide: its voxel's centre this far inside the surface (thinner than a whole voxel)
        raw = torch.where(label == NEAREST, ramp(torch.tensor(cfg.thin_part_half_width_voxels * box.voxel,
                                                              device=dev)), raw)
    if cfg.thin_part_radius_voxels > 0 and cfg.nearest_surface and data.nearest_depth is not None:
        # a tube round the thin parts' points (to a fraction of a voxel) in place of their whole voxels
        tube = thin_part_signed_distance(data, box, cfg.thin_part_radius_voxels * box.voxel, cfg.thin_part_edges,
                                         cfg.thin_part_centre, thin_points).to(dev)
        below = torch.where(label == NEAREST, torch.tensor(cfg.raw_free, device=dev), raw)
        raw = torch.where(torch.isfinite(tube), torch.maximum(below, ramp(tube)), raw)
    return DensityGrid.from_xyz(box, raw.float(), cfg.density_scale), mesh_free
