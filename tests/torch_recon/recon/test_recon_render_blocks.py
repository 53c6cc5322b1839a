"""render_pruned's block pass (issue 11's speed): it keeps exactly the samples a dense march keeps."""

from __future__ import annotations

import torch

from torch_recon.recon.fields import DensityGrid, GridBox
from torch_recon.recon.renderer import composite_packed, occupied_ahead, render_pruned
from torch_recon.recon.sampler import ray_box


def dense_march(grid, occupancy, origins, dirs, near, far, step, tau_grid, stop_tau=12.0):
    """The reference: every sample of every ray tested on its own (render_pruned before session 16)."""
    r = origins.shape[0]
    box = grid.box
    nx, ny, nz = box.shape
    bn, bf = ray_box(origins, dirs, box.bbox_min, box.bbox_max)
    lo, hi = torch.maximum(near, bn), torch.minimum(far, bf)
    n = max(1, int(float((hi - near).clamp(min=0.0).max()) / step) + 1)
    tm = near[:, None] + (torch.arange(n, dtype=origins.dtype) + 0.5) * step
    keep = (tm + 0.5 * step > lo[:, None]) & (tm - 0.5 * step < hi[:, None])
    g = ((origins - box.bbox_min) / box.voxel)[:, None, :] + (dirs / box.voxel)[:, None, :] * tm[..., None]
    gi = torch.minimum(g.long().clamp_(min=0), torch.tensor([nx - 1, ny - 1, nz - 1]))
    flat = (gi[..., 0] * ny + gi[..., 1]) * nz + gi[..., 2]
    keep &= occupancy.reshape(-1)[flat]
    tau_est = torch.where(keep, tau_grid.reshape(-1)[flat], torch.zeros(()))
    keep &= (torch.cumsum(tau_est, 1) - tau_est) < stop_tau
    ray_id, s_id = torch.nonzero(keep, as_tuple=True)
    t0 = near[ray_id] + s_id.to(near.dtype) * step
    t1 = torch.minimum(t0 + step, far[ray_id])
    tmid = 0.5 * (t0 + t1)
    tau = grid(origins[ray_id] + dirs[ray_id] * tmid[:, None]) * (t1 - t0).clamp(min=0.0)
    return composite_packed(tau, tmid, ray_id, r)


def test_occupied_ahead_looks_k_voxels_towards_plus_xyz():
    occ = torch.rand(7, 6, 9, generator=torch.Generator().manual_seed(2)) > 0.97
    ahead = occupied_ahead(occ, 3)
    for x, y, z in ((0, 0, 0), (2, 3, 4), (6, 5, 8), (5, 1, 7)):
        assert bool(ahead[x, y, z]) == bool(occ[x:x + 3, y:y + 3, z:z + 3].any())
    assert torch.equal(occupied_ahead(occ, 1), occ)


def test_block_pass_keeps_the_dense_marchs_samples_bit_for_bit():
    """Sparse occupancy (a shell), rays from outside and from inside the box, segments that end inside, early
    termination on: the same samples, weights and depths to the bit as testing every sample."""
    gen = torch.Generator().manual_seed(3)
    box = GridBox([0.0, -0.2, 0.1], [1.0, 0.7, 0.9], 24)
    nx, ny, nz = box.shape
    raw = torch.randn(nx, ny, nz, generator=gen) * 2.0
    grid = DensityGrid.from_xyz(box, raw, density_scale=20.0)
    c = box.centres() - (box.bbox_min + box.bbox_max) / 2
    occupancy = ((c.norm(dim=-1) - 0.3).abs() < 0.05) | (torch.rand(nx, ny, nz, generator=gen) > 0.995)
    tau_grid = torch.rand(nx, ny, nz, generator=gen) * 2.0
    origins = torch.rand(300, 3, generator=gen) * 1.6 - 0.3
    dirs = torch.nn.functional.normalize(torch.randn(300, 3, generator=gen), dim=-1)
    dirs[:20] = torch.tensor([1.0, 0.0, 0.0])       # along an axis: a block's box one voxel thick
    near = torch.rand(300, generator=gen) * 0.05
    far = near + torch.rand(300, generator=gen) * 1.5
    with torch.no_grad():
        for step, stop in ((box.voxel * 0.5, 12.0), (box.voxel * 0.37, 3.0)):
            ref = dense_march(grid, occupancy, origins, dirs, near, far, step, tau_grid, stop)
            out = render_pruned(grid, occupancy, origins, dirs, near, far, step, tau_grid, stop)
            assert ref.ray_index.numel() > 100
            assert torch.equal(out.ray_index, ref.ray_index)
            for a, b in ((out.weights, ref.weights), (out.depth, ref.depth), (out.transmittance, ref.transmittance)):
                assert torch.equal(a, b)


def test_all_finite_is_the_value_by_value_test():
    from torch_recon.recon.losses import all_finite

    x = torch.randn(1000)
    assert all_finite(x)
    for bad in (float("nan"), float("inf"), -float("inf")):
        y = x.clone()
        y[17] = bad
        assert not all_finite(y)
    big = torch.full((10,), 3e38)       # finite values whose sum overflows: still all finite
    assert not bool(torch.isfinite(big.sum())) and all_finite(big)
    both = torch.tensor([float("inf"), -float("inf"), 1.0])
    assert not all_finite(both)


def test_surface_volume_is_built_once_per_field_and_settings():
    """The export asks for the mesh field twice (free_evidence, then the mesh): the second is the first's copy;
    a step of the optimiser, other thin parts or other settings build it again."""
    from unittest import mock

    from tests.support.recon_fixtures import box_floor_measurements
    from tests.torch_recon.recon.test_recon_fit import small_config
    from tests.torch_recon.recon.test_recon_freeze import _meta
    from torch_recon.recon.data import build_ray_data
    from torch_recon.recon.models import FastModel

    meas = box_floor_measurements(32)
    cfg = small_config(steps=1)
    model = FastModel(build_ray_data(meas), cfg, _meta(meas))
    with mock.patch.object(FastModel, "build_surface_volume", autospec=True,
                           side_effect=FastModel.build_surface_volume) as built:
        vol0, level0 = model.surface_volume()
        vol0[:] = 0.0                           # a caller's change stays its own
        vol1, level1 = model.surface_volume()
        assert built.call_count == 1 and level1 == level0 and vol1.any()
        with torch.no_grad():
            model.grid.raw += 0.5               # in place, as Adam's step
        model.surface_volume()
        assert built.call_count == 2
        cfg.fast.mesh_level_shift_voxels = 0.1
        assert model.surface_volume()[1] != level1 and built.call_count == 3
