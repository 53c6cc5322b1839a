"""Shared by the fast (CI) and slow stress test modules: case parameters and one run of the cases."""

from __future__ import annotations

import pytest

from benchmarks.stress import run_cases
from benchmarks.stress_cases import KNOWN_ISSUES


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
