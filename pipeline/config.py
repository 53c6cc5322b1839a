"""Transition alias: the simulation settings are defined once, in torch_recon.contract.simulation.

Kept so ``from pipeline.config import SimulationConfig`` (the add-on, older scripts) keeps working;
new code imports torch_recon.contract.simulation.
"""

from torch_recon.contract.simulation import (  # noqa: F401
    CONFIG_SCHEMA_VERSION,
    CONFIG_TEXT_NAME,
    ConfigError,
    SimulationConfig,
    SpotConfig,
)

__all__ = ["CONFIG_SCHEMA_VERSION", "CONFIG_TEXT_NAME", "ConfigError", "SimulationConfig", "SpotConfig"]
