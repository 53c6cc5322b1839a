"""Scene-aware test views (torch_recon.contract.test_views): never a camera inside geometry.

Property test over random box rooms with random boxes (a seeded numpy loop: hypothesis is not installed).
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from torch_recon.contract import scenes
from torch_recon.contract.frames import look_at_c2w
from torch_recon.contract.test_views import (SceneViewSettings, check_test_views, free_space,
                                             scene_test_view_cameras)
from torch_recon.contract.frames import paper_test_view_cameras


def _box(lo, hi):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return trimesh.creation.box(extents=hi - lo, transform=trimesh.transformations.translation_matrix((lo + hi) / 2))


def _random_scene(rng):
    """A closed box room (walls as 2 cm slabs outside the interior) with 1-4 random boxes on its floor."""
    size = rng.uniform((2.0, 2.0, 2.0), (6.0, 6.0, 3.5))
    t = 0.02
    walls = [_box((-t, -t, -t), (size[0] + t, size[1] + t, 0)), _box((-t, -t, size[2]), (size[0] + t, size[1] + t, size[2] + t)),
             _box((-t, -t, 0), (0, size[1] + t, size[2])), _box((size[0], -t, 0), (size[0] + t, size[1] + t, size[2])),
             _box((0, -t, 0), (size[0], 0, size[2])), _box((0, size[1], 0), (size[0], size[1] + t, size[2]))]
    boxes = []
    for _ in range(rng.integers(1, 5)):
        ext = rng.uniform((0.1, 0.1, 0.1), np.minimum(size * (0.6, 0.6, 0.9), 2.0))
        lo = np.append(rng.uniform((0, 0), size[:2] - ext[:2]), 0.0)
        boxes.append((lo, lo + ext))
    objs = [_box(lo, hi) for lo, hi in boxes]
    room = trimesh.util.concatenate(walls)
    gt = trimesh.util.concatenate(walls + objs)
    sensor = look_at_c2w((size[0] / 2, 0.2, size[2] / 2), (size[0] / 2, size[1], size[2] / 2))
    return gt, room, objs, boxes, size, sensor


def test_random_rooms_never_put_a_camera_inside_geometry():
    rng = np.random.default_rng(11)
    s = SceneViewSettings(dolly=4, orbit=12, clearance_m=0.05)
    dropped = kept = 0
    for _ in range(12):
        gt, room, objs, boxes, size, sensor = _random_scene(rng)
        cams, rep = scene_test_view_cameras(gt, objs, sensor, s, room_mesh=room, warn=False)
        assert rep["n_valid"] + rep["n_invalid"] == rep["n_requested"] == 16 and len(cams) == rep["n_valid"]
        dropped += rep["n_invalid"]
        kept += len(cams)
        for c in cams:
            o = c[:3, 3]
            assert np.all(o > 0.0) and np.all(o < size), f"camera {o} outside the room {size}"
            for lo, hi in boxes:
                assert not np.all((o > lo - 0.04) & (o < hi + 0.04)), f"camera {o} inside box {lo}-{hi}"
    assert kept > 50 and dropped > 0        # the check was exercised both ways


def test_free_space_reasons():
    gt, room, objs, boxes, size, sensor = _random_scene(np.random.default_rng(1))
    lo, hi = boxes[0]
    inside = 0.5 * (lo + hi)
    ok, why = free_space(gt, [inside, size + 1.0, np.array([0.01, size[1] / 2, size[2] / 2])], 0.05)
    assert not ok.any()
    assert "inside geometry" in why[0] and "bounding box" in why[1] and "from a surface" in why[2]


def test_paper_preset_valid_in_paper_room_and_dropped_behind_a_curved_wall():
    cams = paper_test_view_cameras()
    mesh, _ = scenes.cave_chair().trimesh()
    valid, rep = check_test_views(mesh, cams, warn=False)
    assert valid.all() and rep["n_valid"] == 139
    # a concave back wall reaching only y = 3.7: the paper's orbit (to y = 3.99) passes behind it
    wall = scenes.curved_wall(radius=2.2, centre_y=1.5)
    parts = scenes.room_walls(back_wall=False) + [wall] + scenes.chair()
    curved = trimesh.util.concatenate([trimesh.Trimesh(p.vertices, p.faces, process=False) for p in parts])
    with pytest.warns(UserWarning, match="not in free space"):
        valid, rep = check_test_views(curved, cams)
    assert 5 < rep["n_invalid"] < 60
    for c, ok in zip(cams, valid):                   # kept exactly the cameras in front of the wall
        x, y = c[0, 3], c[1, 3]
        assert ok == (y < 1.5 + np.sqrt(max(2.2 ** 2 - x ** 2, 0.0)) - 0.005)
