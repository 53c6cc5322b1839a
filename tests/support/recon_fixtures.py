"""Tiny synthetic scenes with ideal measurements for the reconstructor's tests."""

from __future__ import annotations

import numpy as np

from torch_recon.contract.frames import look_at_c2w

#: a box on a floor in a three-walled bay, seen from the front and above; its back face
#: (y = BOX_BACK_Y) is hidden from the sensor
BOX_LO = np.array([-0.3, 1.8, 0.0])
BOX_HI = np.array([0.3, 2.3, 0.5])
BOX_BACK_Y = float(BOX_HI[1])
WALL_Y = 3.3
CAMERA = look_at_c2w([0.0, 0.0, 1.2], [0.0, 2.2, 0.0])
SIDE_X = 1.4
# four laser targets on the side walls, low, beside and behind the box: the box casts shadows across
# the floor, and light from lit floor points just past the shadow grazes the hidden back face
SPOTS = np.array([[-SIDE_X, 2.2, 0.25], [SIDE_X, 2.2, 0.25], [-SIDE_X, 2.7, 0.2], [SIDE_X, 2.7, 0.2]])


def box_floor_mesh():
    import trimesh

    floor = trimesh.creation.box((4.0, 4.0, 0.02))
    floor.apply_translation([0.0, 2.0, -0.01])
    wall = trimesh.creation.box((4.0, 0.02, 2.0))
    wall.apply_translation([0.0, WALL_Y + 0.01, 1.0])
    sides = []
    for sx in (-1, 1):
        side = trimesh.creation.box((0.02, 4.0, 2.0))
        side.apply_translation([sx * (SIDE_X + 0.01), 2.0, 1.0])
        sides.append(side)
    box = trimesh.creation.box(BOX_HI - BOX_LO)
    box.apply_translation(0.5 * (BOX_LO + BOX_HI))
    return trimesh.util.concatenate([floor, wall, *sides, box])


def box_floor_measurements(size=32):
    from torch_recon.recon.synthetic_measurements import ideal_measurements

    return ideal_measurements(box_floor_mesh(), CAMERA, size, size, SPOTS, fov_rad=np.deg2rad(70.0))


#: the sensor of the post-before-a-wall scenes: at y = -1, looking along +y at a wall at y = 1 (x, z in [0, 1])
POST_SENSOR = np.array([0.5, -1.0, 0.5])


def wall_pixel_rays(n_pix: int):
    """Pixel centres (gx, gz: (n, n) in [0, 1]), their points on the wall y = 1 (n*n, 3), unit ray directions
    from POST_SENSOR and the wall's range along each: the shared set-up of the thin-post tests."""
    u = (np.arange(n_pix) + 0.5) / n_pix
    gx, gz = np.meshgrid(u, u, indexing="xy")
    wall = np.stack([gx.reshape(-1), np.ones(n_pix * n_pix), gz.reshape(-1)], 1)
    dirs = wall - POST_SENSOR
    depth = np.linalg.norm(dirs, axis=1)
    return gx, gz, wall, dirs / depth[:, None], depth
