"""Laser spot choice (torch_recon/contract/spots.py): candidate directions in view, diversity heuristic."""

import math

import numpy as np
import pytest

from torch_recon.contract.spots import (coverage_radius, pixel_directions, random_candidate_pixels, random_spot_targets,
                                        select_diverse_spots)
from torch_recon.contract.dataset import SensorSpec
from torch_recon.contract.frames import look_at_c2w, project_points


def _directions(n, seed, s, margin=0.1):
    return pixel_directions(s, random_candidate_pixels(n, np.random.default_rng(seed), s.width, s.height, margin))


def test_candidate_directions_inside_field_of_view_and_seeded():
    c2w = look_at_c2w((0.3, -2.0, 1.0), (0.0, 2.0, 0.5))
    s = SensorSpec(width=64, height=48, fov_rad=math.radians(70), camera_to_world=c2w.tolist())
    d = _directions(500, 4, s)
    assert d.shape == (500, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    col, row, depth = project_points(c2w, 64, 48, s.fov_rad, c2w[:3, 3] + 3.0 * d)
    assert np.all(depth > 0)
    # pixel centres of the pixels at least int(0.1 * size) from the border
    assert np.all((col >= 6.5 - 1e-6) & (col <= 57.5 + 1e-6) & (row >= 4.5 - 1e-6) & (row <= 43.5 + 1e-6))
    np.testing.assert_allclose(col % 1.0, 0.5, atol=1e-6)
    assert col.std() > 10 and row.std() > 7                      # spread over the image, not clumped
    np.testing.assert_array_equal(d, _directions(500, 4, s))
    assert not np.array_equal(d, _directions(500, 5, s))
    with pytest.raises(ValueError, match="random_candidates"):
        random_candidate_pixels(-1, np.random.default_rng(0), 8, 8)


def _floor_and_post_cast(origin, direction):
    """Ray cast against the floor z = 0 and a thin post (|x| < 0.1, |y - 2| < 0.1, z < 3)."""
    o, d = np.asarray(origin, float), np.asarray(direction, float)
    best = None
    if d[2] < -1e-9:
        t = -o[2] / d[2]
        best = (t, o + t * d, np.array([0.0, 0.0, 1.0]))
    if abs(d[1]) > 1e-9:
        t = (1.9 - o[1]) / d[1]
        p = o + t * d
        if t > 1e-6 and abs(p[0]) < 0.1 and p[2] < 3 and (best is None or t < best[0]):
            best = (t, p, np.array([0.0, -1.0, 0.0]))
    return None if best is None else (best[1], best[2])


def test_random_spot_targets_seeded_and_reachable_by_the_laser():
    c2w = look_at_c2w((0.0, -2.0, 2.0), (0.0, 2.0, 0.0))
    s = SensorSpec(width=32, height=32, fov_rad=math.radians(60), camera_to_world=c2w.tolist(),
                   laser_origin=[1.5, -2.0, 2.0])
    pts, nrm, found = random_spot_targets(s, _floor_and_post_cast, 24, 6, seed=3)
    assert pts.shape == (6, 3) and nrm.shape == (6, 3) and found == 24
    again = random_spot_targets(s, _floor_and_post_cast, 24, 6, seed=3)
    np.testing.assert_array_equal(pts, again[0])
    assert not np.array_equal(pts, random_spot_targets(s, _floor_and_post_cast, 24, 6, seed=4)[0])
    for p in pts:   # the laser, aimed at each target, lands on it
        d = (p - s.laser_origin) / np.linalg.norm(p - s.laser_origin)
        np.testing.assert_allclose(_floor_and_post_cast(s.laser_origin, d)[0], p, atol=1e-6)
    none = random_spot_targets(s, lambda o, d: None, 4, 2, seed=0)
    assert none[0].shape == (0, 3) and none[2] == 0


def clusters(rng, centres, per=6, spread=0.05):
    return np.concatenate([c + rng.normal(0, spread, (per, 3)) for c in centres])


def test_one_spot_per_cluster():
    rng = np.random.default_rng(0)
    centres = np.array([[0, 0, 0], [3, 0, 0], [0, 3, 0], [0, 0, 3]], float)
    pts = clusters(rng, centres)
    for seed in range(10):
        idx = select_diverse_spots(pts, None, 4, np.random.default_rng(seed))
        assert sorted(i // 6 for i in idx) == [0, 1, 2, 3]


def test_normals_separate_spots_at_one_place():
    """Two places, three candidates each with repeated normals: 4 picks = both normals at both places."""
    pts = np.array([[0, 0, 0]] * 3 + [[1, 0, 0]] * 3, float)
    z, x = [0, 0, 1.0], [1.0, 0, 0]
    normals = np.array([z, z, x, z, x, x])
    for seed in range(6):
        idx = select_diverse_spots(pts, normals, 4, np.random.default_rng(seed))
        assert {(int(pts[i, 0]), int(normals[i, 0])) for i in idx} == {(0, 0), (0, 1), (1, 0), (1, 1)}


def test_selection_beats_random_and_is_seeded():
    rng = np.random.default_rng(2)
    pts = rng.uniform(-2, 2, (24, 3))
    idx = select_diverse_spots(pts, None, 16, np.random.default_rng(0))
    assert len(set(idx.tolist())) == 16
    np.testing.assert_array_equal(idx, select_diverse_spots(pts, None, 16, np.random.default_rng(0)))
    fps = coverage_radius(pts, idx[:8])
    random_radii = [coverage_radius(pts, rng.choice(24, 8, replace=False)) for _ in range(200)]
    assert fps <= np.percentile(random_radii, 10)                 # the first 8 already cover well


def test_misses_are_never_chosen_and_few_candidates():
    pts = np.array([[0, 0, 0], [np.nan] * 3, [1, 0, 0], [0, 5, 0], [np.nan] * 3], float)
    idx = select_diverse_spots(pts, None, 5, np.random.default_rng(0))
    assert sorted(idx.tolist()) == [0, 2, 3]
    dup = np.zeros((4, 3))
    assert sorted(select_diverse_spots(dup, None, 4, np.random.default_rng(0)).tolist()) == [0, 1, 2, 3]
    assert select_diverse_spots(np.full((2, 3), np.nan), None, 2, np.random.default_rng(0)).size == 0
    with pytest.raises(ValueError, match="candidates"):
        select_diverse_spots(np.zeros((3, 2)), None, 1, np.random.default_rng(0))
