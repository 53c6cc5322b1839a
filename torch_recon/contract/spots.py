"""Laser spot choice: random candidate directions and a diversity heuristic (numpy only).

The paper illuminates 24 random scene points and keeps 16 "that maximise diversity".
Its heuristic is not published; this one is greedy farthest-point sampling:

- distance between candidates i, j:  d_ij^2 = |p_i - p_j|^2 + (lambda * extent)^2 * |n_i - n_j|^2 / 4,
  with extent the diagonal of the candidates' bounding box and lambda = NORMAL_WEIGHT. Spots far
  apart cast shadows of the object in different directions; different surface normals (floor
  vs wall) add spots that see the scene from another side even when close together.
- the first spot is drawn with the rng, each next one is the candidate farthest (in the
  min-distance sense) from all chosen so far; ties break to the lowest index.
- the order is the selection order, so the first k of the K chosen are themselves a spread-out
  subset (useful for the 2 / 4 / 8 / 16-spot ablation).
"""

from __future__ import annotations

import math

import numpy as np

from .frames import focal_length_px

#: weight of the normal term relative to the scene extent (see the module docstring)
NORMAL_WEIGHT = 0.5


def random_candidate_directions(n: int, rng: np.random.Generator, sensor, margin: float = 0.05) -> np.ndarray:
    """n unit laser directions (n, 3) in the world frame, aimed inside the sensor's field of view.

    Image-plane points are drawn uniformly over the image shrunk by `margin` (fraction of the
    width / height on each side), so each candidate lands on a pixel the sensor sees. The
    directions leave the sensor centre through those points: exact for a laser co-located with
    the sensor (the paper's set-up); for an offset laser they aim at the same image points at
    infinity.
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise ValueError(f"random_candidates: expected an integer >= 0, got {n!r}")
    if not 0.0 <= margin < 0.5:
        raise ValueError(f"margin: expected a fraction in [0, 0.5), got {margin!r}")
    w, h = sensor.width, sensor.height
    f = focal_length_px(w, h, sensor.fov_rad, sensor.fov_axis)
    cols = rng.uniform(margin * w, (1.0 - margin) * w, n)
    rows = rng.uniform(margin * h, (1.0 - margin) * h, n)
    d_cam = np.stack([(cols - 0.5 * w) / f, -(rows - 0.5 * h) / f, -np.ones(n)], axis=1)  # OpenGL: -Z forward
    d_cam /= np.linalg.norm(d_cam, axis=1, keepdims=True)
    c2w = np.asarray(sensor.camera_to_world, np.float64)
    return d_cam @ c2w[:3, :3].T


def select_diverse_spots(candidates, normals, keep: int, rng: np.random.Generator) -> np.ndarray:
    """Indices (<= keep,) into `candidates` (N, 3) of spread-out first-bounce points, selection order.

    normals (N, 3) or None. Candidates with a non-finite point (the laser hit nothing) are never
    chosen; fewer than `keep` indices come back when fewer valid candidates exist (callers warn).
    """
    pts = np.asarray(candidates, np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"candidates: expected (N, 3) first-bounce points, got shape {pts.shape}")
    if isinstance(keep, bool) or not isinstance(keep, (int, np.integer)) or keep < 0:
        raise ValueError(f"random_keep: expected an integer >= 0, got {keep!r}")
    ok = np.all(np.isfinite(pts), axis=1)
    feats = pts
    if normals is not None:
        nrm = np.asarray(normals, np.float64)
        if nrm.shape != pts.shape:
            raise ValueError(f"normals: expected shape {pts.shape}, got {nrm.shape}")
        ok &= np.all(np.isfinite(nrm), axis=1)
        length = np.linalg.norm(np.where(ok[:, None], nrm, 0.0), axis=1)
        ok &= length > 1e-12
        unit = np.zeros_like(nrm)
        unit[ok] = nrm[ok] / length[ok, None]
        valid_pts = pts[ok]
        extent = float(np.linalg.norm(valid_pts.max(0) - valid_pts.min(0))) if len(valid_pts) else 0.0
        # |n_i - n_j| is at most 2: the normal term adds up to NORMAL_WEIGHT * extent
        feats = np.concatenate([pts, (NORMAL_WEIGHT * extent / 2.0) * unit], axis=1)
    valid = np.flatnonzero(ok)
    k = min(int(keep), len(valid))
    if k == 0:
        return np.zeros(0, np.int64)
    f = feats[valid]
    chosen = [int(rng.integers(len(valid)))]
    dist = np.sum((f - f[chosen[0]]) ** 2, axis=1)
    dist[chosen[0]] = -1.0                      # never again, even among duplicates
    for _ in range(k - 1):
        nxt = int(np.argmax(dist))  # first maximum: lowest index on ties
        chosen.append(nxt)
        dist = np.minimum(dist, np.sum((f - f[nxt]) ** 2, axis=1))
        dist[nxt] = -1.0
    return valid[np.asarray(chosen, np.int64)]


def coverage_radius(points, chosen) -> float:
    """Largest distance from any valid candidate to its nearest chosen one (lower = better spread)."""
    pts = np.asarray(points, np.float64)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    sel = np.asarray(points, np.float64)[np.asarray(chosen, np.int64)]
    if len(sel) == 0 or len(pts) == 0:
        return math.inf if len(pts) else 0.0
    d = np.linalg.norm(pts[:, None, :] - sel[None, :, :], axis=2)
    return float(d.min(axis=1).max())
