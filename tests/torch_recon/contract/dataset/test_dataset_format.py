"""The dataset format: round trips (ours and the PlatoNeRF layout), atomic writes."""

import json

import numpy as np
import pytest

from tests.conftest import make_synthetic_dataset
from torch_recon.contract.dataset import DatasetError, DatasetWriter, Manifest, Transient, load_dataset


def test_round_trip_bit_exact(synthetic_dataset):
    root, manifest, cubes = synthetic_dataset
    ds = load_dataset(root)
    assert ds.manifest == manifest
    for sid, cube in cubes.items():
        got = ds.read_transient(sid).dense()
        assert got.dtype == np.float32 and got.tobytes() == cube.tobytes()
    assert ds.train_depth()[0, 0] == np.inf
    tv, cams, depth = ds.test_views()
    assert depth.shape == (2, 4, 3) and cams.shape == (2, 4, 4)


def test_transient_windowing():
    cube = np.zeros((2, 2, 20), np.float32)
    cube[0, 0, 5:8] = [1, 4, 1]
    cube[1, 1, 17:20] = 2
    tr = Transient.from_dense(cube, 4)
    assert tr.window.sum() == cube.sum()
    assert tr.dense().tobytes() == cube.tobytes()
    with pytest.raises(ValueError):
        Transient.from_dense(cube, 21)
    with pytest.raises(ValueError):
        Transient(np.full((2, 2), 18), np.zeros((2, 2, 4), np.float32), 20)


def test_float16_samples(tmp_path):
    _, cubes = make_synthetic_dataset(tmp_path / "ds", sample_type="float16")
    ds = load_dataset(tmp_path / "ds")
    for sid, cube in cubes.items():  # small Poisson counts are exact in float16
        assert ds.read_transient(sid).dense().tobytes() == cube.tobytes()


def test_writer_is_atomic(tmp_path):
    root = tmp_path / "ds"
    make_synthetic_dataset(root, seed=1)
    before = load_dataset(root).content_hash()
    with pytest.raises(RuntimeError):
        with DatasetWriter(root) as w:
            w.write_depth("ground_truth/train_depth.exr", np.ones((6, 5), np.float32))
            raise RuntimeError("simulated crash half-way")
    assert load_dataset(root).content_hash() == before
    assert [p.name for p in tmp_path.iterdir()] == ["ds"]  # no staging directory left behind
    # a commit with an invalid manifest writes nothing
    m = load_dataset(root).manifest
    m.sensor.bins = 0
    with pytest.raises(DatasetError, match="sensor.bins"):
        with DatasetWriter(root) as w:
            w.commit(m)
    assert load_dataset(root).content_hash() == before


def test_writer_refuses_foreign_directory(tmp_path):
    foreign = tmp_path / "photos"
    foreign.mkdir()
    (foreign / "holiday.jpg").write_bytes(b"x")
    with pytest.raises(FileExistsError, match="not a dataset"):
        DatasetWriter(foreign)
    assert (foreign / "holiday.jpg").read_bytes() == b"x"


def test_manifest_json_is_documented_shape(synthetic_dataset):
    root, _, _ = synthetic_dataset
    d = json.loads((root / "dataset.json").read_text())
    assert d["schema"] == "platolidar.dataset" and d["schema_version"] == "1.0"  # no 1.1 feature used
    assert d["units"]["optical_path"] == "m" and d["units"]["frame"] == "blender_world_z_up"
    for key in ("sensor", "noise", "spots", "layout", "provenance", "ground_truth"):
        assert key in d
    assert Manifest.from_dict(d) == load_dataset(root).manifest


def test_convert_cli(tmp_path, synthetic_dataset, capsys):
    from torch_recon.cli import main

    root, manifest, cubes = synthetic_dataset
    assert main(["convert", "to-platonerf", str(root), str(tmp_path / "pn")]) == 0
    assert main(["convert", "from-platonerf", str(tmp_path / "pn"), str(tmp_path / "back")]) == 0
    assert load_dataset(tmp_path / "back").read_transient(1).dense().tobytes() == cubes[1].tobytes()
    assert main(["convert", "from-platonerf", str(tmp_path / "missing"), str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "transforms_train.json" in err and "Traceback" not in err
