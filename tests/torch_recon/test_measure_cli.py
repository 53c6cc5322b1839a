"""CLI: preprocess, baseline, evaluate end to end on a tiny analytic dataset; user errors exit 2 with one line."""

from __future__ import annotations

import json

import numpy as np
import pytest

from torch_recon.cli import main
from torch_recon.contract.frames import paper_test_view_cameras
from torch_recon.measurements import Measurements
from torch_recon.contract.synthetic import (box_room_scene, default_sensor, paper_laser_directions,
                                           write_analytic_dataset)


@pytest.fixture(scope="module")
def ds_path(tmp_path_factory):
    path, _ = write_analytic_dataset(tmp_path_factory.mktemp("c") / "ds", box_room_scene(),
                                     default_sensor(20, 20, bins=391), paper_laser_directions()[:4],
                                     test_cameras=paper_test_view_cameras(dolly_count=1, orbit_count=2),
                                     test_size=(16, 16))
    return path


def test_preprocess_baseline_evaluate(ds_path, tmp_path, capsys):
    npz = tmp_path / "m.npz"
    assert main(["preprocess", str(ds_path), "--out", str(npz), "--shadow-threshold", "0.25"]) == 0
    m = Measurements.load(npz)
    assert len(m.spots) == 4 and m.shadow_threshold == 0.25 and len(m.settings["dataset_hash"]) == 64
    out = capsys.readouterr().out
    assert "first bounce" in out and "preprocessed in" in out
    assert main(["baseline", str(ds_path), "--out", str(tmp_path / "bl"), "--measurements", str(npz),
                 "--voxels", "32", "--threads", "1"]) == 0
    side = json.loads((tmp_path / "bl" / "mesh.mesh.json").read_text())
    assert side["metadata"]["method"] == "bflidar" and side["metadata"]["dataset_hash"] == m.settings["dataset_hash"]
    reps = []
    for name in ("mesh.ply", "mesh.glb"):
        assert main(["evaluate", str(tmp_path / "bl" / name), "--dataset", str(ds_path), "--out",
                     str(tmp_path / name), "--samples", "5000"]) == 0
        reps.append(json.loads((tmp_path / name / "report.json").read_text()))
    assert reps[0]["n_test_views"] == 3 and np.isfinite(reps[0]["depth_l1_m"])
    assert reps[1]["depth_l1_m"] == pytest.approx(reps[0]["depth_l1_m"], abs=1e-4)   # .ply and .glb: same mesh
    assert "depth L1" in capsys.readouterr().out


def test_user_errors_exit_2(ds_path, tmp_path, capsys):
    assert main(["preprocess", str(tmp_path / "nope"), "--out", str(tmp_path / "m.npz")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["preprocess", str(ds_path), "--out", str(tmp_path / "m.npz"), "--shadow-threshold", "3"]) == 2
    assert "shadow_threshold" in capsys.readouterr().err
    assert main(["evaluate", str(tmp_path / "missing.ply"), "--dataset", str(ds_path), "--out", str(tmp_path)]) == 2
    assert "not found" in capsys.readouterr().err
    assert not (tmp_path / "m.npz").exists()
