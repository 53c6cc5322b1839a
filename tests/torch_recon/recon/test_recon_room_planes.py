"""The room's bounding planes: fitted once per fit and voxel size (`FastModel.room_planes`), and read by each setting
that uses them on its own setting (session 20, issue 11)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.support.recon_fixtures import box_floor_measurements
from tests.torch_recon.recon.test_recon_fit import small_config
from tests.torch_recon.recon.test_recon_freeze import _meta
from torch_recon.recon.data import build_ray_data
from torch_recon.recon.models import FastModel


@pytest.fixture(scope="module")
def meas():
    return box_floor_measurements(32)


def _model(meas, **fast):
    cfg = small_config(steps=1)
    cfg.fast.resolution = 56
    for k, v in fast.items():
        setattr(cfg.fast, k, v)
    return FastModel(build_ray_data(meas), cfg, _meta(meas))


def test_the_edge_freeze_and_the_plane_snap_get_their_planes_with_the_start_fields_readers_off(meas):
    """Neither the unobserved completion, the hull trim, the concave corners nor the objects' measured points read the
    planes: the edge freeze and the plane snap still get them (session 19's code gave both none, silently)."""
    model = _model(meas, complete_unobserved=False, trim_hull_voxels=0, surface_concave_corners="off",
                   explain_measured_scale_voxels=0.0, freeze_spot_radius_voxels=0.0, freeze_plane_edges_voxels=2.0,
                   mesh_plane_snap_voxels=1.0)
    assert model.frozen_voxels is not None and len(model.frozen_voxels) > 0       # the floor-wall edge
    vol, level = model.surface_volume()
    inward = model.mesh_inward(vol, level)
    assert inward is not None and inward.plane_offsets is not None and len(inward.plane_offsets) >= 2


def test_the_plane_snap_runs_with_the_hulls_shrink_off(meas):
    """`fast.mesh_plane_snap_voxels` on its own: with `fast.mesh_hull_shrink_voxels` 0 the export still gets the planes
    (session 19's code returned no inward step at all, so the snap silently did nothing); nothing moves inward."""
    model = _model(meas, mesh_hull_shrink_voxels=0.0, mesh_plane_snap_voxels=1.0)
    vol, level = model.surface_volume()
    inward = model.mesh_inward(vol, level)
    assert inward is not None and not inward.movable.any() and inward.plane_snap_m > 0
    assert inward.plane_offsets is not None and len(inward.plane_offsets) >= 1 and inward.placed.any()
    from torch_recon.mesh_export import mesh_from_volume
    box = model.grid.box
    lo = box.bbox_min.numpy() + 0.5 * box.voxel
    hi = lo + (np.array(box.shape) - 1) * box.voxel
    plain, _ = mesh_from_volume(vol, lo, hi, level, smooth_iterations=10, min_island_fraction=0)
    snapped, _ = mesh_from_volume(vol, lo, hi, level, smooth_iterations=10, inward=inward, min_island_fraction=0)
    moved = np.linalg.norm(snapped.vertices - plain.vertices, axis=1) > 1e-9
    assert len(plain.vertices) == len(snapped.vertices) and moved.any()       # onto the planes, nothing else
    d = np.abs(snapped.vertices[moved] @ inward.plane_normals.T - inward.plane_offsets).min(1)
    assert np.all(d < 1e-6)
    assert _model(meas, mesh_hull_shrink_voxels=0.0, mesh_plane_snap_voxels=0.0).mesh_inward(vol, level) is None


def test_the_planes_are_fitted_once_per_fit(meas, monkeypatch):
    """The start field, the edge freeze and the mesh's plane snap (all on by default) share one RANSAC; the same
    planes as a fresh fit of them (seeded)."""
    from torch_recon.recon import unobserved
    from torch_recon.recon.init import room_planes

    calls = []
    fitted = unobserved.bounding_planes
    monkeypatch.setattr(unobserved, "bounding_planes", lambda *a, **k: calls.append(1) or fitted(*a, **k))
    model = _model(meas)
    fc = model.fc
    assert fc.freeze_plane_edges_voxels > 0 and fc.mesh_plane_snap_voxels > 0 and fc.complete_unobserved
    vol, level = model.surface_volume()
    model.mesh_inward(vol, level)
    assert len(calls) == 1
    box = model.grid.box
    again = room_planes(model.data, box, fc, model.visible_surface(box))
    assert [(tuple(p.normal), p.offset) for p in again] == [(tuple(p.normal), p.offset) for p in model.room_planes(box)]
