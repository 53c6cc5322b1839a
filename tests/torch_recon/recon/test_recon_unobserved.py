"""Outside the sensor's view: the planes bounding the observation continue (recon/unobserved.py)."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from torch_recon.recon.unobserved import bounding_planes, shell_signed_distance  # noqa: E402


def _plane_points(rng, n, origin, u, v, normal):
    a, b = rng.uniform(0, 1, (2, n))
    pts = origin + a[:, None] * u + b[:, None] * v
    return pts, np.broadcast_to(normal, pts.shape).copy()


def test_walls_bound_the_observation_a_table_top_does_not():
    rng = np.random.default_rng(0)
    parts = [_plane_points(rng, 3000, np.array([-2, 1, 0.0]), np.array([4, 0, 0.0]), np.array([0, 3, 0.0]),
                           [0, 0, 1.0]),                                      # floor z = 0
             _plane_points(rng, 3000, np.array([-2, 4, 0.0]), np.array([4, 0, 0.0]), np.array([0, 0, 3.0]),
                           [0, -1, 0.0]),                                     # back wall y = 4
             _plane_points(rng, 1500, np.array([-0.5, 2, 0.8]), np.array([1, 0, 0.0]), np.array([0, 1, 0.0]),
                           [0, 0, 1.0])]                                      # table top z = 0.8
    pts = np.concatenate([p for p, _ in parts])
    nrm = np.concatenate([n for _, n in parts])
    sensor = np.array([0.0, 0.0, 1.5])
    planes = bounding_planes(pts, nrm, sensor, np.array([[0.0, 4.0, 1.0]]), tolerance_m=0.02, seed=0)
    found = sorted((tuple(np.round(p.normal, 3)), round(p.offset, 3)) for p in planes)
    # the floor (normal up, z = 0) and the back wall (normal -y, y = 4); the table top has the floor behind it
    assert len(found) == 2
    assert any(np.allclose(n, (0, 0, 1), atol=1e-3) and abs(o) < 1e-3 for n, o in found)
    assert any(np.allclose(n, (0, -1, 0), atol=1e-3) and abs(o + 4) < 1e-3 for n, o in found)
    # same input, same planes (seeded)
    again = bounding_planes(pts, nrm, sensor, np.array([[0.0, 4.0, 1.0]]), tolerance_m=0.02, seed=0)
    assert [p.offset for p in again] == [p.offset for p in planes]
    # the shell: below the floor or behind the wall is solid (+), inside the room empty (-)
    q = torch.tensor([[0.0, 0.5, -0.1], [0.0, 0.5, 0.3], [0.0, 4.2, 1.0]], dtype=torch.float64)
    sd = shell_signed_distance(q, planes).numpy()
    assert sd[0] == pytest.approx(0.1) and sd[1] == pytest.approx(-0.3) and sd[2] == pytest.approx(0.2)


def test_floor_outside_the_view_is_completed_and_known_free_space_stays_empty():
    from tests.support.recon_fixtures import box_floor_measurements

    from torch_recon.recon.config import FitConfig
    from torch_recon.recon.data import build_ray_data
    from torch_recon.recon.models import FastModel

    meas = box_floor_measurements(24)
    meta = {"camera_to_world": np.asarray(meas.camera_to_world), "fov_rad": meas.fov_rad, "fov_axis": meas.fov_axis}
    data = build_ray_data(meas)
    results = {}
    for complete in (True, False):
        cfg = FitConfig.from_dict({"fast": {"resolution": 40, "complete_unobserved": complete}})
        m = FastModel(data, cfg, meta)
        view = m._view(m.grid.box)
        raw = m.grid.raw_xyz().detach()
        centres = m.grid.box.centres()
        results[complete] = (raw, view, centres, m.free_evidence(), m.grid.box.voxel, m.free.cpu().numpy())
    raw, view, centres, mesh_free, voxel, _ = results[True]
    x, y, z = centres[..., 0], centres[..., 1], centres[..., 2]
    out = ~view & (y > 0.1) & (y < 0.6) & (x.abs() < 1.2)   # floor next to the sensor, between the side walls
    below = out & (z < -0.25 * voxel)
    above = out & (z > 0.75 * voxel) & (z < 0.4)
    assert below.sum() > 5 and above.sum() > 10
    assert bool((raw[below] > 0).all()), "the floor plane continues below z = 0 outside the view"
    assert bool((raw[above] < 0).all()), "the space above it stays empty"
    assert mesh_free[(above & (z < 2 * voxel)).numpy()].any(), "the completed floor is meshed"
    raw_off, _, _, _, _, free_off = results[False]     # the measured free space (the mesh's adds the space
                                                       # in front of visible points)
    # without completion only the visible floor's ramp reaches a voxel or two past the edge of the view
    assert int((raw_off[below] > 0).sum()) < 0.7 * int(below.sum())
    # known free space (seen through by the sensor) is never filled by the completion
    known = torch.as_tensor(free_off)
    assert known.sum() > 100
    assert bool((raw[known] == raw_off[known]).all())


def test_a_floor_whose_far_rows_read_short_is_continued_level():
    """Session 19: the far, grazing rows of a floor and its junction with the back wall read a few mm short (up);
    RANSAC's least squares over every inlier tilted the plane, and continued to below the sensor it lay 5 mm low.
    The default refit (`fast.plane_refit_mad`) fits the points within their own scatter: level to 0.5 mm."""
    from torch_recon.recon.config import FitConfig, SettingsError
    from torch_recon.recon.fast_config import FastConfig

    rng = np.random.default_rng(0)
    pts, nrm = _plane_points(rng, 6000, np.array([-2, 2, 0.0]), np.array([4, 0, 0.0]), np.array([0, 2, 0.0]),
                             [0, 0, 1.0])                                     # floor z = 0 seen from y = 2 to 4
    pts[:, 2] += rng.normal(0.0, 2e-4, len(pts))                              # the measured points' scatter
    far = pts[:, 1] > 3.7                                                     # 15 % of the points
    pts[far, 2] += 0.003 + 0.017 * (pts[far, 1] - 3.7)                        # far rows up by 3 to 8 mm
    sensor = np.array([0.0, 0.0, 2.0])

    def floor_height_below_sensor(refit_mad):
        planes = bounding_planes(pts, nrm, sensor, np.array([[0.0, 3.0, 0.0]]), tolerance_m=0.016, seed=0,
                                 refit_mad=refit_mad)
        assert len(planes) == 1
        return planes[0].offset / planes[0].normal[2]                          # z at x = y = 0

    assert abs(floor_height_below_sensor(0.0)) > 0.002                        # RANSAC's fit: tilted
    assert abs(floor_height_below_sensor(FastConfig().plane_refit_mad)) < 5e-4
    with pytest.raises(SettingsError, match="fast.plane_refit_mad"):
        FitConfig.from_dict({"fast": {"plane_refit_mad": -1.0}})
