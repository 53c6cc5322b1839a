"""Time gating (the simulator's sensor model): SBR gain of the gate against window length, and binning speed.

1. SBR gain of the time gate vs window length W at the paper's sensor (391 bins of 128 ps, 128 ps FWHM
   pulse): half the pixels lit by a two-bounce return at a random path, half in shadow, constant ambient
   background, Poisson counts. Measured: intensity-image SBR (I_lit - I_shadow) / I_shadow with the gate
   over the same without it; also the supplement's Eq. (3)/(5) form sum(s^2) / (N^2 W) with s and N
   estimated from the counts. Predicted: T / W, and T / W times the fraction of the pulse inside the
   window (narrow gates cut the pulse). One row per window (no time fields).
2. Speed at paper scale: bin_two_bounce at 512 x 512 x 391 with S = 4 sub-samples of a smooth box room
   (fresh output vs a reused buffer), and apply_sensor for three noise settings; one row each.
"""

from __future__ import annotations

import statistics
from dataclasses import dataclass

import numpy as np

from benchmarks.harness import Suite, report


@dataclass(frozen=True)
class Settings:
    resolution: int = 512        # binning benchmark sensor
    sbr_pixels: int = 128        # side of the SBR test image
    repeats: int = 3


WINDOWS = (1, 2, 3, 4, 6, 8, 16, 32, 64, 128, 256, 391)


def sbr_measures(tr, lit, path_bin):
    """Intensity SBR and the supplement's Eq. (5) SBR from stored counts (lit / shadow pixel masks).

    Eq. (5): sum_t s(t)^2 / (N^2 W), N the background counts per bin (from shadowed pixels),
    s(t) the mean lit-pixel counts minus N, with every lit pixel's bins aligned on its own return
    bin `path_bin` (so returns at different paths add up instead of smearing).
    """
    img = tr.window.sum(axis=2, dtype=np.float64)
    bg = img[~lit].mean()
    intensity = (img[lit].mean() - bg) / bg
    g = tr.window_bins
    li = np.flatnonzero(lit.ravel())
    counts = tr.window.reshape(-1, g)[li].astype(np.float64)
    rel = tr.start_bin.reshape(-1)[li][:, None] + np.arange(g) - path_bin.reshape(-1)[li][:, None]
    rel -= rel.min()
    sums = np.bincount(rel.ravel(), weights=counts.ravel())
    seen = np.bincount(rel.ravel())
    n_per_bin = float(tr.window[~lit].mean())
    s = sums[seen > 0] / seen[seen > 0] - n_per_bin
    eq5 = float(np.sum(s ** 2) / (n_per_bin ** 2 * g))
    return float(intensity), eq5


def _rel_sigma(signal, background, lit) -> float:
    """1-sigma relative error of the measured intensity SBR (Poisson counts, lit / shadow means)."""
    n_lit, n_sh = int(lit.sum()), int((~lit).sum())
    var_l = (signal + background) / n_lit
    var_b = background / n_sh
    sbr = signal / background
    return float(np.sqrt(var_l + var_b * (1 + sbr) ** 2) / background / sbr)


def sbr_curve(n_side: int, seed: int = 0):
    from pipeline.sensor_model import apply_sensor
    from torch_recon.contract.analytic import pulse_bin_weights
    from torch_recon.contract.dataset import NoiseSpec, SensorSpec, TimeGate
    from torch_recon.contract.units import ps_to_m

    t = 391
    base = dict(width=n_side, height=n_side, bins=t)
    rng = np.random.default_rng(seed)
    lit = rng.random((n_side, n_side)) < 0.5
    # returns at random bins, all at a bin centre: the pulse fraction inside a gate is then the same
    # for every pixel (one predicted curve)
    path_bin = rng.integers(60, 330, (n_side, n_side))
    paths = (path_bin + 0.5) * ps_to_m(128.0)
    sensor = SensorSpec(**base)
    wts = pulse_bin_weights(paths.ravel(), 0.0, sensor.bin_width_m, t, ps_to_m(128.0))
    expected = (wts * lit.ravel()[:, None]).reshape(n_side, n_side, t).astype(np.float32)
    noise = NoiseSpec(photon_counts=True, photons_per_pixel=20.0, ambient_per_bin=1.0, wavelength_filter_factor=0.1)
    ungated, _ = apply_sensor(expected, sensor, noise, np.random.default_rng(seed + 1))
    ref_int, ref_eq5 = sbr_measures(ungated, lit, path_bin)
    rows = []
    for w in WINDOWS:
        s = SensorSpec(**base, time_gate=TimeGate(True, w))
        tr, _ = apply_sensor(expected, s, noise, np.random.default_rng(seed + 1), expected_path=paths)
        g_int, g_eq5 = sbr_measures(tr, lit, path_bin)
        # fraction of the pulse inside each lit pixel's gate (signal the gate cuts away)
        idx = tr.start_bin[lit][:, None] + np.arange(w)
        inside = np.take_along_axis(wts[lit.ravel()], idx, axis=1)
        kept = float(inside.sum(axis=1).mean())
        kept_sq = float((np.sum(inside ** 2, axis=1) / np.sum(wts[lit.ravel()] ** 2, axis=1)).mean())
        b_w = noise.ambient_per_bin * noise.wavelength_filter_factor * w
        rows.append({"window_bins": w, "predicted_gain": t / w, "predicted_gain_pulse_cut": t / w * kept,
                     "predicted_gain_eq5_pulse_cut": t / w * kept_sq,
                     "intensity_gain_rel_sigma": float(np.hypot(_rel_sigma(20.0 * kept, b_w, lit),
                                                                _rel_sigma(20.0, b_w * t / w, lit))),
                     "pulse_fraction_in_window": kept, "measured_gain_intensity": g_int / ref_int,
                     "measured_gain_eq5": g_eq5 / ref_eq5, "sbr_intensity": g_int, "sbr_eq5": g_eq5})
    return rows, {"ungated_sbr_intensity": ref_int, "ungated_sbr_eq5": ref_eq5, "pixels": int(lit.size),
                  "lit_pixels": int(lit.sum()), "photons_per_pixel": 20.0,
                  "background_per_bin": noise.ambient_per_bin * noise.wavelength_filter_factor, "bins": t}


def room_samples(sensor, subpixel=2, lo=(-2.0, -1.0, -1.5), hi=(2.0, 4.5, 1.5)):
    """Sub-pixel world positions and normals of a box room seen from inside (smooth, with corners)."""
    from torch_recon.contract.frames import camera_ray_directions

    c2w = np.asarray(sensor.camera_to_world)
    c = c2w[:3, 3]
    g = (np.arange(subpixel) + 0.5) / subpixel - 0.5
    offs = np.stack(np.meshgrid(g, g, indexing="xy"), -1).reshape(-1, 2)
    d = camera_ray_directions(sensor.width, sensor.height, sensor.fov_rad, sensor.fov_axis, offs) @ c2w[:3, :3].T
    lo, hi = np.asarray(lo), np.asarray(hi)
    with np.errstate(divide="ignore", invalid="ignore"):
        tb = np.where(d > 0, (hi - c) / d, (lo - c) / d)
    tb[~np.isfinite(tb)] = np.inf
    ax = np.argmin(tb, -1)
    x = c + np.take_along_axis(tb, ax[..., None], -1) * d
    n = np.zeros_like(x)
    np.put_along_axis(n, ax[..., None], -np.sign(np.take_along_axis(d, ax[..., None], -1)), -1)
    return x.astype(np.float32), n


def speed(ctx, res: int, repeats: int) -> list[dict]:
    """Rows of binning and sensor-model timings on a box room at res x res."""
    from pipeline.sensor_model import apply_sensor
    from pipeline.transient_binning import bin_two_bounce, expected_return_path
    from torch_recon.contract.dataset import NoiseSpec, SensorSpec, TimeGate
    from torch_recon.contract.frames import look_at_c2w

    sensor = SensorSpec(width=res, height=res, camera_to_world=look_at_c2w((0, 0, 0), (0, 1, 0)).tolist())
    x, n = room_samples(sensor)
    l, nl = np.array([0.5, 4.5, 0.2]), np.array([0.0, -1.0, 0.0])
    v = l - x
    r = np.linalg.norm(v, axis=-1)
    u = v / np.maximum(r, 1e-9)[..., None]
    rad = (np.clip(np.sum(n * u, -1), 0, None) * np.clip(-(u @ nl), 0, None) / np.maximum(r, 1e-3) ** 2)
    rad = rad.astype(np.float32)
    valid = np.ones(rad.shape, bool)
    o = np.zeros(3)
    scene = f"box room {res} x {res} x {sensor.bins}, S={x.shape[0]}"
    with ctx.timed() as first:
        cube = bin_two_bounce(x, rad, valid, l, o, o, sensor)
    rows = [{"method": "bin_two_bounce, fresh output", "scene": scene, **first.times(), "cube_mb": cube.nbytes / 2 ** 20}]
    reuse, single = [], []
    for _ in range(repeats):
        with ctx.timed() as t:
            bin_two_bounce(x, rad, valid, l, o, o, sensor, out=cube)
        reuse.append(t)
        with ctx.timed() as t:
            bin_two_bounce(x, rad, valid, l, o, o, sensor, out=cube, threads=1)
        single.append(t)
    for name, ts in (("bin_two_bounce, reused buffer", reuse), ("bin_two_bounce, reused buffer, 1 thread", single)):
        rows.append({"method": name, "scene": scene, "wall_s": statistics.median(t.wall_s for t in ts),
                     "cpu_s": statistics.median(t.cpu_s for t in ts), "peak_rss_mb": max(t.peak_rss_mb for t in ts),
                     "min_wall_s": min(t.wall_s for t in ts), "repeats": repeats})
    path = expected_return_path(x, valid, l, o, o)
    noisy = NoiseSpec(photon_counts=True, photons_per_pixel=1000.0, ambient_per_bin=0.05)
    for name, noise, gate in (("expected values", NoiseSpec(), TimeGate()), ("poisson, gate 32", noisy, TimeGate(True, 32)),
                              ("poisson + ambient, dense", noisy, TimeGate())):
        s = SensorSpec(**{**sensor.__dict__, "time_gate": gate})
        with ctx.timed() as t:
            tr, layout = apply_sensor(cube, s, noise, np.random.default_rng(0), expected_path=path)
        rows.append({"method": f"apply_sensor, {name}", "scene": scene, **t.times(), "window_bins": layout.window_bins})
        del tr
    return rows


def run(s: Settings, ctx) -> list[dict]:
    curve, ref = sbr_curve(s.sbr_pixels)
    ctx.log(f"  ungated SBR: intensity {ref['ungated_sbr_intensity']:.4f}, Eq.5 {ref['ungated_sbr_eq5']:.5f}")
    rows = [{"method": f"gate {r['window_bins']} bins", "scene": f"half-lit {s.sbr_pixels} px, Poisson",
             "wall_s": None, "cpu_s": None, "peak_rss_mb": None, **r, **{f"ungated_{k}": v for k, v in ref.items()}}
            for r in curve]
    for r in rows:
        ctx.log(f"  W={r['window_bins']:>3}: T/W {r['predicted_gain']:7.2f}, with pulse cut {r['predicted_gain_pulse_cut']:7.2f},"
                f" measured {r['measured_gain_intensity']:7.2f}")
    return rows + speed(ctx, s.resolution, s.repeats)


def plot(rows, settings, path):
    rows = [r for r in rows if "window_bins" in r and "predicted_gain" in r]
    w = [r["window_bins"] for r in rows]
    with report.figure(path, (5.5, 4), dpi=120) as ax:
        ax.loglog(w, [r["predicted_gain"] for r in rows], "k--", label="predicted T/W")
        ax.loglog(w, [r["predicted_gain_pulse_cut"] for r in rows], "k:", label="T/W x pulse fraction in window")
        ax.loglog(w, [r["predicted_gain_eq5_pulse_cut"] for r in rows], ":", color="grey",
                  label="T/W x squared-pulse fraction (Eq. 5)")
        ax.loglog(w, [r["measured_gain_intensity"] for r in rows], "o-", label="measured (intensity SBR)")
        ax.loglog(w, [r["measured_gain_eq5"] for r in rows], "s-", mfc="none", label="measured (supplement Eq. 5)")
        ax.set_xlabel("gate window W (bins of 128 ps)")
        ax.set_ylabel("SBR gain over ungated (T = 391 bins)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)


def readme(results) -> str:
    sbr = [r for r in results["rows"] if "predicted_gain" in r]
    speed_rows = [r for r in results["rows"] if "predicted_gain" not in r]
    return (report.markdown_table(sbr, [("window_bins", "window W (bins)"), ("predicted_gain", "T/W"),
                                        ("predicted_gain_pulse_cut", "T/W x kept pulse"),
                                        ("measured_gain_intensity", "measured gain (intensity)"),
                                        ("measured_gain_eq5", "measured gain (Eq. 5)")])
            + "\n\n" + report.markdown_table(speed_rows, [("method", "operation"), ("scene", "data"), ("wall_s", "wall s"),
                                                          ("cpu_s", "CPU s")]))


SUITE = Suite("gating", __doc__.splitlines()[0], run=run, plot=plot, readme=readme,
              quick=Settings(resolution=128, sbr_pixels=64, repeats=1), full=Settings())
