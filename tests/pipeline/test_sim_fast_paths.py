"""The simulator's fast paths give the numbers of the plain ones they replace (bpy-free, ~2 s).

- ground-truth range images on the simulator's Embree scene = analytic.range_image (trimesh);
- transient windows binned bins-first are written to the same EXR bytes as (H, W, G) windows;
- footprint interpolation by one matrix product = the three-operand einsum it replaced;
- masked_mean = np.nanmean; edge samples' cached shading parts = ShadingSamples built per spot.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("embreex")
pytest.importorskip("OpenEXR")

from pipeline import adaptive_sampling  # noqa: E402
from pipeline.spot_shading import SceneRays, ShadingSamples  # noqa: E402
from torch_recon.contract import analytic, scenes  # noqa: E402
from torch_recon.contract.dataset import Transient  # noqa: E402
from torch_recon.contract.dataset.store import write_transient_file  # noqa: E402
from torch_recon.contract.frames import look_at_c2w  # noqa: E402


@pytest.fixture(scope="module")
def cave():
    mesh, _ = scenes.cave_chair().trimesh()
    return mesh, SceneRays(mesh.vertices, mesh.faces)


def test_range_image_matches_the_analytic_renderer(cave):
    mesh, rays = cave
    for eye, target, fov in (([0.0, -1.0, 0.3], [0.0, 2.0, 0.0], math.pi / 2), ([1.0, 1.5, -0.5], [-2.0, 3.0, 0.5], 1.0)):
        c2w = look_at_c2w(eye, target)
        ref = analytic.range_image(mesh, c2w, 40, 30, fov, "x")
        got = rays.range_image(c2w, 40, 30, fov, "x")
        assert got.shape == (30, 40)
        assert np.array_equal(np.isfinite(ref), np.isfinite(got))
        hit = np.isfinite(ref)
        assert hit.mean() > 0.9
        np.testing.assert_allclose(got[hit], ref[hit], rtol=0, atol=1e-6)


def test_bins_first_windows_write_the_same_file(tmp_path):
    rng = np.random.default_rng(3)
    h, w, g, t = 6, 5, 7, 40
    hwg = np.where(rng.random((h, w, g)) < 0.3, rng.random((h, w, g)), 0.0).astype(np.float32)
    start = rng.integers(0, t - g, (h, w))
    bins_first = np.ascontiguousarray(np.moveaxis(hwg, 2, 0))           # (G, H, W), as bin_windows stores it
    view = np.moveaxis(bins_first, 0, 2)                                 # (H, W, G) view, not a copy
    assert np.shares_memory(view, bins_first) and not view.flags.c_contiguous
    write_transient_file(tmp_path / "a.exr", Transient(start, hwg, t))
    write_transient_file(tmp_path / "b.exr", Transient(start, view, t))
    assert (tmp_path / "a.exr").read_bytes() == (tmp_path / "b.exr").read_bytes()


@pytest.mark.parametrize("side_out", [2, 3, 5, 8])
def test_footprint_samples_match_the_einsum(side_out):
    values = np.random.default_rng(side_out).random((4, 50)) * 10
    a = adaptive_sampling.interpolation_matrix(2, side_out)
    ref = np.einsum("ia,mab,jb->mij", a, values.T.reshape(-1, 2, 2), a).reshape(-1, side_out ** 2)
    got = adaptive_sampling.footprint_samples(values, side_out)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12 * np.abs(ref).max())     # rounding only
    np.testing.assert_allclose(got.mean(axis=1), values.mean(axis=0), rtol=1e-12)   # keeps the pixel's mean


def test_masked_mean_is_nanmean():
    rng = np.random.default_rng(5)
    x = rng.random((4, 9, 11))
    valid = rng.random(x.shape) < 0.6
    valid[:, 0, 0] = False                                               # a pixel with no valid sample: NaN
    with np.errstate(invalid="ignore"), pytest.warns(RuntimeWarning):
        ref = np.nanmean(np.where(valid, x, np.nan), axis=0)
    got = adaptive_sampling.masked_mean(x, valid)
    assert np.array_equal(got, ref, equal_nan=True)


def test_cached_edge_shading_parts_equal_per_spot_ones():
    rng = np.random.default_rng(9)
    x, n, rho = rng.normal(size=(30, 3)), rng.normal(size=(30, 3)), rng.random(30)
    c = np.array([0.1, -0.2, 0.3])
    whole = ShadingSamples(x, n, rho, c)
    idx = np.array([3, 7, 7, 20, 29])
    direct = ShadingSamples(x[idx], n[idx], rho[idx], c)
    for key in ShadingSamples.FIELDS:
        assert np.array_equal(getattr(whole.take(idx), key), getattr(direct, key)), key
    both = ShadingSamples.concatenate([whole.take(idx[:2]), whole.take(idx[2:])])
    assert all(np.array_equal(getattr(both, k), getattr(direct, k)) for k in ShadingSamples.FIELDS)
