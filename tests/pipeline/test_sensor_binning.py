"""Two-bounce binning (pipeline/transient_binning.py): paths, pulse, energy, first bounce, range errors."""

import numpy as np
import pytest

from pipeline.pulse_kernel import PulseKernel
from pipeline.transient_binning import (FAST_SPREAD_BINS, bin_two_bounce, count_out_of_range,
                                        expected_return_path, first_bounce_path, optical_path)
from torch_recon.contract.analytic import pulse_bin_weights
from torch_recon.contract.dataset import PulseSpec, SensorSpec
from torch_recon.contract.units import ps_to_m

O = np.zeros(3)


def make_sensor(w=3, h=2, bins=100, bin_ps=128.0, fwhm_ps=128.0, shape="gaussian", start_m=0.0):
    return SensorSpec(width=w, height=h, bins=bins, bin_width_ps=bin_ps, bin_width_m=ps_to_m(bin_ps),
                      start_m=start_m, pulse=PulseSpec(shape=shape, fwhm_ps=fwhm_ps))


L_AXIS = (0.0, 0.0, 0.1)


def point_at_path(path):
    """A point x on the +z axis with |l - o| + |x - l| + |c - x| == path (o = c = origin, l = L_AXIS)."""
    assert path >= 0.2
    return np.array([0.0, 0.0, path / 2.0])  # 0.1 + (z - 0.1) + z = 2 z


def single_sample(sensor, x, rad=1.0, pixel=(0, 0), l=L_AXIS):
    pos = np.zeros((1, sensor.height, sensor.width, 3), np.float32)
    r = np.zeros((1, sensor.height, sensor.width), np.float32)
    v = np.zeros_like(r, dtype=bool)
    pos[0][pixel] = x
    r[0][pixel] = rad
    v[0][pixel] = True
    return bin_two_bounce(pos, r, v, l, O, O, sensor)


def centroid_m(trace, sensor):
    return float(np.sum(trace * sensor.bin_centres_m()) / np.sum(trace))


@pytest.mark.parametrize("fwhm_ps", [128.0, 300.0])
@pytest.mark.parametrize("frac", [0.1, 0.3, 0.5, 0.7, 0.9])
def test_single_sample_peak_bin_and_subbin_centroid(fwhm_ps, frac):
    s = make_sensor(fwhm_ps=fwhm_ps)
    path = (40 + frac) * s.bin_width_m
    cube = single_sample(s, point_at_path(path), rad=2.5, pixel=(1, 2))
    trace = cube[1, 2]
    assert int(np.argmax(trace)) == 40
    # the bin-integrated Gaussian's centroid sits on the path to well under a bin
    assert abs(centroid_m(trace, s) - path) < 0.03 * s.bin_width_m
    assert trace.sum() == pytest.approx(2.5, rel=1e-5)
    assert np.count_nonzero(cube) == np.count_nonzero(trace)  # nothing leaks to other pixels


def test_box_pulse_is_one_bin():
    s = make_sensor(shape="box")
    cube = single_sample(s, point_at_path(17.8 * s.bin_width_m))
    assert np.flatnonzero(cube[0, 0]).tolist() == [17]
    assert cube[0, 0, 17] == pytest.approx(1.0)


@pytest.mark.parametrize("shape,fwhm_ps", [("gaussian", 128.0), ("gaussian", 40.0), ("gaussian", 900.0),
                                           ("box", 128.0)])
def test_pulse_weights_sum_to_one_and_match_reference(shape, fwhm_ps):
    s = make_sensor(fwhm_ps=fwhm_ps, shape=shape)
    paths = np.random.default_rng(1).uniform(20, 80, 500) * s.bin_width_m
    first, w = PulseKernel(s).weights(paths)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-12)
    assert np.all(w >= 0)
    # independent implementation (torch_recon.contract.analytic, dense erf over all bins)
    ref = pulse_bin_weights(paths, s.start_m, s.bin_width_m, s.bins, ps_to_m(fwhm_ps), shape)
    dense = np.zeros_like(ref)
    for j in range(w.shape[1]):
        np.add.at(dense, (np.arange(len(paths)), first + j), w[:, j])
    np.testing.assert_allclose(dense, ref, atol=2e-4)


def random_scene(sensor, n_sub, rng, spread_m=0.6):
    """Sub-samples on a sphere shell around the sensor with random radiance, some invalid."""
    h, w = sensor.height, sensor.width
    d = rng.normal(size=(n_sub, h, w, 3))
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    r = 2.0 + rng.uniform(0, spread_m, (n_sub, h, w, 1))
    pos = (d * r).astype(np.float32)
    rad = rng.uniform(0, 1, (n_sub, h, w)).astype(np.float32)
    valid = rng.random((n_sub, h, w)) > 0.2
    rad[rng.random((n_sub, h, w)) < 0.2] = 0.0  # shadowed samples
    return pos, rad, valid


def test_energy_conserved_and_matches_independent_reference():
    s = make_sensor(w=16, h=12, bins=300)
    rng = np.random.default_rng(0)
    pos, rad, valid = random_scene(s, 4, rng)
    l = np.array([0.3, -0.2, 1.5])
    cube = bin_two_bounce(pos, rad, valid, l, O, O, s)
    assert cube.dtype == np.float32 and cube.shape == (12, 16, 300)
    expect_total = np.where(valid, rad, 0).sum(axis=0) / 4
    np.testing.assert_allclose(cube.sum(axis=2), expect_total, rtol=1e-5, atol=1e-7)
    # reference: dense per-sample pulse weights from torch_recon.contract.analytic, averaged over samples
    ref = np.zeros(cube.shape)
    paths = optical_path(pos, l, O, O)
    for sub in range(4):
        m = valid[sub] & (rad[sub] > 0)
        wts = pulse_bin_weights(paths[sub][m], s.start_m, s.bin_width_m, s.bins, ps_to_m(128.0))
        ref[m] += rad[sub][m, None] * wts / 4
    np.testing.assert_allclose(cube, ref, atol=2e-4 * rad.max())


@pytest.mark.parametrize("gap_bins", [1.0, FAST_SPREAD_BINS + 5.0])
def test_edge_pixel_spreads_over_two_depths(gap_bins):
    s = make_sensor(w=1, h=1, bins=120)
    near, far = 30.4 * s.bin_width_m, (30.4 + gap_bins) * s.bin_width_m
    pos = np.stack([point_at_path(p) for p in (near, near, far, far)])[:, None, None, :]
    rad = np.ones((4, 1, 1), np.float32)
    trace = bin_two_bounce(pos, rad, np.ones((4, 1, 1), bool), L_AXIS, O, O, s)[0, 0]
    assert trace.sum() == pytest.approx(1.0, rel=1e-5)
    ref = 0.5 * (pulse_bin_weights([near], 0, s.bin_width_m, s.bins, ps_to_m(128.0))[0]
                 + pulse_bin_weights([far], 0, s.bin_width_m, s.bins, ps_to_m(128.0))[0])
    np.testing.assert_allclose(trace, ref, atol=1e-4)
    if gap_bins > 3:
        split = 30 + int(gap_bins) // 2 + 1
        assert trace[:split].sum() == pytest.approx(0.5, abs=1e-4)   # half the energy at each depth
        assert centroid_m(trace[:split], make_sensor(bins=split)) == pytest.approx(near, abs=0.03 * s.bin_width_m)


def test_first_bounce_placement_offset_laser():
    s = make_sensor(w=4, h=3, bins=200)
    l, o, c = np.array([0.5, 0.2, 3.0]), np.array([0.1, 0.0, 0.0]), np.array([-0.1, 0.05, 0.0])
    zeros = np.zeros((1, 3, 4), np.float32)
    cube = bin_two_bounce(np.zeros((1, 3, 4, 3), np.float32), zeros, zeros > 0, l, o, c, s,
                          first_bounce_pixel=(2, 1), first_bounce_radiance=7.0)
    expect = np.linalg.norm(l - o) + np.linalg.norm(c - l)
    assert first_bounce_path(l, o, c) == pytest.approx(expect)
    assert cube[2, 1].sum() == pytest.approx(7.0, rel=1e-5)
    assert centroid_m(cube[2, 1], s) == pytest.approx(expect, abs=0.03 * s.bin_width_m)
    cube[2, 1] = 0
    assert not cube.any()
    with pytest.raises(ValueError, match="first_bounce_pixel"):
        bin_two_bounce(np.zeros((1, 3, 4, 3)), zeros, zeros > 0, l, o, c, s, first_bounce_pixel=(3, 0),
                       first_bounce_radiance=1.0)


def test_paths_beyond_range_are_a_clear_error():
    s = make_sensor(bins=50)                       # range 0 .. 1.92 m
    with pytest.raises(ValueError, match=r"raise 'bins' to at least \d+"):
        single_sample(s, point_at_path(2.5))
    s2 = make_sensor(bins=50, start_m=1.0)
    with pytest.raises(ValueError, match="'start_m'"):
        single_sample(s2, point_at_path(0.5 * 1.0 + 0.2))
    # a shadowed (zero-radiance) sample out of range is no error: it adds nothing
    assert not single_sample(s, point_at_path(2.5), rad=0.0).any()
    # 'drop' keeps going and count_out_of_range reports how many were dropped
    pos = np.stack([point_at_path(1.0), point_at_path(2.5)])[:, None, None, :] * np.ones((1, 2, 3, 1))
    rad = np.ones((2, 2, 3), np.float32)
    cube = bin_two_bounce(pos, rad, rad > 0, L_AXIS, O, O, s, out_of_range="drop")
    assert cube.sum() == pytest.approx(6 * 0.5, rel=1e-5)
    assert count_out_of_range(pos, rad, rad > 0, L_AXIS, O, O, s) == 6


def test_bad_input_and_zero_input_never_give_nan():
    s = make_sensor()
    zeros = np.zeros((2, 2, 3), np.float32)
    cube = bin_two_bounce(np.full((2, 2, 3, 3), np.nan, np.float32), zeros, zeros > 0, (0, 0, 1), O, O, s)
    assert cube.shape == (2, 3, 100) and not cube.any() and np.isfinite(cube).all()
    pos = np.ones((2, 2, 3, 3), np.float32)
    bad = zeros.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="sub_radiance"):
        bin_two_bounce(pos, bad, zeros == 0, (0, 0, 1), O, O, s)
    bad[0, 0, 0] = -1
    with pytest.raises(ValueError, match="negative"):
        bin_two_bounce(pos, bad, zeros == 0, (0, 0, 1), O, O, s)
    with pytest.raises(ValueError, match="sensor is"):
        bin_two_bounce(pos[:, :1], zeros[:, :1], zeros[:, :1] == 0, (0, 0, 1), O, O, s)


def test_out_buffer_is_reused_and_cleared():
    s = make_sensor(w=8, h=6, bins=300)
    pos, rad, valid = random_scene(s, 2, np.random.default_rng(3))
    ref = bin_two_bounce(pos, rad, valid, L_AXIS, O, O, s)
    buf = np.full((6, 8, 300), 9.0, np.float32)
    got = bin_two_bounce(pos, rad, valid, L_AXIS, O, O, s, out=buf)
    assert got is buf
    np.testing.assert_array_equal(got, ref)
    # accumulate: a second light source adds into the same cube
    ref2 = bin_two_bounce(pos, rad, valid, (0.2, 0.1, 0.3), O, O, s)
    bin_two_bounce(pos, rad, valid, (0.2, 0.1, 0.3), O, O, s, out=buf, accumulate=True)
    np.testing.assert_allclose(buf, ref + ref2, rtol=1e-6, atol=1e-9)
    with pytest.raises(ValueError, match="accumulate"):
        bin_two_bounce(pos, rad, valid, L_AXIS, O, O, s, accumulate=True)


def test_expected_return_path_is_mean_of_valid_samples():
    pos = np.zeros((2, 1, 2, 3))
    pos[0, 0, 0], pos[1, 0, 0] = point_at_path(3.0), point_at_path(5.0)
    pos[0, 0, 1] = point_at_path(4.0)
    valid = np.array([[[True, True]], [[True, False]]])
    p = expected_return_path(pos, valid, L_AXIS, O, O)
    assert p.shape == (1, 2) and p.dtype == np.float32
    np.testing.assert_allclose(p, [[4.0, 4.0]], atol=1e-6)
    pos[1, 0, 1] = np.nan                                        # a non-finite position counts as invalid
    np.testing.assert_allclose(expected_return_path(pos, valid | True, L_AXIS, O, O), [[4.0, 4.0]], atol=1e-6)
    assert np.isnan(expected_return_path(pos, valid & False, L_AXIS, O, O)).all()


def test_threads_give_identical_bytes():
    s = make_sensor(w=256, h=130, bins=300)                    # enough pixels for two thread blocks
    pos, rad, valid = random_scene(s, 2, np.random.default_rng(4))
    one = bin_two_bounce(pos, rad, valid, L_AXIS, O, O, s, threads=1)
    two = bin_two_bounce(pos, rad, valid, L_AXIS, O, O, s, threads=2)
    three = bin_two_bounce(pos, rad, valid, L_AXIS, O, O, s, threads=3)
    assert one.any() and one.tobytes() == two.tobytes() == three.tobytes()


@pytest.mark.parametrize("shape", ["gaussian", "box"])
def test_bin_windows_is_the_tabulated_pulse_of_every_sample(shape):
    """Each sample adds amp x its tabulated pulse weights into its pixel's window, tails past the range cut
    (a per-sample reference loop; windows placed into the (P, T) cube)."""
    from pipeline.pulse_kernel import PULSE_SUPPORT_SIGMAS, TABLE_STEPS
    from pipeline.transient_binning import bin_windows
    sensor = make_sensor(w=4, h=3, bins=30, shape=shape)
    kernel = PulseKernel(sensor)
    rng = np.random.default_rng(7)
    n_pixels, n = 12, 400
    pixels = rng.integers(0, n_pixels, n)
    paths = rng.uniform(0.0, kernel.end_m - 1e-6, n)            # near both ends: tails cut
    amps = np.where(rng.random(n) < 0.8, rng.random(n), 0.0)
    start, window, needed = bin_windows(pixels, paths, amps, n_pixels, sensor, sensor.bins)
    assert needed <= sensor.bins
    dense = np.zeros((n_pixels, sensor.bins))
    for p, s in enumerate(start):
        dense[p, s:s + window.shape[1]] = window[p]
    ref = np.zeros_like(dense)
    table = kernel.weight_table()
    for p, x, a in zip(pixels, paths, amps):
        v = (x - kernel.start_m) / kernel.bin_width_m
        if shape == "box":
            ref[p, int(np.floor(v))] += a
            continue
        v -= PULSE_SUPPORT_SIGMAS * kernel.sigma_m / kernel.bin_width_m
        first = int(np.floor(v))
        w = table[min(int((v - first) * TABLE_STEPS + 0.5), TABLE_STEPS)]
        for j, wj in enumerate(w):
            if 0 <= first + j < sensor.bins:
                ref[p, first + j] += a * wj
    np.testing.assert_allclose(dense, ref, rtol=1e-5, atol=1e-6)
    assert (amps > 0).any() and ref.sum() > 0
