"""Where a point lies against what its own pixels measured (session 18): behind the farthest surface its nearest
pixel rays saw (the hidden hull behind a backrest's foot), or in front of the nearest one (the sensor saw through
it, also where no pixel ray's march crossed its voxel: 128 px at 3 m miss every third 3.2 cm voxel column)."""

from __future__ import annotations

import numpy as np
import torch

from .data import RayData


def behind_pixels(data: RayData, points: torch.Tensor, k: int = 4, depth: torch.Tensor | None = None,
                  farthest: bool = True) -> torch.Tensor:
    """Points (N, 3) -> float64 (N,): how far (m) each lies behind the farthest visible surface its `k` nearest pixel
    rays (by direction, within three pixels' angle) measured; NaN where one of them measured nothing or the point is
    outside the image. Positive: hidden behind what the pixels saw, also at a depth edge (one pixel seeing the far
    side makes it negative). depth: (P,) range per pixel (default the visible depth); farthest False: behind the
    nearest of the k surfaces instead (negative: in front of every one, the sensor saw through the point)."""
    from scipy.spatial import cKDTree

    from .data import pixel_angle

    c = data.sensor_origin.detach().cpu().double()
    rel = points.detach().cpu().double().reshape(-1, 3) - c
    r = rel.norm(dim=1).numpy()
    if len(r) == 0:
        return torch.zeros(0, dtype=torch.float64)
    dirs = data.pixel_dirs.detach().cpu().double().numpy()
    dist, j = cKDTree(dirs).query((rel / rel.norm(dim=1).clamp(min=1e-12)[:, None]).numpy(), k=min(k, len(dirs)))
    dist, j = dist.reshape(len(r), -1), j.reshape(len(r), -1)
    rng = data.visible_depth if depth is None else depth
    depth = rng.detach().cpu().double().numpy()[np.minimum(j, len(dirs) - 1)]
    reach = 2.0 * np.sin(1.5 * (pixel_angle(data, at_centre=True) or 1e-3))     # chord of three pixels' angle
    seen = np.isfinite(dist).all(1) & (dist.max(1) <= reach) & np.isfinite(depth).all(1)
    surface = np.where(np.isfinite(depth), depth, 0.0)
    return torch.as_tensor(np.where(seen, r - (surface.max(1) if farthest else surface.min(1)), np.nan))


def seen_through(data: RayData, points: torch.Tensor, margin_m: float, nearest_free: bool = True) -> torch.Tensor:
    """Points (N, 3) -> bool (N,): each lies more than `margin_m` in front of the surface every one of its four
    nearest pixels measured (`behind_pixels`, the nearest of them; with `nearest_free` a thin part's earliest return
    counts): the sensor saw through it, also where no pixel ray's march crossed its voxel."""
    depth = data.visible_depth
    if nearest_free and data.nearest_depth is not None:
        depth = torch.fmin(data.nearest_depth, depth)
    return (behind_pixels(data, points, depth=depth, farthest=False) < -margin_m).to(points.device)
