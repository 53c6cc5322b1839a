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


def test_volume_depth_scores_the_fields_own_rendering():
    """A field that renders every pixel at 2 m against a ground truth at 3 m: L1 1 m (no mesh involved)."""
    import types

    import numpy as np
    import torch

    from benchmarks.suites.time_to_error import _Scorer
    from torch_recon.evaluate import EvalSettings

    class FlatField:
        device = torch.device("cpu")

        def render_depth(self, origins, dirs, min_opacity=None):
            assert min_opacity is None          # the mode's own test rendering, as the reference was scored
            return torch.full((origins.shape[0],), 2.0)

    score = _Scorer.__new__(_Scorer)
    score.views = types.SimpleNamespace(width=8, height=6, fov_rad=0.8, fov_axis="x")
    score.cams, score.gt, score.es = [np.eye(4)] * 2, np.full((2, 6, 8), 3.0, np.float32), EvalSettings()
    assert abs(score.volume_depth(FlatField())["depth_l1_volume_m"] - 1.0) < 1e-6


def test_checkpoint_mesh_is_the_mesh_fit_exports(tmp_path):
    """A checkpoint is scored on the mesh `fit` writes (inward smoothing, plane snap, kept thin parts and all), not
    on a plainer one: `_mesh_of` of the fitted model = the exported mesh.ply."""
    import numpy as np
    import trimesh

    from benchmarks.suites.time_to_error import _mesh_of
    from tests.support.recon_fixtures import box_floor_measurements
    from tests.torch_recon.recon.test_recon_fit import small_config
    from torch_recon.recon import fit

    r = fit(box_floor_measurements(32), out=tmp_path, config=small_config(steps=4), uv=False)
    written = trimesh.load(r.mesh_files["ply"], process=False)
    scored = _mesh_of(r.model)
    assert scored is not None and scored.faces.shape == written.faces.shape
    assert np.allclose(scored.vertices, written.vertices, atol=1e-5)
