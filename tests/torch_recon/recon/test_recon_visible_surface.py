"""The visible surface of the start field and its mesh faces (recon/visible_surface_init.py)."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("skimage")
pytest.importorskip("trimesh")

from torch_recon.mesh_export import mesh_from_volume  # noqa: E402
from torch_recon.recon.fields import GridBox  # noqa: E402
from torch_recon.recon.visible_surface_init import in_front_of_visible_surface  # noqa: E402

N = 16          # voxels per side
VOXEL = 0.1
Z_FLOOR = 0.53  # sub-voxel floor height


def _floor_box_and_points(stride: int):
    box = GridBox(torch.zeros(3), torch.full((3,), N * VOXEL), N)
    assert box.voxel == pytest.approx(VOXEL)
    # sparse measured points (every `stride`-th voxel: pixel footprints at grazing incidence are longer than a voxel)
    g = (np.arange(1, N - 1, stride) + 0.3) * VOXEL
    x, y = np.meshgrid(g, g, indexing="ij")
    pts = np.stack([x.ravel(), y.ravel(), np.full(x.size, Z_FLOOR)], 1)
    nrm = np.broadcast_to([0.0, 0.0, 1.0], pts.shape).copy()    # the sensor looks down on the floor
    return box, pts, nrm


def _floor_field(box):
    """Raw-like field: a linear ramp, positive below the floor (solid), negative above it."""
    z = box.centres()[..., 2]
    return (Z_FLOOR - z) / VOXEL


def test_front_of_a_floor_is_free_only_above_it():
    box, pts, nrm = _floor_box_and_points(stride=2)
    field = _floor_field(box)
    front = in_front_of_visible_surface((pts, nrm), box, field < 0)
    z = box.centres()[..., 2]
    assert front.any()
    assert not front[z < Z_FLOOR].any()                 # never below (behind) the measured surface
    assert front[z > Z_FLOOR + 2.6 * VOXEL].sum() == 0   # only the few voxels just in front of it
    # the layer just above the floor is covered between the sparse points too (the one-voxel growth)
    layer = (z > Z_FLOOR) & (z < Z_FLOOR + VOXEL)
    inner = torch.zeros_like(layer)
    inner[2:N - 3, 2:N - 3] = True
    assert front[layer & inner].all()


def test_floor_keeps_its_faces_where_no_camera_ray_passed():
    """Free evidence that stops short of the floor (a camera march ending a voxel before a grazing surface)
    reports no floor; the space in front of the measured points gives the whole floor back, flat."""
    box, pts, nrm = _floor_box_and_points(stride=2)
    field = _floor_field(box).numpy()
    z = box.centres()[..., 2].numpy()
    camera_free = z > Z_FLOOR + 2.0 * VOXEL           # no voxel within two voxels of the floor
    level = 0.0
    lo, hi = 0.5 * VOXEL * np.ones(3), (N - 0.5) * VOXEL * np.ones(3)      # grid points at the voxel centres
    without, _ = mesh_from_volume(field, lo, hi, level, free_space=camera_free)
    front = in_front_of_visible_surface((pts, nrm), box, torch.from_numpy(field < level)).numpy()
    with_front, _ = mesh_from_volume(field, lo, hi, level, free_space=camera_free | front)
    up = lambda m: m.face_normals[:, 2] > 0.9 if len(m.faces) else np.zeros(0, bool)  # noqa: E731
    floor_area = lambda m: float(m.area_faces[up(m)].sum()) if len(m.faces) else 0.0  # noqa: E731
    assert floor_area(without) < 0.05
    inner_area = ((N - 6) * VOXEL) ** 2
    assert floor_area(with_front) > inner_area
    # flat: every kept upward face lies on the floor plane
    assert np.abs(with_front.triangles_center[up(with_front), 2] - Z_FLOOR).max() < 1e-3


def test_fast_model_box_is_grid_bbox_and_its_visible_surface_is_computed_once(monkeypatch):
    """The fit's box is `init.grid_bbox`'s (the representation oracle builds its box from it), and the start
    field and the mesh's free space share one visible surface per grid level (same result as computing it
    for each)."""
    import torch_recon.recon.init as init
    import torch_recon.recon.models as models
    from tests.support.recon_fixtures import box_floor_measurements
    from tests.torch_recon.recon.test_recon_fit import small_config
    from torch_recon.recon.data import build_ray_data
    from torch_recon.recon.init import grid_bbox, initial_grid

    meas = box_floor_measurements(32)
    meta = {"camera_to_world": np.asarray(meas.camera_to_world), "fov_rad": meas.fov_rad, "fov_axis": meas.fov_axis}
    cfg = small_config(steps=0)
    data = build_ray_data(meas)
    calls = []
    real = models.visible_surface
    for module in (init, models):
        monkeypatch.setattr(module, "visible_surface", lambda d, box: calls.append(box.voxel) or real(d, box))
    model = models.FastModel(data, cfg, meta)
    res = cfg.fast.resolution
    box = GridBox(*grid_bbox(data, res, cfg.fast.bbox_margin_voxels), res)
    assert box.shape == model.grid.box.shape and box.voxel == model.grid.box.voxel
    assert torch.equal(box.bbox_min, model.grid.box.bbox_min.cpu())
    free = model.free_evidence()
    assert calls == [box.voxel]
    monkeypatch.undo()
    # the same free space and start field as without the shared surface
    start, mesh_free, _ = initial_grid(data, box, cfg.fast, model.offset, model._view(box))
    assert torch.equal(start.raw, model.grid.raw.detach()) and torch.equal(mesh_free, model.free)
    vol, iso = model.surface_volume()
    front = in_front_of_visible_surface(real(data, box), box, torch.from_numpy(vol < iso))
    assert np.array_equal(free, (mesh_free | front).numpy()) and (free & ~mesh_free.numpy()).any()


def _coarse_sensor_before_a_wall(w=6, wall=1.5, block=None):
    """A 6 x 6 pixel sensor at the origin looking along -y at a wall (y = -wall); pixel rays lie about five
    voxels apart at the wall. block: (x0, x1, z0, z1, y) a square plate facing the sensor in front of it."""
    from types import SimpleNamespace

    from torch_recon.contract.frames import camera_ray_directions, look_at_c2w
    c2w = look_at_c2w((0.0, 0.0, 0.0), (0.0, -1.0, 0.0))
    fov = np.radians(60.0)
    dirs = (camera_ray_directions(w, w, fov, "x") @ c2w[:3, :3].T).reshape(-1, 3)
    depth = wall / -dirs[:, 1]
    if block is not None:
        x0, x1, z0, z1, yb = block
        t = yb / -dirs[:, 1]
        hx, hz = dirs[:, 0] * t, dirs[:, 2] * t
        depth = np.where((hx > x0) & (hx < x1) & (hz > z0) & (hz < z1), t, depth)
    data = SimpleNamespace(sensor_origin=torch.zeros(3, dtype=torch.float64), pixel_dirs=torch.from_numpy(dirs),
                           visible_depth=torch.from_numpy(depth), height=w, width=w)
    box = GridBox(torch.tensor([-1.0, -1.7, -1.0]), torch.tensor([1.0, 0.3, 1.0]), 40)   # voxel 5 cm
    return data, box, c2w, fov


def test_seen_free_covers_the_space_between_coarse_pixel_rays():
    from torch_recon.contract.frames import project_points
    from torch_recon.recon.visible_surface_init import seen_free

    data, box, c2w, fov = _coarse_sensor_before_a_wall()
    free = seen_free(data, box, c2w, fov, "x", margin_voxels=0.5).numpy()
    p = box.centres().reshape(-1, 3).numpy().astype(np.float64)
    col, row, z = project_points(c2w, 6, 6, fov, p)
    in_img = ((z > 0) & (col >= 0) & (col < 6) & (row >= 0) & (row < 6)).reshape(box.shape)
    y = p[:, 1].reshape(box.shape)
    # the wall is planar and inverse depth is affine in the image: the surface between the pixels is exact,
    # so every voxel of the view more than a voxel in front of the wall is free, none behind it or just in
    # front of it (within the margin along the ray), none outside the view
    assert free[in_img & (y > -1.5 + box.voxel)].all()
    assert not free[y < -1.5 + 0.49 * box.voxel].any()
    assert not free[~in_img].any()


def test_seen_free_stops_at_the_nearest_surface_across_an_occluding_edge():
    from torch_recon.recon.visible_surface_init import seen_free

    plate = (-0.3, 0.3, -0.3, 0.3, 0.8)
    data, box, c2w, fov = _coarse_sensor_before_a_wall(block=plate)
    free = seen_free(data, box, c2w, fov, "x").numpy()
    p = box.centres().reshape(-1, 3).numpy()
    x, y, zz = (p[:, i].reshape(box.shape) for i in range(3))
    # the plate's shadow as the sensor sees it (behind the plate, within its silhouette): never free
    behind = (y < -0.8) & (np.abs(x / -y) < 0.3 / 0.8) & (np.abs(zz / -y) < 0.3 / 0.8) & (y > -1.5)
    assert behind.any() and not free[behind].any()
    assert free[(y > -0.7) & (y < -0.2) & (np.abs(x) < 0.1) & (np.abs(zz) < 0.1)].all()


def test_voxels_behind_either_surface_of_a_concave_corner_are_behind():
    """A floor (z = 4.53 voxels) meeting a wall (y = 10.47 voxels), both seen from the room (y < wall, z > floor),
    the floor at a grazing angle (its points in rows 3 voxels apart): the voxels below the floor next to the
    wall lie in front of the wall's plane, which is nearer than any floor point; the nearest plane alone
    called them empty (a row of pin-holes along the junction)."""
    from torch_recon.recon.visible_surface_init import surface_signed_distance

    box = GridBox(torch.zeros(3), torch.full((3,), N * VOXEL), N)
    zf, yw = 0.53 * VOXEL + 4 * VOXEL, 10.47 * VOXEL
    g = np.arange(0.1, N * VOXEL, 0.25 * VOXEL)
    rows = yw - np.arange(2.0, 14, 3.0) * VOXEL      # the floor seen at a grazing angle: pixel rows 3 voxels apart
    a, b = np.meshgrid(g, rows, indexing="ij")
    floor = np.stack([a.ravel(), b.ravel(), np.full(a.size, zf)], 1)
    floor = floor[floor[:, 1] > 0]
    a, b = np.meshgrid(g, g, indexing="ij")
    wall = np.stack([a.ravel(), np.full(a.size, yw), b.ravel()], 1)
    wall = wall[wall[:, 2] > zf]
    pts = np.concatenate([floor, wall])
    nrm = np.concatenate([np.tile([0.0, 0.0, 1.0], (len(floor), 1)), np.tile([0.0, -1.0, 0.0], (len(wall), 1))])
    c = box.centres().numpy()
    below_floor = (c[..., 2] < zf) & (c[..., 1] < yw)
    behind_wall = (c[..., 1] > yw) & (c[..., 2] > zf)
    room = (c[..., 2] > zf + 0.25 * VOXEL) & (c[..., 1] < yw - 0.25 * VOXEL)
    for concave, ok in ((True, True), (False, False)):
        sd = surface_signed_distance(None, box, 2.0, surface=(pts, nrm), concave_corners=concave).numpy()
        known = np.isfinite(sd)
        assert (sd[below_floor & known] > 0).all() == ok
        assert (sd[behind_wall & known] > 0).all()      # the densely seen wall was right either way
        assert (sd[room & known] < 0).all()          # the room's side of the corner stays in front


def test_a_coarse_sensor_carves_between_its_pixel_rays():
    """12 x 12 pixels on a 40-voxel grid (pixel rays several voxels apart at the far walls): the march leaves
    voxels in front of the visible surface uncarved; carving between the pixel rays (pixel rays farther apart
    than `fast.carve_seen_free_beyond_voxels`) empties them, and only voxels the footprint test sees through."""
    import torch_recon.recon.models as models
    from tests.support.recon_fixtures import box_floor_measurements
    from tests.torch_recon.recon.test_recon_fit import small_config
    from torch_recon.recon.data import build_ray_data

    meas = box_floor_measurements(12)
    meta = {"camera_to_world": np.asarray(meas.camera_to_world), "fov_rad": meas.fov_rad, "fov_axis": meas.fov_axis}
    data = build_ray_data(meas)
    cfg = small_config(steps=0)
    cfg.fast.nearest_free = cfg.fast.nearest_surface = False
    cfg.fast.carve_seen_free_beyond_voxels = 1e9
    plain = models.FastModel(data, cfg, meta)
    cfg.fast.carve_seen_free_beyond_voxels = 1.5
    seen = models.FastModel(data, cfg, meta)
    added = seen.free & ~plain.free
    assert int(added.sum()) > 0
    box = seen.grid.box
    from torch_recon.recon.visible_surface_init import seen_free

    seen_through = seen_free(data, box, meta["camera_to_world"], meta["fov_rad"], meta["fov_axis"],
                             cfg.fast.surface_margin_voxels, data.visible_depth, cfg.fast.seen_free_corners)
    assert bool(seen_through[added].all())
