"""The benchmark harness itself: a tiny fake suite run in quick mode, the results schema, --set typing,
run_cli timing of a real subprocess, the dataset cache's validation, and README marker rendering."""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass

import pytest

from benchmarks.harness import CliError, Suite, report
from benchmarks.harness.cli import readme, run_suite
from benchmarks.harness.context import run_cli
from benchmarks.harness.datasets import cache_problem, integrate_bins, simulate_args
from benchmarks.harness.suite import SettingsError, all_suites


@dataclass(frozen=True)
class FakeSettings:
    n: int = 3
    scale: float = 1.0
    label: str = "fake"
    levels: tuple[int, ...] = (1, 2)
    budget_s: float | None = None


def fake_run(settings, ctx):
    with ctx.timed() as t:
        total = sum(range(settings.n * 1000))
    ctx.log(f"fake: {total}")
    return [{"method": settings.label, "scene": f"level{lv}", **t.times(), "depth_l1_m": 0.1 * lv * settings.scale,
             "n": settings.n} for lv in settings.levels]


FAKE = Suite("fake", "a fake suite for the harness tests", quick=FakeSettings(n=2), full=FakeSettings(), run=fake_run,
             readme=lambda res: report.markdown_table(res["rows"], [("scene", "scene"), ("depth_l1_m", "L1 m")]))


def test_quick_run_writes_schema_json_and_png(tmp_path):
    path = run_suite(FAKE, quick=True, overrides=["scale=2", "levels=[1,3]"], results_dir=tmp_path,
                     data_dir=tmp_path / "data", log=lambda m: None)
    doc = json.loads(path.read_text())
    assert set(doc) == {"machine", "suite", "settings", "rows"}
    assert doc["suite"]["name"] == "fake" and doc["suite"]["quick"] is True
    assert doc["settings"] == {"n": 2, "scale": 2.0, "label": "fake", "levels": [1, 3], "budget_s": None}
    assert [r["scene"] for r in doc["rows"]] == ["level1", "level3"]
    assert doc["rows"][1]["depth_l1_m"] == pytest.approx(0.6)
    for r in doc["rows"]:
        assert list(r)[:5] == list(report.ROW_KEYS)
        assert r["wall_s"] >= 0 and r["cpu_s"] >= 0 and r["peak_rss_mb"] > 10
    for key in ("cpu", "cores", "ram_gb", "numpy", "torch", "loadavg_1min"):
        assert key in doc["machine"]
    assert path.with_suffix(".png").stat().st_size > 1000


@pytest.mark.parametrize("override, message", [("nope=1", "setting nope: unknown setting"),
                                               ("n=1.5", "setting n: expected an integer"),
                                               ("levels=[1,\"a\"]", "setting levels: expected an integer"),
                                               ("n", "KEY=VALUE")])
def test_set_refuses_unknown_keys_and_wrong_types(override, message):
    with pytest.raises(SettingsError, match=message):
        FAKE.settings(True, [override])


def test_set_types_values_by_field():
    s = FAKE.settings(False, ["scale=3", "label=x", "budget_s=null", "levels=4"])
    assert s == FakeSettings(n=3, scale=3.0, label="x", levels=(4,), budget_s=None)
    assert FAKE.settings(False, ["budget_s=5"]).budget_s == 5.0


@pytest.mark.parametrize("bad, field", [({"scene": "x", "wall_s": 1, "cpu_s": 1, "peak_rss_mb": 1}, "method"),
                                        ({"method": "m", "scene": "s", "wall_s": -1, "cpu_s": 1, "peak_rss_mb": 1}, "wall_s"),
                                        ({"method": "m", "scene": "s", "wall_s": 1, "cpu_s": 1, "peak_rss_mb": 1,
                                          "depth_l1_m": float("nan")}, "JSON")])
def test_row_schema_names_the_broken_field(bad, field):
    with pytest.raises(report.RowError, match=field):
        report.check_rows([bad], "fake")


def test_readme_markers_rendered_from_results(tmp_path):
    run_suite(FAKE, quick=True, results_dir=tmp_path, data_dir=tmp_path / "data", log=lambda m: None)
    md = tmp_path / "README.md"
    md.write_text("intro\n<!-- bench:fake -->\nold table\n<!-- /bench:fake -->\n"
                  "<!-- bench:missing -->\nkept\n<!-- /bench:missing -->\nend\n")
    assert readme(md, tmp_path, suites={"fake": FAKE}) == ["fake"]
    text = md.read_text()
    assert "old table" not in text and "| scene | L1 m |" in text and "| level1 | 0.1000 |" in text
    assert "python -m benchmarks run fake --quick" in text and "kept" in text and text.endswith("end\n")
    once = text
    readme(md, tmp_path, suites={"fake": FAKE})
    assert md.read_text() == once          # idempotent


def test_run_cli_times_a_real_subprocess(tmp_path):
    code = "import time; x = bytearray(200 * 2**20); t = time.process_time()\nwhile time.process_time() - t < 0.3: pass"
    r = run_cli(["python", "-c", code])
    assert r.returncode == 0 and r.wall_s >= 0.3 and r.cpu_s >= 0.25 and r.peak_rss_mb > 200
    bad = run_cli(["python", "-c", "import sys; print('boom', file=sys.stderr); sys.exit(3)"], check=False)
    assert bad.returncode == 3 and "boom" in bad.stderr
    with pytest.raises(CliError, match="limit"):
        run_cli(["python", "-c", "import time; time.sleep(30)"], timeout=0.5)


def test_dataset_cache_revalidates(tmp_path):
    args = simulate_args("cave-chair", 8, 4, {"poisson": True, "photons": 100, "no_gt": False})
    assert args == ["--example", "cave-chair", "--resolution", "8", "--spots", "4", "--photons", "100", "--poisson"]
    # a spot list starting with a negative coordinate stays one token (argparse would read '-1.2,...' as a flag)
    assert simulate_args("cave-chair", 8, None, {"spot_list": "-1.2,3,0;1,2,3"}) == [
        "--example", "cave-chair", "--resolution", "8", "--spot-list=-1.2,3,0;1,2,3"]   # spots: from the list
    from pipeline.simulate import build_parser
    assert build_parser().parse_args([*simulate_args("cave-chair", 8, None, {"spot_list": "-1.2,3,0"}),
                                      "--out", "x"]).spot_list == "-1.2,3,0"
    out = tmp_path / "ds"
    assert cache_problem(out, args) == "not cached"
    out.mkdir()
    (out / "t.exr").write_bytes(b"12345")
    (out / "bench_cache.json").write_text(json.dumps({"args": args, "files": {"t.exr": 5}}))
    assert "invalid" in cache_problem(out, args)           # no manifest: not a dataset
    assert cache_problem(out, args[:-1]) == "cached with other settings"
    (out / "t.exr").write_bytes(b"12")                       # truncated
    assert cache_problem(out, args) == "cached files changed or missing"


def test_every_suite_declares_dataclass_settings():
    suites = all_suites()
    for name, s in suites.items():
        assert s.name == name and s.description
        assert type(s.quick) is type(s.full)
        s.settings(True)       # the dataclass check


def test_cli_list_and_bad_set(capsys):
    from benchmarks.harness.cli import main
    assert main(["list"]) == 0
    assert main(["run", "no-such-suite"]) == 2
    assert "no suite" in capsys.readouterr().err


def test_integrate_bins_sums_adjacent_bins(tmp_path):
    """The temporal ablation's bin integration: coarse bin j = sum of fine bins f*j .. f*j+f-1; GT carried over."""
    import numpy as np
    from tests.conftest import make_synthetic_dataset
    from torch_recon.contract.dataset import load_dataset

    make_synthetic_dataset(tmp_path / "src", bins=40, window_bins=8, spots=2)
    a, b = load_dataset(tmp_path / "src"), load_dataset(integrate_bins(tmp_path / "src", tmp_path / "dst", 4))
    assert (b.sensor.bins, b.sensor.bin_width_ps) == (10, 4 * a.sensor.bin_width_ps)
    assert abs(b.sensor.bin_width_m - 4 * a.sensor.bin_width_m) < 1e-9
    for s in a.manifest.spots:
        fine, coarse = a.read_transient(s.id).dense(), b.read_transient(s.id).dense()
        np.testing.assert_allclose(fine.reshape(6, 5, 10, 4).sum(-1), coarse, rtol=1e-5)
    np.testing.assert_array_equal(a.test_views()[2], b.test_views()[2])


def test_runner_turns_exit_2_into_refused_and_other_failures_into_cli_error(tmp_path):
    from benchmarks.harness import Refused, runners
    from benchmarks.harness.context import Context
    ctx = Context("fake", quick=True, data_dir=tmp_path, log=lambda m: None)
    assert ctx.work_dir.is_dir()
    with pytest.raises(Refused, match="^error: --steps: expected"):
        runners._run(ctx, ["python", "-c", "import sys; print('error: --steps: expected >= 0', file=sys.stderr); "
                                           "sys.exit(2)"], None)
    with pytest.raises(CliError) as err:
        runners._run(ctx, ["python", "-c", "raise SystemExit(1)"], None)
    assert err.value.returncode == 1
    assert runners.combined({"wall_s": 1, "cpu_s": 2, "peak_rss_mb": 30}, {"wall_s": 3, "cpu_s": 1, "peak_rss_mb": 20}) \
        == {"wall_s": 4, "cpu_s": 3, "peak_rss_mb": 30}


def test_every_suites_settings_pass_the_settings_mechanism():
    """--set on any suite goes through torch_recon/contract/settings.py: its quick/full settings must fit it."""
    from torch_recon.contract.settings import merged

    for name, suite in all_suites().items():
        for s in (suite.quick, suite.full):
            assert merged(s, {}) == s, name


def test_every_committed_result_renders_with_one_provenance_line():
    """A suite's own table renderer leaves the provenance line to the harness (it was printed twice)."""
    from benchmarks.harness.cli import RESULTS_DIR, render
    suites = all_suites()
    rendered = 0
    for name, suite in suites.items():
        f = RESULTS_DIR / f"{name}.json"
        if suite.readme is None or not f.is_file():
            continue
        text = render(suite, json.loads(f.read_text()))
        assert text.count("<sub>") == 1 and text.count("`python") >= 1, name     # merged: one line per run inside
        rendered += 1
    assert rendered >= 3
