"""numpy's OpenBLAS on one thread during a fit (issue 11's speed, session 17): its products there are small."""

from __future__ import annotations

import sys

import pytest

from torch_recon.blas_threads import _loaded_openblas, single_threaded_blas

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/maps")


def test_single_threaded_inside_restored_after():
    libs = _loaded_openblas()
    if not libs:
        pytest.skip("numpy is not linked against OpenBLAS here")
    before = [get() for get, _ in libs]
    with single_threaded_blas():
        assert [get() for get, _ in _loaded_openblas()] == [1] * len(libs)
    assert [get() for get, _ in libs] == before


def test_a_fit_runs_numpys_blas_on_one_thread():
    from tests.support.recon_fixtures import box_floor_measurements
    from tests.torch_recon.recon.test_recon_fit import small_config
    from torch_recon.recon import fit

    if not _loaded_openblas():
        pytest.skip("numpy is not linked against OpenBLAS here")
    seen = []

    def watch(step, loss):
        seen.append([get() for get, _ in _loaded_openblas()])
        return loss

    fit(box_floor_measurements(24), config=small_config(steps=2), export=False, fault_hook=watch)
    assert seen and all(set(s) == {1} for s in seen)
