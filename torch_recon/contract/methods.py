"""The one table of reconstruction methods; a method's name is looked up here and nowhere else.

`fit` trains a density field (fast, platonerf) through the `FieldModel` interface; `baseline` runs
the closed-form Bounce Flash Lidar carving. The CLI's choices, the fit settings' `mode`, the
settings section each method reads, and the add-on's Mode menu all come from `METHODS`.
Implementations are named by import path so this module imports neither torch nor bpy.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from .errors import SettingsError


@dataclass(frozen=True)
class Method:
    name: str
    label: str          # shown in the add-on
    description: str
    command: str        # the CLI subcommand that runs it: 'fit' or 'baseline'
    section: str        # its settings section (FitConfig.fast, FitConfig.platonerf, BaselineSettings.bflidar)
    model: str = ""     # 'module:callable(data, cfg, meas_meta, generator) -> FieldModel' for fit methods
    grid_setting: str = ""  # the setting holding its grid resolution (voxels along the longest side)
    mends_mesh_gaps: bool = False  # its export closes the holes mesh_gaps.py explains (the fast field's; session 19):
                                   # others' meshes stay plain marching cubes, the published method as it was


METHODS = {m.name: m for m in (
    Method("fast", "Fast", "Grid field fit (default, CPU friendly)", "fit", "fast",
           "torch_recon.recon.models:build_fast", "fast.resolution", mends_mesh_gaps=True),
    Method("platonerf", "PlatoNeRF", "The published NeRF method (slow reference)", "fit", "platonerf",
           "torch_recon.recon.models:build_platonerf", "platonerf.volume_resolution"),
    Method("bflidar", "BF Lidar", "Bounce Flash Lidar baseline: visible depth + shadow carving", "baseline",
           "bflidar", grid_setting="bflidar.voxels"),
)}
FIT_METHODS = tuple(n for n, m in METHODS.items() if m.command == "fit")
DEFAULT_FIT_METHOD = FIT_METHODS[0]


def method(name: str) -> Method:
    if name not in METHODS:
        raise SettingsError("mode", f"expected one of {', '.join(METHODS)}, got {name!r}")
    return METHODS[name]


def load(entry: str):
    """The object an entry 'package.module:Name.attr' names (imported on first use)."""
    mod, _, attr = entry.partition(":")
    obj = importlib.import_module(mod)
    for part in attr.split("."):
        obj = getattr(obj, part)
    return obj


@runtime_checkable
class FieldModel(Protocol):
    """What the trainer and the exporters need of a fit method's model (torch tensors in and out)."""

    device: object
    optimizer: object

    def before_step(self, step: int, total: int) -> bool: ...
    def loss(self, idx, step: int, total: int, gen): ...
    def params_finite(self) -> bool: ...
    def state_dict(self) -> dict: ...
    def load_state_dict(self, st: dict) -> None: ...
    def density(self, pts): ...
    def density_volume(self): ...
    def render_depth(self, origins, dirs, chunk: int = ..., min_opacity=None): ...
