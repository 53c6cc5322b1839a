"""evaluate() writes the summary page (HTML + PNG montage) and every file it references exists."""

from __future__ import annotations

import re

import numpy as np
import trimesh

from torch_recon.contract.dataset import load_dataset
from torch_recon.contract.frames import paper_test_view_cameras
from torch_recon.contract.synthetic import box_room_scene, default_sensor, paper_laser_directions, write_analytic_dataset
from torch_recon.evaluate import EvalSettings, evaluate


import json
import shutil

import pytest


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory):
    """A box room evaluated against itself shifted 1 cm, as the `fit` output folder fast/ of a run."""
    tmp_path = tmp_path_factory.mktemp("run")
    cams = paper_test_view_cameras(dolly_count=2, orbit_count=2)
    path, _ = write_analytic_dataset(tmp_path / "ds", box_room_scene(), default_sensor(8, 8),
                                     paper_laser_directions()[:1], test_cameras=cams, test_size=(16, 16))
    ds = load_dataset(path)
    gt = trimesh.load(ds.path(ds.manifest.ground_truth.mesh_file), force="mesh")
    rec = gt.copy()
    rec.apply_translation([0.0, 0.0, 0.01])
    fit_dir = tmp_path / "fast"
    fit_dir.mkdir()
    rec.export(fit_dir / "mesh.ply")
    (fit_dir / "fit.json").write_text(json.dumps({"setup_seconds": 2.0, "train_seconds": 10.0, "run_seconds": 15.5,
                                                  "steps": 200, "stopped": "steps"}))
    out = fit_dir / "eval"
    light = {"gt_samples_per_object": 4000, "recon_samples_per_m2": 5000, "scene_samples": 10_000,
             "scene_samples_per_m2": 300.0}
    r = evaluate(ds, out, mesh=rec, settings=EvalSettings(n_surface_samples=5000, error_images=0, picture_size=48,
                                                          cull_back_faces=False, object_metric_settings=light),
                 extra={"reconstruction": str(fit_dir / "mesh.ply")})
    return tmp_path, out, r


def test_summary_page_written_and_its_pictures_exist(evaluated):
    _, out, r = evaluated
    # no labels in this dataset: the box is split off the room's shell
    assert r["objects_source"].startswith("split") and len(r["object_metrics"]["objects"]) == 1
    box = next(iter(r["object_metrics"]["objects"].values()))
    assert box["fscore@2cm"] > 0.95 and box["fscore@5cm"] > 0.99      # light sampling: distances are upper bounds
    for rel in r["pictures"]:
        assert (out / rel).is_file() and (out / rel).stat().st_size > 1000, rel
    html = (out / "summary.html").read_text()
    refs = re.findall(r"src='([^']+)'", html)
    assert refs and all((out / ref).is_file() for ref in refs)
    assert "fscore" not in html and "F@2cm" in html and "degenerate faces" in html
    png = (out / "summary.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert np.isfinite(r["object_metrics"]["scene"]["spurious_fraction"])


def test_summary_has_the_time_breakdown(evaluated):
    from torch_recon.evaluation.report import time_rows
    _, out, r = evaluated
    rows = dict(time_rows(r))
    assert rows["fit: set-up (measurements, rays, initial field)"] == 2.0
    assert rows["fit: optimisation (200 steps, steps)"] == 10.0
    assert rows["fit: volume + mesh export"] == pytest.approx(3.5)
    assert rows["evaluation"] == r["eval_seconds"] > 0
    stages = r["stage_seconds"]     # the slow stages after the view renders are announced and timed
    assert {"surface metrics", "summary pictures"} <= set(stages) and any(k.startswith("object metrics") for k in stages)
    assert all(v >= 0 for v in stages.values())
    html = (out / "summary.html").read_text()
    assert "<h2>Time</h2>" in html and "volume + mesh export" in html


def test_run_summary_one_page_for_several_methods(evaluated):
    """The demo's page: a metrics row per method, a time chart, each method's pictures; links resolve."""
    from torch_recon.evaluation.report import write_run_summary
    run, out, r = evaluated
    shutil.copytree(out, run / "bflidar" / "eval")
    rep = json.loads((run / "bflidar" / "eval" / "report.json").read_text())
    rep["depth_l1_m"] = 0.123456
    (run / "bflidar" / "eval" / "report.json").write_text(json.dumps(rep))
    written = write_run_summary(run, {"fast": out, "bflidar": run / "bflidar" / "eval", "missing": run / "nope"},
                                {"simulate": 4.0, "fit": 15.5, "evaluate fast": 3.0}, title="demo: box room")
    assert written == ["summary.png", "summary.html"]
    html = (run / "summary.html").read_text()
    refs = re.findall(r"(?:src|href)='([^']+)'", html)
    assert len(refs) >= 5 and all((run / ref).is_file() for ref in refs), refs
    assert "0.1235" in html and "<td>bflidar</td>" in html and "missing" not in html
    assert "<td>total</td><td>22.5</td>" in html
    png = (run / "summary.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000
