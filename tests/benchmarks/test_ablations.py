"""The ablation suites' rows carry the object-level columns (issue 11) next to depth L1, and render them."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from benchmarks.harness import runners
from benchmarks.harness.context import Context
from benchmarks.suites import ablation_ambient, ablations

REPORT = {"depth_l1_m": 0.04, "n_test_views_invalid": 0,
          "object_metrics": {"objects": {"chair": {}, "lamp": {}},
                             "summary": {"fscore@1cm": 0.6, "fscore@2cm": 0.88, "fscore@5cm": 0.97,
                                         "recall_hidden@2cm": 0.87, "recall_visible@2cm": 0.95,
                                         "normal_consistency": 0.85},
                             "scene": {"spurious_fraction": 0.0036, "objects_spurious_fraction": 0.01,
                                       "normal_consistency": 0.9, "degenerate_faces": 0}}}


def test_object_fields_reads_the_evaluate_report():
    f = runners.object_fields(REPORT)
    assert set(f) == set(runners.OBJECT_FIELDS)
    assert (f["obj_f2cm"], f["hidden_recall_2cm"], f["spurious"], f["degenerate_faces"]) == (0.88, 0.87, 0.0036, 0)
    assert f["objects"] == "chair,lamp"
    assert (f["normal_consistency"], f["obj_normals"]) == (0.9, 0.85)     # whole mesh vs mean over the objects
    empty = runners.object_fields({"depth_l1_m": 0.1})          # a dataset without object labels
    assert empty["obj_f2cm"] is None and empty["objects"] is None


def test_fit_row_carries_object_columns(tmp_path, monkeypatch):
    """fit_row: the fit's evaluate metrics (depth and object level) and times land in the row; a subset transform's
    signal fraction is the measurements' after the change."""
    from torch_recon import measurements
    ctx = Context("abl", quick=True, data_dir=tmp_path, log=lambda m: None)
    spots = [SimpleNamespace(signal=np.array([True, False])) for _ in range(4)]
    monkeypatch.setattr(measurements.Measurements, "load", staticmethod(lambda p: SimpleNamespace(spots=spots)))
    seen = {}

    def fake_fit(ctx, source, tag, **kw):
        seen.update(kw)
        return {"wall_s": 2.0, "cpu_s": 2.0, "peak_rss_mb": 10.0, "steps": 100, "depth_l1_m": 0.04,
                "depth_psnr_db": 20.0, **runners.object_fields(REPORT)}
    monkeypatch.setattr(runners, "fit", fake_fit)
    prep = {"measurements": tmp_path / "m.npz", "wall_s": 1.0, "cpu_s": 1.0, "peak_rss_mb": 5.0}
    s = ablations.Settings(levels=("16",), threads=1)
    row = ablations.fit_row(ctx, s, 16, tmp_path, prep, "spots16")
    assert seen["sets"] == () and seen["threads"] == 1 and seen["steps"] is None      # the mode's own grid and steps
    assert (row["obj_f2cm"], row["hidden_recall_2cm"], row["spurious"]) == (0.88, 0.87, 0.0036)
    assert row["depth_l1_m"] == 0.04 and row["wall_s"] == 3.0 and row["signal_fraction"] == 0.5
    row96 = ablations.fit_row(ctx, ablations.Settings(grid=96), 16, tmp_path, prep, "g96")
    assert seen["sets"] == ("fast.resolution=96", "fast.coarse_resolution=48") and row96["obj_f2cm"] == 0.88
    assert (ctx.work_dir / "rows.jsonl").read_text().count("\n") == 2       # kept as they are measured


def _rows():
    base = {"method": "fast", "wall_s": 50.0, "steps": 100, "depth_psnr_db": 20.0, "load_1min": 3.0,
            "signal_fraction": 0.3}
    return [{**base, "scene": sc, "level": k, "depth_l1_m": 0.04 + 0.01 * i, "obj_f2cm": 0.88 - 0.1 * i,
             "hidden_recall_2cm": 0.87, "spurious": 0.0036,
             "paper_depth_l1_m": ablations.paper_l1(k) if sc == ablations.PAPER_SCENE else None}
            for sc in ("cave-chair", "organic-occluded") for i, k in enumerate((16, 8, 4, 2))] + \
        [{"method": "fast", "scene": "cave-chair", "level": 1, "wall_s": 1.0, "refused": "no two-bounce return"}]


def test_ablation_table_shows_object_columns_scene_and_paper(tmp_path):
    rows = _rows()
    text = ablations.readme({"rows": rows})
    header = text.splitlines()[0]
    for col in ("scene", "depth L1 m", "obj F@2cm", "hidden R@2cm", "spurious %", "paper L1 m"):
        assert col in header, col
    assert "| cave-chair | 16 | 0.0400 | 20.00 | 0.880 | 0.870 | 0.36 |" in text
    assert "0.0862" in text and "refused" in text
    one_scene = ablations.readme({"rows": [r for r in rows if r["scene"] == "cave-chair"]})
    assert "scene" not in one_scene.splitlines()[0]
    ablations.plot(rows, ablations.Settings(), tmp_path / "a.png")
    assert (tmp_path / "a.png").stat().st_size > 1000


def test_ambient_table_cell_has_object_fscore():
    row = {"ambient_per_bin": 0.0, "variant": "lidar gate off", "depth_l1_m": 0.0412, "obj_f2cm": 0.871,
           "shadow_f1": 0.95}
    text = ablation_ambient.readme({"rows": [row]})
    assert "0.041 m, F@2cm 0.87 (shadow F1 0.95)" in text


def test_integrated_dataset_keeps_the_labelled_objects(tmp_path):
    """The temporal ablation's coarser-bin copy carries the objects' meshes (evaluate's object metrics need them)."""
    import json
    import shutil

    from benchmarks.harness.datasets import integrate_bins
    from tests.conftest import make_synthetic_dataset
    from torch_recon.contract.dataset import load_dataset

    src = tmp_path / "src"
    make_synthetic_dataset(src, bins=40, window_bins=8, spots=2)
    (src / "ground_truth" / "objects").mkdir()
    shutil.copy(src / "ground_truth" / "mesh.ply", src / "ground_truth" / "objects" / "box.ply")
    man = json.loads((src / "dataset.json").read_text())
    man["ground_truth"]["objects"] = [{"name": "box", "mesh_file": "ground_truth/objects/box.ply"}]
    (src / "dataset.json").write_text(json.dumps(man))
    assert [o.name for o in load_dataset(src).manifest.ground_truth.objects] == ["box"]
    out = load_dataset(integrate_bins(src, tmp_path / "dst", 2))
    assert [o.mesh_file for o in out.manifest.ground_truth.objects] == ["ground_truth/objects/box.ply"]
    assert (tmp_path / "dst" / "ground_truth" / "objects" / "box.ply").is_file()
