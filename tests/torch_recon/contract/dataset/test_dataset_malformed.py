"""Every malformed dataset is refused with a DatasetError naming the file and the field."""

import json
import shutil

import numpy as np
import pytest

from tests.conftest import make_synthetic_dataset
from torch_recon.contract.dataset import DatasetError, load_dataset
from torch_recon.contract.dataset.exr import read_exr, write_exr
from torch_recon.contract.dataset.platonerf_layout import export_platonerf, import_platonerf


def _edit_manifest(root, edit):
    p = root / "dataset.json"
    d = json.loads(p.read_text())
    edit(d)
    p.write_text(json.dumps(d))


def _refused(root, file_part, field_part, reader=None):
    with pytest.raises(DatasetError) as ei:
        (reader or (lambda r: load_dataset(r)))(root)
    err = ei.value
    assert file_part in err.file, str(err)
    assert field_part in err.field, str(err)
    assert file_part in str(err) and (not field_part or field_part in str(err))
    return err


MANIFEST_CASES = {
    "unknown schema version": (lambda d: d.update(schema_version="9.9"), "schema_version"),
    "not our schema": (lambda d: d.update(schema="something.else"), "schema"),
    "missing sensor field": (lambda d: d["sensor"].pop("bins"), "sensor.bins"),
    "zero bins": (lambda d: d["sensor"].update(bins=0), "sensor.bins"),
    "bin widths disagree": (lambda d: d["sensor"].update(bin_width_m=0.05), "sensor.bin_width_m"),
    "negative start": (lambda d: d["sensor"].update(start_m=-1.0), "sensor.start_m"),
    "fov of 180 degrees": (lambda d: d["sensor"].update(fov_rad=3.2), "sensor.fov_rad"),
    "bad fov axis": (lambda d: d["sensor"].update(fov_axis="z"), "sensor.fov_axis"),
    "non-rigid camera": (lambda d: d["sensor"]["camera_to_world"][0].__setitem__(0, 2.0), "sensor.camera_to_world"),
    "NaN in laser origin": (lambda d: d["sensor"].update(laser_origin=[0, float("nan"), 0]), "sensor.laser_origin"),
    "window larger than bins": (lambda d: d["layout"].update(window_bins=100), "layout.window_bins"),
    "unknown layout": (lambda d: d["layout"].update(kind="sparse"), "layout.kind"),
    "bad sample type": (lambda d: d["layout"].update(sample_type="int8"), "layout.sample_type"),
    "non-unit laser direction": (lambda d: d["spots"][1].update(laser_direction=[0, 2, 0]), "spots[1].laser_direction"),
    "duplicate spot ids": (lambda d: d["spots"][1].update(id=0), "spots"),
    "spot without direction": (lambda d: d["spots"][2].pop("laser_direction"), "spots[2].laser_direction"),
    "negative noise": (lambda d: d["noise"].update(dark_counts_per_bin=-1), "noise.dark_counts_per_bin"),
    "filter factor above one": (lambda d: d["noise"].update(wavelength_filter_factor=2), "noise.wavelength_filter_factor"),
    "gate larger than bins": (lambda d: d["sensor"]["time_gate"].update(window_bins=500), "sensor.time_gate.window_bins"),
    "wrong units": (lambda d: d["units"].update(optical_path="ps"), "units"),
    "rgb list of wrong length": (lambda d: d.update(rgb_files=["a.png"]), "rgb_files"),
    "missing provenance": (lambda d: d.pop("provenance"), "provenance"),
}


@pytest.mark.parametrize("case", sorted(MANIFEST_CASES))
def test_malformed_manifest(synthetic_dataset, case):
    root, _, _ = synthetic_dataset
    edit, field = MANIFEST_CASES[case]
    _edit_manifest(root, edit)
    _refused(root, "dataset.json", field)


def test_missing_manifest_is_not_a_dataset(synthetic_dataset):
    root, _, _ = synthetic_dataset
    (root / "dataset.json").unlink()
    _refused(root, "dataset.json", "")


def test_manifest_not_json(synthetic_dataset):
    root, _, _ = synthetic_dataset
    (root / "dataset.json").write_text('{"schema": "platolidar.dataset", ')
    err = _refused(root, "dataset.json", "")
    assert "not valid JSON" in str(err)


def test_missing_directory(tmp_path):
    _refused(tmp_path / "nope", "nope", "")


def test_manifest_file_instead_of_its_directory(synthetic_dataset):
    root, _, _ = synthetic_dataset
    err = _refused(root / "dataset.json", "dataset.json", "")
    assert "expected a dataset directory, got a file" in str(err) and str(root) in str(err)


def test_missing_transient_file(synthetic_dataset):
    root, _, _ = synthetic_dataset
    (root / "transients" / "spot_0001.exr").unlink()
    _refused(root, "spot_0001.exr", "spots[1].transient_file")


def test_missing_ground_truth_file(synthetic_dataset):
    root, _, _ = synthetic_dataset
    (root / "ground_truth" / "test_depth.exr").unlink()
    _refused(root, "test_depth.exr", "ground_truth.test_views.depth_file")


def _rewrite_transient(root, spot, mutate):
    path = root / "transients" / f"spot_{spot:04d}.exr"
    chans, _ = read_exr(path)
    mutate(chans)
    write_exr(path, chans)


def _read_spot(spot):
    return lambda root: load_dataset(root).read_transient(spot)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_counts(synthetic_dataset, bad):
    root, _, _ = synthetic_dataset
    _rewrite_transient(root, 2, lambda c: c["w0003"].__setitem__((1, 1), bad))
    err = _refused(root, "spot_0002.exr", "spots[2].transient_file", _read_spot(2))
    assert "NaN or infinite" in str(err)


def test_negative_counts(synthetic_dataset):
    root, _, _ = synthetic_dataset
    _rewrite_transient(root, 0, lambda c: c["w0000"].__setitem__((0, 0), -1.0))
    assert "negative" in str(_refused(root, "spot_0000.exr", "spots[0]", _read_spot(0)))


def test_wrong_image_shape(synthetic_dataset):
    root, _, _ = synthetic_dataset

    def crop(c):
        for k in list(c):
            c[k] = np.ascontiguousarray(c[k][:-1])
    _rewrite_transient(root, 1, crop)
    assert "sensor.height" in str(_refused(root, "spot_0001.exr", "spots[1]", _read_spot(1)))


def test_missing_window_channel(synthetic_dataset):
    root, _, _ = synthetic_dataset
    _rewrite_transient(root, 1, lambda c: c.pop("w0007"))
    assert "w0007" in str(_refused(root, "spot_0001.exr", "spots[1]", _read_spot(1)))


def test_window_beyond_bins(synthetic_dataset):
    root, _, _ = synthetic_dataset
    _rewrite_transient(root, 1, lambda c: c["start"].__setitem__((2, 2), 39))
    assert "sensor.bins" in str(_refused(root, "spot_0001.exr", "spots[1]", _read_spot(1)))


def test_bins_inconsistent_with_data(synthetic_dataset):
    """A manifest claiming fewer bins than the stored windows reach is refused."""
    root, _, _ = synthetic_dataset
    _edit_manifest(root, lambda d: d["sensor"].update(bins=9))
    _refused(root, "spot_", "spots[", lambda r: [load_dataset(r).read_transient(k) for k in range(3)])


def test_truncated_exr(synthetic_dataset):
    root, _, _ = synthetic_dataset
    p = root / "transients" / "spot_0000.exr"
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])
    assert "not a readable EXR" in str(_refused(root, "spot_0000.exr", "spots[0]", _read_spot(0)))


def test_ground_truth_depth_wrong_shape(synthetic_dataset):
    root, _, _ = synthetic_dataset
    write_exr(root / "ground_truth" / "train_depth.exr", {"range": np.ones((3, 3), np.float32)})
    _refused(root, "train_depth.exr", "ground_truth.train_depth_file", lambda r: load_dataset(r).train_depth())
    write_exr(root / "ground_truth" / "test_depth.exr", {"range": np.ones((4, 3), np.float32)})
    assert "2 views" in str(_refused(root, "test_depth.exr", "ground_truth.test_views.depth_file",
                                     lambda r: load_dataset(r).test_views()))


# -- the PlatoNeRF layout ---------------------------------------------------------------

@pytest.fixture
def platonerf_dir(tmp_path):
    make_synthetic_dataset(tmp_path / "ds")
    return export_platonerf(tmp_path / "ds", tmp_path / "pn")


def _edit_transforms(pn, edit):
    p = pn / "transforms_train.json"
    d = json.loads(p.read_text())
    edit(d)
    p.write_text(json.dumps(d))


PN_CASES = {
    "no camera angle": (lambda d: d.pop("camera_angle_x"), "camera_angle_x"),
    "camera angle of 0": (lambda d: d.update(camera_angle_x=0), "camera_angle_x"),
    "camera angle of 180 degrees": (lambda d: d.update(camera_angle_x=180), "camera_angle_x"),
    "ignore not a list": (lambda d: d.update(ignore="0,1"), "ignore"),
    "no frames": (lambda d: d.update(frames=[]), "frames"),
    "frame without light": (lambda d: d["frames"][1].pop("light_origin"), "frames[1].light_origin"),
    "zero light direction": (lambda d: d["frames"][0].update(light_direction=[0, 0, 0]), "frames[0].light_direction"),
    "two cameras": (lambda d: d["frames"][2]["transform_matrix"][0].__setitem__(3, 5.0), "frames[2].transform_matrix"),
    "matrix of wrong shape": (lambda d: d["frames"][0].update(transform_matrix=[[1, 0], [0, 1]]),
                              "frames[0].transform_matrix"),
    "missing cube": (lambda d: d["frames"][1].update(file_path="./train/nowhere"), "frames[1].file_path"),
}


@pytest.mark.parametrize("case", sorted(PN_CASES))
def test_malformed_platonerf_layout(platonerf_dir, tmp_path, case):
    edit, field = PN_CASES[case]
    _edit_transforms(platonerf_dir, edit)
    _refused(platonerf_dir, "", field, lambda r: import_platonerf(r, tmp_path / "out"))
    assert not (tmp_path / "out").exists()  # nothing half-written


def test_platonerf_cube_problems(platonerf_dir, tmp_path):
    cube_path = platonerf_dir / "train" / "001.npy"
    good = np.load(cube_path)
    for bad, msg in ((good[:, :, :10], "differs"), (good[..., 0], "H x W x T"),
                     (np.where(good > 2, np.nan, good), "NaN"), (-good - 1, "negative")):
        np.save(cube_path, bad)
        err = _refused(platonerf_dir, "001.npy", "frames[1].file_path",
                       lambda r: import_platonerf(r, tmp_path / "out"))
        assert msg in str(err)
    cube_path.write_bytes(b"\x93NUMPY garbage")
    _refused(platonerf_dir, "001.npy", "frames[1].file_path", lambda r: import_platonerf(r, tmp_path / "out"))
    shutil.rmtree(platonerf_dir / "train")
    _refused(platonerf_dir, "000.npy", "frames[0].file_path", lambda r: import_platonerf(r, tmp_path / "out"))
    (platonerf_dir / "transforms_train.json").unlink()
    _refused(platonerf_dir, "transforms_train.json", "", lambda r: import_platonerf(r, tmp_path / "out"))
