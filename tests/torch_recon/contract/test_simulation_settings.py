"""The simulation settings are defined once, in the contract layer; pipeline.config only re-exports them."""

from __future__ import annotations

import re
from pathlib import Path

from torch_recon.contract import simulation

REPO = Path(__file__).resolve().parents[3]


def test_one_definition_of_the_simulation_settings():
    where = []
    for path in REPO.rglob("*.py"):
        rel = path.relative_to(REPO)
        if rel.parts[0] in (".venv", "build", "dist") or "_vendor" in rel.parts:
            continue
        text = path.read_text(encoding="utf-8", errors="replace")
        for cls in ("SimulationConfig", "SpotConfig"):
            if re.search(rf"^class {cls}\b", text, re.M):
                where.append((cls, rel.as_posix()))
    assert sorted(where) == [("SimulationConfig", "torch_recon/contract/simulation.py"),
                             ("SpotConfig", "torch_recon/contract/simulation.py")]


def test_pipeline_config_is_the_same_class():
    from pipeline import config

    assert config.SimulationConfig is simulation.SimulationConfig
    assert config.ConfigError is simulation.ConfigError and config.CONFIG_TEXT_NAME == simulation.CONFIG_TEXT_NAME


def test_settings_round_trip_and_checked_values():
    cfg = simulation.SimulationConfig(width=64, height=32, spots=[simulation.SpotConfig(target=[1, 2, 3])])
    again = simulation.SimulationConfig.from_json(cfg.to_json())
    assert again.to_dict() == cfg.to_dict()
    try:
        simulation.SimulationConfig.from_dict({"width": "wide"}, "x.json")
    except simulation.ConfigError as exc:
        assert "width" in str(exc) and "x.json" in str(exc)
    else:
        raise AssertionError("a bad width was accepted")
