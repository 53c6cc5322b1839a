"""The fast grid's size from the sensor: no finer than the pixels resolve.

Every visible point, camera ray and secondary ray is one per pixel, so a grid finer than the pixels'
footprint at the far surfaces has voxels between the rays that no measurement reaches: the visible
surface's ramps (a couple of voxels round each measured point) leave holes between the points, and the
shadow hull keeps every voxel between the lit secondary rays. A 32 x 32 px sensor on the 128 grid (4.4
voxels a pixel on cave-chair) gave a lattice of blobs over the room (depth L1 0.84 m, spurious 42 %).
`fast.max_voxels_per_pixel` caps the grid: at most that many voxels across one pixel's footprint at the
far surfaces (the 95th percentile visible depth, `voxel_evidence.far_pixel_spacing`). At 128 px the footprint is
about one voxel of the 128 grid and at 64 px about two, so the default grid (cap 2.2) stays 128 there; a
32 px sensor gets a grid of 65 (cave-chair: depth L1 0.84 -> 0.33 m, the walls whole; the chair stays a
blob, object F@2cm 0.23 -> 0.20: 32 px leaves about 3 x 5 pixels on it). A cap of 1.5 (grid 45 at 32 px)
gave L1 0.24 m but lost the chair (F@2cm 0.08), and at 64 px (grid 89) F@2cm 0.774 -> 0.732.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .config import FitConfig
from .data import RayData


def sensor_grid_resolution(data: RayData, max_voxels_per_pixel: float) -> int | None:
    """Voxels along the longest side of the observed scene at which one pixel's footprint at the far surfaces
    spans `max_voxels_per_pixel` voxels; None when that cannot be said (no visible depth, a one-pixel image)."""
    from .init import scene_bbox
    from .voxel_evidence import far_pixel_spacing

    spacing = far_pixel_spacing(data)
    if spacing is None or data.width < 2 or max_voxels_per_pixel <= 0:
        return None
    lo, hi = scene_bbox(data, 0.0)
    return max(4, int(math.ceil(max_voxels_per_pixel * float(np.max(hi - lo)) / spacing)))


def sensor_grid(data: RayData, cfg: FitConfig) -> tuple[FitConfig, dict | None]:
    """`cfg` with the fast grid capped by the sensor (`sensor_grid_resolution`), and a note saying so (None:
    unchanged). The coarse level keeps its ratio to the fine one."""
    fc = cfg.fast
    if cfg.mode != "fast" or fc.max_voxels_per_pixel <= 0:
        return cfg, None
    cap = sensor_grid_resolution(data, fc.max_voxels_per_pixel)
    if cap is None or cap >= fc.resolution:
        return cfg, None
    coarse = max(4, int(round(fc.coarse_resolution * cap / fc.resolution)))
    fast = dataclasses.replace(fc, resolution=cap, coarse_resolution=coarse)
    note = {"resolution": cap, "requested": fc.resolution, "max_voxels_per_pixel": fc.max_voxels_per_pixel,
            "sensor_px": [data.width, data.height]}
    return dataclasses.replace(cfg, fast=fast), note


def describe(note: dict) -> str:
    """One line for the fit log."""
    w, h = note["sensor_px"]
    return (f"grid {note['resolution']} (not {note['requested']}): a {w} x {h} px sensor resolves no finer "
            f"(fast.max_voxels_per_pixel={note['max_voxels_per_pixel']:g}; set it to 0 to keep fast.resolution)")
