"""The hidden-recall diagnostic: where a lit two-bounce segment can carve, and the face directions."""

from __future__ import annotations

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh")

from torch_recon.contract.synthetic import default_sensor  # noqa: E402
from torch_recon.evaluation.hidden_causes import face_direction, lit_segment_passes  # noqa: E402


def _quad(corners):
    return trimesh.Trimesh(np.asarray(corners, float), [[0, 1, 2], [0, 2, 3]], process=False)


def test_lit_segment_passes_only_where_light_lands_on_a_seen_surface():
    back = _quad([[-3, 3, -3], [3, 3, -3], [3, 3, 3], [-3, 3, 3]])         # the wall the sensor looks at
    side = _quad([[-2, -1, -3], [-2, 5, -3], [-2, 5, 3], [-2, -1, 3]])     # a side wall, seen at grazing angles
    gt = trimesh.util.concatenate([back, side])
    sensor = default_sensor()                                               # at the origin, looking along +y
    spot = np.array([-2.0, 2.0, 0.0])                                       # the laser spot on the side wall
    q = np.array([[-1.0, 2.5, 0.0],     # light passes here and lands on the back wall in view: carvable
                  [-1.0, 3.5, 0.0],     # behind the back wall: blocked before it
                  [-1.0, 1.0, 0.0],     # the light going on towards -y hits nothing
                  [-1.5, 2.0, 0.0]])    # lands on the back wall? no: towards +x along y = 2, nothing there
    assert lit_segment_passes(q, gt, [spot], sensor).tolist() == [True, False, False, False]


def test_face_direction_names_the_dominant_axis():
    n = np.array([[0.9, 0.1, 0.0], [-0.2, -0.9, 0.1], [0.1, 0.2, -0.95]])
    assert face_direction(n).tolist() == ["+x", "-y", "-z"]
