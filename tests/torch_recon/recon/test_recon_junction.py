"""Concave junctions of the room (a floor meeting a wall) in the start field and the mesh's free test
(recon/visible_surface_init.py, recon/unobserved.on_planes)."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("scipy")
pytest.importorskip("skimage")

from torch_recon.recon.fields import GridBox  # noqa: E402
from torch_recon.recon.visible_surface_init import surface_signed_distance  # noqa: E402

N = 16
VOXEL = 0.1


def _floor_meets_wall(spacing_voxels: float):
    """Floor z = zf seen from above and wall y = yw seen from the room, their points on a grid `spacing_voxels`
    apart (a coarse sensor: rows four voxels apart, the nearest 4.5 voxels from the wall and 1.5 above the floor)."""
    box = GridBox(torch.zeros(3), torch.full((3,), N * VOXEL), N)
    zf, yw = 4.83 * VOXEL, 11.47 * VOXEL
    s = spacing_voxels * VOXEL
    g = np.arange(0.3 * VOXEL, N * VOXEL, s)
    a, b = np.meshgrid(g, yw - 4.5 * VOXEL - np.arange(0, 3) * s, indexing="ij")
    floor = np.stack([a.ravel(), b.ravel(), np.full(a.size, zf)], 1)
    a, b = np.meshgrid(g, zf + 1.5 * VOXEL + np.arange(0, 3) * s, indexing="ij")
    wall = np.stack([a.ravel(), np.full(a.size, yw), b.ravel()], 1)
    pts = np.concatenate([floor, wall])
    nrm = np.concatenate([np.tile([0.0, 0.0, 1.0], (len(floor), 1)), np.tile([0.0, -1.0, 0.0], (len(wall), 1))])
    c = box.centres().numpy()
    below_floor = (c[..., 2] < zf - 0.25 * VOXEL) & (c[..., 1] < yw)
    room = (c[..., 2] > zf + 0.25 * VOXEL) & (c[..., 1] < yw - 0.25 * VOXEL)
    corner = (np.abs(c[..., 2] - zf) < 2 * VOXEL) & (np.abs(c[..., 1] - yw) < 2.5 * VOXEL)
    return box, pts, nrm, below_floor, room, corner, len(floor)


def test_a_coarse_sensors_junction_stays_behind_the_floor():
    """Points four voxels apart (64 px): the voxels below the floor next to the wall have a wall point as
    their nearest (in front of its plane) and no floor point within the ramp's reach; the other surface is
    looked for as far as twice the nearest point's distance. Without that, a groove a voxel deep ran along
    the junction and the mesh's face test dropped its faces (rows of pin-holes at 64 px)."""
    box, pts, nrm, below_floor, room, corner, _ = _floor_meets_wall(4.0)
    sd = surface_signed_distance(None, box, 2.0, surface=(pts, nrm), concave_corners=True).numpy()
    known = np.isfinite(sd)
    assert (below_floor & corner & known).sum() >= N          # a row of voxels along the junction
    assert (sd[below_floor & corner & known] > 0).all()
    assert (sd[room & known] < 0).all()
    off = surface_signed_distance(None, box, 2.0, surface=(pts, nrm), concave_corners=False).numpy()
    assert (off[below_floor & corner & known] < 0).any()     # the nearest plane alone: the groove


def test_only_the_corner_points_count_as_the_other_surface():
    """corner_points (the points on the room's bounding planes) restrict the rule: with none it is the plain
    nearest-plane field (an object's own concave corner, a seat meeting its back, is left alone); with the
    floor's points the voxels below the floor by the wall are behind."""
    box, pts, nrm, below_floor, _, corner, n_floor = _floor_meets_wall(4.0)
    off = surface_signed_distance(None, box, 2.0, surface=(pts, nrm)).numpy()
    none = surface_signed_distance(None, box, 2.0, surface=(pts, nrm), concave_corners=True,
                                   corner_points=np.zeros(len(pts), bool)).numpy()
    assert np.array_equal(np.isnan(off), np.isnan(none)) and np.allclose(off[~np.isnan(off)], none[~np.isnan(none)])
    floor_only = np.arange(len(pts)) < n_floor
    sd = surface_signed_distance(None, box, 2.0, surface=(pts, nrm), concave_corners=True,
                                 corner_points=floor_only).numpy()
    known = np.isfinite(sd)
    assert (sd[below_floor & corner & known] > 0).all()


def test_on_planes_is_the_ransac_inlier_test():
    from torch_recon.recon.unobserved import Plane, on_planes

    floor = Plane(np.array([0.0, 0.0, 1.0]), 0.0, 1.0)
    pts = np.array([[0.0, 0.0, 0.01], [1.0, 2.0, -0.02], [0.0, 0.0, 0.05], [0.0, 0.0, 0.0]])
    nrm = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.7071, 0.7071]])   # last: 45 degrees
    assert on_planes(pts, nrm, [floor], 0.03).tolist() == [True, True, False, False]
    assert not on_planes(pts, nrm, [], 0.03).any()


def _coarse_sensor_in_a_corner(w=12):
    """A w x w pixel sensor at the origin looking along -y at a wall y = -1.5 meeting a floor z = -0.4: pixel
    rays about three voxels apart at the junction."""
    from types import SimpleNamespace

    from torch_recon.contract.frames import camera_ray_directions, look_at_c2w
    c2w = look_at_c2w((0.0, 0.0, 0.0), (0.0, -1.0, 0.0))
    fov = np.radians(70.0)
    dirs = (camera_ray_directions(w, w, fov, "x") @ c2w[:3, :3].T).reshape(-1, 3)
    t_wall = 1.5 / -dirs[:, 1]
    t_floor = np.where(dirs[:, 2] < 0, 0.4 / np.maximum(-dirs[:, 2], 1e-9), np.inf)
    data = SimpleNamespace(sensor_origin=torch.zeros(3, dtype=torch.float64), pixel_dirs=torch.from_numpy(dirs),
                           visible_depth=torch.from_numpy(np.minimum(t_wall, t_floor)), height=w, width=w)
    box = GridBox(torch.tensor([-1.2, -1.7, -0.6]), torch.tensor([1.2, 0.3, 1.4]), 48)   # voxel about 4 cm
    return data, box, c2w, fov


def test_seen_free_reaches_into_a_concave_corner():
    """Between pixel rays that straddle the junction the chord cuts the corner: points in front of both the
    wall and the floor but behind the chord were not seen free (the mesh dropped the junction's faces).
    With corner_planes the nearest tangent plane along the ray bounds the free space: all of those points
    are free and still none behind either surface."""
    from torch_recon.contract.frames import project_points
    from torch_recon.recon.visible_surface_init import seen_free

    data, box, c2w, fov = _coarse_sensor_in_a_corner()
    p = box.centres().reshape(-1, 3).numpy().astype(np.float64)
    col, row, z = project_points(c2w, 12, 12, fov, p)
    in_img = ((z > 0) & (col >= 0.5) & (col < 11.5) & (row >= 0.5) & (row < 11.5)).reshape(box.shape)
    y, zz = p[:, 1].reshape(box.shape), p[:, 2].reshape(box.shape)
    clear = in_img & (y > -1.5 + box.voxel) & (zz > -0.4 + box.voxel)   # in front of both by a voxel
    by_corner = clear & (y < -1.5 + 4 * box.voxel) & (zz < -0.4 + 4 * box.voxel)
    chord = seen_free(data, box, c2w, fov, "x", margin_voxels=0.5).numpy()
    planes = seen_free(data, box, c2w, fov, "x", margin_voxels=0.5, corner_planes=True).numpy()
    assert by_corner.sum() >= 100 and (~chord[by_corner]).sum() >= 20
    assert planes[clear].all()
    behind = (y < -1.5) | (zz < -0.4)
    assert not planes[behind].any() and not chord[behind].any()
