"""3 x 3 neighbourhood operations on (H, W) images, in numpy.

Why not scipy.ndimage: the simulator needs only these three, and `import scipy.ndimage` costs ~0.1 CPU-s
of a 128 x 128 run beyond the scipy.special it imports anyway. Each returns exactly what its
scipy.ndimage counterpart returns for these arguments (tests/pipeline/test_sim_neighbourhood.py).
"""
from __future__ import annotations

import numpy as np


def _shifts(padded: np.ndarray, h: int, w: int, structure: np.ndarray):
    """The (H, W) views of a 1-padded image shifted to each True offset of a 3 x 3 structure."""
    for dy in range(3):
        for dx in range(3):
            if structure[dy, dx]:
                yield padded[dy:dy + h, dx:dx + w]


def binary_dilation(mask: np.ndarray, structure: np.ndarray) -> np.ndarray:
    """scipy.ndimage.binary_dilation(mask, structure) for a symmetric 3 x 3 structure (outside is False)."""
    mask = np.asarray(mask, bool)
    h, w = mask.shape
    padded = np.pad(mask, 1, constant_values=False)
    out = np.zeros_like(mask)
    for view in _shifts(padded, h, w, np.asarray(structure, bool)):
        out |= view
    return out


def maximum_filter3(image: np.ndarray) -> np.ndarray:
    """scipy.ndimage.maximum_filter(image, size=3): the 3 x 3 maximum, the border repeated ('reflect')."""
    return _extreme3(image, np.maximum)


def minimum_filter3(image: np.ndarray) -> np.ndarray:
    """scipy.ndimage.minimum_filter(image, size=3)."""
    return _extreme3(image, np.minimum)


def _extreme3(image, op):
    image = np.asarray(image)
    h, w = image.shape
    padded = np.pad(image, 1, mode="edge")     # 'reflect' repeats the edge sample: for a 3-wide window, the same
    rows = op(op(padded[0:h], padded[1:h + 1]), padded[2:h + 2])
    return op(op(rows[:, 0:w], rows[:, 1:w + 1]), rows[:, 2:w + 2])
