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
    """outside-fov's room, chair and column; three in-view paper spots and one spot on the right wall beside the
    sensor whose light passes the column."""
    mesh, _ = outside_fov().trimesh()
    lds = np.concatenate([paper_laser_directions()[[0, 5, 9]], _unit(OUTSIDE_FOV_TARGETS[:1])])
    path, parts = write_analytic_dataset(tmp_path_factory.mktemp("oov") / "ds", mesh, default_sensor(RES, RES, bins=391),
                                         lds)
    return load_dataset(path), parts


def test_out_of_view_spot_is_located_from_two_bounce_times(column_ds):
    ds, parts = column_ds
    sensor = ds.sensor
    assert [laser_ray_seen(sensor, s.laser_direction) for s in ds.manifest.enabled_spots] == [True] * 3 + [False]
    m = preprocess_dataset(ds)
    assert [s.spot_id for s in m.spots] == [s.id for s in ds.manifest.enabled_spots]
    oov, truth = m.spots[3], parts["spots"][3].first_bounce
    err = float(np.linalg.norm(oov.first_bounce - truth))
    assert err < SPOT_TOLERANCE_M, (oov.first_bounce, truth)
    assert oov.first_bounce_pixel is None
    # the column shadows a large part of the image from this spot (tests/torch_recon/contract checks where)
    assert oov.shadow.sum() > 0.2 * RES * RES
    assert oov.signal.sum() > 0.2 * RES * RES


def test_every_spot_out_of_view_is_one_clear_error(tmp_path):
    mesh, _ = outside_fov().trimesh()
    path, _ = write_analytic_dataset(tmp_path / "ds", mesh, default_sensor(16, 16, bins=391),
                                     _unit(OUTSIDE_FOV_TARGETS[:2]))
    with pytest.raises(PreprocessError) as e:
        preprocess_dataset(load_dataset(path))
    msg = str(e.value)
    assert "\n" not in msg and "at least one spot inside the view" in msg
