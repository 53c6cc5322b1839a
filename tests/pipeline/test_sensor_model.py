"""Sensor model (pipeline/sensor_model.py): photons, background, Poisson, time gate, storage, determinism."""

import math

import numpy as np
import pytest
from scipy import stats

from pipeline.sensor_model import apply_sensor, gate_starts, widen_window
from torch_recon.contract.analytic import pulse_bin_weights
from torch_recon.contract.dataset import NoiseSpec, PulseSpec, SensorSpec, TimeGate
from torch_recon.contract.units import ps_to_m


def make_sensor(w=64, h=64, bins=200, gate=0):
    return SensorSpec(width=w, height=h, bins=bins, bin_width_ps=128.0, bin_width_m=ps_to_m(128.0),
                      pulse=PulseSpec("gaussian", 128.0), time_gate=TimeGate(gate > 0, gate))


def pulse_cube(sensor, paths, amps):
    """(H, W, T) expected transient: one Gaussian pulse per pixel at paths (H, W) with totals amps (H, W)."""
    wts = pulse_bin_weights(np.ravel(paths), sensor.start_m, sensor.bin_width_m, sensor.bins, ps_to_m(128.0))
    return (wts * np.ravel(amps)[:, None]).reshape(sensor.height, sensor.width, sensor.bins).astype(np.float32)


@pytest.mark.parametrize("signal,background", [(3.0, 0.0), (0.0, 0.8), (1.5, 0.8)])
def test_poisson_counts_have_requested_mean_and_variance(signal, background):
    """Signal and background are drawn as separate Poisson parts: each and their sum must be Poisson."""
    s = make_sensor(bins=16)
    lam = signal + background
    tr, layout = apply_sensor(np.full((64, 64, 16), signal, np.float32), s,
                              NoiseSpec(photon_counts=True, ambient_per_bin=background), np.random.default_rng(0))
    x = tr.window.ravel().astype(np.float64)
    n = x.size
    assert layout.kind == "dense" and np.all(x == np.round(x))
    per_bin = tr.window.reshape(-1, 16).mean(axis=0)                  # background spread evenly over bins
    assert np.all(np.abs(per_bin - lam) < 5 * math.sqrt(lam / 4096))
    assert abs(x.mean() - lam) < 5 * math.sqrt(lam / n)
    # dispersion index: sum (x - lam)^2 / lam ~ chi2(n) for Poisson
    z = (np.sum((x - lam) ** 2) / lam - n) / math.sqrt(2 * n)
    assert abs(z) < 5
    # goodness of fit to the Poisson pmf over 0..9 (+ tail)
    k = np.arange(10)
    observed = np.append(np.bincount(x.astype(int), minlength=11)[:10], np.sum(x >= 10))
    pmf = np.append(stats.poisson.pmf(k, lam), stats.poisson.sf(9, lam))
    assert stats.chisquare(observed, pmf * n).pvalue > 1e-4


def test_photon_budget_of_brightest_pixel():
    s = make_sensor(w=8, h=4)
    rng = np.random.default_rng(1)
    amps = rng.uniform(0.1, 2.0, (4, 8))
    amps[1, 3] = 2.5                               # brightest two-bounce pixel
    amps[0, 0] = 400.0                             # first-bounce pixel: excluded from the budget
    cube = pulse_cube(s, np.full((4, 8), 3.0), amps)
    tr, _, info = apply_sensor(cube, s, NoiseSpec(photons_per_pixel=1000.0), rng, first_bounce_pixel=(0, 0),
                               return_info=True)
    totals = tr.window.sum(axis=2)
    assert totals[1, 3] == pytest.approx(1000.0, rel=1e-5)
    np.testing.assert_allclose(totals, amps * 1000.0 / 2.5, rtol=1e-4)
    assert info["photon_scale"] == pytest.approx(400.0, rel=1e-6)
    # with Poisson counts, many copies of the brightest pixel average to the budget
    s2 = make_sensor()
    cube2 = pulse_cube(s2, np.full((64, 64), 3.0), np.full((64, 64), 0.02))
    tr2, _ = apply_sensor(cube2, s2, NoiseSpec(photon_counts=True, photons_per_pixel=50.0), rng)
    per_pixel = tr2.window.sum(axis=2)
    assert abs(per_pixel.mean() - 50.0) < 5 * math.sqrt(50.0 / per_pixel.size)


def test_ambient_times_filter_factor_and_dark_counts():
    s = make_sensor(w=32, h=32, bins=50)
    zero = np.zeros((32, 32, 50), np.float32)
    noise = NoiseSpec(ambient_per_bin=2.0, wavelength_filter_factor=0.25, dark_counts_per_bin=0.3)
    tr, layout = apply_sensor(zero, s, noise, np.random.default_rng(0))
    assert layout.kind == "dense" and layout.window_bins == 50
    np.testing.assert_allclose(tr.window, 2.0 * 0.25 + 0.3, rtol=1e-6)
    # the filter blocks ambient light only; dark counts remain
    tr0, _ = apply_sensor(zero, s, NoiseSpec(ambient_per_bin=2.0, wavelength_filter_factor=0.0,
                                             dark_counts_per_bin=0.3), np.random.default_rng(0))
    np.testing.assert_allclose(tr0.window, 0.3, rtol=1e-6)
    # Poisson counts of the background have its mean
    noise.photon_counts = True
    trp, _ = apply_sensor(zero, s, noise, np.random.default_rng(0))
    assert abs(trp.window.mean() - 0.8) < 5 * math.sqrt(0.8 / trp.window.size)
    # a per-pixel ambient image scales the ambient part
    scale = np.linspace(0, 2, 32 * 32).reshape(32, 32)
    trs, _ = apply_sensor(zero, s, NoiseSpec(ambient_per_bin=2.0, wavelength_filter_factor=0.25), np.random.
                          default_rng(0), ambient_scale=scale)
    np.testing.assert_allclose(trs.window[..., 7], 0.5 * scale, rtol=1e-6)


def intensity_sbr(tr, lit):
    """Measured SBR of the intensity image (sum of stored bins): (I_lit - I_shadow) / I_shadow."""
    img = tr.window.sum(axis=2, dtype=np.float64)
    background = img[~lit].mean()
    return (img[lit].mean() - background) / background


def test_time_gate_gains_about_T_over_W():
    """Supplement A: gating W of T bins keeps the signal and W/T of the background -> SBR x T/W."""
    t_bins, w_bins = 200, 20
    rng = np.random.default_rng(5)
    lit = rng.random((64, 64)) < 0.5
    paths = rng.uniform(60, 140, (64, 64)) * ps_to_m(128.0)          # returns spread over the transient
    noise = NoiseSpec(photon_counts=True, photons_per_pixel=50.0, ambient_per_bin=1.0,
                      wavelength_filter_factor=0.5)
    expected = pulse_cube(make_sensor(bins=t_bins), paths, lit * 1.0)
    ungated, lay_u = apply_sensor(expected, make_sensor(bins=t_bins), noise, np.random.default_rng(1))
    gated, lay_g = apply_sensor(expected, make_sensor(bins=t_bins, gate=w_bins), noise, np.random.default_rng(1),
                                expected_path=paths)
    assert lay_u.kind == "dense" and (lay_g.kind, lay_g.window_bins) == ("windowed", w_bins)
    sbr_u, sbr_g = intensity_sbr(ungated, lit), intensity_sbr(gated, lit)
    # predicted: 50 / (0.5 * 200) = 0.5 ungated, 50 / (0.5 * 20) = 5 gated; statistical error ~1.3 %
    assert sbr_u == pytest.approx(0.5, rel=0.05)
    assert sbr_g / sbr_u == pytest.approx(t_bins / w_bins, rel=0.10)


def test_gate_is_centred_on_the_expected_path():
    s = make_sensor(w=3, h=1, bins=100, gate=10)
    path = np.array([[50.2, 2.0, 99.0]]) * s.bin_width_m
    st = gate_starts(path, s, 10)
    assert st.tolist() == [[45, 0, 90]]                               # centred, clipped at both ends
    assert gate_starts(np.array([[50.5]]) * s.bin_width_m, s, 5).tolist() == [[48]]   # bins 48..52 around 50.5
    assert gate_starts(np.array([[np.nan]]), s, 10).tolist() == [[-1]]
    # without a path the gate sits on the strongest window of the expected signal
    cube = pulse_cube(s, np.array([[30.5, 70.5, 10.5]]) * s.bin_width_m, np.ones((1, 3)))
    tr, _ = apply_sensor(cube, s, NoiseSpec(), np.random.default_rng(0))
    lo = tr.start_bin[0]
    assert np.all((lo <= np.array([30, 70, 10])) & (np.array([30, 70, 10]) < lo + 10))
    np.testing.assert_allclose(tr.window.sum(axis=2), 1.0, rtol=1e-4)


def test_empty_bins_not_stored_and_round_trip():
    s = make_sensor(w=16, h=8, bins=300)
    rng = np.random.default_rng(2)
    paths = rng.uniform(20, 280, (8, 16)) * s.bin_width_m
    cube = pulse_cube(s, paths, rng.uniform(0, 1, (8, 16)))
    cube[cube < 1e-6] = 0                                            # a compact pulse support
    cube[3, 4] = 0                                                   # an all-zero (shadowed) pixel
    tr, layout = apply_sensor(cube, s, NoiseSpec(), rng)
    assert layout.kind == "windowed" and layout.window_bins < 10
    np.testing.assert_array_equal(tr.dense(), cube)                  # nothing non-zero was dropped
    wide = widen_window(tr, 40)
    assert wide.window_bins == 40
    np.testing.assert_array_equal(wide.dense(), cube)
    # Poisson counts stay inside the stored windows too (zero rate -> zero counts)
    trp, layp = apply_sensor(cube, s, NoiseSpec(photon_counts=True, photons_per_pixel=100.0), rng)
    assert layp.window_bins == layout.window_bins


def run(cube, sensor, noise, seed, **kw):
    return apply_sensor(cube, sensor, noise, np.random.default_rng(seed), **kw)


def test_determinism_same_seed_same_bytes():
    s = make_sensor(w=32, h=32, bins=100)
    cube = pulse_cube(s, np.full((32, 32), 2.0), np.ones((32, 32)))
    noise = NoiseSpec(photon_counts=True, photons_per_pixel=20.0, ambient_per_bin=0.1)
    a, _ = run(cube, s, noise, 7)
    b, _ = run(cube, s, noise, 7)
    c, _ = run(cube, s, noise, 8)
    assert a.window.tobytes() == b.window.tobytes() and a.start_bin.tobytes() == b.start_bin.tobytes()
    assert a.window.tobytes() != c.window.tobytes()


def test_float16_storable_option():
    s = make_sensor(w=16, h=16, bins=50)
    cube = pulse_cube(s, np.full((16, 16), 1.0), np.ones((16, 16)))
    tr, layout = run(cube, s, NoiseSpec(photons_per_pixel=3000.0), 0, sample_type="float16")
    assert layout.sample_type == "float16" and tr.window.dtype == np.float32
    np.testing.assert_array_equal(tr.window.astype(np.float16).astype(np.float32), tr.window)
    assert tr.window.sum(axis=2).max() == pytest.approx(3000.0, rel=2e-3)
    with pytest.raises(ValueError, match="float16"):
        run(cube, s, NoiseSpec(photons_per_pixel=1e6), 0, sample_type="float16")


@pytest.mark.parametrize("noise", [NoiseSpec(), NoiseSpec(photon_counts=True, photons_per_pixel=100.0),
                                   NoiseSpec(photon_counts=True, photons_per_pixel=100.0, ambient_per_bin=0.5,
                                             wavelength_filter_factor=0.1, dark_counts_per_bin=0.01)])
@pytest.mark.parametrize("gate", [0, 8])
def test_all_zero_input_gives_finite_output(noise, gate):
    s = make_sensor(w=8, h=8, bins=40, gate=gate)
    tr, layout = run(np.zeros((8, 8, 40), np.float32), s, noise, 0)
    assert np.isfinite(tr.window).all() and (tr.window >= 0).all()
    if noise.ambient_per_bin == 0 and noise.dark_counts_per_bin == 0:
        assert not tr.window.any()
    assert layout.window_bins == (gate if gate else (40 if noise.ambient_per_bin else 1))


def test_bad_expected_input_is_a_clear_error():
    s = make_sensor(w=4, h=4, bins=10)
    cube = np.zeros((4, 4, 10), np.float32)
    cube[1, 1, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        run(cube, s, NoiseSpec(), 0)
    cube[1, 1, 1] = -1
    with pytest.raises(ValueError, match="negative"):
        run(cube, s, NoiseSpec(), 0)
    with pytest.raises(ValueError, match="shape"):
        run(np.zeros((4, 4, 11), np.float32), s, NoiseSpec(), 0)
    tiny = np.zeros((4, 4, 10), np.float32)
    tiny[0, 0, 3], tiny[0, 1, 3] = 1e-30, 1.0                       # scale 1e10 / 1e-30 overflows float32
    with pytest.raises(ValueError, match="photons_per_pixel"):
        run(tiny, s, NoiseSpec(photons_per_pixel=1e10), 0, first_bounce_pixel=(0, 1))


def test_spot_lighting_only_hidden_surfaces_keeps_its_first_bounce():
    """No visible pixel gets two-bounce light: the budget falls on the first-bounce return
    instead of scaling everything (the first bounce included) to zero."""
    from pipeline.sensor_model import photon_scale

    noise = NoiseSpec(photons_per_pixel=50.0)
    totals = np.zeros((4, 4))
    totals[2, 1] = 8.0                      # only the first-bounce pixel has light
    assert photon_scale(totals, noise, first_bounce_pixel=(2, 1)) == pytest.approx(50.0 / 8.0)
    assert photon_scale(np.zeros((4, 4)), noise, first_bounce_pixel=(2, 1)) == 1.0


@pytest.mark.parametrize("noise", [NoiseSpec(photons_per_pixel=100.0),
                                   NoiseSpec(photon_counts=True, photons_per_pixel=100.0)])
def test_windows_in_place_gives_the_same_samples(noise):
    """apply_sensor_windows(in_place=True) (the simulator's, one window less in memory) overwrites its input
    with exactly what the copying call returns, Poisson draws included (same seed)."""
    from pipeline.sensor_model import apply_sensor_windows

    s = make_sensor(w=8, h=6, bins=40)
    rng = np.random.default_rng(3)
    window = rng.random((6, 8, 12)).astype(np.float32) * (rng.random((6, 8, 1)) > 0.3)
    start = rng.integers(0, 28, (6, 8))
    ref, lay = apply_sensor_windows(start, window.copy(), s, noise, np.random.default_rng(7), first_bounce_pixel=(1, 2))
    buf = window.copy()
    out, lay2 = apply_sensor_windows(start, buf, s, noise, np.random.default_rng(7), first_bounce_pixel=(1, 2),
                                     in_place=True)
    assert lay == lay2
    np.testing.assert_array_equal(out.window, ref.window)
    np.testing.assert_array_equal(buf, ref.window)            # written into the caller's array
    assert not np.array_equal(ref.window, window)             # the copying call left its input alone
