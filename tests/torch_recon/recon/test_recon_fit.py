"""Fast-mode fits on a tiny scene (box on a floor, 4 spots, 32 x 32): geometry, robustness, bookkeeping."""

from __future__ import annotations

import os
import signal

import numpy as np
import pytest
import torch

from tests.support.recon_fixtures import BOX_BACK_Y, box_floor_measurements

from torch_recon.recon import FitConfig, fit  # noqa: E402

#: the back face must come out within this distance (m); the grid voxel is ~0.1 m at resolution 40
BACK_FACE_TOL_M = 0.12


@pytest.fixture(scope="module")
def meas():
    return box_floor_measurements(32)


def small_config(steps=20, **kw) -> FitConfig:
    cfg = FitConfig(progress=False, steps=steps, threads=1, plateau_patience=0, **kw)
    cfg.fast.resolution = 40
    cfg.fast.coarse_resolution = 20
    cfg.fast.coarse_fraction = 0.0
    cfg.fast.rays_per_batch = 512
    return cfg


def back_face_y(result) -> float:
    """Median far end (y) of the occupied run through the box, over columns inside its footprint."""
    vol, lo, hi = result.volume, result.bbox_min, result.bbox_max
    v = (hi - lo) / np.array(vol.shape)
    centres = [lo[a] + (np.arange(vol.shape[a]) + 0.5) * v[a] for a in range(3)]
    xs, ys, zs = centres
    ends = []
    for i in np.flatnonzero(np.abs(xs) < 0.2):
        for k in np.flatnonzero((zs > 0.08) & (zs < 0.42)):
            occ = vol[i, :, k] > 0.5
            j = int(np.searchsorted(ys, 2.0))
            if not occ[j]:
                continue
            while j < len(ys) and occ[j]:
                j += 1
            ends.append(ys[j - 1] + 0.5 * v[1])
    assert ends, "nothing occupied inside the box"
    return float(np.median(ends))


def test_fast_mode_recovers_hidden_back_face(meas):
    r = fit(meas, config=small_config(steps=30))
    assert r.train.steps_done == 30 and np.isfinite(r.volume).all()
    assert abs(back_face_y(r) - BOX_BACK_Y) < BACK_FACE_TOL_M
    # the visible floor in front of the box is where the measurements put it
    from tests.support.recon_fixtures import CAMERA

    d = r.render_depth(CAMERA, 32, 32, meas.fov_rad)
    err = np.abs(d - np.asarray(meas.visible_depth))
    assert np.median(err) < 0.03, np.median(err)


def test_same_seed_same_result(meas):
    a = fit(meas, config=small_config(steps=8))
    b = fit(meas, config=small_config(steps=8))
    assert np.array_equal(a.volume, b.volume)


def test_checkpoint_resume_equals_uninterrupted(meas, tmp_path):
    full = fit(meas, out=tmp_path / "full", config=small_config(steps=12), export=False)
    part = fit(meas, out=tmp_path / "part", config=small_config(steps=12), export=False, stop_after=6)
    assert part.train.stopped == "paused" and (tmp_path / "part" / "checkpoint.pt").is_file()
    resumed = fit(meas, out=tmp_path / "part", config=small_config(steps=12), export=False)
    assert resumed.train.resumed_from == 6 and resumed.train.steps_done == 12
    np.testing.assert_allclose(resumed.volume, full.volume, atol=1e-6)


def test_checkpoint_from_other_settings_is_refused(meas, tmp_path):
    fit(meas, out=tmp_path, config=small_config(steps=2), export=False)
    with pytest.raises(ValueError, match="other settings"):
        fit(meas, out=tmp_path, config=small_config(steps=3), export=False)


def test_nan_is_reported_and_last_good_state_restored(meas):
    seen = []

    def inject(step, loss):
        if step == 13 and not seen:
            seen.append(step)
            return loss * float("nan")
        return loss

    with pytest.warns(RuntimeWarning, match="non-finite"):
        r = fit(meas, config=small_config(steps=16), fault_hook=inject)
    assert r.train.nan_restores == 1 and r.train.stopped == "done"
    assert np.isfinite(r.volume).all()


def test_ctrl_c_stops_cleanly_with_a_checkpoint(meas, tmp_path):
    def interrupt(step, loss):
        if step == 3:
            os.kill(os.getpid(), signal.SIGINT)
        return loss

    r = fit(meas, out=tmp_path, config=small_config(steps=50), export=False, fault_hook=interrupt)
    assert r.train.stopped == "interrupted" and r.train.steps_done == 4
    ck = torch.load(tmp_path / "checkpoint.pt", weights_only=False)
    assert ck["step"] == 4


def test_all_shadow_is_refused_before_writing(meas, tmp_path):
    import copy

    m = copy.deepcopy(meas)
    for s in m.spots:
        s.signal[:] = False
        s.path_length[:] = np.nan
        s.shadow[:] = ~s.excluded
    out = tmp_path / "fit"
    with pytest.raises(ValueError, match="no pixel has a two-bounce return"):
        fit(m, out=out, config=small_config(steps=5))
    assert not out.exists()


@pytest.mark.parametrize("case", ["no_shadows", "spot_on_own_surface"])
def test_degenerate_measurements_fit_without_nan(meas, case):
    import copy

    m = copy.deepcopy(meas)
    for s in m.spots:
        if case == "no_shadows":
            s.shadow[:] = False
    if case == "spot_on_own_surface":
        # l_k exactly at a pixel's surface point: that pixel's secondary ray has zero length
        c = m.camera_to_world[:3, 3]
        from torch_recon.contract.frames import pixel_rays

        _, dirs = pixel_rays(m.camera_to_world, m.width, m.height, m.fov_rad)
        x = c + dirs[20, 16] * m.visible_depth[20, 16]
        m.spots[0].first_bounce = x.astype(np.float32)
        m.spots[0].signal[20, 16] = True
        m.spots[0].path_length[20, 16] = np.linalg.norm(x - m.laser_origin) + m.visible_depth[20, 16]
    r = fit(m, config=small_config(steps=20))
    assert np.isfinite(r.volume).all() and r.train.nan_restores == 0
    assert all(np.isfinite(h["loss"]) for h in r.train.history)


def test_fast_mesh_is_clean_planar_and_has_the_hidden_face(meas, tmp_path):
    """The exported mesh of the closed-form field (shadow carving + visible-surface signed distance, no
    optimisation): no zero-area faces; the visible floor is flat (no grid-aligned spikes); the box's
    hidden back face is reported where the lit secondary rays bound it."""
    from tests.support.recon_fixtures import BOX_HI, BOX_LO

    r = fit(meas, out=tmp_path, config=small_config(steps=0), uv=False)
    m = r.mesh
    assert len(m.faces) > 0
    assert int((m.area_faces < 1e-12).sum()) == 0
    v = np.asarray(m.vertices)
    voxel = float(np.max(r.bbox_max - r.bbox_min)) / 40
    # floor vertices away from the box and the walls: on the plane z = 0 (95 % within 0.4
    # voxel, none a grid step or more off: a grid-aligned spike would stand a whole voxel proud)
    floor = (v[:, 2] < 0.5 * voxel + 0.1) & (np.abs(v[:, 0]) < 1.0) & (v[:, 1] > 0.8) & (v[:, 1] < 3.0) \
        & ~((np.abs(v[:, 0]) < 0.5) & (v[:, 1] > 1.6) & (v[:, 1] < 2.8))
    assert floor.sum() > 20
    z = np.abs(v[floor, 2])
    assert np.quantile(z, 0.95) < 0.4 * voxel and z.max() < 0.75 * voxel, (np.quantile(z, 0.95), z.max(), voxel)
    # the hidden back face (y = BOX_BACK_Y): reconstructed surface within one voxel of it
    back = (np.abs(v[:, 0]) < 0.2) & (v[:, 2] > 0.1) & (v[:, 2] < 0.4) & (v[:, 1] > BOX_LO[1] + 0.2)
    assert back.sum() > 3
    assert np.abs(np.median(v[back, 1]) - BOX_BACK_Y) < voxel, np.median(v[back, 1])
    assert BOX_HI[2] > 0   # (fixture sanity)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_fast_mode_on_cuda_recovers_the_hidden_back_face_as_on_the_cpu(meas, tmp_path):
    # the fast mode's CUDA path (start field, carving, training, the mesh export: session 20's device run
    # found the export's boxes mixing devices) on the device; CPU and GPU kernels round differently, so the
    # two fields agree to the voxel, not bit for bit
    cpu = fit(meas, config=small_config(steps=30))
    gpu = fit(meas, out=tmp_path, config=small_config(steps=30, device="cuda"), uv=False)
    assert (tmp_path / "mesh.ply").stat().st_size > 0
    assert gpu.metadata.get("device", "").startswith("cuda") and np.isfinite(gpu.volume).all()
    assert abs(back_face_y(gpu) - BOX_BACK_Y) < BACK_FACE_TOL_M
    assert abs(back_face_y(gpu) - back_face_y(cpu)) < 0.5 * (gpu.bbox_max[1] - gpu.bbox_min[1]) / gpu.volume.shape[1]
    assert np.mean((gpu.volume > 0.5) != (cpu.volume > 0.5)) < 0.01


def test_grid_boxes_stay_on_their_corners_device():
    # a box rebuilt from a corner on the GPU put its far corner's sum on the CPU: `fit --device cuda` failed at
    # the export (session 20, H200). PyTorch's meta device refuses the same mix without a GPU.
    from torch_recon.recon.fields import GridBox

    corner = torch.zeros(3, device="meta")
    assert GridBox.exact(corner, 0.1, [2, 3, 4]).bbox_max.device.type == "meta"
