"""Per-spot transients in memory: a window of bins per pixel.

A transient cube (H, W, T) is stored as `start_bin` (H, W) and `window` (H, W, G):
pixel (i, j) holds bins start_bin[i, j] .. start_bin[i, j] + G - 1. The dense
layout is the special case G == T, start 0, so one code path serves both.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Transient:
    start_bin: np.ndarray  # (H, W) int64
    window: np.ndarray     # (H, W, G) float32 photon counts (or expected counts)
    bins: int              # T, the full histogram length

    def __post_init__(self):
        self.start_bin = np.asarray(self.start_bin, dtype=np.int64)
        if self.window.ndim != 3 or self.start_bin.shape != self.window.shape[:2]:
            raise ValueError(f"window {self.window.shape} and start_bin {self.start_bin.shape} disagree")
        if self.window_bins > self.bins:
            raise ValueError(f"window of {self.window_bins} bins exceeds {self.bins} bins")
        if self.start_bin.size and (self.start_bin.min() < 0 or self.start_bin.max() + self.window_bins > self.bins):
            raise ValueError("start_bin places part of a window outside [0, bins)")

    @property
    def shape(self) -> tuple:
        return self.window.shape[:2]

    @property
    def window_bins(self) -> int:
        return self.window.shape[2]

    @property
    def is_dense(self) -> bool:
        return self.window_bins == self.bins and not np.any(self.start_bin)

    def dense(self, dtype=np.float32) -> np.ndarray:
        """The full (H, W, T) histogram (zeros outside each pixel's window)."""
        h, w, g = self.window.shape
        if self.is_dense:
            return self.window.astype(dtype, copy=False)
        out = np.zeros((h, w, self.bins), dtype=dtype)
        idx = self.start_bin[..., None] + np.arange(g)
        np.put_along_axis(out, idx, self.window.astype(dtype, copy=False), axis=2)
        return out

    @classmethod
    def from_dense(cls, cube: np.ndarray, window_bins: int | None = None,
                   start_bin: np.ndarray | None = None) -> "Transient":
        """Window a dense cube. Without `start_bin`, each pixel keeps the
        `window_bins` consecutive bins holding the most counts (ties: earliest)."""
        cube = np.asarray(cube)
        h, w, t = cube.shape
        g = t if window_bins is None else int(window_bins)
        if not 1 <= g <= t:
            raise ValueError(f"window_bins must be in [1, {t}], got {g}")
        if g == t:
            return cls(np.zeros((h, w), np.int64), cube.astype(np.float32, copy=False), t)
        if start_bin is None:
            csum = np.concatenate([np.zeros((h, w, 1)), np.cumsum(cube, axis=2, dtype=np.float64)], axis=2)
            start_bin = np.argmax(csum[..., g:] - csum[..., :-g], axis=2)
        start_bin = np.clip(np.asarray(start_bin, np.int64), 0, t - g)
        idx = start_bin[..., None] + np.arange(g)
        return cls(start_bin, np.take_along_axis(cube, idx, axis=2).astype(np.float32), t)
