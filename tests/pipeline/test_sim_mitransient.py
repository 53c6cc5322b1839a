"""The Cycles simulator (pipeline/simulate.py) against an independent path tracer: mitransient (Mitsuba 3), slow.

Needs `pip install mitransient "mitsuba==3.8.0"` (not a project dependency; see
../shared/REFERENCE_RENDERER.md); skipped without it. The Mitsuba scene is built in
benchmarks/mitransient_reference.py (shared with the fidelity_mitransient benchmark).
mitransient's laser is a projector emitter in its own units, so energies are compared up to one global factor per spot
(the factor must be the same for every pixel), and time by each pixel's energy-weighted
mean bin (mitransient jitters samples over the pixel; the simulator takes stratified ones).
"""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.mitransient_reference import MitransientRenderer, missing
from torch_recon.contract import scenes
from torch_recon.contract.dataset import load_dataset

pytest.importorskip("bpy")
if missing():
    pytest.skip(missing(), allow_module_level=True)

from tests.support.sim_fixtures import simulate  # noqa: E402

RES, SPP = 64, 256


@pytest.mark.slow
@pytest.mark.parametrize("spot", [4, 9])
def test_matches_mitransient(tmp_path, spot):
    ex = scenes.cave_chair()
    target = ex.spot_targets[spot]
    simulate(tmp_path / "ds", "--example", "cave-chair", "--resolution", RES, "--photons", 0, "--no-gt",
             "--spot-list=" + ",".join(map(str, target)))
    ds = load_dataset(tmp_path / "ds")
    (_, tr), = ds.iter_transients()
    ours = tr.dense().astype(np.float64)
    ref = MitransientRenderer(ex.parts, ds.sensor, tmp_path / "mi").render(target, SPP)
    e, e_ref = ours.sum(-1), ref.sum(-1)
    e[np.unravel_index(np.argmax(e), e.shape)] = 0          # mitransient records no first bounce
    lit = (e > 1e-3 * np.median(e[e > 0])) & (e_ref > 0)
    assert ((e > 0) != (e_ref > 0)).mean() < 0.01           # the same pixels lit and in shadow
    ratio = e_ref[lit] / e[lit]
    lo, hi = np.percentile(ratio, [5, 95])
    assert hi / lo < 1.06                                    # one factor for all pixels (cosines, 1/r^2 agree)
    assert np.corrcoef(e.ravel(), e_ref.ravel())[0, 1] > 0.998
    bins = np.arange(ours.shape[-1]) + 0.5
    mean_bin = (ours * bins).sum(-1)[lit] / ours.sum(-1)[lit]
    mean_bin_ref = (ref * bins).sum(-1)[lit] / e_ref[lit]
    assert np.mean(np.abs(mean_bin - mean_bin_ref) < 0.5) >= 0.97
