"""Running some methods of a suite and merging their rows into its results (`run NAME --methods a,b --merge`)."""

from __future__ import annotations

import json
from dataclasses import dataclass

import pytest

from benchmarks.harness import Suite, report
from benchmarks.harness.cli import main, render, run_suite


@dataclass(frozen=True)
class MethodSettings:
    methods: tuple[str, ...] = ("fast", "slow")
    scenes: tuple[str, ...] = ("a", "b")
    error: float = 1.0


def method_run(settings, ctx):
    return [{"method": m, "scene": sc, "wall_s": 1.0, "cpu_s": 1.0, "peak_rss_mb": 50.0,
             "depth_l1_m": settings.error} for sc in settings.scenes for m in settings.methods]


SUITE = Suite("twomethods", "a stand-in suite with a methods setting", quick=MethodSettings(),
              full=MethodSettings(), run=method_run)


def _run(tmp_path, **kw):
    path = run_suite(SUITE, quick=False, results_dir=tmp_path, data_dir=tmp_path / "data", log=lambda m: None, **kw)
    return json.loads(path.read_text())


def test_merge_replaces_rerun_rows_and_keeps_the_others_with_their_run(tmp_path):
    first = _run(tmp_path)
    assert "runs" not in first and len(first["rows"]) == 4
    merged = _run(tmp_path, methods=["slow"], merge=True, overrides=["error=2"])
    by = {(r["method"], r["scene"]): r for r in merged["rows"]}
    assert [(r["method"], r["scene"]) for r in merged["rows"]] == [(m, s) for s in "ab" for m in ("fast", "slow")]
    assert by["fast", "a"]["depth_l1_m"] == 1.0 and by["fast", "a"]["run"] == 1
    assert by["slow", "b"]["depth_l1_m"] == 2.0 and by["slow", "b"]["run"] == 2
    runs = merged["runs"]
    assert runs[0]["command"] == "python -m benchmarks run twomethods"
    assert runs[1]["command"] == "python -m benchmarks run twomethods --methods slow --merge --set error=2"
    assert runs[1]["settings"]["methods"] == ["slow"] and runs[0]["settings"]["methods"] == ["fast", "slow"]
    for run in runs:
        assert run["measured"]["date"] and "loadavg_1min" in run["machine"] and "loadavg_1min_end" in run["machine"]
    text = render(SUITE, merged)
    assert text.count("<sub>`") == 0 and text.count("<sub>run 1: `") == 1 and "<br>run 2: `" in text
    assert "| run |" in text


def test_merging_again_drops_runs_no_row_comes_from(tmp_path):
    _run(tmp_path, methods=["slow"])
    _run(tmp_path, methods=["fast"], merge=True)
    merged = _run(tmp_path, methods=["slow"], merge=True, overrides=["error=3"])
    assert len(merged["runs"]) == 2
    assert {r["method"]: r["run"] for r in merged["rows"]} == {"slow": 1, "fast": 2}
    assert "--methods slow" in merged["runs"][0]["command"] and "--methods fast" in merged["runs"][1]["command"]


def test_merge_refuses_rows_it_cannot_key():
    doc = {"suite": {"command": "x"}, "rows": [{"method": "m", "scene": "s"}, {"method": "m", "scene": "s"}]}
    with pytest.raises(report.RowError, match="two rows for method 'm', scene 's'"):
        report.merge_results(doc, {"suite": {"command": "y"}, "rows": []})


def test_cli_refuses_methods_on_a_suite_without_them_and_an_unmergeable_file(capsys, monkeypatch, tmp_path):
    assert main(["run", "chain", "--methods", "fast"]) == 2
    assert "suite chain has no methods setting" in capsys.readouterr().err
    import benchmarks.harness.cli as cli
    monkeypatch.setattr(cli, "RESULTS_DIR", tmp_path)
    monkeypatch.setattr(cli, "REPO_ROOT", tmp_path)
    (tmp_path / "objects.json").write_text(json.dumps({"rows": [{"method": "m", "scene": "s"}] * 2}))
    assert main(["run", "objects", "--methods", "bflidar", "--merge"]) == 2
    assert "objects.json has two rows" in capsys.readouterr().err


def test_a_suite_may_key_rows_by_more_fields():
    def doc(cmd, *rows):
        return {"suite": {"command": cmd}, "rows": [{"method": "m", "scene": "s", "resolution": r, "v": v}
                                                     for r, v in rows]}
    merged = report.merge_results(doc("a", (128, 1), (512, 2)), doc("b", (512, 3)), ("method", "scene", "resolution"))
    assert [(r["resolution"], r["v"], r["run"]) for r in merged["rows"]] == [(128, 1, 1), (512, 3, 2)]


def test_objects_table_orders_by_scene_and_method_and_says_no_surface():
    from benchmarks.suites.objects import readme
    base = {"wall_s": 1.0, "cpu_s": 1.0, "peak_rss_mb": 1.0}
    rows = [{"method": "platonerf", "scene": "curved-wall", **base, "steps": 3, "load_1min": 9.5,
             "no_surface": "fit wrote no mesh", "note": "short budget", "run": 2},
            {"method": "fast", "scene": "curved-wall", **base, "obj_f2cm": 0.8, "run": 1},
            {"method": "bflidar", "scene": "cave-chair", **base, "obj_f2cm": 0.3, "run": 2}]
    lines = readme({"rows": rows}).splitlines()[2:]
    assert [line.split(" | ")[:2] for line in lines] == [["| cave-chair", "bflidar"], ["| curved-wall", "fast"],
                                                         ["| curved-wall", "platonerf"]]
    assert "| 3 | 9.5 |" in lines[2] and "no surface; short budget" in lines[2] and lines[2].endswith("| 2 |")


def test_objects_table_prints_the_whole_mesh_and_the_objects_region_spurious_fractions():
    # the walls dilute the whole mesh's fraction: the objects' region's must be printed beside it
    from benchmarks.suites.objects import readme
    rows = [{"method": "fast", "scene": "cave-chair", "wall_s": 1.0, "spurious": 0.002, "objects_spurious": 0.059,
             "run": 1}]
    header, _, line = readme({"rows": rows}).splitlines()
    cells = [c.strip() for c in line.strip("|").split("|")]
    names = [c.strip() for c in header.strip("|").split("|")]
    assert cells[names.index("spurious (whole mesh)")] == "0.002"
    assert cells[names.index("spurious (objects' region)")] == "0.059"
