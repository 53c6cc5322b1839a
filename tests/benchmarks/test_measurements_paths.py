"""benchmarks/suites/measurements.py: the path-estimator rows on a small analytic dataset (no Cycles here)."""

from __future__ import annotations

import contextlib

import numpy as np

from benchmarks.harness.suite import all_suites


class _Timer:
    wall_s = cpu_s = 0.1
    peak_rss_mb = 1.0

    def times(self):
        return {"wall_s": self.wall_s, "cpu_s": self.cpu_s, "peak_rss_mb": self.peak_rss_mb}


class _Ctx:
    def __init__(self, path):
        self.path = path

    def dataset(self, example, resolution, spots=16, **options):
        return self.path

    @contextlib.contextmanager
    def timed(self):
        yield _Timer()


def test_each_path_estimator_gives_a_row_with_its_depth_error(tmp_path):
    from benchmarks.suites.measurements import path_rows
    from torch_recon.contract.synthetic import box_room_scene, default_sensor, paper_laser_directions, write_analytic_dataset

    path, _ = write_analytic_dataset(tmp_path / "room", box_room_scene(), default_sensor(16, 16, bins=391),
                                     paper_laser_directions()[:2])
    s = all_suites()["measurements"].settings(False, ["path_scenes=cave-chair", "shadow_resolution=16"])
    rows = path_rows(_Ctx(path), s, "cave-chair")
    assert [r["method"] for r in rows] == ["path: return centroid", "path: 3-bin Gaussian fit"]
    for r in rows:
        assert r["spots"] == 2 and r["resolution"] == 16
        assert 0 <= r["visible_depth_median_mm"] <= r["visible_depth_p95_mm"] <= r["visible_depth_p99_mm"] < 50
        assert np.isfinite(r["visible_depth_far_signed_mm"])
    assert rows[0]["visible_depth_median_mm"] != rows[1]["visible_depth_median_mm"]     # two estimators ran
