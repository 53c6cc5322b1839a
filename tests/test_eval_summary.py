"""evaluate() writes the summary page (HTML + PNG montage) and every file it references exists."""

from __future__ import annotations

import re

import numpy as np
import trimesh

from torch_recon.contract.dataset import load_dataset
from torch_recon.contract.frames import paper_test_view_cameras
from torch_recon.contract.synthetic import box_room_scene, default_sensor, paper_laser_directions, write_analytic_dataset
from torch_recon.evaluate import EvalSettings, evaluate


def test_summary_page_written_and_its_pictures_exist(tmp_path):
    cams = paper_test_view_cameras(dolly_count=2, orbit_count=2)
    path, _ = write_analytic_dataset(tmp_path / "ds", box_room_scene(), default_sensor(8, 8),
                                     paper_laser_directions()[:1], test_cameras=cams, test_size=(16, 16))
    ds = load_dataset(path)
    gt = trimesh.load(ds.path(ds.manifest.ground_truth.mesh_file), force="mesh")
    rec = gt.copy()
    rec.apply_translation([0.0, 0.0, 0.01])
    out = tmp_path / "ev"
    light = {"gt_samples_per_object": 4000, "recon_samples_per_m2": 5000, "scene_samples": 10_000,
             "scene_samples_per_m2": 300.0}
    r = evaluate(ds, out, mesh=rec, settings=EvalSettings(n_surface_samples=5000, error_images=0, picture_size=48,
                                                          cull_back_faces=False, object_metric_settings=light))
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
