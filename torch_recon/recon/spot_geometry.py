"""Geometry of the spot advisor (recon/spot_advice.py): which side of the fit's voxels faces away from the
sensor (the back faces only grazing light places), laser directions beyond the sensor's image, and the
two-bounce paths a spot causes (which the sensor must record)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from ..contract.spots import pixel_directions
from .fields import GridBox


def _neighbour_axes(grid: torch.Tensor):
    """(axis, sign, neighbour) for the six face neighbours of each voxel of a bool grid (outside: False)."""
    for axis in range(3):
        for sign in (1, -1):
            nb = torch.zeros_like(grid)
            src, dst = [slice(None)] * 3, [slice(None)] * 3
            src[axis] = slice(1, None) if sign > 0 else slice(None, -1)
            dst[axis] = slice(None, -1) if sign > 0 else slice(1, None)
            nb[tuple(dst)] = grid[tuple(src)]
            yield axis, sign, nb


def _away_from_sensor(box: GridBox, camera_to_world, device) -> torch.Tensor:
    """(nx, ny, nz, 3) voxel centre minus the sensor's position."""
    sensor = torch.as_tensor(np.asarray(camera_to_world, np.float64)[:3, 3], dtype=torch.float32, device=device)
    return box.centres().to(device) - sensor


def back_facing_free(occupied: torch.Tensor, box: GridBox, camera_to_world) -> torch.Tensor:
    """(nx, ny, nz) bool: occupied voxels with an unoccupied face neighbour on the side facing away from the
    sensor (the neighbour's direction d with d . (voxel centre - sensor) > 0): the fit's back faces."""
    away = _away_from_sensor(box, camera_to_world, occupied.device)
    out = torch.zeros_like(occupied)
    for axis, sign, free_nb in _neighbour_axes(~occupied):
        out |= free_nb & (sign * away[..., axis] > 0)
    return occupied & out


def beyond_view_directions(sensor, beyond_deg: float, n: int = 64):
    """Laser directions (M, 3) outside the sensor's image and at most `beyond_deg` beyond its edge, on a
    regular grid of image coordinates (the image's own projection, extended)."""
    w, h = sensor.width, sensor.height
    f = 0.5 * (w if sensor.fov_axis == "x" else h) / math.tan(0.5 * sensor.fov_rad)
    half_x, half_y = math.atan(0.5 * w / f), math.atan(0.5 * h / f)
    ext_x = f * math.tan(min(half_x + math.radians(beyond_deg), math.radians(85.0)))
    ext_y = f * math.tan(min(half_y + math.radians(beyond_deg), math.radians(85.0)))
    cols = 0.5 * w + np.linspace(-ext_x, ext_x, n)
    rows = 0.5 * h + np.linspace(-ext_y, ext_y, n)
    cc, rr = np.meshgrid(cols, rows)
    outside = (cc < 0) | (cc >= w) | (rr < 0) | (rr >= h)
    return pixel_directions(sensor, np.stack([cc[outside], rr[outside]], 1))


def degrees_beyond_view(sensor, points) -> float:
    """How far (deg) beyond the edge of the sensor's image the farthest of `points` (N, 3) lies, along the
    image's x or y axis (the measure `beyond_view_directions` extends the image by); 0 when all project
    inside or lie behind the sensor."""
    from ..contract.frames import focal_length_px, project_points

    col, row, depth = project_points(sensor.camera_to_world, sensor.width, sensor.height, sensor.fov_rad,
                                     np.asarray(points, np.float64).reshape(-1, 3), sensor.fov_axis)
    front = depth > 0
    if not np.any(front):
        return 0.0
    f = focal_length_px(sensor.width, sensor.height, sensor.fov_rad, sensor.fov_axis)
    over_x = np.arctan(np.abs(col[front] - 0.5 * sensor.width) / f) - math.atan(0.5 * sensor.width / f)
    over_y = np.arctan(np.abs(row[front] - 0.5 * sensor.height) / f) - math.atan(0.5 * sensor.height / f)
    return float(np.degrees(max(0.0, over_x.max(), over_y.max())))


#: two-bounce paths must end this far before the sensor's last bin (the pulse's width and the sub-pixel spread)
PATH_MARGIN_M = 0.25


def _path_range_end(dataset):
    """The optical path (m) at the end of the dataset's last time bin; None without a dataset directory."""
    if dataset is None or not Path(dataset).is_dir():
        return None
    from ..contract.dataset import load_dataset

    sensor = load_dataset(dataset).manifest.sensor
    return float(sensor.start_m + sensor.bins * sensor.bin_width_m)


def _longest_lit_path(spots, spot_nrm, xs, ns, data):
    """Per spot (N, 3), the longest two-bounce path |l - o| + |x - l| + |c - x| over the visible points x that
    face it and that it faces (what the sensor must record)."""
    to_cam = torch.linalg.vector_norm(xs - data.sensor_origin, dim=1)
    out = []
    for l, n in zip(spots, spot_nrm):
        v = l - xs
        facing = ((v * ns).sum(1) > 0) & ((v * n).sum(1) <= 0)
        path = torch.linalg.vector_norm(l - data.laser_origin) + torch.linalg.vector_norm(v, dim=1) + to_cam
        out.append(path[facing].max() if bool(facing.any()) else path.new_tensor(0.0))
    return torch.stack(out)
