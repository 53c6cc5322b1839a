"""The fast mode's grid filled from the ground truth: what the representation can reach at all.

The "oracle" field is the fit's start-field ramp (`fast.surface_slope` raw units per voxel across the
surface, raw value `surface_offset(...)` at it, clamped to [raw_free, raw_occupied]) evaluated on the
TRUE signed distance at the voxel centres of the fit's own box (`init.grid_bbox` + `GridBox`), then
exported through the fit's path (`FastModel.surface_volume`, `api.export_volume`: marching cubes at
its level, faces facing free space only, Taubin smoothing, island cleanup). Free space for the export
is the truly empty space (the best any measurement could say).

Solid (positive signed distance):
- inside a labelled object: per watertight connected component, ray parity (trimesh `contains`, embree
  through embreex); per component because the parts of one object may overlap, where parity over the
  whole object flips. A component that is not watertight gets the sign of its nearest face's normal.
- behind the room: the room's shell (the GT without the objects) is thin slabs (2 cm walls) and open
  sheets (the curved wall, normals facing the room); the fit models the space behind a wall as solid
  (the wall's plane continues), so the oracle does too: for each room component only the faces facing
  the sensor count, and a point is solid when it lies behind the nearest of them (its normal's side).
  Parity would make each 2 cm slab a 2 cm sheet with empty space behind it: not what the fit represents.
Distances are exact (point-triangle) within `band_voxels` of a surface; elsewhere the ramp is clamped
anyway and only the sign matters: each connected region of far cells takes the sign of the band cells
around it (a scipy label pass), so no inside test runs on millions of cells.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: cells nearer a surface than this (voxels) get an exact distance; the export clips the ramp at 1 voxel
BAND_VOXELS = 1.5


@dataclass
class SolidPart:
    """A piece of the truth: `mesh` (trimesh) and how its inside is decided ('object' or 'room')."""
    mesh: object
    kind: str


def _behind_room_part(part: SolidPart, pts, sensor_origin, chunk: int = 1 << 19):
    """Points (N, 3) whose segment to the sensor crosses the part's sensor-facing faces: behind it."""
    out = np.zeros(len(pts), bool)
    for s in range(0, len(pts), chunk):
        p = pts[s:s + chunk]
        to_sensor = sensor_origin - p
        dist = np.linalg.norm(to_sensor, axis=1)
        _, ray, loc = part.mesh.ray.intersects_id(p, to_sensor / np.maximum(dist, 1e-12)[:, None],
                                                  multiple_hits=False, return_locations=True)
        hit = np.linalg.norm(loc - p[ray], axis=1) < dist[ray]
        out[s + ray[hit]] = True
    return out


def scene_parts(gt_mesh, object_meshes, sensor_origin) -> list[SolidPart]:
    """The GT split into object components and room components (the room keeps its sensor-facing faces)."""
    from torch_recon.evaluation.objects import room_without_objects

    parts = [SolidPart(c, "object") for m in object_meshes for c in m.split(only_watertight=False)]
    room = room_without_objects(gt_mesh, list(object_meshes))
    for c in ([] if room is None else room.split(only_watertight=False)):
        facing = ((np.asarray(sensor_origin, float) - c.triangles_center) * c.face_normals).sum(1) > 1e-6
        if facing.any():
            parts.append(SolidPart(c.submesh([np.flatnonzero(facing)], append=True), "room"))
    return parts


def _closest(mesh, pts, k: int = 16, chunk: int = 1 << 16):
    """Exact nearest point on `mesh` of each point: candidates = the k triangles with the nearest
    centroids (all of them for small meshes), then trimesh's point-triangle closest point."""
    import trimesh
    from scipy.spatial import cKDTree

    tri = np.asarray(mesh.triangles, np.float64)
    k = min(k, len(tri))
    tree = cKDTree(tri.mean(1))
    q_all, d_all, t_all = np.empty_like(pts), np.empty(len(pts)), np.empty(len(pts), np.int64)
    for s in range(0, len(pts), chunk):
        p = pts[s:s + chunk]
        cand = np.arange(len(tri))[None].repeat(len(p), 0) if k == len(tri) else \
            tree.query(p, k=k)[1].reshape(len(p), k)
        q = trimesh.triangles.closest_point(tri[cand.ravel()], np.repeat(p, k, 0)).reshape(len(p), k, 3)
        d = np.linalg.norm(q - p[:, None], axis=2)
        j = d.argmin(1)
        r = np.arange(len(p))
        q_all[s:s + chunk], d_all[s:s + chunk], t_all[s:s + chunk] = q[r, j], d[r, j], cand[r, j]
    return q_all, d_all, t_all


def _part_sd(part: SolidPart, pts):
    """Signed distance (m, + solid) of points to one part."""
    q, d, t = _closest(part.mesh, pts)
    if part.kind == "object" and part.mesh.is_watertight:
        inside = part.mesh.contains(pts)
    else:   # behind the nearest face (room: its sensor-facing faces)
        inside = ((pts - q) * part.mesh.face_normals[t]).sum(1) < 0
    return np.where(inside, d, -d)


def _band_cells(part: SolidPart, lo, voxel, shape, reach_voxels: int, seed: int):
    """Flat indices of the cells within `reach_voxels` of the part's surface (dense surface samples
    marked, then dilated)."""
    import trimesh
    from scipy.ndimage import binary_dilation

    n = int(np.ceil(part.mesh.area / (0.25 * voxel) ** 2)) + 64
    pts, _ = trimesh.sample.sample_surface(part.mesh, n, seed=seed)
    pts = np.concatenate([pts, part.mesh.vertices])
    idx = np.floor((pts - lo) / voxel).astype(np.int64)
    idx = idx[np.all((idx >= -reach_voxels) & (idx < np.array(shape) + reach_voxels), 1)]
    if len(idx) == 0:
        return np.zeros(0, np.int64)
    # dilate inside the part's own index box only (cheap for small parts on a big grid)
    a = np.maximum(idx.min(0) - reach_voxels, 0)
    b = np.minimum(idx.max(0) + reach_voxels + 1, shape)
    if np.any(b <= a):
        return np.zeros(0, np.int64)
    sub = np.zeros(tuple(b - a), bool)
    inside = np.all((idx >= a) & (idx < b), 1)
    sub[tuple((idx[inside] - a).T)] = True
    sub = binary_dilation(sub, np.ones((3, 3, 3), bool), iterations=reach_voxels)
    cells = np.argwhere(sub) + a
    return np.ravel_multi_index(tuple(cells.T), shape)


def oracle_signed_distance(parts: list[SolidPart], lo, voxel: float, shape, band_voxels: float = BAND_VOXELS,
                           seed: int = 0, sensor_origin=None) -> np.ndarray:
    """True signed distance (m, + solid) at the voxel centres lo + (i + 0.5) voxel of a (nx, ny, nz) grid,
    exact within `band_voxels` of a surface, +-band elsewhere (the sign of the region around it).
    sensor_origin: needed with room parts: a cell near one part's surface may lie deep behind a room part
    (the side walls' faces continue behind the curved wall), found by a ray to the sensor."""
    from scipy.ndimage import label

    shape = tuple(int(n) for n in shape)
    lo = np.asarray(lo, np.float64)
    size = int(np.prod(shape))
    best = np.full(size, -np.inf, np.float32)
    reach = int(np.ceil(band_voxels)) + 1
    own_cells = []
    for i, part in enumerate(parts):
        cells = _band_cells(part, lo, voxel, shape, reach, seed + i)
        own_cells.append(cells)
        if len(cells) == 0:
            continue
        centres = lo + (np.stack(np.unravel_index(cells, shape), 1) + 0.5) * voxel
        best[cells] = np.maximum(best[cells], _part_sd(part, centres).astype(np.float32))   # union of solids
    band = float(band_voxels) * voxel
    near = np.flatnonzero(np.isfinite(best) & (best < band))
    for part, own in zip(parts, own_cells):
        if part.kind != "room" or len(near) == 0:
            continue
        if sensor_origin is None:
            raise ValueError("oracle_signed_distance: room parts need the sensor origin")
        other = near[~np.isin(near, own)]                 # the part's own band has its exact distance
        centres = lo + (np.stack(np.unravel_index(other, shape), 1) + 0.5) * voxel
        best[other[_behind_room_part(part, centres, np.asarray(sensor_origin, np.float64))]] = band
    decided = (np.abs(best) <= band) | (best > band)           # exact near a surface, or deep inside a part
    sd = np.where(decided, np.minimum(best, band), np.nan).reshape(shape)
    lab, n = label(~decided.reshape(shape))
    if n:
        votes = np.zeros(n + 1)
        sign = np.sign(np.nan_to_num(sd))
        for ax in range(3):      # each far region votes with the signs of its decided neighbours
            for a, b in ((slice(1, None), slice(None, -1)), (slice(None, -1), slice(1, None))):
                sa = [slice(None)] * 3
                sb = [slice(None)] * 3
                sa[ax], sb[ax] = a, b
                la, sg = lab[tuple(sa)], sign[tuple(sb)]
                m = (la > 0) & (sg != 0)
                np.add.at(votes, la[m], sg[m])
        fill = np.where(votes[lab] > 0, band, -band)
        sd = np.where(np.isnan(sd), fill, sd)
    return sd.astype(np.float32)


def oracle_surface_volume(sd: np.ndarray, voxel: float, fast_config):
    """(volume, level) for marching cubes: the start field's ramp on `sd` through the fit's own
    `FastModel.surface_volume` (the raw density clipped to one voxel's ramp around the surface value)."""
    import types

    import torch

    from torch_recon.recon.fields import DensityGrid, GridBox
    from torch_recon.recon.models import FastModel
    from torch_recon.recon.visible_surface_init import surface_offset

    fc = fast_config
    b = surface_offset(fc.density_scale, voxel, max(fc.surface_slope, 1e-3))
    raw = np.clip(fc.surface_slope * sd / voxel + b, fc.raw_free, fc.raw_occupied) if fc.surface_slope > 0 else \
        np.where(sd > 0, fc.raw_occupied, fc.raw_free)
    box = GridBox.exact(np.zeros(3), voxel, sd.shape)
    grid = DensityGrid.from_xyz(box, torch.from_numpy(raw.astype(np.float32)), fc.density_scale)
    # no measured thin parts here: the export's hull inset (the fit's setting) spares none
    return FastModel.build_surface_volume(types.SimpleNamespace(fc=fc, grid=grid, thin_parts=None))


def export_oracle(sd, box, fit_config, out_path, smooth_iterations=None, min_island_fraction=None, metadata=None):
    """Marching cubes of the oracle field through the fit's export (api.export_volume, no UVs), free
    space = the truly empty cells; returns (files, mesh). smooth_iterations / min_island_fraction: other
    than the fit's (None: the fit's Taubin passes and island cleanup)."""
    from torch_recon.mesh_export import export_mesh
    from torch_recon.recon.api import export_volume, voxel_centre_box

    vol, level = oracle_surface_volume(sd, box.voxel, fit_config.fast)
    lo, hi = box.bbox_min.cpu().numpy(), box.bbox_max.cpu().numpy()
    smooth = fit_config.mesh_smooth_iterations if smooth_iterations is None else smooth_iterations
    meta = metadata or {"method": "oracle"}
    if min_island_fraction is None:     # the fast field's export, its hole mending too
        return export_volume(vol, lo, hi, level, out_path, meta, uv=False, free_space=sd < 0,
                             smooth_iterations=smooth, mend_gaps=True)
    # as export_volume, with the island cleanup changed (the exporter's grid points are the voxel centres)
    res = export_mesh(vol, *voxel_centre_box(vol, lo, hi), level, out_path.with_suffix(".ply"), meta, uv=False,
                      free_space=sd < 0, smooth_iterations=smooth, min_island_fraction=min_island_fraction,
                      mend_gaps=True)
    return {p.suffix.lstrip("."): p for p in res.paths}, res.mesh
