"""Where a voxel lies against what its own pixels measured (`behind_pixels.py`, session 18): the hidden hull behind
a seen surface keeps its occupied start where the nearest measured point's plane (another face's: a seat's top at its
backrest's foot) puts it in front (`fast.surface_hidden_hull_voxels`: cave-chair's two dents at the backrest's lower
edge); a restored shadow blocker the sensor saw through is dropped (`fast.seen_through_voxels`: the columns beside
cave-chair's front legs)."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from tests.support.recon_fixtures import POST_SENSOR, wall_pixel_rays  # noqa: E402
from torch_recon.recon.data import RayData  # noqa: E402
from torch_recon.recon.fields import GridBox  # noqa: E402

N_PIX = 16


def _wall_seen():
    """Pixels seeing the wall y = 1 (x, z in [0, 1]) from POST_SENSOR: no spots needed for the ramp's test."""
    _, _, _, dirs, depth = wall_pixel_rays(N_PIX)
    f = lambda a, dt=torch.float32: torch.as_tensor(np.asarray(a), dtype=dt)  # noqa: E731
    c = POST_SENSOR
    empty = torch.zeros(0, dtype=torch.long)
    return RayData(sensor_origin=f(c), laser_origin=f(c), pixel_dirs=f(dirs), spot_points=f(np.zeros((1, 3))),
                   laser_to_spot=f([1.0]), pair_pixel=empty, pair_spot=empty, path=f(np.zeros(0)),
                   lit=torch.zeros(0, dtype=torch.bool), shadowed=torch.zeros(0, dtype=torch.bool),
                   visible_depth=f(depth), height=N_PIX, width=N_PIX)


def test_how_far_a_point_lies_behind_what_its_pixels_saw():
    from torch_recon.recon.behind_pixels import behind_pixels

    data = _wall_seen()
    c = POST_SENSOR
    on = np.array([0.5, 1.0, 0.5])
    u = (on - c) / np.linalg.norm(on - c)
    pts = torch.as_tensor(np.stack([on + 0.05 * u, on - 0.05 * u, c + np.array([0.0, -1.0, 0.0])]), dtype=torch.float32)
    behind = behind_pixels(data, pts).numpy()
    assert 0.04 < behind[0] < 0.06                      # 5 cm behind the wall along its ray
    assert -0.06 < behind[1] < -0.04                    # in front of it
    assert np.isnan(behind[2])                          # behind the sensor: no pixel looks there


def test_hull_behind_a_seen_surface_keeps_its_start_where_another_faces_plane_says_in_front():
    """sd < 0 (a junction point's plane puts the voxel in front) on hull voxels: one 1.2 voxels behind the wall its
    pixels saw keeps the hull (the old start took the ramp there: a hole at the surface level); one in front of the
    wall, one far behind it (a wall's plane behind an object is believed) and a lit-carved one are left to the ramp."""
    from torch_recon.recon.init import _ramp_in_front_of_hidden

    data = _wall_seen()
    box = GridBox([0.0, 0.5, 0.0], [1.0, 1.5, 1.0], 25)           # 4 cm voxels; the wall at y = 1
    centres = box.centres()
    sd = torch.full(box.shape, float("nan"))
    label = torch.zeros(box.shape, dtype=torch.int8)
    i, k = 12, 12                                                   # the image's middle
    y = centres[0, :, 0, 1]
    behind_1 = int(torch.argmin((y - 1.05).abs()))                 # ~1.2 voxels behind the wall
    in_front = int(torch.argmin((y - 0.95).abs()))
    far = int(torch.argmin((y - 1.45).abs()))                      # 11 voxels behind
    carved = behind_1 + 1
    for j in (behind_1, in_front, far, carved):
        sd[i, j, k] = -0.01
    label[i, carved, k] = 3
    kept = _ramp_in_front_of_hidden(data, box, sd, label, margin_m=0.5 * box.voxel, reach_m=3.0 * box.voxel)
    assert bool(kept[i, behind_1, k])
    assert not bool(kept[i, in_front, k]) and not bool(kept[i, far, k]) and not bool(kept[i, carved, k])
    assert int(kept.sum()) == 1


def test_a_point_the_pixels_saw_through_unless_a_thin_parts_earliest_return_lies_before_it():
    from torch_recon.recon.behind_pixels import seen_through

    data = _wall_seen()
    c = POST_SENSOR
    on = np.array([0.5, 1.0, 0.5])
    u = (on - c) / np.linalg.norm(on - c)
    pts = torch.as_tensor(np.stack([on - 0.1 * u, on - 0.01 * u, on + 0.05 * u]), dtype=torch.float32)
    assert seen_through(data, pts, 0.02).tolist() == [True, False, False]
    # a post under a pixel wide 20 cm before the wall: its earliest return in every pixel; nothing seen through
    data.nearest_depth = data.visible_depth - 0.2
    assert seen_through(data, pts, 0.02).tolist() == [False, False, False]
    assert seen_through(data, pts, 0.02, nearest_free=False).tolist() == [True, False, False]


def test_a_lit_carved_voxel_the_pixels_saw_through_keeps_the_carving_where_a_plane_would_fill_it():
    """sd > 0 (the nearest measured point's plane puts the voxel behind the surface) on lit-carved voxels: one 2.5
    voxels in front of the wall its pixels saw (a plane extended past a silhouette, dark-room's backrest fins, session
    21) keeps its carving; one on the wall, a hull voxel in front of it and a lit-carved voxel the plane puts in front
    (sd < 0) are left to the ramp."""
    from torch_recon.recon.init import _lit_ramp_seen_through

    data = _wall_seen()
    box = GridBox([0.0, 0.5, 0.0], [1.0, 1.5, 1.0], 25)           # 4 cm voxels; the wall at y = 1
    y = box.centres()[0, :, 0, 1]
    sd = torch.full(box.shape, float("nan"))
    label = torch.full(box.shape, 3, dtype=torch.int8)
    i, k = 12, 12
    in_front = int(torch.argmin((y - 0.90).abs()))                 # 2.5 voxels in front of the wall
    on_wall = int(torch.argmin((y - 1.0).abs()))
    hull, before_plane = in_front - 1, in_front - 2
    for j, d in ((in_front, 0.01), (on_wall, 0.01), (hull, 0.01), (before_plane, -0.01)):
        sd[i, j, k] = d
    label[i, hull, k] = 0
    for nearest in (True, False):
        kept = _lit_ramp_seen_through(data, box, sd, label, 0.5 * box.voxel, nearest)
        assert bool(kept[i, in_front, k]) and int(kept.sum()) == 1


@pytest.mark.parametrize("key", ["surface_hidden_hull_voxels", "seen_through_voxels", "surface_seen_through_voxels"])
def test_pixel_depth_margins_are_range_checked(key):
    from torch_recon.contract.errors import SettingsError
    from torch_recon.recon.config import FitConfig, override

    with pytest.raises(SettingsError, match=rf"fast\.{key}"):
        override(FitConfig(), [f"fast.{key}=-1"])
