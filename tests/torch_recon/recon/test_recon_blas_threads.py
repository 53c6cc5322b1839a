"""numpy's BLAS on one thread during a fit (issue 11's speed, session 17): its products there are small."""

from __future__ import annotations

import pytest
from threadpoolctl import threadpool_info


def _blas_threads() -> dict:
    """Threads of each loaded BLAS library, by file."""
    return {lib["filepath"]: lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"}


def test_a_fit_runs_numpys_blas_on_one_thread_and_restores_it():
    from tests.support.recon_fixtures import box_floor_measurements
    from tests.torch_recon.recon.test_recon_fit import small_config
    from torch_recon.recon import fit

    before = _blas_threads()
    if not before:
        pytest.skip("numpy is linked against no BLAS threadpoolctl knows here")
    seen = []

    def watch(step, loss):
        seen.append(set(_blas_threads().values()))
        return loss

    fit(box_floor_measurements(24), config=small_config(steps=2), export=False, fault_hook=watch)
    assert seen and all(s == {1} for s in seen)
    after = _blas_threads()                        # scipy may load its own BLAS during the fit
    assert {k: after[k] for k in before} == before
