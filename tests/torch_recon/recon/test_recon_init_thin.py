"""A post thinner than a pixel, seen past by the sensor and grazed by lit rays, survives the fast start
because the shadows it casts from several spots cross it (recon/voxel_evidence.py `explain_shadows`)."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from tests.support.recon_fixtures import POST_SENSOR, wall_pixel_rays  # noqa: E402
from torch_recon.recon.data import RayData  # noqa: E402
from torch_recon.recon.fields import GridBox  # noqa: E402
from torch_recon.recon.hull_trim import unneeded_hull  # noqa: E402
from torch_recon.recon.voxel_evidence import NEAREST, RESTORED, evidence_grid  # noqa: E402
from torch_recon.recon.fields import dilate_cube  # noqa: E402

POST_XY, POST_R, POST_TOP = np.array([0.55, 0.45]), 0.02, 0.6


def _post_scene(n_pix=24, seen_top=False, post_r=POST_R):
    """Sensor 2 m above a 1 x 1 m floor looking down; a vertical post (radius `post_r`, 60 cm tall) the depth
    image does not see (`seen_top`: the pixels whose ray meets the post's top see it there); 6 spots above the
    floor round it; a pair is shadowed when its segment hits the post."""
    c = np.array([0.5, 0.5, 2.0])
    u = (np.arange(n_pix) + 0.5) / n_pix
    floor = np.stack(np.meshgrid(u, u, indexing="ij"), -1).reshape(-1, 2)
    x = np.concatenate([floor, np.zeros((len(floor), 1))], 1)
    dirs = x - c
    depth = np.linalg.norm(dirs, axis=1)
    dirs /= depth[:, None]
    if seen_top:
        t_top = (POST_TOP - c[2]) / dirs[:, 2]
        top = c + dirs * t_top[:, None]
        on_top = np.linalg.norm(top[:, :2] - POST_XY, axis=1) < post_r
        x[on_top], depth[on_top] = top[on_top], t_top[on_top]
    ang = np.linspace(0, 2 * np.pi, 6, endpoint=False)
    spots = np.stack([0.5 + 0.4 * np.cos(ang), 0.5 + 0.4 * np.sin(ang), np.zeros(6)], 1)
    t = np.linspace(0, 1, 400)
    spots[:, 2] = 0.9             # above the floor: a segment to a floor spot would graze the floor
    pix = np.tile(np.arange(len(x)), len(spots))
    spt = np.repeat(np.arange(len(spots)), len(x))
    shd = []
    for k, l in enumerate(spots):
        seg = x[:, None] + (l - x)[:, None] * t[None, :, None]
        shd.append(((np.linalg.norm(seg[..., :2] - POST_XY, axis=-1) < post_r) & (seg[..., 2] < POST_TOP - 1e-6)).any(1))
    shd = np.concatenate(shd)
    f = lambda a, dt=torch.float32: torch.as_tensor(np.asarray(a), dtype=dt)  # noqa: E731
    return RayData(sensor_origin=f(c), laser_origin=f(c), pixel_dirs=f(dirs), spot_points=f(spots),
                   laser_to_spot=f(np.linalg.norm(spots - c, axis=1)), pair_pixel=f(pix, torch.long),
                   pair_spot=f(spt, torch.long), path=f(np.where(shd, np.nan, 1.0)), lit=f(~shd, torch.bool),
                   shadowed=f(shd, torch.bool), visible_depth=f(depth), height=n_pix, width=n_pix)


def test_a_post_thinner_than_a_pixel_survives_the_start(score="ratio"):
    data = _post_scene()
    assert int(data.shadowed.sum()) > 30
    box = GridBox([-0.05, -0.05, -0.05], [1.05, 1.05, 1.05], 22)     # 5 cm voxels: the post is 4 cm wide
    label = evidence_grid(data, box, carve_spacing_voxels=0.5, explain_shadow_rays=True,
                          explain_camera_free=True, explain_score=score)[0].label
    centres = box.centres()
    near_post = torch.linalg.vector_norm(centres[..., :2] - torch.tensor(POST_XY, dtype=torch.float32), dim=-1)
    z = centres[..., 2]
    column = (near_post < box.voxel) & (z > 0.15) & (z < POST_TOP - 0.1)
    blocked = (label != 2) & (label != 3)
    # every height of the post's middle keeps a blocker within a voxel of its axis
    heights = sorted(set(torch.nonzero(column)[:, 2].tolist()))
    kept = [bool((blocked & column)[..., k].any()) for k in heights]
    assert len(heights) >= 6 and sum(kept) >= len(heights) - 1, (score, kept)
    # and nothing far from the post is put back
    far = (near_post > 3 * box.voxel) & (z > 0.1)
    assert int(((label == RESTORED) & far).sum()) == 0


def _column_and_far(box):
    centres = box.centres()
    near_post = torch.linalg.vector_norm(centres[..., :2] - torch.tensor(POST_XY, dtype=torch.float32), dim=-1)
    z = centres[..., 2]
    column = (near_post < box.voxel) & (z > 0.15) & (z < POST_TOP - 0.1)
    return column, (near_post > 2 * box.voxel) & (z > 0.1)


def _heights_kept(label, column):
    blocked = (label != 2) & (label != 3)
    heights = sorted(set(torch.nonzero(column)[:, 2].tolist()))
    return sum(bool((blocked & column)[..., k].any()) for k in heights), len(heights)


def test_hull_no_shadow_needs_is_trimmed_the_post_stays():
    """The corners of the box beside the sensor's view cone, which no ray of any kind crosses, are shadow hull
    (a lump) that nothing measured needs: trimmed from the free side. The post, which every shadow it casts
    crosses, stays, and so does the floor's visible-surface band."""
    data = _post_scene()
    box = GridBox([-0.05, -0.05, -0.05], [1.05, 1.05, 1.05], 22)
    evidence, shadow = evidence_grid(data, box, carve_spacing_voxels=0.5, count_shadow=True, explain_shadow_rays=True,
                                     explain_camera_free=True)
    label = evidence.label
    free = (label == 2) | (label == 3)
    band = dilate_cube((label == 1).float(), 1) > 0
    trimmed = unneeded_hull(free, label == 0, shadow, band, 8)
    column, far = _column_and_far(box)
    lump = (label == 0) & far & (box.centres()[..., 2] > 0.2)
    assert int(lump.sum()) > 100 and int((trimmed & lump).sum()) > 0.9 * int(lump.sum())
    kept, n = _heights_kept(torch.where(trimmed, torch.tensor(3, dtype=label.dtype), label), column)
    assert kept >= n - 1, (kept, n)
    assert not bool((trimmed & band).any()) and not bool((trimmed & (shadow > 0)).any())


@pytest.mark.parametrize("assignment", ["fast.trim_hull_voxels=-1", "fast.thin_part_half_width_voxels=0.7",
                                        "fast.thin_part_centre=middle", "fast.thin_part_raw=1"])
def test_start_field_settings_refuse_bad_values(assignment):
    from torch_recon.contract.errors import SettingsError
    from torch_recon.recon.config import FitConfig, override

    with pytest.raises(SettingsError, match=assignment.split("=")[0].replace(".", r"\.")):
        override(FitConfig(), [assignment])


WALL_POST_XY, WALL_POST_R, WALL_POST_TOP = np.array([0.52, 0.5]), 0.01, 0.8


def _post_before_a_wall(n_pix=24, with_nearest=True, post_xy=WALL_POST_XY, front=False):
    """Sensor at y = -1 looking at a wall at y = 1; a 2 cm post at y = 0.5 (under a pixel wide there: pixel
    rows 3.1 cm apart) that the strongest return of every pixel misses. With `with_nearest`, each pixel
    whose footprint (half a pixel either side) overlaps the post has its nearest depth there (its earliest
    return). Four spots in front (y = 0); a pair is shadowed when its segment hits the post."""
    c = POST_SENSOR
    _, _, x, dirs, depth = wall_pixel_rays(n_pix)
    nearest = depth.copy()
    if with_nearest:
        t = (post_xy[1] - c[1]) / dirs[:, 1]           # range where the ray crosses the post's plane
        at = c + dirs * t[:, None]
        half = 0.5 * (t / depth) * (1.0 / n_pix)             # half a pixel's footprint at that range
        seen = (np.abs(at[:, 0] - post_xy[0]) < WALL_POST_R + half) & (at[:, 2] < WALL_POST_TOP)
        if front:
            t = (post_xy[1] - WALL_POST_R - c[1]) / dirs[:, 1]
        nearest[seen] = t[seen]
    spots = np.array([[0.1, 0.0, 0.2], [0.9, 0.0, 0.2], [0.1, 0.0, 0.8], [0.9, 0.0, 0.8]])
    tt = np.linspace(0, 1, 400)
    pix = np.tile(np.arange(len(x)), len(spots))
    spt = np.repeat(np.arange(len(spots)), len(x))
    shd = []
    for l in spots:
        seg = x[:, None] + (l - x)[:, None] * tt[None, :, None]
        hit = np.linalg.norm(seg[..., [0, 1]] - post_xy, axis=-1) < WALL_POST_R
        shd.append((hit & (seg[..., 2] < WALL_POST_TOP)).any(1))
    shd = np.concatenate(shd)
    f = lambda a, dt=torch.float32: torch.as_tensor(np.asarray(a), dtype=dt)  # noqa: E731
    return RayData(sensor_origin=f(c), laser_origin=f(c), pixel_dirs=f(dirs), spot_points=f(spots),
                   laser_to_spot=f(np.linalg.norm(spots - c, axis=1)), pair_pixel=f(pix, torch.long),
                   pair_spot=f(spt, torch.long), path=f(np.where(shd, np.nan, 1.0)), lit=f(~shd, torch.bool),
                   shadowed=f(shd, torch.bool), visible_depth=f(depth), height=n_pix, width=n_pix,
                   nearest_depth=f(nearest))


def test_a_post_narrower_than_a_pixel_in_front_of_a_wall_is_kept_by_the_earliest_returns():
    """Without the nearest depth the sensor's own rays (the wall's depth) and the lit rays grazing the post's
    3.3 cm voxels carve every height of it; with it, the post is occupied at every height (joined across
    pixel rows), and nothing more than a voxel from it is."""
    data = _post_before_a_wall()
    box = GridBox([-0.05, -1.05, -0.05], [1.05, 1.05, 1.05], 64)
    centres = box.centres()
    off_axis = torch.linalg.vector_norm(centres[..., :2] - torch.tensor(WALL_POST_XY, dtype=torch.float32), dim=-1)
    z = centres[..., 2]
    column = (off_axis < box.voxel) & (z > 0.1) & (z < WALL_POST_TOP - 0.1)
    plain = evidence_grid(data, box)[0].label
    with_nearest = evidence_grid(data, box, nearest_free=True, nearest_surface=True)[0].label
    kept_plain, n = _heights_kept(plain, column)
    kept, _ = _heights_kept(with_nearest, column)
    assert n >= 15 and kept_plain <= 2 and kept == n, (kept_plain, kept, n)
    assert int(((with_nearest == NEAREST) & (off_axis > 1.5 * box.voxel)).sum()) == 0
    # camera free space alone (no occupied nearest surface): the sensor no longer carves the post, lit rays do
    free_only = evidence_grid(data, box, nearest_free=True)[0].label
    zs = torch.arange(0.1, WALL_POST_TOP - 0.1, 0.5 * box.voxel)
    axis = torch.stack([torch.full_like(zs, WALL_POST_XY[0]), torch.full_like(zs, WALL_POST_XY[1]), zs], 1)
    i = box.cell_index(axis)[0]
    assert int((free_only[i[:, 0], i[:, 1], i[:, 2]] == 2).sum()) == 0 < int((plain[i[:, 0], i[:, 1], i[:, 2]] == 2).sum())


def _board_before_a_wall(n_pix=24):
    """As `_post_before_a_wall`, with a 20 cm wide board (x 0.4-0.6, y = 0.5, z < 0.8) that the pixels whose
    centre ray meets it see as their strongest return; the pixels on its silhouette (footprint overlapping it,
    centre missing it) see the wall strongest and the board earliest (their nearest depth)."""
    data = _post_before_a_wall(n_pix, with_nearest=False)
    c, dirs = data.sensor_origin.double().numpy(), data.pixel_dirs.double().numpy()
    depth, nearest = data.visible_depth.double().numpy().copy(), data.visible_depth.double().numpy().copy()
    t = (WALL_POST_XY[1] - c[1]) / dirs[:, 1]
    at = c + dirs * t[:, None]
    half = 0.5 * (t / depth) * (1.0 / n_pix)
    centre_on = (np.abs(at[:, 0] - 0.5) < 0.1) & (at[:, 2] < WALL_POST_TOP)
    overlaps = (np.abs(at[:, 0] - 0.5) < 0.1 + half) & (at[:, 2] < WALL_POST_TOP + half)
    depth[centre_on] = t[centre_on]
    nearest[overlaps] = t[overlaps]
    data.visible_depth = torch.as_tensor(depth, dtype=torch.float32)
    data.nearest_depth = torch.as_tensor(nearest, dtype=torch.float32)
    return data, int((overlaps & ~centre_on).sum())


def test_the_silhouette_of_a_part_the_sensor_sees_is_not_fattened():
    """A board's silhouette pixels (the board their earliest return, the wall their strongest) mark no whole voxel
    beside the board: their neighbours' visible surface holds it. With `thin_part_edges` they do (the old
    behaviour: the outline grows by up to a voxel); the 2 cm post that no pixel sees strongest stays whole."""
    data, n_edge = _board_before_a_wall()
    box = GridBox([-0.05, -1.05, -0.05], [1.05, 1.05, 1.05], 64)
    x = box.centres()[..., 0]
    beside = (x - 0.5).abs() > 0.1 + 0.5 * box.voxel           # centre outside the board's extent
    edges = evidence_grid(data, box, nearest_free=True, nearest_surface=True, thin_part_edges=True)[0].label
    plain = evidence_grid(data, box, nearest_free=True, nearest_surface=True, thin_part_edges=False)[0].label
    assert n_edge > 20 and int(((edges == NEAREST) & beside).sum()) > 10
    assert int((plain == NEAREST).sum()) == 0
    post = _post_before_a_wall()
    box = GridBox([-0.05, -1.05, -0.05], [1.05, 1.05, 1.05], 64)
    z = box.centres()[..., 2]
    off_axis = torch.linalg.vector_norm(box.centres()[..., :2] - torch.tensor(WALL_POST_XY, dtype=torch.float32), -1)
    column = (off_axis < box.voxel) & (z > 0.1) & (z < WALL_POST_TOP - 0.1)
    kept, n = _heights_kept(evidence_grid(post, box, nearest_free=True, nearest_surface=True,
                                          thin_part_edges=False, thin_part_centre="mean")[0].label, column)
    assert kept == n >= 15, (kept, n)


def test_thin_part_points_lie_on_the_part_not_on_the_pixels_beside_it():
    """A 2 cm post on the boundary of two pixel columns (3.1 cm footprints) that both see its front earliest:
    centred, the points lie between the columns, inside the post (within 6 mm of its axis); uncentred they
    are on its front, each column's half a footprint off the axis."""
    from torch_recon.recon.thin_parts import thin_part_points

    xy = np.array([0.5312, 0.5])
    data = _post_before_a_wall(post_xy=xy, front=True)
    axis_dist = lambda p: torch.linalg.vector_norm(p[:, :2] - torch.tensor(xy, dtype=p.dtype), dim=-1)  # noqa: E731
    raw = next(thin_part_points(data, 0.033, centre="off"))
    mid = next(thin_part_points(data, 0.033, centre="mean"))
    assert len(raw) >= 30 and len(mid) == len(raw)
    assert float(axis_dist(raw).min()) > 0.015
    assert float(axis_dist(mid).max()) < 0.006
