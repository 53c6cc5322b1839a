"""Laser spot choice, shared by the add-on and the simulator: random candidates and a diversity heuristic.

Numpy only; the ray casts come in as a callable (Blender's scene.ray_cast in pipeline.blender_scene).

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


def random_candidate_pixels(n: int, rng: np.random.Generator, width: int, height: int,
                            margin: float = 0.05) -> np.ndarray:
    """(n, 2) random pixel centres (col, row), pixels within `margin` of the image border skipped.

    Pixel centres (not any image point): the pixel that holds the spot then sees the spot itself,
    so its first-bounce return is recorded even next to a depth edge.
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise ValueError(f"random_candidates: expected an integer >= 0, got {n!r}")
    if not 0.0 <= margin < 0.5:
        raise ValueError(f"margin: expected a fraction in [0, 0.5), got {margin!r}")
    c0, r0 = int(margin * width), int(margin * height)
    cols = rng.integers(c0, max(c0 + 1, width - c0), n)
    rows = rng.integers(r0, max(r0 + 1, height - r0), n)
    return np.stack([cols + 0.5, rows + 0.5], axis=1)


def pixel_directions(sensor, pixels) -> np.ndarray:
    """World unit directions (N, 3) from the sensor centre through image points (col, row) in pixels."""
    px = np.asarray(pixels, np.float64).reshape(-1, 2)
    w, h = sensor.width, sensor.height
    f = focal_length_px(w, h, sensor.fov_rad, sensor.fov_axis)
    d_cam = np.stack([(px[:, 0] - 0.5 * w) / f, -(px[:, 1] - 0.5 * h) / f, -np.ones(len(px))], axis=1)  # OpenGL
    d_cam /= np.linalg.norm(d_cam, axis=1, keepdims=True)
    return d_cam @ np.asarray(sensor.camera_to_world, np.float64)[:3, :3].T


def random_spot_targets(sensor, cast, n_candidates: int, keep: int, seed: int, margin: float = 0.05,
                        max_tries_per_spot: int = 20):
    """The one random-spot recipe: the add-on's "Generate Spots" and the simulator's random spots.

    `cast(origin, direction)` returns the first surface (point (3,), normal (3,)) along a ray, or
    None; it skips the laser's own object. Candidates are surface points seen through random pixel
    centres that the laser, aimed at them from `sensor.laser_origin`, really lands on (nothing in
    between); then `keep` spread-out ones are chosen (`select_diverse_spots`) with the same seeded
    rng. Returns (points (k, 3), normals (k, 3), n_found) in selection order.
    """
    rng = np.random.default_rng(seed)
    c2w = np.asarray(sensor.camera_to_world, np.float64)
    cam, laser = c2w[:3, 3], np.asarray(sensor.laser_origin, np.float64)
    points, normals = [], []
    for _ in range(max(1, int(n_candidates)) * max_tries_per_spot):
        if len(points) >= n_candidates:
            break
        d = pixel_directions(sensor, random_candidate_pixels(1, rng, sensor.width, sensor.height, margin))[0]
        hit = cast(cam, d)
        if hit is None:
            continue
        p, normal = np.asarray(hit[0], np.float64), np.asarray(hit[1], np.float64)
        to_p = p - laser
        if np.linalg.norm(to_p) < 1e-9:
            continue
        q = cast(laser, to_p / np.linalg.norm(to_p))
        # the laser must land where the camera looks (not on an occluder in between)
        if q is not None and np.linalg.norm(np.asarray(q[0]) - p) <= 1e-3 * np.linalg.norm(p - cam) + 1e-4:
            points.append(np.asarray(q[0], np.float64))
            normals.append(normal)
    if not points:
        return np.zeros((0, 3)), np.zeros((0, 3)), 0
    pts, nrm = np.array(points), np.array(normals)
    idx = select_diverse_spots(pts, nrm, keep, rng)
    return pts[idx], nrm[idx], len(points)


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
