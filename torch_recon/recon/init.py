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


def _accumulate(box: GridBox, origins, dirs, near, far, step, counts, chunk_samples=1 << 22, core: float = 0.5):
    """Add 1 to `counts` (flat, x-major) for every marching sample of each segment inside the box whose
    position lies within `core` voxel of the voxel centre on every axis (0.5: anywhere in the voxel;
    smaller: a segment that only clips a corner of a partly filled voxel does not count)."""
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
        if core < 0.5:
            frac = (pts - box.bbox_min) / box.voxel - idx
            keep &= ((frac - 0.5).abs() <= core).all(-1)
        flat = (idx[..., 0] * ny + idx[..., 1]) * nz + idx[..., 2]
        counts += torch.bincount(flat[keep], minlength=counts.numel())


def _accumulate_signed(box: GridBox, origins, dirs, depth, half_width, step, sums, counts, chunk_samples=1 << 22):
    """For samples within +-half_width of each ray's surface depth: per-voxel sum of (t - depth) and count."""
    n_per = int(2 * half_width / step) + 1
    k = (torch.arange(n_per, device=origins.device, dtype=origins.dtype) - (n_per - 1) / 2) * step
    nx, ny, nz = box.shape
    rays = max(1, chunk_samples // n_per)
    for i in range(0, origins.shape[0], rays):
        t = depth[i:i + rays, None] + k
        pts = origins[i:i + rays, None] + dirs[i:i + rays, None] * t[..., None]
        idx, inside = box.cell_index(pts)
        flat = ((idx[..., 0] * ny + idx[..., 1]) * nz + idx[..., 2])[inside]
        sd = k.expand_as(t)[inside]
        sums += torch.bincount(flat, weights=sd.double(), minlength=sums.numel())
        counts += torch.bincount(flat, minlength=counts.numel())


def surface_offset(density_scale: float, voxel: float, slope: float) -> float:
    """Raw value at the surface so that a ramp raw = slope * s / voxel + b (s: signed distance along
    the ray) has half its transmittance left at s = 0: integral of density_scale * softplus = ln 2."""
    x = np.linspace(-40.0, 40.0, 80001)
    sp = np.logaddexp(0.0, x)
    cum = np.cumsum(sp) * (x[1] - x[0])                     # integral of softplus from -inf to x
    need = math.log(2.0) * slope / (density_scale * voxel)
    return float(np.interp(need, cum, x))


def _segment_counts(data: RayData, box: GridBox, mask, off, step, core):
    """Per-voxel count of marching samples of the secondary segments x -> l of the pairs in `mask`."""
    counts = torch.zeros(int(np.prod(box.shape)), dtype=torch.long, device=data.pixel_dirs.device)
    pairs = torch.nonzero(mask & torch.isfinite(data.visible_depth[data.pair_pixel]), as_tuple=False).squeeze(1)
    if pairs.numel() == 0:
        return counts
    px = data.pair_pixel[pairs]
    x = data.sensor_origin + data.pixel_dirs[px] * data.visible_depth[px, None]
    v = data.spot_points[data.pair_spot[pairs]] - x
    length = torch.linalg.vector_norm(v, dim=-1)
    good = length > 2 * off
    u = v[good] / length[good, None]
    _accumulate(box, x[good], u, torch.full_like(length[good], off), length[good] - off, step, counts, core=core)
    return counts


def _pixel_stride(data: RayData, voxel: float, spacing_voxels: float = 1.0) -> int:
    """Pixel stride keeping neighbouring carving rays within `spacing_voxels` of each other out to the
    far surfaces (the 95th percentile depth): finer images carve with a subset of their pixels."""
    d = data.visible_depth[torch.isfinite(data.visible_depth)]
    if d.numel() == 0:
        return 1
    dirs = data.pixel_dirs.reshape(data.height, data.width, 3)
    ang = float(torch.arccos((dirs[0, 0] * dirs[0, 1]).sum().clamp(-1, 1))) if data.width > 1 else 1.0
    footprint = max(ang * float(torch.quantile(d, 0.95)), 1e-6)
    return max(1, int(spacing_voxels * voxel / footprint))


def evidence_grid(data: RayData, box: GridBox, surface_margin_voxels: float = 1.0, carve_min_lit: int = 1,
                  secondary_offset_m: float = 0.0, step_voxels: float = 0.5, carve_core: float = 0.5,
                  count_shadow: bool = False, carve_spacing_voxels: float = 1.0):
    """Per-voxel labels (nx, ny, nz) int8: 1 surface, 2 camera-free, 3 lit-free, 0 hidden; and the mean
    signed distance (m, along camera rays, + behind the surface; NaN far from any visible surface)."""
    dev = data.pixel_dirs.device
    n = int(np.prod(box.shape))
    step = step_voxels * box.voxel
    stride = _pixel_stride(data, box.voxel, carve_spacing_voxels)
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
    # shadow carving: lit pairs on the carving pixels only; shadowed pairs count occluder evidence
    on_sub = torch.zeros(data.height * data.width, dtype=torch.bool, device=dev)
    on_sub[sub] = True
    off = max(secondary_offset_m, surface_margin_voxels * box.voxel)
    lit_count = _segment_counts(data, box, data.lit & on_sub[data.pair_pixel], off, step, carve_core)
    shadow_count = (_segment_counts(data, box, data.shadowed & on_sub[data.pair_pixel], off, step, 0.5)
                    if count_shadow else torch.zeros_like(lit_count))
    label = torch.zeros(n, dtype=torch.int8, device=dev)
    label[lit_count >= max(1, carve_min_lit)] = 3
    label[cam_free > 0] = 2
    label[surface > 0] = 1
    # signed distance along the camera rays (all pixels) near the visible surfaces
    sd_sum = torch.zeros(n, dtype=torch.float64, device=dev)
    sd_cnt = torch.zeros(n, dtype=torch.long, device=dev)
    vd = data.visible_depth[okx]
    dirs_all = data.pixel_dirs[okx]
    _accumulate_signed(box, c.expand_as(dirs_all).contiguous(), dirs_all, vd, 2.0 * box.voxel, step, sd_sum, sd_cnt)
    sd = torch.where(sd_cnt > 0, sd_sum / sd_cnt.clamp(min=1), torch.full_like(sd_sum, float("nan"))).float()
    return label.reshape(box.shape), sd.reshape(box.shape), shadow_count.reshape(box.shape)


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


def hidden_occupied(box: GridBox, data: RayData, camera_to_world, fov_rad, fov_axis, thickness_m: float,
                    shell_voxels: float) -> torch.Tensor:
    """Which hidden voxels to fill (nx, ny, nz) bool: those at most `thickness_m` behind the visible
    surface on the sensor ray through them (objects and walls have some thickness), and those within
    `shell_voxels` of the box faces (the measured extent is bounded by walls, floor and ceiling)."""
    from ..contract.frames import project_points

    centres = box.centres()
    pts = centres.reshape(-1, 3).cpu().numpy()
    col, row, _ = project_points(camera_to_world, data.width, data.height, fov_rad, pts, fov_axis)
    ci = np.clip(np.floor(np.nan_to_num(col, nan=-1.0)), -1, data.width).astype(np.int64)
    ri = np.clip(np.floor(np.nan_to_num(row, nan=-1.0)), -1, data.height).astype(np.int64)
    inview = (ci >= 0) & (ci < data.width) & (ri >= 0) & (ri < data.height)
    vd = data.visible_depth.cpu().numpy().reshape(data.height, data.width)
    d = np.full(len(pts), np.nan, np.float32)
    d[inview] = vd[ri[inview], ci[inview]]
    rng = np.linalg.norm(pts - data.sensor_origin.cpu().numpy(), axis=1)
    behind = rng - d
    fill = np.isfinite(behind) & (behind >= -0.5 * box.voxel) & (behind <= thickness_m)
    fill = torch.as_tensor(fill.reshape(box.shape), device=centres.device)
    g = (centres - box.bbox_min) / box.voxel
    size = torch.tensor(box.shape, device=centres.device, dtype=g.dtype)
    edge = torch.minimum(g, size - g).amin(-1) < shell_voxels
    return fill | edge


def fov_xy(width: int, height: int, fov_rad: float, fov_axis: str):
    if fov_axis == "x":
        return fov_rad, 2.0 * math.atan(math.tan(0.5 * fov_rad) * height / width)
    return 2.0 * math.atan(math.tan(0.5 * fov_rad) * width / height), fov_rad


def initial_grid(data: RayData, box: GridBox, cfg, camera_to_world, fov_x: float, fov_y: float,
                 secondary_offset_m: float = 0.0) -> DensityGrid:
    """The fast mode's starting field (cfg: FastConfig)."""
    label, sd, shadow_count = evidence_grid(data, box, cfg.surface_margin_voxels, cfg.carve_min_lit,
                                            secondary_offset_m, cfg.step_voxels, cfg.carve_core,
                                            count_shadow=cfg.fill_min_shadow > 0,
                                            carve_spacing_voxels=cfg.carve_spacing_voxels)
    free = (label == 2) | (label == 3)
    if cfg.hidden_thickness_m is not None:   # hidden and uncarved: occupied only near surfaces / walls
        fov = fov_x if data.width >= data.height else fov_y
        axis = "x" if data.width >= data.height else "y"
        fill = hidden_occupied(box, data, camera_to_world, fov, axis, cfg.hidden_thickness_m, cfg.shell_voxels)
        if cfg.fill_min_shadow > 0:        # ... or where shadowed secondary rays say an occluder may be
            fill |= shadow_count >= cfg.fill_min_shadow
        free |= (label == 0) & ~fill
    raw = torch.where(free, torch.tensor(cfg.raw_free), torch.tensor(cfg.raw_occupied)).float().to(sd.device)
    if cfg.surface_slope > 0:
        # near visible surfaces a linear ramp in the signed distance puts the rendered surface at the
        # measured depth to a fraction of a voxel (trilinear interpolation reproduces a linear ramp)
        b = surface_offset(cfg.density_scale, box.voxel, cfg.surface_slope)
        ramp = (cfg.surface_slope * sd / box.voxel + b).clamp(cfg.raw_free, cfg.raw_occupied)
        near = torch.isfinite(sd) & ((label != 3) | (sd >= 0))   # a seen surface beats carving behind it
        raw = torch.where(near, ramp, raw)
    raw = extrude_unseen(raw, box, camera_to_world, fov_x, fov_y)
    return DensityGrid.from_xyz(box, raw.to(data.pixel_dirs.device), cfg.density_scale)
