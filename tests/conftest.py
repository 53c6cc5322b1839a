"""Shared pytest fixtures. Areas' own helpers live in their test files or in tests/support/ (plain modules)."""

from __future__ import annotations

import os

import numpy as np
import pytest

os.environ.setdefault("MPLBACKEND", "Agg")


def make_synthetic_dataset(root, *, height=6, width=5, bins=40, window_bins=8, spots=3, seed=0,
                           with_ground_truth=True, sample_type="float32"):
    """A small random but valid dataset (windowed transients, optional GT) and its dense cubes."""
    from torch_recon.contract.dataset import (DatasetWriter, GroundTruth, GroundTruthViews, Manifest, NoiseSpec, Provenance,
                                     SensorSpec, Spot, TimeGate, Transient, TransientLayout)
    from torch_recon.contract.frames import look_at_c2w

    rng = np.random.default_rng(seed)
    sensor = SensorSpec(width=width, height=height, bins=bins,
                        camera_to_world=look_at_c2w([0, 0, 0], [0, 3, 0]).tolist(),
                        time_gate=TimeGate(window_bins < bins, window_bins if window_bins < bins else 0))
    cubes = {}
    spot_list = []
    with DatasetWriter(root) as w:
        for k in range(spots):
            start = rng.integers(0, bins - window_bins + 1, (height, width))
            tr = Transient(start, rng.poisson(3.0, (height, width, window_bins)).astype(np.float32), bins)
            cubes[k] = tr.dense()
            d = rng.normal(size=3)
            spot_list.append(Spot(id=k, laser_direction=(d / np.linalg.norm(d)).tolist(),
                                  transient_file=w.write_transient(k, tr, sample_type),
                                  first_bounce=rng.normal(size=3).tolist(), content_hash=f"h{k}"))
        gt = GroundTruth()
        if with_ground_truth:
            depth = rng.uniform(1, 4, (height, width)).astype(np.float32)
            depth[0, 0] = np.inf
            tv_depth = rng.uniform(1, 4, (2, 4, 3)).astype(np.float32)
            import trimesh

            box = trimesh.creation.box((1.0, 2.0, 0.5))
            box.apply_translation([0.25, 3.0, -1.0])
            box.export(w.path("ground_truth/mesh.ply"))
            gt = GroundTruth(train_depth_file=w.write_depth("ground_truth/train_depth.exr", depth),
                             mesh_file="ground_truth/mesh.ply",
                             test_views=GroundTruthViews(width=3, height=4, fov_rad=1.2, fov_axis="x",
                                                         camera_to_world=[np.eye(4).tolist()] * 2,
                                                         depth_file=w.write_depth("ground_truth/test_depth.exr",
                                                                                  tv_depth)))
        manifest = Manifest(sensor=sensor, spots=spot_list,
                            layout=TransientLayout("windowed" if window_bins < bins else "dense", window_bins,
                                                   sample_type),
                            noise=NoiseSpec(photon_counts=True, photons_per_pixel=100.0, seed=seed),
                            ground_truth=gt,
                            provenance=Provenance(generator="tests", generator_version="0", seed=seed, scene="random"))
        w.commit(manifest)
    return manifest, cubes


@pytest.fixture
def synthetic_dataset(tmp_path):
    """(path, manifest, dense cubes by spot id) of a small valid dataset."""
    root = tmp_path / "ds"
    manifest, cubes = make_synthetic_dataset(root)
    return root, manifest, cubes
