"""Fast-mode initialisation: a density grid from the closed-form visible depth and shadow carving.

The voxels' evidence labels (surface, camera-free, lit-free, hidden, restored blocker: voxel_evidence.py) decide
the start: known free space is empty; hidden voxels inside the sensor's view are occupied, the shadow hull of
BF Lidar; outside the view (no measurement reaches it) the planes bounding the observation continue there
(`unobserved.py`). Hull voxels no shadowed ray crosses, connected to measured free space, start empty
(`hull_trim.py`, `fast.trim_hull_voxels`): no measurement needs them.
Near visible surfaces the raw density is a ramp in the point-to-plane signed distance to the measured
surface (normals from the depth image), so planar walls start planar at sub-voxel accuracy.
Which voxels are known free (2 and 3) is kept: the mesh exporter reports only surfaces that face
measured free space (`free_evidence`) or completed empty space next to a completed plane.
"""

from __future__ import annotations

import numpy as np
import torch

from ..contract.errors import UnconstrainedMeasurementsError
from .behind_pixels import behind_pixels
from .data import RayData
from .fields import DensityGrid, GridBox, dilate_cube
from .segment_crossings import pair_segments, spot_crossings
from .thin_parts import thin_part_signed_distance
from .visible_surface_init import surface_offset, surface_signed_distance, visible_surface
from .voxel_evidence import (CAMERA_FREE, HULL, LIT_FREE, NEAREST, RESTORED, SURFACE, carving_pixel_mask,
                             configured_evidence_grid)


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


def _hull_prior(data: RayData, box: GridBox, cfg, label, free, view, sd, shell, off):
    """Free space and the hull voxels a scene-independent prior empties (`fast.hull_opening_voxels`: thinner
    than a ball; `fast.hull_closure`: outside the convex hull of the voxels a shadow's edge or a measured surface
    places, per connected part), every measured shadow staying blocked (hull_trim.py)."""
    from .hull_trim import keep_blocked, opening, outside_convex_closure, sole_blockers
    solid = ~free
    band = torch.isfinite(sd) if sd is not None else dilate_cube((label == SURFACE).float(), 2) > 0
    removable = (label == HULL) & solid & ~band & (shell < -0.5 * box.voxel)
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
        placed = (label == SURFACE) | (label == RESTORED) | (label == NEAREST)     # a measured surface or blocker
        anchors = (parts & placed) | (sole_blockers(box, solid.reshape(-1), segs, step,
                                                        min_segments=cfg.hull_closure_min_segments,
                                                        max_samples=cfg.hull_closure_graze_samples).reshape(solid.shape)
                                          & parts)
        outside = removable & outside_convex_closure(parts, anchors, cfg.hull_closure_margin_voxels)
        # ... and the layer of hull between it and the floor or wall it stood on (parts leave that layer out)
        removed |= outside | (removable & ~parts & (dilate_cube(outside.float(), 1) > 0))
    removed = keep_blocked(box, solid, removed, segs, step) if bool(removed.any()) else removed
    return free | removed, removed



def _ramp_in_front_of_hidden(data: RayData, box: GridBox, sd: torch.Tensor, label: torch.Tensor, margin_m: float,
                             reach_m: float) -> torch.Tensor:
    """Hull voxels (nx, ny, nz bool) the nearest measured point's plane puts in front of the surface (sd < 0) though
    they lie more than `margin_m` behind the surface their own pixels saw, and within `reach_m` of it (the ramp's
    surface, not a wall far behind an object): the plane is another face's (a concave junction's points carry the
    seat's normal at its backrest's foot), and the hull, not that ramp, decides them."""
    cand = torch.isfinite(sd) & (sd < 0) & (label == HULL)
    out = torch.zeros_like(cand)
    if bool(cand.any()):
        behind = behind_pixels(data, box.centres()[cand.to(box.bbox_min.device)])
        out[cand] = ((behind > margin_m) & (behind <= reach_m)).to(out.device)
    return out


def _lit_ramp_seen_through(data: RayData, box: GridBox, sd: torch.Tensor, label: torch.Tensor, margin_m: float,
                           nearest_free: bool) -> torch.Tensor:
    """Lit-carved voxels (nx, ny, nz bool) the nearest measured point's plane puts behind the surface (0 < sd, within
    the half voxel the ramp reaches into carved space) though they lie more than `margin_m` in front of what the pixel
    nearest them in direction saw (with `nearest_free` its earliest return): that pixel looked past the voxel to a
    farther surface, so the plane is extended past its object's silhouette (dark-room's backrest, 3 cm beside its
    side edges) or mixed with a nearer part, and the carving, not the ramp, decides the voxel (session 21). One pixel,
    not four (`behind_pixels.seen_through`): beside a silhouette one of four sees the object itself."""
    cand = torch.isfinite(sd) & (sd > 0) & (label == LIT_FREE)
    out = torch.zeros_like(cand)
    if bool(cand.any()):
        depth = data.visible_depth
        if nearest_free and data.nearest_depth is not None:
            depth = torch.fmin(data.nearest_depth, depth)
        ahead = behind_pixels(data, box.centres()[cand.to(box.bbox_min.device)], k=1, depth=depth, farthest=False)
        out[cand] = (ahead < -margin_m).to(out.device)
    return out


def _blocker_on_measured_plane(box: GridBox, sd: torch.Tensor, shell, band_voxels: float) -> torch.Tensor:
    """Voxels (nx, ny, nz) bool within `band_voxels` of both the measured visible surface (`sd`) and a plane bounding
    the room (`shell`; none without planes): a restored blocker there is a wall voxel a grazing shadowed segment
    picked (the true blocker, a leg a metre away, was carved), and the wall's measured ramp places it; occupied,
    it put the wall half a voxel into the room (cave-chair's ridges beside the chair, session 21)."""
    if band_voxels <= 0 or shell is None:
        return torch.zeros_like(sd, dtype=torch.bool)
    band = band_voxels * box.voxel
    return (sd.abs() <= band) & (shell.abs() <= band)


#: spots whose secondary rays must cross a voxel outside the camera's view for it to count as measured
MIN_SPOTS_BEYOND_VIEW = 2


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


def room_planes(data: RayData, box: GridBox, cfg, surface) -> list:
    """The planes bounding the observation (`unobserved.bounding_planes`) of the visible `surface` (points, normals)
    on `box`'s voxel size. Seeded: the same inputs give the same planes, so a fit computes them once per voxel size
    (`FastModel.room_planes`) for every setting that reads them (`start_field_reads_planes`, the edge freeze, the
    mesh's plane snap)."""
    from .unobserved import bounding_planes
    return bounding_planes(*surface, data.sensor_origin.cpu().numpy(), data.spot_points.cpu().numpy(),
                           cfg.plane_tolerance_voxels * box.voxel, cfg.plane_min_support,
                           refit_mad=cfg.plane_refit_mad)


def start_field_reads_planes(cfg, in_view_known: bool = True) -> bool:
    """Whether `initial_grid` reads the room's bounding planes: completing the unobserved space (needs the view:
    `in_view_known`), trimming the hull, concave corners, the objects' measured points."""
    return ((cfg.complete_unobserved and in_view_known) or cfg.trim_hull_voxels > 0
            or cfg.surface_concave_corners == "planes" or cfg.explain_measured_scale_voxels > 0)


def objects_measured_points(data: RayData, box: GridBox, cfg, surface, planes: list | None = None):
    """The measured points a shadowed segment's blocker ranks by (`fast.explain_measured_scale_voxels`; None
    when off): the visible points off the room's bounding planes (`room_planes`; computed here when None). Beside a
    chair's foot every candidate is as near the floor's points, and blockers slid down onto it (session 17). The
    start field and the spot advisor's voxel classes both take them from here."""
    from .unobserved import on_planes
    if cfg.explain_measured_scale_voxels <= 0:
        return None
    planes = room_planes(data, box, cfg, surface) if planes is None else planes
    pts = np.asarray(surface[0])
    return torch.as_tensor(pts[~on_planes(pts, surface[1], planes, cfg.plane_tolerance_voxels * box.voxel)])


def initial_grid(data: RayData, box: GridBox, cfg, secondary_offset_m: float = 0.0, view=None, surface=None,
                 seen_free=None, thin_points=None, planes=None):
    """The fast mode's starting field (cfg: FastConfig), the voxels the mesh may face (nx, ny, nz) bool and the
    voxels' evidence it was built from (`voxel_evidence.VoxelEvidence`: the mesh export reads it back).

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
    `thin_parts.thin_part_cloud` (the model's frozen thin-part mask uses the same points), and planes `room_planes`
    (computed here when None and `start_field_reads_planes`).
    """
    from .beyond_view import lit_side_of_hull, out_of_view_spots, unneeded_beside_view
    from .unobserved import on_planes, shell_signed_distance

    surface = visible_surface(data, box) if surface is None else surface
    if planes is None:
        planes = room_planes(data, box, cfg, surface) if start_field_reads_planes(cfg, view is not None) else []
    measured = objects_measured_points(data, box, cfg, surface, planes)
    evidence, shadow_count = configured_evidence_grid(data, box, cfg, secondary_offset_m, seen_free,
                                                      count_shadow=cfg.trim_hull_voxels > 0, thin_points=thin_points,
                                                      measured_points=measured, surface=surface)
    label = evidence.label
    free = (label == CAMERA_FREE) | (label == LIT_FREE)
    dev = data.pixel_dirs.device
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
        band = torch.isfinite(sd) if sd is not None else dilate_cube((label == SURFACE).float(), 2) > 0
        hull = (label == HULL) & (shell < -0.5 * box.voxel)     # never through a wall, floor or ceiling plane
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
        near = (torch.isfinite(sd) & ((label != LIT_FREE) | (sd <= 0.5 * box.voxel))
                & ((label != CAMERA_FREE) | (sd <= 0))
                & ((label != RESTORED) | _blocker_on_measured_plane(box, sd, shell, cfg.surface_plane_blocker_voxels))
                & (label != NEAREST))
        if cfg.surface_hidden_hull_voxels > 0:
            near &= ~_ramp_in_front_of_hidden(data, box, sd, label, cfg.surface_hidden_hull_voxels * box.voxel,
                                              (cfg.surface_half_width_voxels + 1.0) * box.voxel)
        if cfg.surface_seen_through_voxels > 0:
            near &= ~_lit_ramp_seen_through(data, box, sd, label, cfg.surface_seen_through_voxels * box.voxel,
                                            cfg.nearest_free)
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
    return DensityGrid.from_xyz(box, raw.float(), cfg.density_scale), mesh_free, evidence

