"""Out-of-view laser spots: located from two-bounce arrival times at pixels whose depth in-view spots measured."""

from __future__ import annotations

import numpy as np
import pytest

from torch_recon.contract.dataset import load_dataset
from torch_recon.contract.scenes import OUTSIDE_FOV_TARGETS, outside_fov
from torch_recon.contract.synthetic import default_sensor, paper_laser_directions, write_analytic_dataset
from torch_recon.first_bounce import laser_ray_seen
from torch_recon.preprocess import PreprocessError, preprocess_dataset

RES = 32
#: stated tolerance of the fitted out-of-view spot position (noise-free analytic transients, 3.84 cm bins)
SPOT_TOLERANCE_M = 0.01


def _unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@pytest.fixture(scope="module")
def column_ds(tmp_path_factory):
    """outside-fov's room, chair and column; three in-view paper spots and its five out-of-view spots beside the
    sensor (right wall, floor) whose light passes the column."""
    mesh, _ = outside_fov().trimesh()
    lds = np.concatenate([paper_laser_directions()[[0, 5, 9]], _unit(OUTSIDE_FOV_TARGETS)])
    path, parts = write_analytic_dataset(tmp_path_factory.mktemp("oov") / "ds", mesh,
                                         default_sensor(RES, RES, bins=391), lds)
    return load_dataset(path), parts


def test_out_of_view_spot_is_located_from_two_bounce_times(column_ds):
    ds, parts = column_ds
    sensor = ds.sensor
    seen = [laser_ray_seen(sensor, s.laser_direction) for s in ds.manifest.enabled_spots]
    assert seen == [True] * 3 + [False] * len(OUTSIDE_FOV_TARGETS)
    m = preprocess_dataset(ds)
    assert [s.spot_id for s in m.spots] == [s.id for s in ds.manifest.enabled_spots]
    for k in range(3, len(m.spots)):
        oov, truth = m.spots[k], parts["spots"][k].first_bounce
        err = float(np.linalg.norm(oov.first_bounce - truth))
        assert err < SPOT_TOLERANCE_M, (k, oov.first_bounce, truth)
        assert oov.first_bounce_pixel is None
    oov = m.spots[3]
    # the column shadows a large part of the image from this spot (tests/torch_recon/contract checks where)
    assert oov.shadow.sum() > 0.2 * RES * RES
    assert oov.signal.sum() > 0.2 * RES * RES


def test_every_spot_out_of_view_is_one_clear_error(tmp_path):
    mesh, _ = outside_fov().trimesh()
    path, _ = write_analytic_dataset(tmp_path / "ds", mesh, default_sensor(16, 16, bins=391),
                                     _unit(OUTSIDE_FOV_TARGETS))
    with pytest.raises(PreprocessError) as e:
        preprocess_dataset(load_dataset(path))
    msg = str(e.value)
    assert "\n" not in msg and "at least one spot inside the view" in msg


def test_out_of_view_secondary_rays_count_as_measured_space(column_ds):
    """recon.init.in_view: the space beside the sensor that two out-of-view spots' light crosses is measured
    (most of the column's voxels among it); without those spots it is not."""
    from torch_recon.recon.data import build_ray_data
    from torch_recon.recon.fields import GridBox
    from torch_recon.recon.init import in_view

    ds, _ = column_ds
    m = preprocess_dataset(ds)
    s = ds.sensor
    box = GridBox(np.array([-2.1, -0.1, -2.1]), np.array([2.1, 4.1, 2.1]), 42)
    centres = box.centres().reshape(-1, 3).numpy()
    column = ((centres[:, 0] > 1.35) & (centres[:, 0] < 1.55) & (centres[:, 1] > 0.75) & (centres[:, 1] < 0.95)
              & (centres[:, 2] > -1.9) & (centres[:, 2] < 0.4))
    assert column.sum() >= 4
    view = in_view(build_ray_data(m), box, s.camera_to_world, s.fov_rad, s.fov_axis).reshape(-1).numpy()
    assert view[column].mean() > 0.7, view[column].mean()     # rays reach visible points from most of it
    m.spots = m.spots[:3]
    view = in_view(build_ray_data(m), box, s.camera_to_world, s.fov_rad, s.fov_axis).reshape(-1).numpy()
    assert not view[column].any()
