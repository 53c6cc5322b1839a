"""`python -m torch_recon fit`: outputs, metadata, readable errors."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from tests.support.recon_fixtures import box_floor_measurements



class _Run:
    def __init__(self, returncode, stdout, stderr):
        self.returncode, self.stdout, self.stderr = returncode, stdout, stderr


@pytest.fixture
def run_cli(capsys):
    """`python -m torch_recon fit ARGS` in-process (the same entry point, without a second interpreter)."""
    from torch_recon.cli import main

    def run(*args):
        rc = main(["fit", *map(str, args)])
        cap = capsys.readouterr()
        return _Run(rc, cap.out, cap.err)
    return run


@pytest.fixture(scope="module")
def meas_file(tmp_path_factory):
    p = tmp_path_factory.mktemp("m") / "measurements.npz"
    box_floor_measurements(24).save(p)
    return p


def test_fit_cli_writes_mesh_volume_and_report(meas_file, tmp_path, run_cli):
    out = tmp_path / "fit"
    p = run_cli(meas_file, "--out", out, "--steps", "6", "--set", "fast.resolution=24", "--threads", "1", "--quiet")
    assert p.returncode == 0, p.stderr
    for name in ("mesh.glb", "mesh.ply", "mesh.obj", "mesh.mesh.json", "volume.npz", "fit.json", "checkpoint.pt"):
        assert (out / name).is_file(), name
    rep = json.loads((out / "fit.json").read_text())
    assert rep["method"] == "platolidar-fast" and rep["steps"] == 6 and rep["source_hash"].startswith("measurements:")
    side = json.loads((out / "mesh.mesh.json").read_text())
    assert side["metadata"]["method"] == "platolidar-fast" and "run_seconds" in side["metadata"]
    import trimesh

    mesh = trimesh.load(out / "mesh.ply", force="mesh")
    vol = np.load(out / "volume.npz")
    # the mesh lies in the Blender world frame, inside the reconstruction box
    assert np.all(mesh.bounds[0] >= vol["bbox_min"] - 1e-3) and np.all(mesh.bounds[1] <= vol["bbox_max"] + 1e-3)
    assert mesh.bounds[1][1] > 3.0          # reaches the back wall at y = 3.3


def test_fit_cli_no_uv_skips_the_atlas(meas_file, tmp_path, run_cli):
    out = tmp_path / "fit"
    p = run_cli(meas_file, "--out", out, "--steps", "2", "--set", "fast.resolution=24", "--threads", "1", "--quiet",
                "--no-uv")
    assert p.returncode == 0, p.stderr
    side = json.loads((out / "mesh.mesh.json").read_text())
    assert side["mesh"]["uv"] is None
    with_uv = tmp_path / "fit_uv"
    assert run_cli(meas_file, "--out", with_uv, "--steps", "2", "--set", "fast.resolution=24", "--threads", "1",
                   "--quiet").returncode == 0
    assert json.loads((with_uv / "mesh.mesh.json").read_text())["mesh"]["uv"] == "xatlas"


def test_fit_cli_errors_are_one_line(meas_file, tmp_path, run_cli):
    p = run_cli(tmp_path / "missing", "--out", tmp_path / "o")
    assert p.returncode == 2 and "no such dataset" in p.stderr and "Traceback" not in p.stderr
    ds_json = tmp_path / "ds" / "dataset.json"      # the dataset's JSON instead of its folder
    ds_json.parent.mkdir()
    ds_json.write_text("{}")
    p = run_cli(ds_json, "--out", tmp_path / "o")
    assert p.returncode == 2 and "expected a dataset directory" in p.stderr and str(ds_json.parent) in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1 and not (tmp_path / "o").exists()
    p = run_cli(meas_file, "--out", tmp_path / "o", "--set", "fast.voxels=3")
    assert p.returncode == 2 and "unknown setting" in p.stderr and "Traceback" not in p.stderr
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    p = run_cli(meas_file, "--out", tmp_path / "o", "--config", bad)
    assert p.returncode == 2 and "not valid JSON" in p.stderr


@pytest.mark.parametrize("user_value, expected", [(None, "PASSIVE"), ("ACTIVE", "ACTIVE")])
def test_cli_lets_idle_openmp_threads_sleep_unless_the_user_chose(user_value, expected):
    # set before torch is imported (libgomp reads it once): spinning threads made a 2-thread fit 1.5x slower
    # while another process held a core (session 20)
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    if user_value:
        env["OMP_WAIT_POLICY"] = user_value
    code = ("import sys, os, torch_recon.cli; assert 'torch' not in sys.modules; "
            "print(os.environ.get('OMP_WAIT_POLICY'))")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == expected
