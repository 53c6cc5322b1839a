"""--bin-m (bin width in metres of optical path) against --bin-ps: one bin, either way."""

from __future__ import annotations

import pytest

from torch_recon.contract.simulation import ConfigError, SimulationConfig
from pipeline.simulate import load_config, parse_args
from torch_recon.contract.units import m_to_ps, ps_to_m

PAPER_BIN_M = 0.0384
PAPER_BIN_PS = 128.08861255609037      # what --bin-ps needed before --bin-m existed


def _cfg(*argv):
    return load_config(parse_args(["--out", "x", *argv]))


def test_bin_m_round_trips_with_bin_ps():
    by_m, by_ps = _cfg("--bin-m", str(PAPER_BIN_M)), _cfg("--bin-ps", repr(PAPER_BIN_PS))
    assert by_m.bin_m == PAPER_BIN_M and by_ps.bin_m is None
    assert by_m.bin_ps == pytest.approx(PAPER_BIN_PS, rel=1e-12)
    assert ps_to_m(by_ps.bin_ps) == pytest.approx(PAPER_BIN_M, rel=1e-12)
    assert m_to_ps(ps_to_m(by_m.bin_ps)) == pytest.approx(by_m.bin_ps, rel=1e-12)
    # through the settings file too
    again = SimulationConfig.from_json(by_m.to_json())
    assert again.bin_m == PAPER_BIN_M and again.bin_ps == pytest.approx(PAPER_BIN_PS, rel=1e-12)
    assert SimulationConfig.from_dict({"bin_m": PAPER_BIN_M}).bin_ps == pytest.approx(PAPER_BIN_PS, rel=1e-12)


def test_bin_m_and_bin_ps_are_exclusive(capsys):
    with pytest.raises(SystemExit) as exc:
        parse_args(["--out", "x", "--bin-m", "0.0384", "--bin-ps", "128"])
    assert exc.value.code == 2
    assert "--bin-ps" in capsys.readouterr().err
    with pytest.raises(ConfigError, match="bin_m"):
        SimulationConfig.from_dict({"bin_m": 0.05, "bin_ps": 128.0})
    with pytest.raises(ConfigError, match="bin_m"):
        _cfg("--bin-m", "-1")


def test_sensor_takes_the_metres_exactly():
    pytest.importorskip("bpy")
    import numpy as np

    from pipeline.simulator import sensor_spec

    s_m = sensor_spec(_cfg("--bin-m", "0.0384"), np.eye(4), 1.0, "x", [0, 0, 0])
    s_ps = sensor_spec(_cfg("--bin-ps", repr(PAPER_BIN_PS)), np.eye(4), 1.0, "x", [0, 0, 0])
    assert s_m.bin_width_m == PAPER_BIN_M
    assert s_ps.bin_width_m == pytest.approx(PAPER_BIN_M, rel=1e-12)
    assert s_m.bin_width_ps == pytest.approx(s_ps.bin_width_ps, rel=1e-12)
