"""Bounce Flash Lidar baseline: the posterior by hand, carving a box in the paper's room."""

from __future__ import annotations

import numpy as np
import pytest

from torch_recon.bflidar import BFLidarSettings, carve, grid_search, occupancy_posterior, rethreshold
from torch_recon.contract.dataset import load_dataset
from torch_recon.preprocess import preprocess_dataset
from torch_recon.contract.synthetic import (box_room_scene, default_sensor, paper_laser_directions,
                                           write_analytic_dataset)


def test_occupancy_posterior_by_hand():
    p = occupancy_posterior
    assert float(p(0, 0, 0.05, 0.5, 0.8, 0.2)) == pytest.approx(0.2)                   # the prior
    assert float(p(1, 0, 0.05, 0.5, 0.8, 0.2)) == pytest.approx(0.01 / 0.41)           # seen lit once
    assert float(p(0, 2, 0.05, 0.5, 0.8, 0.2)) == pytest.approx(0.2 * 0.9025 / (0.8 * 0.25 + 0.2 * 0.9025))


@pytest.fixture(scope="module")
def box_meas(tmp_path_factory):
    path, _ = write_analytic_dataset(tmp_path_factory.mktemp("b") / "ds", box_room_scene(),
                                     default_sensor(40, 40, bins=391), paper_laser_directions()[::2])
    return preprocess_dataset(load_dataset(path))


def _value_at(res, field, point):
    vox = (res.bbox_max - res.bbox_min) / (np.array(field.shape) - 1)
    i = np.round((np.asarray(point) - res.bbox_min) / vox).astype(int)
    return field[tuple(i)]


def test_carving_finds_the_box_and_empties_the_room(box_meas):
    res = carve(box_meas, BFLidarSettings(voxels=48))
    assert res.probability.shape == res.occupancy.shape and np.all(np.isfinite(res.probability))
    assert _value_at(res, res.probability, (0.0, 3.0, -1.7)) > 0.3     # inside the box (hidden core)
    assert _value_at(res, res.probability, (0.0, 2.0, 0.0)) < 0.05     # open air, crossed by lit rays
    assert res.counts_outside.max() > 0 and res.counts_inside.max() > 0
    mesh = res.mesh()
    assert len(mesh.faces) > 100
    lo, hi = mesh.bounds
    assert lo[0] < -1.8 and hi[0] > 1.8 and hi[1] > 3.9                # walls and back wall are in the mesh
    r2 = rethreshold(res, 0.9)
    assert r2.occupancy.sum() <= res.occupancy.sum()


def test_grid_search_picks_the_best_threshold(box_meas):
    calls = []

    def score(mesh):
        calls.append(len(mesh.faces))
        return abs(len(mesh.faces) - 5000)
    best, sc, table = grid_search(box_meas, score, BFLidarSettings(voxels=32), occupancy_thresholds=(0.1, 0.5, 0.9))
    assert len(table) == 3 and sc == min(t[2] for t in table)
    assert best.settings["occupancy_threshold"] == table[int(np.argmin([t[2] for t in table]))][1]


def test_bad_settings_are_refused(box_meas):
    with pytest.raises(ValueError, match="occupancy_threshold"):
        carve(box_meas, BFLidarSettings(occupancy_threshold=1.2))
    box_meas_no_depth = type(box_meas)(**{**box_meas.__dict__, "visible_depth": None})
    with pytest.raises(ValueError, match="visible depth"):
        carve(box_meas_no_depth)
