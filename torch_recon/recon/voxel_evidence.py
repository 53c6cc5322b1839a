"""Per-voxel evidence labels of the fast start field (`init.initial_grid`), from the measurements alone.

Evidence, voxel by voxel (priority top to bottom):
1. the voxel holding a visible surface point x = c + d u (closed-form depth d): occupied; so is the voxel
   holding a pixel's nearest surface where its strongest return lies behind it (a leg under a pixel wide in
   front of the floor: `thin_part_points`), and the voxels joining it to its neighbours' at the same range;
2. crossed by a camera ray before its visible surface (before its nearest surface): free;
3. crossed by at least `carve_min_lit` lit secondary rays x -> l: free (shadow carving; a pair whose path
   disagrees with its pixel's depth carves from where its own path puts the surface, `unexplained_lit`);
4. otherwise hidden (the start field decides: shadow hull inside the view, `init.initial_grid`); a carved
   voxel a shadowed segment needs as its blocker is put back (`explain_shadows`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .behind_pixels import seen_through
from .data import RayData, lit_path_tolerance, pixel_angle, unexplained_lit
from .fields import GridBox
from .sampler import ray_box
from .segment_crossings import accumulate_crossings, marching_cells, pair_segments, segment_counts, spot_crossings
from .shadow_blockers import MeasuredSurfacePoints, blocker_weight, shared_blockers
from .thin_parts import thin_part_cloud, thin_part_voxels

#: evidence labels of a voxel (`evidence_grid`): never carved (the shadow hull decides), holding a measured visible
#: surface point, seen through by the sensor, crossed by a lit secondary ray
HULL, SURFACE, CAMERA_FREE, LIT_FREE = 0, 1, 2, 3
#: evidence label of a carved voxel put back because a shadowed segment needs a blocker there
RESTORED = 4
#: evidence label of the nearest surface of a pixel whose strongest return lies behind (a part under a pixel wide)
NEAREST = 6


@dataclass
class VoxelEvidence:
    """What the start field's one evidence labelling found per voxel of its box (session 14, issue 11): the fit keeps
    it, and the mesh export reads the hull's lit carving and the restored blockers back from it instead of marching
    the lit secondary segments again (+2.3 s of export on cave-chair 128 px, session 13)."""

    label: torch.Tensor         # (nx, ny, nz) int8: the labels of `evidence_grid`
    lit_crossed: torch.Tensor   # (nx, ny, nz) bool: a lit segment's marching sample (within `carve_core`) lies in the
                                # voxel, also where the label says otherwise (a surface, a restored blocker)

    @property
    def restored(self) -> torch.Tensor:
        """The restored blockers (`explain_shadows`, nx, ny, nz bool)."""
        return self.label == RESTORED


def explain_shadows(box: GridBox, label: torch.Tensor, free_count, shadow_count, origins, dirs, near, far, step,
                    restorable=(3,), chunk_samples: int = 1 << 20, score=None, lead: float = 0.0,
                    weight=None, shared_cluster_voxels: int = 0, measured=None) -> int:
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
    `shared_cluster_voxels` > 0: a segment whose pick lies in a cluster of at least that many restored voxels takes
    the pick on its path that most segments made (`shadow_blockers.shared_blockers`). `measured`
    (`shadow_blockers.MeasuredSurfacePoints`): the ranking divided by how far each sample lies from the measured
    surface points (a blocker where a measured part is). Returns the number of voxels restored."""
    if origins.shape[0] == 0:
        return 0
    if score is None:
        score = shadow_count.float() / (free_count.float() + 1.0)
    if weight is not None:
        score = score * weight
    can = torch.zeros(8, dtype=torch.bool, device=label.device)
    can[list(restorable)] = True
    lead = min(max(float(lead), 0.0), float(near.min()))
    picked, paths = [], []
    for rays, flat, keep in marching_cells(box, origins, dirs, near - lead, far, step, chunk_samples):
        flat = flat.where(keep, 0.0).long()
        lab = label[flat]
        past = torch.arange(flat.shape[1], device=flat.device)[None] * step >= lead - 1e-6
        blocked = (keep & past & (lab != 2) & (lab != 3)).any(1)
        cand = keep & can[lab.long()] & ~blocked[:, None]
        sc = torch.where(cand, score[flat], torch.full_like(flat, -1, dtype=score.dtype))
        if measured is not None:
            sc = measured.rank(sc, cand, origins[rays], dirs[rays], near[rays] - lead, far[rays], step)
        best, j = sc.max(1)
        ok = best >= 0
        picked.append(flat[ok].gather(1, j[ok, None]).squeeze(1))
        if shared_cluster_voxels > 0:
            paths.append((flat[ok], cand[ok]))
    picked = torch.cat(picked)
    if shared_cluster_voxels > 0 and picked.numel() > 0:
        picked = shared_blockers(box, picked, paths, score, shared_cluster_voxels)
    picked = torch.unique(picked)
    label[picked] = RESTORED
    return int(picked.numel())



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
                  explain_shared_cluster_voxels: int = 0, explain_measured_scale_voxels: float = 0.0,
                  measured_points=None, in_plane=None):
    """`VoxelEvidence`: per-voxel labels (nx, ny, nz) int8: 1 surface, 2 camera-free, 3 lit-free, 0 hidden, 4 restored
    blocker of a shadowed segment (with `explain_shadow_rays`), 6 a part under a pixel wide (with
    `nearest_surface`: `thin_part_points`), and the voxels lit segments cross; and the count of shadowed secondary
    segments through each voxel (with `count_shadow`; zeros without). With `nearest_free` a camera ray is free only
    up to its pixel's nearest depth.
    seen_free: optional bool (nx, ny, nz), voxels the pixels' footprints saw through (camera-free as well).
    thin_points: `thin_parts.thin_part_cloud` of these settings when already computed.
    lit_path_tolerance_m > 0: a lit pair whose path disagrees with its pixel's visible point by more carves from
    where its own path puts the surface on the pixel ray (`unexplained_lit`).
    explain_neighbour_power > 0: a restored blocker is looked for next to what stayed occupied (`blocker_weight`).
    explain_shared_cluster_voxels > 0: blockers in clusters at least this large are shared (`shared_blockers`).
    explain_measured_scale_voxels > 0: a restored blocker is looked for where the segment passes nearest to the measured
    surface points, visible and thin parts' (`MeasuredSurfacePoints`, this scale in voxels); measured_points (N, 3):
    the visible points to use (the start field leaves out the room's bounding planes), else every pixel's.
    in_plane: bool (N pairs,): shadowed pairs whose spot lies in their pixel's tangent plane (`in_plane_pairs`), no
    shadow evidence (neither counted nor explained)."""
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
        if thin_points is None:
            thin_points = thin_part_cloud(data, box.voxel, thin_part_edges, thin_part_centre)
        nearest = thin_part_voxels(data, box, points=thin_points).reshape(-1)
    # shadow carving: lit pairs on the carving pixels only; shadowed pairs count occluder evidence
    on_sub = torch.zeros(data.height * data.width, dtype=torch.bool, device=dev)
    on_sub[sub] = True
    off = max(secondary_offset_m, surface_margin_voxels * box.voxel)
    own = unexplained_lit(data, lit_path_tolerance_m) if lit_path_tolerance_m > 0 else None
    lit_count = segment_counts(data, box, data.lit & on_sub[data.pair_pixel], off, step, carve_core, own)
    shadowed = data.shadowed if in_plane is None else data.shadowed & ~in_plane.to(data.shadowed.device)
    consistent = explain_shadow_rays and bool(shadowed.any())
    shadow_count = (segment_counts(data, box, shadowed & on_sub[data.pair_pixel], off, step, 0.5)
                    if count_shadow or consistent else torch.zeros_like(lit_count))
    label = torch.full((n,), HULL, dtype=torch.int8, device=dev)
    label[lit_count >= max(1, carve_min_lit)] = LIT_FREE
    label[cam_free > 0] = CAMERA_FREE
    label[surface > 0] = SURFACE
    label[nearest & (surface == 0)] = NEAREST
    if consistent:
        seg = pair_segments(data, shadowed & on_sub[data.pair_pixel], off)
        score = None
        if explain_score == "spots":    # distinct spots whose shadows cross a voxel, over distinct lit spots
            sh = shadowed & on_sub[data.pair_pixel]
            score = (spot_crossings(data, box, sh, off, step).float()
                     / (spot_crossings(data, box, data.lit & on_sub[data.pair_pixel], off, step, carve_core) + 1.0))
        lead = explain_lead_voxels * box.voxel
        weight = blocker_weight(label.reshape(box.shape), explain_neighbour_power)
        measured = None
        if explain_measured_scale_voxels > 0:
            pts = x_all[okx] if measured_points is None else measured_points.to(x_all)
            pts = pts if thin_points is None else torch.cat([pts, thin_points.to(x_all)])
            measured = MeasuredSurfacePoints(pts, explain_measured_scale_voxels * box.voxel)
        if explain_camera_free:     # a part thinner than a pixel: the pixel ray saw past it
            explain_shadows(box, label, lit_count + cam_free, shadow_count, *seg, step, restorable=(2, 3),
                            score=score, lead=lead, weight=weight, shared_cluster_voxels=explain_shared_cluster_voxels,
                            measured=measured)
        else:
            explain_shadows(box, label, lit_count, shadow_count, *seg, step, score=score, lead=lead, weight=weight,
                            shared_cluster_voxels=explain_shared_cluster_voxels, measured=measured)
    return VoxelEvidence(label.reshape(box.shape), (lit_count > 0).reshape(box.shape)), shadow_count.reshape(box.shape)


def in_plane_pairs(data: RayData, surface, tol_m: float) -> torch.Tensor:
    """Pairs (bool (N,)) whose spot lies within `tol_m` of their pixel's tangent plane (surface: `visible_surface`
    points and normals of the finite-depth pixels, in pixel order): light from a spot on the same wall or floor
    arrives at grazing incidence and returns nothing, a shadow no occluder casts."""
    ok = torch.isfinite(data.visible_depth).cpu()
    nrm = torch.full((len(ok), 3), float("nan"), dtype=torch.float64)
    nrm[ok] = torch.as_tensor(np.asarray(surface[1]), dtype=torch.float64)
    x = torch.full((len(ok), 3), float("nan"), dtype=torch.float64)
    x[ok] = torch.as_tensor(np.asarray(surface[0]), dtype=torch.float64)
    pp, ps = data.pair_pixel.cpu(), data.pair_spot.cpu()
    off_plane = ((data.spot_points.cpu().double()[ps] - x[pp]) * nrm[pp]).sum(-1).abs()
    return torch.nan_to_num(off_plane, nan=float("inf")) <= tol_m


def configured_evidence_grid(data: RayData, box: GridBox, cfg, secondary_offset_m: float, seen_free=None,
                             count_shadow: bool = False, thin_points=None, measured_points=None, surface=None):
    """`evidence_grid` with a FastConfig's settings: the one place that maps the settings onto its arguments
    (the start field and the spot advisor both label voxels this way; surface: `visible_surface`, for
    `fast.explain_in_plane_voxels`). With `fast.seen_through_voxels` a restored
    blocker the sensor saw through (`behind_pixels.seen_through`) is no shadow's blocker: lit-free as before."""
    evidence, shadow_count = evidence_grid(
        data, box, cfg.surface_margin_voxels, cfg.carve_min_lit, secondary_offset_m, cfg.step_voxels, cfg.carve_core,
        carve_spacing_voxels=cfg.carve_spacing_voxels, count_shadow=count_shadow,
        explain_shadow_rays=cfg.explain_shadows, explain_camera_free=cfg.explain_camera_free,
        explain_score=cfg.explain_score, nearest_free=cfg.nearest_free, nearest_surface=cfg.nearest_surface,
        seen_free=seen_free, thin_part_edges=cfg.thin_part_edges, thin_part_centre=cfg.thin_part_centre,
        explain_lead_voxels=cfg.explain_lead_voxels, thin_points=thin_points,
        lit_path_tolerance_m=lit_path_tolerance(data, box.voxel, cfg.lit_path_tolerance_voxels),
        explain_neighbour_power=cfg.explain_neighbour_power,
        explain_shared_cluster_voxels=cfg.explain_shared_cluster_voxels,
        explain_measured_scale_voxels=cfg.explain_measured_scale_voxels, measured_points=measured_points,
        in_plane=(in_plane_pairs(data, surface, cfg.explain_in_plane_voxels * box.voxel)
                  if cfg.explain_in_plane_voxels > 0 and surface is not None else None))
    label = evidence.label
    if cfg.seen_through_voxels > 0:
        restored = label == RESTORED
        seen = seen_through(data, box.centres()[restored.to(box.bbox_min.device)],
                            cfg.seen_through_voxels * box.voxel, cfg.nearest_free).to(label.device)
        lit_free = torch.tensor(LIT_FREE, dtype=label.dtype, device=label.device)
        label[restored] = torch.where(seen, lit_free, label[restored])
    return evidence, shadow_count

