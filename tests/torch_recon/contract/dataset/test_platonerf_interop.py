"""Interoperation with the PlatoNeRF authors' data and code, both directions.

Their conventions are encoded in tests/support/platonerf_fixtures.py (a directory written as their
preprocessing writes it; what their loader and training derive from one).
"""

import json
import math

import numpy as np
import pytest

from tests.conftest import make_synthetic_dataset
from tests.support.platonerf_fixtures import (paper_room_cubes, their_loader_view, their_test_cameras_blender,
                                write_paper_dataset, write_their_simulated_layout)
from torch_recon.contract.dataset import load_dataset
from torch_recon.contract.dataset.platonerf_layout import cube_scale_for, export_platonerf, import_platonerf
from torch_recon.contract.frames import blender_to_paper_points, blender_to_platonerf_train_points, paper_to_blender_points

USED_16 = (4, 5, 6, 7, 8, 9, 11, 12, 14, 15, 16, 17, 18, 19, 21, 23)
CHAIR_IGNORE = [0, 1, 2, 3, 10, 13, 20, 22]


@pytest.fixture(scope="module")
def paper_export(tmp_path_factory):
    """Our 32 x 32 dataset of the paper's room with the paper's 16 spots, exported to their layout."""
    tmp = tmp_path_factory.mktemp("pn")
    mesh, sensor, parts = write_paper_dataset(tmp / "ds", USED_16, USED_16)
    out = export_platonerf(tmp / "ds", tmp / "pn")
    return tmp / "ds", out, parts


def test_export_reads_in_their_loader(paper_export):
    ds_path, out, _ = paper_export
    doc = json.loads((out / "transforms_train.json").read_text())
    assert doc["camera_angle_x"] == 90.0                     # degrees
    assert len(doc["frames"]) == 24 and doc["ignore"] == CHAIR_IGNORE
    assert "ignore = [0,1,2,3,10,13,20,22]" in (out / "platonerf_config.txt").read_text()
    for i, fr in enumerate(doc["frames"]):
        assert fr["file_path"] == f"./train/{i:03d}" and not fr["file_path"].endswith(".npy")
        assert (out / (fr["file_path"] + ".npy")).is_file() == (i not in CHAIR_IGNORE)
        assert 0 <= fr["wall_idx_cam"] < len(doc["walls"]) and 0 <= fr["wall_idx_light"] < len(doc["walls"])
    view = their_loader_view(out, CHAIR_IGNORE)
    assert view["tof"][0].dtype == np.float16 and view["tof"][0].shape == (32, 32, 391)
    assert view["focal"] == pytest.approx(16.0)              # 90 degrees over 32 pixels, not radians
    # after their flips the camera sits at the origin looking down -z (their training frame)
    np.testing.assert_allclose(view["pose"][:3, :3], np.eye(3), atol=1e-7)
    ds = load_dataset(ds_path)
    for sp, lo, ld in zip(ds.manifest.spots, view["light_o"], view["light_d"]):
        np.testing.assert_allclose(ld, blender_to_platonerf_train_points(sp.laser_direction), atol=1e-6)
        assert ld[2] < 0                                     # every laser points ahead of the camera
        np.testing.assert_allclose(lo, 0.0)


def test_their_first_bounce_within_their_bin_rounding(paper_export):
    """Their extract_first = 1 (brightest bin read as (k + 1) * 0.0384 m) lands within 2.5 cm of l_k."""
    ds_path, out, parts = paper_export
    view = their_loader_view(out, CHAIR_IGNORE)
    ours = np.stack([blender_to_platonerf_train_points(s.first_bounce) for s in load_dataset(ds_path).manifest.spots])
    err = np.linalg.norm(np.stack(view["first_bounce"]) - ours, axis=1)
    assert err.max() < 0.025, err
    # the pixel seeing l_k: their corner rays are half a pixel up-left of our pixel centres
    for k in range(len(ours)):
        tof = view["tof"][k].astype(np.float32)
        bright = np.array(np.unravel_index(np.argmax(tof.max(-1)), tof.shape[:2]))
        rd = view["rays_d"] @ (ours[k] / np.linalg.norm(ours[k]))
        nearest_corner_ray = np.array(np.unravel_index(np.argmax(rd), rd.shape))
        assert np.all(np.abs(nearest_corner_ray - bright) <= 1)


def test_import_as_their_preprocessing_writes(tmp_path):
    """A directory exactly as their preprocess_tof.py writes it, with their ground-truth files."""
    from torch_recon.contract.synthetic import paper_laser_directions

    mesh, sensor, dirs, cubes, parts = paper_room_cubes(res=16, bins=391)
    targets = blender_to_paper_points(np.stack([s.first_bounce for s in parts["spots"]]))
    write_their_simulated_layout(tmp_path / "pn", cubes * np.float32(1e3), targets)
    gt = tmp_path / "pn" / "ground_truth"
    gt.mkdir()
    from torch_recon.contract.analytic import range_image
    for i, cam in enumerate(their_test_cameras_blender()):   # their 39 dolly + 100 orbit views
        d = range_image(mesh, cam, 8, 8, math.pi / 2)
        np.save(gt / f"depth_{i:04d}.npy", np.where(np.isfinite(d), d, 0.0).astype(np.float32))
    np.save(gt / "train_depth.npy", np.where(np.isfinite(parts["range"]), parts["range"], 0).astype(np.float32))
    ds = import_platonerf(tmp_path / "pn", tmp_path / "ours", ignore=CHAIR_IGNORE)
    s = ds.sensor
    assert s.fov_rad == pytest.approx(math.pi / 2) and (s.height, s.width, s.bins) == (16, 16, 391)
    np.testing.assert_allclose(s.camera_to_world, sensor.camera_to_world, atol=1e-12)
    np.testing.assert_allclose(s.laser_origin, 0.0)
    want = paper_laser_directions(used_only=False)
    for sp in ds.manifest.spots:
        np.testing.assert_allclose(sp.laser_direction, want[sp.id], atol=1e-9)   # not mirrored
    assert [sp.id for sp in ds.manifest.spots if sp.enabled] == list(USED_16)
    assert ds.manifest.layout.sample_type == "float16"
    np.testing.assert_array_equal(ds.read_transient(5).dense(), (cubes[5] * np.float32(1e3)).astype(np.float16))
    tv, cams, depth = ds.test_views()
    assert len(cams) == 139 and depth.shape == (139, 8, 8) and tv.fov_rad == pytest.approx(math.pi / 2)
    # dolly: from the sensor's position 1.5 m below towards the chair; orbit: 0.99 m around it
    centre = paper_to_blender_points([0.0, -1.5, 3.0])
    np.testing.assert_allclose(cams[0][:3, 3], paper_to_blender_points([0.0, -1.5, 0.0]), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(cams[39:, :3, 3] - centre, axis=1), 0.99, atol=1e-9)
    from torch_recon.evaluate import EvalSettings, evaluate
    rep = evaluate(ds, tmp_path / "eval", mesh=mesh,         # the true mesh scores ~0 only with the right poses
                   settings=EvalSettings(n_surface_samples=2000, error_images=0))
    assert rep["n_test_views"] == 139 and rep["depth_l1_m"] < 5e-3
    np.testing.assert_allclose(cams, their_test_cameras_blender(), atol=1e-9)
    train = ds.train_depth()
    assert np.array_equal(np.isinf(train), ~np.isfinite(parts["range"]))
    # our preprocessing finds their first bounces
    from torch_recon.first_bounce import find_first_bounce
    from torch_recon.preprocess import PreprocessSettings
    for sp in ds.manifest.enabled_spots[:4]:
        fb = find_first_bounce(ds.read_transient(sp.id), s, sp.laser_direction, sp.id, PreprocessSettings())
        assert np.linalg.norm(fb.point - parts["spots"][sp.id].first_bounce) < 0.02


def test_their_layout_round_trips_bit_exactly(tmp_path):
    mesh, sensor, dirs, cubes, parts = paper_room_cubes(res=8, bins=200, ids=range(6))
    targets = blender_to_paper_points(np.stack([s.first_bounce for s in parts["spots"]]))
    src = write_their_simulated_layout(tmp_path / "pn", cubes * np.float32(7.0), targets)
    doc0 = json.loads((src / "transforms_train.json").read_text())
    doc0["ignore"] = [1]
    (src / "transforms_train.json").write_text(json.dumps(doc0, indent=4))
    ds = import_platonerf(src, tmp_path / "ours")
    assert [sp.enabled for sp in ds.manifest.spots] == [True, False, True, True, True, True]
    back = export_platonerf(ds, tmp_path / "back")
    doc1 = json.loads((back / "transforms_train.json").read_text())
    for key in ("camera_angle_x", "walls", "ignore"):
        assert doc1[key] == doc0[key], key
    for f0, f1 in zip(doc0["frames"], doc1["frames"]):
        for key in ("file_path", "transform_matrix", "light_origin", "light_direction", "wall_idx_cam",
                    "wall_idx_light"):
            assert f1[key] == f0[key], key
        assert (back / (f1["file_path"] + ".npy")).read_bytes() == (src / (f0["file_path"] + ".npy")).read_bytes()


@pytest.mark.parametrize("sample_type", ["float32", "float16"])
def test_our_dataset_round_trips(tmp_path, sample_type):
    manifest, cubes = make_synthetic_dataset(tmp_path / "ds", window_bins=8)
    ds = load_dataset(tmp_path / "ds")
    pn = export_platonerf(ds, tmp_path / "pn", sample_type=sample_type)
    doc = json.loads((pn / "transforms_train.json").read_text())
    assert len(doc["frames"]) == 3 and doc["ignore"] == []   # not the paper's spots: one frame per spot
    cube0 = np.load(pn / (doc["frames"][0]["file_path"] + ".npy"))
    assert cube0.dtype == np.dtype(sample_type) and cube0.shape == (6, 5, 40)
    back = import_platonerf(pn, tmp_path / "back")
    assert back.manifest.sensor == manifest.sensor and back.manifest.layout == manifest.layout
    assert back.manifest.spots == manifest.spots and back.manifest.ground_truth == manifest.ground_truth
    for sid, cube in cubes.items():   # Poisson counts times a power of two are exact in float16 too
        assert back.read_transient(sid).dense().tobytes() == cube.tobytes()
    assert back.train_depth().tobytes() == ds.train_depth().tobytes()
    assert back.test_views()[2].tobytes() == ds.test_views()[2].tobytes()
    import trimesh

    m0 = trimesh.load(ds.path(manifest.ground_truth.mesh_file), process=False)
    m1 = trimesh.load(back.path(back.manifest.ground_truth.mesh_file), process=False)
    assert m0.vertices.tobytes() == m1.vertices.tobytes() and np.array_equal(m0.faces, m1.faces)


def test_float16_scale_keeps_radiance_in_range(paper_export):
    ds_path, out, _ = paper_export
    doc = json.loads((out / "transforms_train.json").read_text())
    scale = doc["platolidar"]["cube_scale"]
    assert math.log2(scale) == int(math.log2(scale))        # a power of two: exact
    ds = load_dataset(ds_path)
    sp = ds.manifest.spots[0]
    ours = ds.read_transient(sp.id).dense()
    theirs = np.load(out / f"train/{sp.id:03d}.npy")
    assert np.isfinite(theirs).all() and theirs.max() <= 2.0 ** 14
    big = ours > ours.max() * 1e-3
    np.testing.assert_allclose(theirs[big].astype(np.float64) / scale, ours[big], rtol=2 ** -10)
    assert cube_scale_for(3e5) == 2.0 ** -5 and cube_scale_for(0.0) == 1.0
    back = import_platonerf(out, ds_path.parent / "back")
    assert [s.id for s in back.manifest.spots] == list(USED_16) and all(s.enabled for s in back.manifest.spots)


def test_convert_cli_ignore(tmp_path, paper_export, capsys):
    from torch_recon.cli import main

    _, out, _ = paper_export
    assert main(["convert", "from-platonerf", str(out), str(tmp_path / "a"), "--ignore",
                 "[0,1,2,3,4,5,10,13,20,22]"]) == 0
    assert "16 spots (14 enabled)" in capsys.readouterr().out
    # --ignore replaces the list (as their config does): frames 0-3 have no cube
    assert main(["convert", "from-platonerf", str(out), str(tmp_path / "b"), "--ignore", "4,5"]) == 2
    assert "train/000.npy" in capsys.readouterr().err
    assert main(["convert", "from-platonerf", str(out), str(tmp_path / "c"), "--ignore", "4,x"]) == 2
    assert "setting ignore: expected an integer, got 'x'" in capsys.readouterr().err
    assert not (tmp_path / "b").exists() and not (tmp_path / "c").exists()


@pytest.mark.parametrize("flag, value, field", [("--window-bins", "4", "layout.window_bins"),
                                                  ("--bin-ps", "64", "sensor.bin_width_ps"),
                                                  ("--bin-m", "0.02", "sensor.bin_width_m"),
                                                  ("--pulse-fwhm-ps", "50", "sensor.pulse.fwhm_ps")])
def test_convert_refuses_options_our_export_fixes(tmp_path, capsys, flag, value, field):
    """Our export records bins, pulse and window: an option contradicting them is refused, naming the flag."""
    from torch_recon.cli import main

    manifest, _ = make_synthetic_dataset(tmp_path / "ds", window_bins=8)
    pn = export_platonerf(tmp_path / "ds", tmp_path / "pn")
    assert main(["convert", "from-platonerf", str(pn), str(tmp_path / "back"), flag, value]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and flag in err and f"platolidar.{field}" in err, err
    assert not (tmp_path / "back").exists()
    # the recorded value itself is harmless, and without options the export comes back whole
    recorded = {"--window-bins": manifest.layout.window_bins, "--bin-ps": manifest.sensor.bin_width_ps,
                "--bin-m": manifest.sensor.bin_width_m, "--pulse-fwhm-ps": manifest.sensor.pulse.fwhm_ps}[flag]
    assert main(["convert", "from-platonerf", str(pn), str(tmp_path / "same"), flag, str(recorded)]) == 0
    assert load_dataset(tmp_path / "same").manifest.layout == manifest.layout


def test_training_frame_is_where_their_flipped_pose_lives():
    """Their training negates rows 0 and 2 of the stored pose; lights are written in that frame."""
    from torch_recon.contract.frames import (blender_to_paper_c2w, look_at_c2w, pixel_rays,
                                             platonerf_train_to_blender_points)

    rng = np.random.default_rng(3)
    c2w = look_at_c2w(rng.normal(size=3), rng.normal(size=3) + [0, 4, 0])
    stored = blender_to_paper_c2w(c2w)
    flipped = stored.copy()
    flipped[0, :] *= -1
    flipped[2, :] *= -1
    o, d = pixel_rays(c2w, 4, 3, 1.1)
    o_t, d_t = pixel_rays(flipped, 4, 3, 1.1)
    np.testing.assert_allclose(o_t, blender_to_platonerf_train_points(o), atol=1e-12)
    np.testing.assert_allclose(d_t, blender_to_platonerf_train_points(d), atol=1e-12)
    p = rng.normal(size=(5, 3))
    assert platonerf_train_to_blender_points(blender_to_platonerf_train_points(p)).tobytes() == p.tobytes()
