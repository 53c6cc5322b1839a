"""A post thinner than a pixel, seen past by the sensor and grazed by lit rays, survives the fast start
because the shadows it casts from several spots cross it (recon/init.py `explain_shadows`)."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from torch_recon.recon.data import RayData  # noqa: E402
from torch_recon.recon.fields import GridBox  # noqa: E402
from torch_recon.recon.init import RESTORED, evidence_grid  # noqa: E402

POST_XY, POST_R, POST_TOP = np.array([0.55, 0.45]), 0.02, 0.6


def _post_scene(n_pix=24):
    """Sensor 2 m above a 1 x 1 m floor looking down; a vertical post (radius 2 cm, 60 cm tall) the depth
    image does not see; 6 spots on the above the floor round it; a pair is shadowed when its segment hits the post."""
    c = np.array([0.5, 0.5, 2.0])
    u = (np.arange(n_pix) + 0.5) / n_pix
    floor = np.stack(np.meshgrid(u, u, indexing="ij"), -1).reshape(-1, 2)
    x = np.concatenate([floor, np.zeros((len(floor), 1))], 1)
    dirs = x - c
    depth = np.linalg.norm(dirs, axis=1)
    dirs /= depth[:, None]
    ang = np.linspace(0, 2 * np.pi, 6, endpoint=False)
    spots = np.stack([0.5 + 0.4 * np.cos(ang), 0.5 + 0.4 * np.sin(ang), np.zeros(6)], 1)
    t = np.linspace(0, 1, 400)
    spots[:, 2] = 0.9             # above the floor: a segment to a floor spot would graze the floor
    pix = np.tile(np.arange(len(x)), len(spots))
    spt = np.repeat(np.arange(len(spots)), len(x))
    shd = []
    for k, l in enumerate(spots):
        seg = x[:, None] + (l - x)[:, None] * t[None, :, None]
        shd.append(((np.linalg.norm(seg[..., :2] - POST_XY, axis=-1) < POST_R) & (seg[..., 2] <= POST_TOP)).any(1))
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
    label, _ = evidence_grid(data, box, carve_spacing_voxels=0.5, explain_shadow_rays=True,
                             explain_camera_free=True, explain_score=score)
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
