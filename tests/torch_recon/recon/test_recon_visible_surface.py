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
    start, mesh_free = initial_grid(data, box, cfg.fast, model.offset, model._view(box))
    assert torch.equal(start.raw, model.grid.raw.detach()) and torch.equal(mesh_free, model.free)
    vol, iso = model.surface_volume()
    front = in_front_of_visible_surface(real(data, box), box, torch.from_numpy(vol < iso))
    assert np.array_equal(free, (mesh_free | front).numpy()) and (free & ~mesh_free.numpy()).any()
