"""The reconstructor: PlatoNeRF's losses on a fast explicit grid (`fast`) or the published NeRF (`platonerf`).

Pieces (nerfstudio-like): config (dataclasses), data (measurements -> rays), fields (grid, MLP),
sampler, renderer, losses, init (fast-mode start from visible depth + shadow carving), models,
trainer (loop, checkpoints, NaN recovery, early stop), api (`fit`).
"""

from ..contract.errors import UnconstrainedMeasurementsError
from .config import FitConfig, override    # torch-free: the command line builds its options from FitConfig


def __getattr__(name):
    # torch is imported only when a fit is asked for, not to print --help or parse settings
    if name in ("fit", "FitResult"):
        from . import api
        return getattr(api, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["fit", "FitResult", "FitConfig", "override", "UnconstrainedMeasurementsError"]
