"""Numerical stress, the rest of the suite (slow marker; `make test-all`): every case not in the fast subset."""

from __future__ import annotations

import pytest

from tests.support.stress_fixtures import case_params, check_case, run_by_name, select

pytestmark = pytest.mark.slow
_QUICK = {c.name for c in select(quick=True)}
CASES = [c for c in select(quick=False) if c.name not in _QUICK]
# the same-seed simulator pair must run together and in order (the second compares with the first)
assert [c.name for c in CASES].index("sim-photons-3-seed7") < [c.name for c in CASES].index("sim-photons-3-seed7-again")


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    return run_by_name(CASES, tmp_path_factory.mktemp("stress_slow"))


@pytest.mark.parametrize("name", case_params(CASES))
def test_stress_case(results, name):
    check_case(results, name)


def test_relative_depth_error_independent_of_room_size(results):
    """1 m, 4 m (paper) and 10 m rooms: relative visible-depth error within 20 % of each other."""
    rel = [results[n].metrics["depth_median_rel_err"] for n in ("sim-room-1m", "sim-room-4m", "sim-room-10m")]
    assert max(rel) - min(rel) < 0.2 * max(rel), rel
