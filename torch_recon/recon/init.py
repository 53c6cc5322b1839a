"""Fast-mode initialisation: a density grid from the closed-form visible depth and shadow carving.

Evidence, voxel by voxel (priority top to bottom):
1. the voxel holding a visible surface point x = c + d u (closed-form depth d): occupied;
2. crossed by a camera ray before its visible surface: free;
3. crossed by at least `carve_min_lit` lit secondary rays x -> l: free (shadow carving);
4. otherwise (hidden from the sensor and never lit through): occupied, the shadow hull of BF Lidar.
Outside the sensor's field of view nothing was measured; those voxels copy the nearest measured
cross-section along the viewing axis (a room's floor, walls and ceiling continue towards the sensor).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from .data import RayData
from .fields import DensityGrid, GridBox
from .sampler import marching_intervals, ray_box


def scene_bbox(data: RayData, margin_m: float, quantile: float = 0.001):
    """Robust extent of the observed surface points, the spots and the sensor, grown by `margin_m`.

    The sensor is inside: the space between it and the surfaces was measured (free), and the
    unseen parts of a room next to the sensor are filled from there (see extrude_unseen).
    """
    pts = data.scene_points()
    if len(pts) < 2:
        raise ValueError("measurements: no visible depth and no spots: cannot bound the scene")
    lo = np.quantile(pts, quantile, axis=0) - margin_m
    hi = np.quantile(pts, 1.0 - quantile, axis=0) + margin_m
    must = np.concatenate([pts[-len(data.spot_points):], data.sensor_origin.cpu().numpy()[None]], 0)
    lo = np.minimum(lo, must.min(0) - margin_m)
    hi = np.maximum(hi, must.max(0) + margin_m)
    return lo.astype(np.float32), hi.astype(np.float32)


def _accumulate(box: GridBox, origins, dirs, near, far, step, counts, chunk_samples=1 << 22):
    """Add 1 to `counts` (flat, x-major) for every marching sample of each segment inside the box."""
    nx, ny, nz = box.shape
    if origins.shape[0] == 0:
        return
    n_per = max(1, int(float((far - near).clamp(min=0).max()) / step) + 1)
    rays = max(1, chunk_samples // n_per)
    for i in range(0, origins.shape[0], rays):
        t0, t1 = marching_intervals(near[i:i + rays], far[i:i + rays], step)
        pts = origins[i:i + rays, None] + dirs[i:i + rays, None] * (0.5 * (t0 + t1))[..., None]
        idx, inside = box.cell_index(pts)
        keep = inside & (t1 > t0)
        flat = (idx[..., 0] * ny + idx[..., 1]) * nz + idx[..., 2]
        counts += torch.bincount(flat[keep], minlength=counts.numel())


def _pixel_stride(data: RayData, voxel: float) -> int:
    """Pixel stride keeping neighbouring carving rays within 0.7 voxel of each other out to the far surfaces."""
    d = data.visible_depth[torch.isfinite(data.visible_depth)]
    if d.numel() == 0:
        return 1
    dirs = data.pixel_dirs.reshape(data.height, data.width, 3)
    ang = float(torch.arccos((dirs[0, 0] * dirs[0, 1]).sum().clamp(-1, 1))) if data.width > 1 else 1.0
    footprint = max(ang * float(torch.quantile(d, 0.95)), 1e-6)
    return max(1, int(0.7 * voxel / footprint))


def evidence_grid(data: RayData, box: GridBox, surface_margin_voxels: float = 1.0, carve_min_lit: int = 1,
                  secondary_offset_m: float = 0.0, step_voxels: float = 0.5):
    """Per-voxel labels (nx, ny, nz) int8: 1 surface, 2 camera-free, 3 lit-free, 0 hidden."""
    dev = data.pixel_dirs.device
    n = int(np.prod(box.shape))
    step = step_voxels * box.voxel
    stride = _pixel_stride(data, box.voxel)
    rows = torch.arange(0, data.height, stride, device=dev)
    cols = torch.arange(0, data.width, stride, device=dev)
    sub = (rows[:, None] * data.width + cols[None, :]).reshape(-1)
    d = data.visible_depth[sub]
    ok = torch.isfinite(d)
    sub, d = sub[ok], d[ok]
    c = data.sensor_origin
    dirs = data.pixel_dirs[sub]
    org = c.expand_as(dirs).contiguous()
    near, _ = ray_box(org, dirs, box.bbox_min, box.bbox_max)
    free_end = d - surface_margin_voxels * box.voxel
    cam_free = torch.zeros(n, dtype=torch.long, device=dev)
    _accumulate(box, org, dirs, near, torch.maximum(free_end, near), step, cam_free)
    surface = torch.zeros(n, dtype=torch.long, device=dev)
    x_all = c + data.pixel_dirs * data.visible_depth[:, None]
    okx = torch.isfinite(data.visible_depth)
    idx, inside = box.cell_index(x_all[okx])
    flat = (idx[:, 0] * box.shape[1] + idx[:, 1]) * box.shape[2] + idx[:, 2]
    surface += torch.bincount(flat[inside], minlength=n)
    # shadow carving: lit pairs on the carving pixels only
    on_sub = torch.zeros(data.height * data.width, dtype=torch.bool, device=dev)
    on_sub[sub] = True
    pairs = torch.nonzero(data.lit & on_sub[data.pair_pixel], as_tuple=False).squeeze(1)
    lit_count = torch.zeros(n, dtype=torch.long, device=dev)
    if pairs.numel():
        px = data.pair_pixel[pairs]
        x = c + data.pixel_dirs[px] * data.visible_depth[px, None]
        l = data.spot_points[data.pair_spot[pairs]]
        v = l - x
        length = torch.linalg.vector_norm(v, dim=-1)
        off = max(secondary_offset_m, surface_margin_voxels * box.voxel)
        good = length > 2 * off
        u = v[good] / length[good, None]
        _accumulate(box, x[good], u, torch.full_like(length[good], off), length[good] - off, step, lit_count)
    label = torch.zeros(n, dtype=torch.int8, device=dev)
    label[lit_count >= max(1, carve_min_lit)] = 3
    label[cam_free > 0] = 2
    label[surface > 0] = 1
    return label.reshape(box.shape)


def extrude_unseen(values: torch.Tensor, box: GridBox, camera_to_world, fov_x: float, fov_y: float):
    """Voxels outside the sensor's view frustum copy the first voxel inside it along the viewing axis."""
    c2w = torch.as_tensor(np.asarray(camera_to_world), dtype=torch.float32, device=values.device)
    centres = box.centres().reshape(-1, 3)
    rel = (centres - c2w[:3, 3]) @ c2w[:3, :3]          # camera coordinates (x right, y up, -z forward)
    depth = -rel[:, 2]
    tx, ty = math.tan(0.5 * fov_x), math.tan(0.5 * fov_y)
    need = torch.maximum(rel[:, 0].abs() / tx, rel[:, 1].abs() / ty)   # depth at which the point is in view
    shift = (need - depth).clamp(min=0.0)
    outside = shift > 0
    if not outside.any():
        return values
    fwd = -c2w[:3, 2]
    src = centres[outside] + (shift[outside] + 0.5 * box.voxel)[:, None] * fwd
    idx, inside = box.cell_index(src)
    flat = values.reshape(-1).clone()
    vals = values.reshape(-1)[(idx[:, 0] * box.shape[1] + idx[:, 1]) * box.shape[2] + idx[:, 2]]
    tgt = torch.nonzero(outside, as_tuple=False).squeeze(1)
    flat[tgt[inside]] = vals[inside]
    return flat.reshape(values.shape)


def fov_xy(width: int, height: int, fov_rad: float, fov_axis: str):
    if fov_axis == "x":
        return fov_rad, 2.0 * math.atan(math.tan(0.5 * fov_rad) * height / width)
    return 2.0 * math.atan(math.tan(0.5 * fov_rad) * width / height), fov_rad


def initial_grid(data: RayData, box: GridBox, cfg, camera_to_world, fov_x: float, fov_y: float,
                 secondary_offset_m: float = 0.0) -> DensityGrid:
    """The fast mode's starting field (cfg: FastConfig)."""
    label = evidence_grid(data, box, cfg.surface_margin_voxels, cfg.carve_min_lit, secondary_offset_m,
                          cfg.step_voxels)
    label = extrude_unseen(label, box, camera_to_world, fov_x, fov_y)
    free = (label == 2) | (label == 3)
    raw = torch.where(free, torch.tensor(cfg.raw_free), torch.tensor(cfg.raw_occupied)).float()
    return DensityGrid.from_xyz(box, raw.to(data.pixel_dirs.device), cfg.density_scale)
