"""Their real-capture layout (.mat files) -> a measurements-only dataset -> preprocess and fit."""

import json

import numpy as np
import pytest

from tests.support.platonerf_fixtures import write_their_real_capture
from torch_recon.contract.dataset import DatasetError, load_dataset
from torch_recon.contract.dataset.platonerf_real import import_platonerf_real
from torch_recon.contract.frames import pixel_rays
from torch_recon.contract.synthetic import box_room_scene, default_sensor, paper_laser_directions

RES = 32


@pytest.fixture(scope="module")
def real_capture(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("real")
    mesh = box_room_scene()
    sensor = default_sensor(width=RES, height=RES, bins=10)
    ls, lit, paths = write_their_real_capture(tmp / "mat", mesh, sensor, paper_laser_directions())
    return tmp, mesh, sensor, ls, lit, paths


def test_real_capture_import(real_capture):
    tmp, mesh, sensor, ls, lit, paths = real_capture
    ds = import_platonerf_real(tmp / "mat", tmp / "ds")
    m = ds.manifest
    assert m.kind == "measurements" and json.loads((tmp / "ds" / "dataset.json").read_text())["schema_version"] == "1.1"
    assert (ds.sensor.width, ds.sensor.height, len(m.spots)) == (RES, RES, 16)
    np.testing.assert_allclose(ds.sensor.laser_origin, [0.257, 0, 0], atol=1e-12)   # their x = our x
    np.testing.assert_allclose(ds.sensor.camera_to_world, sensor.camera_to_world, atol=1e-6)
    assert ds.sensor.fov_rad == pytest.approx(sensor.fov_rad, abs=1e-6)
    _, d = pixel_rays(sensor.camera_to_world, RES, RES, sensor.fov_rad)
    np.testing.assert_allclose(ds.ray_directions(), d, atol=1e-6)
    for k, sp in enumerate(m.spots):
        np.testing.assert_allclose(sp.first_bounce, ls[k], atol=1e-12)
        got = ds.read_spot_measurement(sp.id)
        assert np.array_equal(got["lit"], lit[k]) and got["valid"].all() and 0.2 < lit[k].mean() < 0.99
        np.testing.assert_allclose(got["path_m"][lit[k]], paths[k][lit[k]], rtol=1e-6)


def test_real_capture_preprocess_and_fit(real_capture, tmp_path):
    from torch_recon.cli import main
    from torch_recon.preprocess import preprocess_dataset
    from torch_recon.recon import FitConfig, fit

    tmp, mesh, sensor, ls, lit, paths = real_capture
    assert main(["convert", "from-platonerf-real", str(tmp / "mat"), str(tmp_path / "ds")]) == 0
    meas = preprocess_dataset(load_dataset(tmp_path / "ds"))
    from torch_recon.measurements import Measurements
    again = Measurements.load(meas.save(tmp_path / "m.npz"))       # the per-pixel rays travel with them
    assert again.ray_directions is not None and np.array_equal(again.pixel_directions(), meas.pixel_directions())
    from torch_recon.contract.analytic import range_image
    truth = range_image(mesh, sensor.camera_to_world, RES, RES, sensor.fov_rad)
    ok = np.isfinite(meas.visible_depth)
    assert ok.mean() > 0.8
    assert np.median(np.abs(meas.visible_depth[ok] - truth[ok])) < 0.01    # closed form from t2 is exact
    cfg = FitConfig(progress=False, steps=10, threads=1, plateau_patience=0)
    cfg.fast.resolution, cfg.fast.coarse_resolution, cfg.fast.coarse_fraction = 32, 16, 0.0
    r = fit(tmp_path / "ds", config=cfg, export=False)
    depth = r.render_depth(sensor.camera_to_world, RES, RES, sensor.fov_rad)
    err = np.abs(depth - truth)[np.isfinite(truth)]
    print("median train-view depth error of the fit", np.median(err))
    assert np.median(err) < 0.1, np.median(err)


def test_real_capture_refusals(real_capture, tmp_path):
    tmp, *_ = real_capture
    with pytest.raises(DatasetError, match="t2.mat"):
        import_platonerf_real(tmp_path, tmp_path / "x")
    with pytest.raises(DatasetError, match="illum_pts"):
        import_platonerf_real(tmp / "mat", tmp_path / "y", spots=40)
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()


def _edited(src, dst, edit):
    import shutil

    shutil.copytree(src, dst)
    p = dst / "dataset.json"
    d = json.loads(p.read_text())
    edit(d)
    p.write_text(json.dumps(d))
    return dst


MEAS_CASES = {
    "1.1 fields in a 1.0 manifest": (lambda d: d.update(schema_version="1.0"), "kind"),
    "no measurement file": (lambda d: d["spots"][0].pop("measurement_file"), "spots[0].measurement_file"),
    "no first bounce": (lambda d: d["spots"][1].update(first_bounce=None), "spots[1].first_bounce"),
    "rays with transients": (lambda d: d.update(kind="transients"), "spots[0].transient_file"),
    "missing ray file": (lambda d: d["sensor"].update(ray_directions_file="sensor/none.exr"),
                         "sensor.ray_directions_file"),
}


@pytest.mark.parametrize("case", sorted(MEAS_CASES))
def test_measurements_dataset_refusals(real_capture, tmp_path, case):
    tmp, *_ = real_capture
    src = tmp / "ds_for_refusals"
    if not src.exists():
        import_platonerf_real(tmp / "mat", src)
    edit, field = MEAS_CASES[case]
    with pytest.raises(DatasetError) as ei:
        load_dataset(_edited(src, tmp_path / "bad", edit))
    assert field in ei.value.field, str(ei.value)


def test_measurement_file_contents_refused(real_capture, tmp_path):
    from torch_recon.contract.dataset.exr import write_exr

    tmp, *_ = real_capture
    src = tmp / "ds_for_files"
    if not src.exists():
        import_platonerf_real(tmp / "mat", src)
    ds = load_dataset(_edited(src, tmp_path / "bad", lambda d: None))
    rel = ds.manifest.spots[0].measurement_file
    one = np.ones((RES, RES), np.float32)
    write_exr(ds.root / rel, {"path_m": 0 * one, "lit": one.astype(np.float16), "valid": one.astype(np.float16)})
    with pytest.raises(DatasetError, match="without a positive two-bounce path"):
        ds.read_spot_measurement(0)
    write_exr(ds.root / rel, {"path_m": one, "lit": one.astype(np.float16)})
    with pytest.raises(DatasetError, match="'valid' missing"):
        ds.read_spot_measurement(0)
    write_exr(ds.root / ds.sensor.ray_directions_file, {c: 2 * one for c in "XYZ"})
    with pytest.raises(DatasetError, match="not unit vectors"):
        ds.ray_directions()
    with pytest.raises(DatasetError, match="no transients"):
        ds.read_transient(0)
