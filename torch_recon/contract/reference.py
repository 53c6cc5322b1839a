"""The paper's reference numbers (PlatoNeRF, CVPR 2024): the only copy, read from data/platonerf_cave.json.

Everything here is in the paper's y-up frame exactly as the JSON states it; callers convert
with `frames.paper_to_blender_points`. The JSON is package data (shipped in the wheel and in
the add-on's vendored copy).
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

REFERENCE_FILE = Path(__file__).resolve().parent / "data" / "platonerf_cave.json"


@lru_cache(maxsize=1)
def cave() -> dict:
    """The parsed reference JSON (cached; treat as read-only)."""
    return json.loads(REFERENCE_FILE.read_text(encoding="utf-8"))


def laser_targets_24() -> np.ndarray:
    """(24, 3) laser targets of the paper, its y-up frame."""
    return np.asarray(cave()["laser_targets_24"], np.float64)


def used_16_indices() -> tuple[int, ...]:
    """Indices into `laser_targets_24` of the 16 spots the paper keeps."""
    return tuple(int(i) for i in cave()["laser_targets_used_16_indices"])


def _dolly_step_m(origin_formula: str) -> float:
    # the JSON states the dolly as "(0, -1.5, STEP*i), i=0..38"
    m = re.search(r"([0-9.]+)\*i", origin_formula)
    if m is None:
        raise ValueError(f"{REFERENCE_FILE.name}: test_views.dolly.origin: no 'STEP*i' in {origin_formula!r}")
    return float(m.group(1))


@dataclass(frozen=True)
class PaperTestViews:
    """The paper's ground-truth test views (dolly + orbit), in the paper's y-up frame.

    `PaperTestViews.from_reference()` gives the paper's: 39 dolly views from (0, -1.5, 0)
    towards the chair at (0, -1.5, 3), and 100 orbit views on a circle of radius 0.99 m around it.
    """

    dolly_count: int
    dolly_step_m: float
    orbit_count: int
    orbit_radius_m: float
    orbit_start_rad: float
    height_m: float
    centre_xz: tuple

    @classmethod
    def from_reference(cls) -> "PaperTestViews":
        tv = cave()["test_views"]
        d, o = tv["dolly"], tv["orbit"]
        return cls(dolly_count=int(d["count"]), dolly_step_m=_dolly_step_m(d["origin"]),
                   orbit_count=int(o["count"]), orbit_radius_m=float(o["radius"]),
                   orbit_start_rad=float(o["start_angle_rad"]), height_m=float(o["y"]),
                   centre_xz=tuple(float(v) for v in o["center_xz"]))


def test_view_fov_rad() -> float:
    return math.radians(float(cave()["test_views"]["fov_deg"]))
