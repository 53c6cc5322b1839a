"""The time_to_error suite's bookkeeping (the fits themselves are benchmarks, not tests)."""

from __future__ import annotations

import shlex

from benchmarks.harness.report import check_rows
from benchmarks.suites.time_to_error import AUTHORS_CURVE, GPU_SUITE, SUITE, reference_rows, time_to_reach


def test_reference_rows_are_valid_rows_and_labelled():
    rows = check_rows(reference_rows(), "time_to_error")
    assert [r["step"] for r in rows] == [p[0] for p in AUTHORS_CURVE["points"]]
    assert all("outside the project" in r["method"] and r["kind"] == "reference" for r in rows)
    assert rows[-1]["depth_l1_m"] == 0.128 and rows[-1]["wall_s"] == 1333.0


def test_time_to_reach_takes_the_first_checkpoint_at_or_below():
    rows = [{"wall_s": 3.0, "depth_l1_m": 0.2}, {"wall_s": 1.0, "depth_l1_m": 0.5}, {"wall_s": 9.0, "depth_l1_m": 0.1}]
    assert time_to_reach(rows, 0.2) == 3.0
    assert time_to_reach(rows, 0.05) is None


def test_settings_pick_a_device():
    assert SUITE.settings(False, ["device=cuda"]).device == "cuda"
    assert SUITE.settings(True).view_stride > 1             # the quick run stays affordable on a CPU


def test_the_gpu_suite_runs_the_issue_setting():
    s = GPU_SUITE.settings(False)
    assert (s.device, s.resolution, s.view_stride, s.fast_steps, s.platonerf_budget_s) == ("cuda", 128, 1, None, 1800.0)
    assert GPU_SUITE.settings(False, ["platonerf_budget_s=420"]).platonerf_budget_s == 420.0
