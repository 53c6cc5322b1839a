"""A post under a pixel wide, partly covering two pixels side by side, is centred on its axis by
`fast.thin_part_centre=coverage`: each pixel's point pulls by how much of its footprint the post covers (the
surface behind returns that much less), where the plain 3 x 3 mean puts it halfway between the two pixels."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from tests.support.recon_fixtures import POST_SENSOR, wall_pixel_rays  # noqa: E402
from torch_recon.recon.data import RayData  # noqa: E402
from torch_recon.recon.thin_parts import part_coverage, thin_part_points  # noqa: E402

N_PIX, POST_Y, POST_HALF, POST_TOP = 24, 0.5, 0.01, 0.8


def _post_covering(phase: float):
    """Sensor at (0.5, -1, 0.5) looking along +y at a wall at y = 1 (24 x 24 pixels, 3.1 cm apart at the post);
    a vertical post 2 cm wide at y = 0.5 whose left edge lies `phase` pixel footprints right of pixel column 12's
    centre. Per pixel the post covers the fraction `cov` of the footprint (a box of one pixel): the earliest return
    is the post's where cov > 0; the strongest is the post's where cov > 0.5 (else the wall's, that much weaker:
    amplitude (1 - cov) x a smooth shading, 4 spots)."""
    c = POST_SENSOR
    gx, gz, _, dirs, depth = wall_pixel_rays(N_PIX)
    u = (np.arange(N_PIX) + 0.5) / N_PIX
    t_post = (POST_Y - c[1]) / dirs[:, 1]
    at = c + dirs * t_post[:, None]
    foot = (1.0 / N_PIX) * (POST_Y - c[1]) / (1.0 - c[1])          # a pixel's footprint at the post
    x12 = 0.5 + (u[12] - 0.5) * (POST_Y - c[1]) / (1.0 - c[1])
    lo = x12 + phase * foot
    hi = lo + 2 * POST_HALF
    cov = np.clip(np.minimum(at[:, 0] + foot / 2, hi) - np.maximum(at[:, 0] - foot / 2, lo), 0, None) / foot
    cov[at[:, 2] > POST_TOP] = 0.0
    nearest = np.where(cov > 0, t_post, depth)
    visible = np.where(cov > 0.5, t_post, depth)
    spots = np.array([[0.1, 0.0, 0.2], [0.9, 0.0, 0.2], [0.1, 0.0, 0.8], [0.9, 0.0, 0.8]])
    shade = 10.0 + 3.0 * gx.reshape(-1) + 2.0 * gz.reshape(-1)
    amp = np.stack([(k + 1.0) * shade * np.where(cov > 0.5, cov, 1.0 - cov) for k in range(len(spots))])
    n = N_PIX * N_PIX
    f = lambda a, dt=torch.float32: torch.as_tensor(np.asarray(a), dtype=dt)  # noqa: E731
    data = RayData(sensor_origin=f(c), laser_origin=f(c), pixel_dirs=f(dirs), spot_points=f(spots),
                   laser_to_spot=f(np.linalg.norm(spots - c, axis=1)), pair_pixel=f(np.tile(np.arange(n), 4), torch.long),
                   pair_spot=f(np.repeat(np.arange(4), n), torch.long), path=f(np.ones(4 * n)),
                   lit=f(np.ones(4 * n, bool), torch.bool), shadowed=f(np.zeros(4 * n, bool), torch.bool),
                   visible_depth=f(visible), height=N_PIX, width=N_PIX, nearest_depth=f(nearest), amplitude=f(amp))
    return data, cov.reshape(N_PIX, N_PIX), 0.5 * (lo + hi)


def _axis_error(data, axis_x, centre):
    """Median |x - axis| (m) of the post's pixel points (the first chunk of `thin_part_points`) below its top."""
    pts = next(thin_part_points(data, 0.025, edges=False, centre=centre))
    pts = pts[(pts[:, 2] > 0.1) & (pts[:, 2] < POST_TOP - 0.1)]
    assert len(pts) >= 10
    return float((pts[:, 0] - axis_x).abs().median())


@pytest.mark.parametrize("phase", [0.05, -0.1])
def test_coverage_centres_a_post_between_two_pixels_on_its_axis(phase):
    """phase 0.05: the post covers 0.45 of pixel 12 and 0.19 of pixel 13 (both see the wall strongest);
    -0.1: 0.6 of pixel 12 (seen strongest there) and 0.04 of pixel 13. The mean of the two pixels' points lies
    about half a pixel from the axis's side; weighted by coverage, within a fifth of a pixel of it."""
    data, cov, axis_x = _post_covering(phase)
    foot = 0.75 / N_PIX
    err_mean = _axis_error(data, axis_x, "mean")
    err_cov = _axis_error(data, axis_x, "coverage")
    assert err_cov < 0.2 * foot, (err_cov / foot, err_mean / foot)
    assert err_cov < 0.6 * err_mean, (err_cov / foot, err_mean / foot)


def test_part_coverage_is_the_background_returns_deficit():
    """`part_coverage` of the pixels seeing the post only in front of the wall: 1 - their wall return against the
    wall-only neighbours', i.e. the covered fraction (shading varies 1 % a pixel: within 0.03)."""
    data, cov, _ = _post_covering(0.05)
    h = w = N_PIX
    front = (data.nearest_depth < data.visible_depth - 0.025).reshape(h, w)
    est = part_coverage(data, front, 0.025)
    rows = slice(4, 14)                 # below the post's top, away from the image's edge
    got, want = est[rows][front[rows]], torch.as_tensor(cov[rows][front[rows].numpy()], dtype=torch.float32)
    assert len(got) >= 10 and bool(torch.isnan(est[~front]).all())
    assert float((got - want).abs().max()) < 0.03, (got[:4], want[:4])
    # without amplitudes (older measurements) nothing is known: the plain mean's weights
    data.amplitude = None
    assert bool(torch.isnan(part_coverage(data, front, 0.025)).all())
