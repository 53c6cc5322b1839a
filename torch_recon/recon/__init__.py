"""The reconstructor: PlatoNeRF's losses on a fast explicit grid (`fast`) or the published NeRF (`platonerf`).

Pieces (nerfstudio-like): config (dataclasses), data (measurements -> rays), fields (grid, MLP),
sampler, renderer, losses, init (fast-mode start from visible depth + shadow carving), models,
trainer (loop, checkpoints, NaN recovery, early stop), api (`fit`).
"""

from .api import FitResult, fit
from .config import FitConfig, override
from .data import UnconstrainedMeasurementsError

__all__ = ["fit", "FitResult", "FitConfig", "override", "UnconstrainedMeasurementsError"]
