"""The reliability contract, one row of tests/support/fault_cases.py per test: exit code, one-line message naming
the file / field / setting, and the files left behind (docs/reliability.md)."""

from __future__ import annotations

import pytest

from tests.support.fault_cases import CASES
from tests.support.fault_workspace import (FaultData, Workspace, message_lines, run_recon, run_simulate,
                             run_simulate_batch)

assert len({c.name for c in CASES}) == len(CASES), "duplicate case names"


@pytest.fixture(scope="session")
def fault_data(tmp_path_factory):
    pytest.importorskip("torch")
    return FaultData(tmp_path_factory.mktemp("fault_data"))


def _batched(case) -> bool:
    """Plain simulate refusals run together in one process (bpy and Cycles start once)."""
    return case.name.startswith("sim-") and not case.slow and case.after is None


@pytest.fixture(scope="session")
def sim_batch(fault_data, tmp_path_factory):
    """{case name: (workspace, exit code, stderr)} for every batched simulate case."""
    pytest.importorskip("bpy")
    root = tmp_path_factory.mktemp("sim_batch")
    cases = [c for c in CASES if _batched(c)]
    spaces, argvs = [], []
    for c in cases:
        ws = Workspace(root / c.name, fault_data)
        kind, argv = c.run(ws)
        assert kind == "sim", c.name
        if c.prepare is not None:
            c.prepare(ws, None)
        ws.snapshot()
        spaces.append(ws)
        argvs.append(argv)
    results = run_simulate_batch(argvs)
    return {c.name: (ws, rc, err) for c, ws, (rc, err) in zip(cases, spaces, results)}


def _params():
    out = []
    for c in CASES:
        marks = [pytest.mark.slow] if c.slow else []
        out.append(pytest.param(c, id=c.name, marks=marks))
    return out


@pytest.mark.parametrize("case", _params())
def test_fault(case, fault_data, tmp_path, monkeypatch, capsys, request):
    if case.name.startswith(("sim-", "addon-")):
        pytest.importorskip("bpy")
    if _batched(case):
        ws, rc, err = request.getfixturevalue("sim_batch")[case.name]
        ran = ("batched",)
    else:
        ws = Workspace(tmp_path / "ws", fault_data)
        ran = case.run(ws)                    # composite cases build their state first
        if ran[0] != "done" and case.prepare is not None:
            case.prepare(ws, monkeypatch)
        if not ws.before and ran[0] != "done":
            ws.snapshot()
    if ran[0] == "batched":
        pass
    elif ran[0] == "recon":
        rc, err = run_recon(ran[1], capsys)
    elif ran[0] == "sim":
        rc, err = run_simulate(ran[1])
    elif ran[0] == "call":
        rc, err = ran[1]()
    else:
        rc, err = ran[1], ran[2]
    monkeypatch.undo()
    assert "Traceback" not in err, err[-3000:]
    assert rc == case.rc, f"exit {rc}, expected {case.rc}:\n{err[-3000:]}"
    if case.says or case.rc != 0:
        lines = [ln for ln in message_lines(err) if "error" in ln.lower() or "interrupted" in ln.lower()
                 or ln.startswith("usage:")]
        if any(ln.startswith("usage:") for ln in lines):     # argparse: usage line + one error line
            lines = [ln for ln in lines if not ln.startswith("usage:")]
        assert len(lines) == 1, f"expected one message line, got {lines}\n{err[-2000:]}"
        for word in case.says:
            assert word.lower() in lines[0].lower(), f"{word!r} not in {lines[0]!r}"
    if case.after is not None:
        case.after(ws)
    else:
        ch = ws.changed()
        assert ch == {"lost": [], "modified": [], "new": []}, ch
        assert not ws.leftovers(), ws.leftovers()
