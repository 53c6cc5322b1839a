"""The hidden hull's bounded inward smoothing (recon/hull_subvoxel.py, mesh_export.inward_smoothing; session 13)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torch_recon.contract.errors import SettingsError
from torch_recon.mesh_export import InwardSmoothing, inward_smoothing, mesh_from_volume
from torch_recon.recon.config import FitConfig, override
from torch_recon.recon.hull_subvoxel import hull_voxels


def _cube_volume(n=12, lo=3, hi=9):
    """A binary occupied cube on an (n, n, n) grid (1 m grid steps)."""
    v = np.zeros((n, n, n), np.float32)
    v[lo:hi, lo:hi, lo:hi] = 1.0
    return v


def test_inward_smoothing_cuts_convex_steps_bounded_and_only_inward():
    mesh, _ = mesh_from_volume(_cube_volume(), (0, 0, 0), (11, 11, 11), 0.5, min_island_fraction=0)
    start = mesh.vertices.copy()
    normals = mesh.vertex_normals.copy()
    movable = start[:, 0] > 5.5                  # the half of the cube at +x moves, the rest stays
    volume = mesh.volume
    inward_smoothing(mesh, movable, 0.3, 10)
    moved = mesh.vertices - start
    assert np.allclose(moved[~movable], 0.0)
    assert np.linalg.norm(moved, axis=1).max() <= 0.3 + 1e-9
    assert np.linalg.norm(moved[movable], axis=1).max() > 0.1         # the cube's edges and corners are cut
    assert (np.einsum("ij,ij->i", moved, normals) <= 1e-9).all()     # never outward
    assert mesh.volume < volume


def test_inward_smoothing_through_the_exporter_only_where_movable():
    vol = _cube_volume()
    plain, _ = mesh_from_volume(vol, (0, 0, 0), (11, 11, 11), 0.5, min_island_fraction=0)
    none, _ = mesh_from_volume(vol, (0, 0, 0), (11, 11, 11), 0.5, min_island_fraction=0,
                               inward=InwardSmoothing(np.zeros(vol.shape, bool), 0.4, 10))
    assert np.allclose(plain.vertices, none.vertices)
    cut, _ = mesh_from_volume(vol, (0, 0, 0), (11, 11, 11), 0.5, min_island_fraction=0,
                              inward=InwardSmoothing(vol > 0, 0.4, 10))
    assert cut.volume < plain.volume - 1.0 and np.all(np.isfinite(cut.vertices))


def test_restored_blockers_and_ramps_are_not_hull():
    """(7, 3, 3) start field: hull x >= 3 (raw 4), free x < 3 (raw -10)."""
    start = torch.full((7, 3, 3), -10.0)
    start[3:] = 4.0
    lit = torch.zeros(start.shape, dtype=torch.bool)
    assert bool(hull_voxels(start, -10.0, 4.0, lit)[3].all())
    assert not bool(hull_voxels(start, -10.0, 4.0, lit)[4:].any())        # the boundary layer only
    lit[3, 0] = True                                        # a carved voxel put back (a lit segment crossed it)
    start[2, 2] = 1.0                                       # a measured surface's ramp next to the hull
    hull = hull_voxels(start, -10.0, 4.0, lit)
    assert not bool(hull[3, 0].any()) and not bool(hull[3, 2].any()) and bool(hull[3, 1].all())


@pytest.mark.parametrize("key,bad", [("mesh_hull_shrink_voxels", "0.6"), ("mesh_hull_shrink_voxels", "-0.1"),
                                     ("mesh_hull_shrink_graze_samples", "-1")])
def test_shrink_settings_refused_on_one_line(key, bad):
    with pytest.raises(SettingsError, match=f"fast.{key}"):
        override(FitConfig(mode="fast"), [f"fast.{key}={bad}"])
    assert override(FitConfig(mode="fast"), ["fast.mesh_hull_shrink_voxels=0.5"]).fast.mesh_hull_shrink_voxels == 0.5


def test_fast_model_moves_only_the_hidden_hull_and_only_when_asked():
    """Box on a floor: the movable voxels are the shadow hull's boundary (behind the box, out of the sensor's
    view), none on the measured floor, walls or the box's seen faces, none beside camera-free space."""
    from tests.support.recon_fixtures import BOX_LO, box_floor_measurements
    from tests.torch_recon.recon.test_recon_fit import small_config
    from tests.torch_recon.recon.test_recon_freeze import _meta
    from torch_recon.recon.data import build_ray_data
    from torch_recon.recon.models import FastModel

    meas = box_floor_measurements(32)
    cfg = small_config(steps=1)
    assert cfg.fast.mesh_hull_shrink_voxels == 0.5      # the default since session 13
    cfg.fast.mesh_hull_shrink_voxels = 0.0
    model = FastModel(build_ray_data(meas), cfg, _meta(meas))
    vol, level = model.surface_volume()
    assert not model.mesh_inward(vol, level).movable.any()     # the plane snap alone (test_recon_room_planes.py)
    cfg.fast.mesh_hull_shrink_voxels = 0.4
    inward = model.mesh_inward(vol, level)
    movable, metres, steps = inward.movable, inward.max_move_m, inward.iterations
    assert movable.any() and metres == pytest.approx(0.4 * model.grid.box.voxel) and steps > 0
    centres = model.grid.box.centres().numpy()[movable]
    # the hull behind the box's seen front face (its back, the floor its shadow hides), not the measured surfaces
    assert (centres[:, 1] > BOX_LO[1] + model.grid.box.voxel).mean() > 0.9
    data = build_ray_data(meas)
    seen = (data.sensor_origin + data.pixel_dirs * data.visible_depth[:, None])[torch.isfinite(data.visible_depth)]
    idx, inside = model.grid.box.cell_index(seen)
    assert not movable[tuple(idx[inside].T.numpy())].any()      # no voxel holding a measured surface point
    from torch_recon.recon.fields import next_to
    from torch_recon.recon.hull_subvoxel import camera_free
    assert not (movable & next_to(camera_free(model, model.grid.box)).numpy()).any()     # no silhouette face


def test_the_export_reads_the_start_fields_lit_crossings_back_and_marches_no_lit_segment(monkeypatch):
    """Session 14 (issue 11): the start field's `VoxelEvidence` carries the voxels lit segments cross, the same as
    the lit march the export used to repeat (session 13's `shrinkable_hull`), and the hull's placement at export
    marches only the camera rays (its silhouettes) and the shadowed segments (their grazes), no lit segment (this
    box's hull has no flat patch: `fast.mesh_hull_flat_approach` marches the lit segments only near those)."""
    import torch_recon.recon.hull_trim as hull_trim
    import torch_recon.recon.segment_crossings as crossings
    from tests.support.recon_fixtures import box_floor_measurements
    from tests.torch_recon.recon.test_recon_fit import small_config
    from tests.torch_recon.recon.test_recon_freeze import _meta
    from torch_recon.recon.data import build_ray_data, lit_path_tolerance, unexplained_lit
    from torch_recon.recon.models import FastModel
    from torch_recon.recon.voxel_evidence import carving_pixel_mask

    meas = box_floor_measurements(32)
    data = build_ray_data(meas)
    model = FastModel(data, small_config(steps=1), _meta(meas))
    fc, box = model.fc, model.grid.box
    step, off = fc.step_voxels * box.voxel, max(model.offset, fc.surface_margin_voxels * box.voxel)
    on_sub = carving_pixel_mask(data, box, fc.carve_spacing_voxels)[data.pair_pixel]
    tol = lit_path_tolerance(data, box.voxel, fc.lit_path_tolerance_voxels)
    lit = crossings.segment_counts(data, box, data.lit & on_sub, off, step, fc.carve_core,
                                   unexplained_lit(data, tol) if tol > 0 else None).reshape(box.shape)
    assert lit.any() and torch.equal(model.evidence.lit_crossed, lit > 0)
    assert torch.equal(model.start_evidence().restored, model.evidence.label == 4)

    marched = []
    real = crossings.marching_cells

    def counted(box, origins, *args, **kwargs):
        marched.append(origins.shape[0])
        return real(box, origins, *args, **kwargs)

    for module in (crossings, hull_trim):
        monkeypatch.setattr(module, "marching_cells", counted)
    vol, level = model.surface_volume()
    movable = model.mesh_inward(vol, level).movable
    cameras = int(torch.isfinite(data.visible_depth).sum())
    shadowed = crossings.pair_segments(data, data.shadowed & on_sub, off)[0].shape[0]
    assert movable.any() and sorted(marched) == sorted([cameras, shadowed]), (marched, cameras, shadowed)
