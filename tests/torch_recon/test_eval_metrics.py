"""Metric definitions on hand-made depth maps and meshes (values computed by hand), and evaluate() end to end."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import trimesh

from torch_recon.contract.dataset import load_dataset
from torch_recon.evaluate import EvalSettings, depth_metrics, evaluate, render_density_depth, render_mesh_depth
from torch_recon.evaluation.surface import surface_metrics
from torch_recon.contract.frames import camera_ray_directions, look_at_c2w, paper_test_view_cameras
from torch_recon.contract.synthetic import (box_room_scene, default_sensor, paper_laser_directions,
                                           write_analytic_dataset)

INF = np.inf


def test_depth_l1_and_psnr_by_hand():
    gt = np.array([[[1.0, 2.0], [INF, 4.0]]])
    pred = np.array([[[1.5, 2.0], [3.0, INF]]])
    r = depth_metrics(pred, gt)                       # miss -> 0: errors 0.5, 0, 4 over 3 valid pixels
    assert r["n_excluded_pixels"] == 1 and r["n_valid_pixels"] == 3 and r["n_reconstruction_misses"] == 1
    assert r["depth_l1_m"] == pytest.approx(4.5 / 3)
    assert r["max_gt_depth_m"] == 4.0
    assert r["depth_psnr_db"] == pytest.approx(10 * math.log10(3 / (0.125 ** 2 + 1.0)))   # 4.7040 dB
    r = depth_metrics(pred, gt, miss_depth="max")     # miss -> 4: only the 0.5 error is left
    assert r["depth_l1_m"] == pytest.approx(0.5 / 3)
    assert r["depth_psnr_db"] == pytest.approx(10 * math.log10(3 / 0.125 ** 2))          # 22.833 dB


def test_psnr_pools_views_and_caps_perfect():
    gt = np.stack([np.full((2, 2), 2.0), np.full((2, 2), 4.0)])
    pred = gt + np.stack([np.zeros((2, 2)), np.full((2, 2), 0.4)])
    r = depth_metrics(pred, gt)
    assert r["depth_l1_m"] == pytest.approx(0.2)
    assert r["depth_psnr_db"] == pytest.approx(10 * math.log10(1 / (0.5 * 0.1 ** 2)))     # pooled: 23.01 dB
    assert r["per_view_psnr_db"][0] == 100.0 and r["per_view_psnr_db"][1] == pytest.approx(20.0)
    with pytest.raises(ValueError, match="every ground-truth pixel"):
        depth_metrics(np.ones((1, 2, 2)), np.full((1, 2, 2), INF))


def _square(z, size=1.0, x0=0.0):
    v = np.array([[x0, 0, z], [x0 + size, 0, z], [x0 + size, size, z], [x0, size, z]], float)
    return trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], process=False)


def test_chamfer_and_fscore_by_hand():
    a, b = _square(0.0), _square(0.03)              # parallel unit squares 3 cm apart
    r = surface_metrics(a, b, threshold_m=0.05, n_samples=20000)
    assert r["chamfer_m"] == pytest.approx(0.03, abs=1e-6) and r["fscore"] == 1.0
    r = surface_metrics(a, b, threshold_m=0.02, n_samples=20000)
    assert r["fscore"] == 0.0
    gt = trimesh.util.concatenate([b, _square(1.0)])  # GT has a second square 1 m above the reconstruction
    r = surface_metrics(a, gt, threshold_m=0.05, n_samples=40000)
    assert r["precision"] == 1.0 and r["recall"] == pytest.approx(0.5, abs=0.02)
    assert r["fscore"] == pytest.approx(2 * 0.5 / 1.5, abs=0.02)
    assert r["chamfer_m"] == pytest.approx(0.5 * (0.03 + 0.5 * 0.03 + 0.5 * 1.0), abs=0.01)


def test_mesh_and_density_depth_of_a_wall():
    c2w = look_at_c2w([0, 0, 0], [0, 1, 0])
    wall = trimesh.creation.box(extents=(10, 0.1, 10))
    wall.apply_translation([0, 2.05, 0])             # front face at y = 2
    w = h = 8
    fov = math.radians(60)
    dirs = camera_ray_directions(w, h, fov) @ c2w[:3, :3].T
    expected = 2.0 / dirs[..., 1]                   # range to the plane y = 2
    np.testing.assert_allclose(render_mesh_depth(wall, c2w, w, h, fov), expected, rtol=1e-5)

    import torch

    def density(x):
        return torch.where((x[:, 1] > 2.0) & (x[:, 1] < 2.5), torch.tensor(1e3), torch.tensor(0.0))
    d = render_density_depth(density, c2w, w, h, fov, (-3, 0, -3), (3, 3, 3), n_samples=512)
    assert np.abs(d - expected).max() < 0.03          # sample spacing <= 0.012 m, plus 1/sigma
    empty = render_density_depth(lambda x: torch.zeros(len(x)), c2w, w, h, fov, (-3, 0, -3), (3, 3, 3))
    assert np.all(np.isinf(empty))


@pytest.fixture(scope="module")
def small_ds(tmp_path_factory):
    cams = paper_test_view_cameras(dolly_count=2, orbit_count=3)
    path, _ = write_analytic_dataset(tmp_path_factory.mktemp("e") / "ds", box_room_scene(), default_sensor(8, 8),
                                     paper_laser_directions()[:1], test_cameras=cams, test_size=(24, 20))
    return load_dataset(path)


def test_evaluate_ground_truth_mesh_is_perfect(small_ds, tmp_path):
    gt = trimesh.load(small_ds.path(small_ds.manifest.ground_truth.mesh_file), force="mesh")
    # the GT mesh is not a closed solid with outward normals (an inverted room box): render it two-sided
    r = evaluate(small_ds, tmp_path / "ev", mesh=gt,
                 settings=EvalSettings(n_surface_samples=20000, cull_back_faces=False, objects=False, pictures=False))
    saved = json.loads((tmp_path / "ev" / "report.json").read_text())
    for k in ("depth_l1_m", "depth_psnr_db", "chamfer_m", "fscore", "n_test_views", "n_excluded_pixels"):
        assert k in saved
    _, _, depth = small_ds.test_views()
    assert r["n_test_views"] == 5 and r["n_excluded_pixels"] == int(np.isinf(depth).sum()) > 0
    assert r["depth_l1_m"] < 1e-5 and r["depth_psnr_db"] > 90 and r["fscore"] > 0.999 and r["chamfer_m"] < 1e-3
    assert len(list((tmp_path / "ev" / "views").glob("*.png"))) == 5


def test_evaluate_shifted_mesh_costs_the_shift(small_ds, tmp_path):
    gt = trimesh.load(small_ds.path(small_ds.manifest.ground_truth.mesh_file), force="mesh")
    moved = gt.copy()
    moved.apply_translation([0, 0, 0.1])
    r = evaluate(small_ds, tmp_path / "ev", mesh=moved, settings=EvalSettings(n_surface_samples=20000, error_images=0,
                                                                         objects=False, pictures=False))
    assert 0.01 < r["depth_l1_m"] < 0.3 and r["fscore"] < 1.0
    with pytest.raises(ValueError, match="exactly one"):
        evaluate(small_ds, tmp_path / "x")
