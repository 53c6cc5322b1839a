"""Light between lit pixels (recon/lit_between.py): the surface between two neighbouring lit pixels on one
surface is lit, so its segment to the spot carves the voxels the pixel centres' segments pass by."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from torch_recon.recon.data import RayData  # noqa: E402
from torch_recon.recon.fields import GridBox  # noqa: E402
from torch_recon.recon.init import evidence_grid  # noqa: E402
from torch_recon.recon.lit_between import lit_midpoints  # noqa: E402


def _floor(n=4, spacing=0.3, block=False, shadow_pixel=None):
    """n x n pixels seeing a floor (z = 0) `spacing` apart from a sensor 2 m above; one spot 1 m above the floor.
    block: the last column sees a block's top at z = 0.4 instead (a depth edge); shadow_pixel: that pixel is
    shadowed. Returns RayData and the visible surface (points, normals)."""
    c = np.array([0.5, 0.5, 2.0])
    u = 0.05 + spacing * np.arange(n)
    x = np.stack(np.meshgrid(u, u, indexing="ij"), -1).reshape(-1, 2)
    x = np.concatenate([x, np.zeros((len(x), 1))], 1)
    if block:
        x[np.arange(len(x)) % n == n - 1, 2] = 0.4
    dirs = x - c
    depth = np.linalg.norm(dirs, axis=1)
    dirs /= depth[:, None]
    spot = np.array([[0.5, 0.5, 1.0]])
    lit = np.ones(len(x), bool)
    if shadow_pixel is not None:
        lit[shadow_pixel] = False
    f = lambda a, dt=torch.float32: torch.as_tensor(np.asarray(a), dtype=dt)  # noqa: E731
    data = RayData(sensor_origin=f(c), laser_origin=f(c), pixel_dirs=f(dirs), spot_points=f(spot),
                   laser_to_spot=f([1.0]), pair_pixel=f(np.arange(len(x)), torch.long),
                   pair_spot=f(np.zeros(len(x)), torch.long), path=f(np.where(lit, 1.0, np.nan)), lit=f(lit, torch.bool),
                   shadowed=f(~lit, torch.bool), visible_depth=f(depth), height=n, width=n)
    normals = np.tile([0.0, 0.0, 1.0], (len(x), 1))
    return data, (x, normals)


def _mids(data, normals, n):
    rows = cols = torch.arange(n)
    out = list(lit_midpoints(data, torch.as_tensor(normals, dtype=torch.float32), rows, cols, voxel=0.05))
    return torch.cat([m for _, m in out]).numpy()


def test_midpoints_of_lit_neighbours_on_one_surface():
    data, (x, nrm) = _floor()
    mids = _mids(data, nrm, 4)
    assert len(mids) == 12 + 12 + 9 + 9             # right, down and both diagonal neighbours of a 4 x 4 image
    assert np.allclose(mids[:, 2], 0.0, atol=1e-6)   # on the floor, between the pixels
    assert np.allclose(mids[0], 0.5 * (x[0] + x[1]), atol=1e-6)


def test_no_midpoint_across_a_depth_edge_or_next_to_a_shadowed_pixel():
    data, (x, nrm) = _floor(block=True)
    mids = _mids(data, nrm, 4)
    assert len(mids) == 42 - 4 - 3 - 3                # 4 right and 2 x 3 diagonal pairs cross the edge
    assert np.all(np.isin(np.round(mids[:, 2], 6), [0.0, 0.4]))
    data, (x, nrm) = _floor(shadow_pixel=5)           # pixel (1, 1): 8 neighbours
    assert len(_mids(data, nrm, 4)) == 42 - 8


def test_the_segment_between_two_lit_pixels_carves_what_the_centres_miss():
    data, visible = _floor()
    box = GridBox([-0.1, -0.1, -0.1], [1.1, 1.1, 1.1], 24)           # 5 cm voxels, pixels 30 cm apart
    mid = 0.5 * (visible[0][0] + visible[0][1])                       # between pixels (0, 0) and (0, 1)
    spot = data.spot_points[0].numpy()
    p = mid + (spot - mid) / np.linalg.norm(spot - mid) * 0.15       # 3 voxels up its segment to the spot
    i, j, k = np.floor((p - box.bbox_min.numpy()) / box.voxel).astype(int)
    kw = dict(surface_margin_voxels=1.0, carve_spacing_voxels=0.1, visible=visible)
    before, _ = evidence_grid(data, box, **kw)
    after, _ = evidence_grid(data, box, lit_between_voxels=0.5, **kw)
    assert int(before[i, j, k]) == 0 and int(after[i, j, k]) == 3      # hidden hull before, lit-free after
    assert int((after == 3).sum()) > int((before == 3).sum())
