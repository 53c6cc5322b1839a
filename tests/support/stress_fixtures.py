"""Numerical stress: adversarial but valid inputs through simulator, preprocessing, fit, mesh, evaluation.

(Formerly benchmarks/stress.py; bad inputs and faults are in tests/support/fault_cases.py.)
Every case ends in one status: ok, refused (a user-facing error: a PlatolidarError, or a CLI's exit 2
with one line), crash (any other exception, a traceback, a dead worker), nan (NaN/inf in an output:
transients, depths, measurements, volumes, mesh vertices, metrics) or fail (a check on the numbers:
noise sweep not smooth, seeds not reproducible, error too large). A case passes when its status is what
it expects (`ok`, `refuse`, or `any`) and a refusal's message is one clear line naming what it must
name. Simulator cases run in one worker process (tests/support/stress_sim_worker.py; Cycles start-up paid
once). Cases: tests/support/stress_cases.py; test_stress_fast.py runs the quick subset, test_stress_slow.py
the rest.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from tests.support.stress_cases import KNOWN_ISSUES, all_cases
from tests.support.stress_checks import CheckFailed, NonFinite

REPO_ROOT = Path(__file__).resolve().parents[2]


@dataclass
class Case:
    name: str
    kind: str                  # 'sim' (bpy worker, then `post` on the dataset), 'data' (in process), 'cli'
    expect: str                # 'ok' | 'refuse' | 'any'
    quick: bool                # part of the fast subset (CI)
    fn: object = None          # data/cli: fn(work_dir) -> metrics dict; sim: post(dataset_dir, work_dir)
    must_mention: tuple = ()   # a refusal's message must contain each of these (case-insensitive)
    note: str = ""


@dataclass
class Result:
    name: str
    kind: str
    expect: str
    status: str
    passed: bool
    seconds: float
    message: str = ""
    metrics: dict = field(default_factory=dict)


def _refusal_types():
    from torch_recon.contract.errors import PlatolidarError
    return (PlatolidarError, ValueError, FileNotFoundError)


def _judge(case: Case, status: str, message: str) -> bool:
    if status == "ok":
        return case.expect in ("ok", "any")
    if status == "refused":
        clear = bool(message.strip()) and "\n" not in message.strip() and "Traceback" not in message
        named = all(m.lower() in message.lower() for m in case.must_mention)
        return case.expect in ("refuse", "any") and clear and named
    return False


def _run_in_process(case: Case, fn, *args) -> tuple:
    """(status, message, metrics) of fn(*args)."""
    try:
        metrics = fn(*args) or {}
        return "ok", "", metrics
    except NonFinite as exc:
        return "nan", str(exc), {}
    except CheckFailed as exc:
        return "fail", str(exc), dict(exc.metrics)
    except _refusal_types() as exc:
        return "refused", str(exc), {}
    except Exception as exc:  # noqa: BLE001 - every other exception is a crash
        return "crash", f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=5)}", {}


def run_sim_worker(names, work: Path) -> dict:
    """Run the simulator cases `names` in one worker process; {name: worker record}."""
    if not names:
        return {}
    res_file = work / "sim_results.jsonl"
    res_file.unlink(missing_ok=True)
    proc = subprocess.run([sys.executable, str(Path(__file__).with_name("stress_sim_worker.py")), "--cases",
                           ",".join(names), "--work", str(work / "sim"), "--results", str(res_file)],
                          capture_output=True, text=True, cwd=REPO_ROOT)
    records = {}
    if res_file.exists():
        for line in res_file.read_text().splitlines():
            r = json.loads(line)
            records[r["name"]] = r
    for n in names:   # a worker that died takes the remaining cases with it
        records.setdefault(n, {"status": "crash", "message": f"simulator worker exited {proc.returncode} before "
                               f"this case: {proc.stderr.strip()[-600:]}"})
    return records


def run_cases(cases, work: Path | None = None, progress=print) -> list:
    tmp = None
    if work is None:
        tmp = tempfile.TemporaryDirectory(prefix="stress_")
        work = Path(tmp.name)
    work.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    sim = run_sim_worker([c.name for c in cases if c.kind == "sim"], work)
    sim_seconds = time.perf_counter() - t0
    results = []
    for c in cases:
        t = time.perf_counter()
        if c.kind == "sim":
            rec = sim[c.name]
            status, message, metrics = rec["status"], rec.get("message", ""), {"simulate_s": rec.get("seconds")}
            if status == "crash" and rec.get("traceback"):
                message += "\n" + rec["traceback"]
            if status == "ok" and c.fn is not None:
                status, message, more = _run_in_process(c, c.fn, Path(rec["dataset"]), work)
                metrics.update(more)
                if status == "refused":         # a later stage refused a dataset the simulator accepted
                    metrics["refused_stage"] = "post"
        else:
            (work / c.name).mkdir(parents=True, exist_ok=True)
            status, message, metrics = _run_in_process(c, c.fn, work / c.name)
        r = Result(c.name, c.kind, c.expect, status, _judge(c, status, message), time.perf_counter() - t,
                   message.strip(), metrics)
        results.append(r)
        if progress:
            progress(f"  {'PASS' if r.passed else 'FAIL'} {c.name:34s} {status:8s} {r.seconds:6.1f} s  "
                     f"{(message.strip().splitlines() or [''])[0][:110]}")
    if progress and sim:
        progress(f"  (simulator worker: {len(sim)} cases in {sim_seconds:.1f} s)")
    if tmp is not None:
        tmp.cleanup()
    return results


def summary(results) -> dict:
    n = len(results)
    by = {s: sum(r.status == s for r in results) for s in ("ok", "refused", "crash", "nan", "fail")}
    exp_ref = sum(r.status == "refused" and r.expect in ("refuse", "any") for r in results)
    return {"cases": n, "passed": sum(r.passed for r in results), "ok": by["ok"], "crashes": by["crash"],
            "nan": by["nan"], "failed_checks": by["fail"], "refusals_expected": exp_ref,
            "refusals_unexpected": by["refused"] - exp_ref,
            "failing": [r.name for r in results if not r.passed and r.name not in KNOWN_ISSUES],
            "known_issues": {r.name: KNOWN_ISSUES[r.name] for r in results if not r.passed and r.name in KNOWN_ISSUES}}


def select(quick: bool, only=None):
    cases = all_cases(Case)
    if only:
        names = set(only)
        unknown = names - {c.name for c in cases}
        if unknown:
            raise ValueError(f"unknown stress case(s) {sorted(unknown)}")
        return [c for c in cases if c.name in names]
    return [c for c in cases if c.quick] if quick else cases


def case_params(cases):
    """One pytest parameter per case; a case failing on a reported bug is xfail (strict: fails once fixed)."""
    out = []
    for c in cases:
        if c.name in KNOWN_ISSUES:
            out.append(pytest.param(c.name, marks=pytest.mark.xfail(strict=True, reason=KNOWN_ISSUES[c.name])))
        else:
            out.append(c.name)
    return out


def run_by_name(cases, tmp_dir) -> dict:
    return {r.name: r for r in run_cases(cases, tmp_dir, progress=None)}


def check_case(results, name):
    r = results[name]
    assert r.passed, f"{name}: expected {r.expect}, got {r.status}: {r.message[:3000]}"
