"""Flat faces of the hidden hull move inward, to the middle of the gap the light left (`fast.mesh_hull_flat_approach`,
session 15; recon/hull_flat.py)."""

from __future__ import annotations

import numpy as np
import pytest

from torch_recon.contract.errors import SettingsError
from torch_recon.mesh_export import InwardSmoothing, mesh_from_volume
from torch_recon.recon.config import FitConfig, override
from torch_recon.recon.hull_flat import flat_patch_voxels


def _slab_volume(n=16):
    """A binary occupied block (1 m grid steps): x 3..8, y and z 3..12 (a 10 x 10 face at +x)."""
    v = np.zeros((n, n, n), np.float32)
    v[3:9, 3:13, 3:13] = 1.0
    return v


def test_flat_patches_are_the_large_coplanar_faces_only():
    occ = np.zeros((16, 16, 16), bool)
    occ[3:9, 3:13, 3:13] = True                 # faces of 6 x 10 and 10 x 10 voxels
    occ[9, 5, 5] = True                         # a one-voxel step on the +x face
    free = ~occ
    flat = flat_patch_voxels(occ, free, 15)
    assert flat[8, 8, 8] and flat[3, 8, 8]       # the +x and -x faces' layers
    assert not flat[9, 5, 5]                     # the step: a patch of 1 (+x) and 4 side faces of 1
    assert not flat[5, 8, 8]                     # inside
    assert not flat_patch_voxels(occ, free, 200).any()


def test_the_flat_face_moves_inward_by_its_offset_where_smoothing_alone_leaves_it():
    vol = _slab_volume()
    hull = vol > 0
    hull[4:8, 4:12, 4:12] = False                # the outer layer only
    free = vol == 0
    kw = dict(min_island_fraction=0, smooth_iterations=0)
    plain, _ = mesh_from_volume(vol, (0, 0, 0), (15, 15, 15), 0.5, inward=InwardSmoothing(hull, 0.5, 10), **kw)
    flat_voxels = flat_patch_voxels(hull, free, 15)
    offsets = np.where(flat_voxels[..., None], 0.25, 0.0) * np.ones(6)     # a quarter voxel on every face
    flat, _ = mesh_from_volume(vol, (0, 0, 0), (15, 15, 15), 0.5,
                               inward=InwardSmoothing(hull, 0.5, 10, offsets), **kw)
    mid = lambda m: m.vertices[(np.abs(m.vertices[:, 1] - 7.5) < 1.6) & (np.abs(m.vertices[:, 2] - 7.5) < 1.6)
                               & (m.vertices[:, 0] > 8)]
    assert np.all(mid(plain)[:, 0] > 8.44)                        # the smoothing leaves the flat run (about)
    assert np.all(mid(flat)[:, 0] < 8.27)                         # the offset moves it a quarter voxel in
    assert np.all(mid(flat)[:, 0] > 8.2)
    assert np.all(np.isfinite(flat.vertices))


def test_flat_patch_size_is_range_checked():
    with pytest.raises(SettingsError, match="fast.mesh_hull_flat_patch_faces"):
        override(FitConfig(mode="fast"), ["fast.mesh_hull_flat_patch_faces=0"])


def _unit_box(n=6):
    import torch

    from torch_recon.recon.fields import GridBox
    return GridBox.exact(torch.zeros(3), 1.0, [n, n, n])


def test_light_approach_is_the_nearest_lit_sample_to_each_face_of_the_cell():
    """Voxel (2, 2, 2) spans [2, 3]^3 (1 m voxels): a segment along z at x 2.3, y 2.5 and one along y at x 2.8,
    z 2.6 pass through it; one along z at x 4.5 does not. Approach to -x: 0.3, +x: 0.2, -y / +y: 0.5 / 0.5 less
    the fine step's half (the y segment's samples), -z: 0.4 (the y segment), +z: the z segment's last sample."""
    import torch

    from torch_recon.recon.hull_flat import APPROACH_STEP_VOXELS, light_approach
    box = _unit_box()
    cells = torch.zeros(box.shape, dtype=torch.bool)
    cells[2, 2, 2] = cells[4, 4, 4] = True
    o = torch.tensor([[2.3, 2.5, 0.0], [2.8, 0.0, 2.6], [4.5, 2.5, 0.0]])
    u = torch.tensor([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    near, far = torch.full((3,), 0.2), torch.full((3,), 5.9)
    d = light_approach(box, o, u, near, far, cells)
    half = 0.5 * APPROACH_STEP_VOXELS
    assert d.shape == (2, 6)
    assert d[0, 0] == pytest.approx(0.3, abs=1e-5) and d[0, 1] == pytest.approx(0.2, abs=1e-5)
    assert d[0, 2] == pytest.approx(half, abs=half + 1e-5) and d[0, 3] == pytest.approx(half, abs=half + 1e-5)
    assert d[0, 4] == pytest.approx(half, abs=half + 1e-5) and d[0, 5] == pytest.approx(half, abs=half + 1e-5)
    assert bool(torch.isinf(d[1]).all())         # (4, 4, 4): no segment entered it


def test_light_approach_misses_no_corner_the_coarse_march_skips():
    """Random segments (seeded): the two-stage march (one-voxel steps, then the fine step near the cells) gives the
    same approach as marching every segment at the fine step, to a fine step; segments clipping a cell's corner
    (chords far shorter than the coarse step) included."""
    import torch

    from torch_recon.recon.hull_flat import APPROACH_STEP_VOXELS, light_approach
    from torch_recon.recon.segment_crossings import marching_cells
    box = _unit_box(8)
    g = torch.Generator().manual_seed(3)
    cells = torch.rand(box.shape, generator=g) < 0.1
    o = torch.rand(400, 3, generator=g) * 8
    u = torch.nn.functional.normalize(torch.randn(400, 3, generator=g), dim=1)
    near, far = torch.zeros(400), torch.full((400,), 6.0)
    d = light_approach(box, o, u, near, far, cells)
    index = torch.full((cells.numel(),), -1, dtype=torch.long)
    index[cells.reshape(-1)] = torch.arange(int(cells.sum()))
    ref = torch.full_like(d, float("inf"))
    for _, flat, keep, pos in marching_cells(box, o, u, near, far, APPROACH_STEP_VOXELS, positions=True):
        j = index[flat.where(keep, 0).long()]
        ok = keep & (j >= 0)
        p = pos[ok]
        ref.scatter_reduce_(0, j[ok][:, None].expand(-1, 6),
                            torch.stack([p[:, 0], 1 - p[:, 0], p[:, 1], 1 - p[:, 1], p[:, 2], 1 - p[:, 2]], 1), "amin")
    assert bool((torch.isinf(d) == torch.isinf(ref)).all())
    fin = torch.isfinite(ref)
    assert fin.sum() > 50 and float((d[fin] - ref[fin]).abs().max()) <= APPROACH_STEP_VOXELS + 1e-4


def test_flat_face_offsets_go_to_the_middle_of_the_lights_gap():
    """Flat voxel (2, 2, 2), free +x neighbour (3, 2, 2) whose -x face the light came within 0.4 voxel of: the
    +x face moves (1 - 0.4) / 2 voxel in; a -x neighbour the light never entered (d inf) or came within > 1 (none
    possible) leaves the -x face where it is."""
    from torch_recon.recon.hull_flat import flat_face_offsets
    flat = np.zeros((5, 5, 5), bool)
    flat[2, 2, 2] = True
    free = ~flat
    cells = np.zeros_like(flat)
    cells[3, 2, 2] = cells[1, 2, 2] = True          # rows in x-major order: (1, 2, 2) then (3, 2, 2)
    approach = np.full((2, 6), np.inf)
    approach[1, 0] = 0.4                              # (3, 2, 2)'s -x face
    out = flat_face_offsets(flat, free, cells, approach, 0.5)
    assert out[2, 2, 2, 1] == pytest.approx(0.3 * 0.5) and out[2, 2, 2, 0] == 0.0
    assert np.count_nonzero(out) == 1


def test_the_hidden_flat_face_moves_to_the_lights_gap_in_a_fitted_scene():
    """Box on a floor (32 px, 56 voxels along the longest side, 6.2 cm voxels): the box's hidden back face
    (y = BOX_BACK_Y) lies 0.47 voxel into its hull layer, which no lit segment crosses; marching cubes and the inward
    smoothing leave it 2.3 cm out. With `fast.mesh_hull_flat_approach` it moves to within 1 cm of the truth."""
    from tests.support.recon_fixtures import BOX_BACK_Y, box_floor_measurements
    from tests.torch_recon.recon.test_recon_fit import small_config
    from tests.torch_recon.recon.test_recon_freeze import _meta
    from torch_recon.recon.data import build_ray_data
    from torch_recon.recon.models import FastModel

    meas = box_floor_measurements(32)
    cfg = small_config(steps=1)
    cfg.fast.resolution = 56
    model = FastModel(build_ray_data(meas), cfg, _meta(meas))
    box = model.grid.box
    vol, level = model.surface_volume()
    lo = box.bbox_min.numpy() + 0.5 * box.voxel
    hi = lo + (np.array(box.shape) - 1) * box.voxel

    def back_face_offset(approach: bool) -> float:
        cfg.fast.mesh_hull_flat_approach = approach
        mesh, _ = mesh_from_volume(vol, lo, hi, level, smooth_iterations=10, inward=model.mesh_inward(vol, level),
                                   min_island_fraction=0)
        v, n = mesh.vertices, mesh.vertex_normals
        back = ((np.abs(v[:, 0]) < 0.2) & (v[:, 2] > 0.08) & (v[:, 2] < 0.42) & (np.abs(v[:, 1] - BOX_BACK_Y) < 0.15)
                & (n[:, 1] > 0.7))
        assert back.sum() > 20 and np.all(np.isfinite(v))
        return float(np.median(v[back, 1]) - BOX_BACK_Y)

    assert back_face_offset(False) > 0.02             # the layer's outer side, less what the smoothing cut
    assert abs(back_face_offset(True)) < 0.01


def test_flat_approach_is_the_default_and_the_removed_fixed_offset_is_refused():
    assert FitConfig(mode="fast").fast.mesh_hull_flat_approach      # the default since session 15
    assert not override(FitConfig(mode="fast"), ["fast.mesh_hull_flat_approach=false"]).fast.mesh_hull_flat_approach
    with pytest.raises(SettingsError, match="fast.mesh_hull_flat_centre_voxels: removed setting"):
        override(FitConfig(mode="fast"), ["fast.mesh_hull_flat_approach=false", "fast.mesh_hull_flat_centre_voxels=0.25"])
