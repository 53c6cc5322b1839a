"""examples/two_pass_capture.py: the two-pass capture recipe (first pass, fit, advise-spots, second pass)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "examples" / "two_pass_capture.py"


def _run(*args):
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, args)], cwd=ROOT, capture_output=True, text=True)


def test_a_first_pass_not_below_the_total_is_refused_in_one_line(tmp_path):
    run = _run("--first", 16, "--total", 16, "--out", tmp_path / "x")
    assert run.returncode == 2 and run.stderr.strip().count("\n") == 0 and "--first" in run.stderr
    assert not (tmp_path / "x").exists()


@pytest.mark.slow
def test_the_second_pass_holds_the_first_pass_spots_and_the_advised_ones(tmp_path):
    pytest.importorskip("bpy")
    out = tmp_path / "two-pass"
    run = _run("--example", "organic-occluded", "--resolution", 32, "--first", 3, "--total", 4, "--test-views", 2,
               "--out", out)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    advice = json.loads((out / "advice.json").read_text())
    assert len(advice["advised"]) == 1 and len(advice["existing"]) == 3
    second = json.loads((out / "second" / "dataset.json").read_text())["spots"]
    assert len(second) == 4
    # the advised spot is simulated where the advisor put it (the laser lands on the fit's surface there)
    assert min(sum((a - b) ** 2 for a, b in zip(s["first_bounce"], advice["advised"][0]["point"])) ** 0.5
               for s in second) < 0.05
    assert (out / "second-eval" / "report.json").is_file()
