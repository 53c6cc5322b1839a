"""A 4-task plan on a local 2-worker Dask cluster: it completes; a second run does nothing; a worker
killed mid-task loses nothing and the plan completes with identical results; a failed stage is recorded
and run again by the next run. Stages are real (bpy simulator, torch fit) at 16 x 16 pixels."""

from __future__ import annotations

import csv
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("distributed")
pytest.importorskip("bpy")
pytest.importorskip("torch")

REPO = Path(__file__).resolve().parents[3]

# two procedural rooms, each simulated (16 x 16 px, 3 spots, 2 test views) and fitted (fast, 10 steps)
PLAN = """
[scenes.procedural]
count = 2
first_seed = 0
settings = { max_objects = 1 }

[simulate]
resolution = 16
spots = 3
test_views = 2
test_view_resolution = 16
subpixel_samples = 1
adaptive_subpixel_samples = 0

[[methods]]
name = "fast"
settings = { steps = 10, "fast.resolution" = 24, "fast.coarse_resolution" = 12 }

[evaluate]
enabled = false
"""
#: result columns that depend on the data, not on how long things took
SAME = ("scene", "method", "status", "width", "height", "spots", "dataset_hash", "mesh_hash")


def _batch_cmd(plan, out, *extra):
    return [sys.executable, "-m", "pipeline.batch", str(plan), "--out", str(out), "--workers", "2", "--no-progress",
            *extra]


def _env():
    return {**os.environ, "PYTHONPATH": str(REPO)}


def _run(plan, out, *extra, timeout=800):
    return subprocess.run(_batch_cmd(plan, out, *extra), capture_output=True, text=True, env=_env(), cwd=REPO,
                          timeout=timeout)


def _rows(out):
    with open(Path(out) / "results.csv", newline="") as f:
        return sorted(({k: r.get(k) for k in SAME} for r in csv.DictReader(f)), key=lambda r: r["scene"])


def _records(out):
    return {p.parent.name: json.loads(p.read_text()) for p in Path(out).glob("tasks/*/*/task.json")}


@pytest.fixture(scope="module")
def plan(tmp_path_factory):
    p = tmp_path_factory.mktemp("plan") / "plan.toml"
    p.write_text(PLAN)
    return p


@pytest.fixture(scope="module")
def clean_run(plan):
    out = plan.parent / "clean"
    r = _run(plan, out)
    return out, r


def test_four_task_plan_completes(clean_run):
    out, r = clean_run
    assert r.returncode == 0, r.stdout + r.stderr
    assert "4 tasks (simulate 2, fit 2)" in r.stdout and "run 4" in r.stdout, r.stdout
    recs = _records(out)
    assert len(recs) == 4 and all(rec["status"] == "done" for rec in recs.values())
    rows = _rows(out)
    assert [row["scene"] for row in rows] == ["procedural-00000", "procedural-00001"]
    assert all(row["status"] == "done" and row["mesh_hash"] and row["dataset_hash"] for row in rows)
    for folder in Path(out).glob("tasks/*/*"):
        assert (folder / "log.txt").read_text().count("=== attempt ") == 1
        assert not list(folder.glob(".*partial*"))               # no staging folder left behind
    sims = list(Path(out).glob("tasks/simulate/*"))
    assert all((s / "scene.blend").is_file() and (s / "output" / "dataset.json").is_file() for s in sims)
    page = (Path(out) / "summary.html").read_text()
    assert "procedural-00001" in page and "<table>" in page
    data = json.loads((Path(out) / "results.json").read_text())
    assert len(data["rows"]) == 2 and len(data["tasks"]) == 4 and data["summary"]["workers"] == 2


def test_second_run_does_nothing(plan, clean_run):
    out, _ = clean_run
    before = {p: p.stat().st_mtime_ns for p in Path(out).glob("tasks/**/*") if p.is_file()}
    rows = _rows(out)
    r = _run(plan, out)
    assert r.returncode == 0, r.stderr
    assert "4 finished earlier, 0 to run" in r.stdout and "cached 4" in r.stdout, r.stdout
    after = {p: p.stat().st_mtime_ns for p in Path(out).glob("tasks/**/*") if p.is_file()}
    assert after == before                                       # not a file of any task touched
    assert _rows(out) == rows


def _worker_of_running_fit(out, deadline):
    """(worker pid, task folder) once a fit stage has started in a worker."""
    pat = re.compile(r"=== attempt 1 on \S+ pid (\d+) ")
    while time.time() < deadline:
        for log in Path(out).glob("tasks/fit/*/log.txt"):
            text = log.read_text(errors="replace")
            m = pat.search(text)
            if m and "torch_recon fit" in text:
                return int(m.group(1)), log.parent
        time.sleep(0.2)
    raise AssertionError("no fit task started")


def test_worker_killed_mid_task_loses_nothing(plan, clean_run):
    clean_out, _ = clean_run
    out = plan.parent / "killed"
    proc = subprocess.Popen(_batch_cmd(plan, out), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=_env(), cwd=REPO)
    try:
        pid, folder = _worker_of_running_fit(out, time.time() + 600)
        assert pid != proc.pid
        time.sleep(1.0)                     # the fit subprocess is running
        assert not (folder / "task.json").exists()
        os.kill(pid, signal.SIGKILL)        # the worker process, mid-task
        stdout, stderr = proc.communicate(timeout=800)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stdout + stderr
    assert _rows(out) == _rows(clean_out)                        # identical results
    log = (folder / "log.txt").read_text()
    pids = [int(x) for x in re.findall(r"=== attempt \d+ on \S+ pid (\d+) ", log)]
    assert len(pids) == 2 and pids[0] == pid and pids[1] != pid     # run again, on a live worker
    rec = json.loads((folder / "task.json").read_text())
    assert rec["status"] == "done" and rec["attempt"] == 2
    assert not list(folder.glob("**/.*partial*"))                # the killed attempt's staging is gone
    assert not list(folder.glob("**/*.tmp"))


@pytest.mark.slow
def test_failed_stage_recorded_and_retried(tmp_path):
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN.replace("count = 2", "count = 1").replace("spots = 3", "spots = 3\nbins = 5"))
    out = tmp_path / "out"
    r = _run(plan, out)
    assert r.returncode == 1, r.stdout + r.stderr
    recs = _records(out)
    (sim,) = [rec for rec in recs.values() if rec["stage"] == "simulate"]
    assert sim["status"] == "failed" and sim["exit_code"] == 2 and "bins" in sim["error"]
    assert not any(rec["stage"] == "fit" for rec in recs.values())       # its fit was skipped, not recorded
    assert "bins" in (out / "summary.html").read_text()
    r = _run(plan, out)                                          # the next run tries it again
    assert r.returncode == 1 and "0 finished earlier, 2 to run" in r.stdout, r.stdout
    log = (Path(sim["folder"]) / "log.txt").read_text()
    assert log.count("=== attempt ") == 2
