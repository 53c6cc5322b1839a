"""GridAdam (issue 11's speed, session 17): torch.optim.Adam's arithmetic without its torch._dynamo import."""

from __future__ import annotations

import copy
import os
import subprocess
import sys
from pathlib import Path
from unittest import mock

import torch

from torch_recon.recon.adam import GridAdam

REPO = Path(__file__).resolve().parents[3]


def _same_state(a: dict, b: dict):
    assert a["param_groups"] == b["param_groups"]
    assert a["state"].keys() == b["state"].keys()
    for i in a["state"]:
        assert a["state"][i].keys() == b["state"][i].keys()
        for k in a["state"][i]:
            x, y = a["state"][i][k], b["state"][i][k]
            assert torch.equal(x, y) and x.dtype == y.dtype and x.shape == y.shape


def test_grid_adam_is_torch_adam_bit_for_bit():
    """Random gradients (some tiny, below eps), a halved learning rate (the trainer's restore) and state dicts
    handed across the two classes mid-run: the parameters and moments stay equal to the bit."""
    gen = torch.Generator().manual_seed(5)
    for shape, lr, eps in (((1, 1, 9, 7, 11), 0.05, 1e-3), ((1000,), 1e-2, 1e-8), ((7, 9), 0.3, 1e-15)):
        a = torch.randn(shape, generator=gen).requires_grad_()
        b = a.detach().clone().requires_grad_()
        ta, gb = torch.optim.Adam([a], lr=lr, eps=eps), GridAdam([b], lr=lr, eps=eps)
        for step in range(60):
            w = torch.randn(shape, generator=gen) * (1e-20 if step % 7 == 3 else 1.0)
            for p, opt in ((a, ta), (b, gb)):
                opt.zero_grad(set_to_none=True)
                ((p * p) * w).sum().backward()
                opt.step()
            assert torch.equal(a, b), (shape, step)
            if step == 30:
                for opt in (ta, gb):
                    for g in opt.param_groups:
                        g["lr"] *= 0.5
                sa, sb = copy.deepcopy(ta.state_dict()), copy.deepcopy(gb.state_dict())
                _same_state(sa, sb)
                ta = torch.optim.Adam([a], lr=1.0, eps=eps)
                ta.load_state_dict(sb)
                gb = GridAdam([b], lr=1.0, eps=eps)
                gb.load_state_dict(sa)
                _same_state(ta.state_dict(), gb.state_dict())
        _same_state(ta.state_dict(), gb.state_dict())


def test_fast_fit_trains_the_same_grid_as_torch_adam():
    from tests.support.recon_fixtures import box_floor_measurements
    from tests.torch_recon.recon.test_recon_fit import small_config
    from torch_recon.recon import fit

    meas = box_floor_measurements(32)
    ours = fit(meas, config=small_config(steps=6), export=False)
    with mock.patch("torch_recon.recon.models.GridAdam", torch.optim.Adam):
        theirs = fit(meas, config=small_config(steps=6), export=False)
    assert isinstance(ours.model.optimizer, GridAdam) and isinstance(theirs.model.optimizer, torch.optim.Adam)
    assert torch.equal(ours.model.grid.raw, theirs.model.grid.raw)


def test_fast_fit_does_not_import_dynamo():
    """torch.optim's Optimizer imports torch._dynamo on its first call (2-3 CPU-s); a fast fit needs none of it."""
    code = ("import sys\n"
            "from tests.support.recon_fixtures import box_floor_measurements\n"
            "from tests.torch_recon.recon.test_recon_fit import small_config\n"
            "from torch_recon.recon import fit\n"
            "fit(box_floor_measurements(24), config=small_config(steps=2), export=False)\n"
            "print('torch._dynamo' in sys.modules)\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "False"
