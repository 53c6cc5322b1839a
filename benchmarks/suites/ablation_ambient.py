"""Ambient light: lidar without / with a time gate vs intensity (RGB) shadows, at several ambient levels.

Per ambient level A (Cycles cave-chair, Poisson counts, 1000 photons for the brightest two-bounce pixel,
A ambient photons per pixel per bin, preprocessing background 'median'), each row a fast fit through the
harness runners (suites/ablations.py: fit_row):
- lidar, gate off: the dense dataset (all 391 bins), matched-filter shadows;
- lidar, gate 32: the windowed dataset (32 bins kept per pixel);
- intensity (RGB) shadows: the gate-off dataset's transients summed over time (what a camera without
  time resolution records: two-bounce light + all ambient light), shadows by intensity ratio
  (torch_recon.rgb_shadow), distances still from the gate-off lidar. This isolates the shadow source;
  it is not S3-NeRF (which has no distances).
- intensity - laser-off: the same after subtracting one seeded laser-off exposure (Poisson counts of the
  background over the whole exposure), as a careful RGB system would: the ambient mean goes, its shot
  noise stays.
- no shadows (control): the gate-off lidar's distances with every shadow label dropped.
Every row also reports the agreement of its shadow masks with the reference: the noise-free, ambient-free
lidar masks (the base dataset, default preprocessing), over the pixels the reference labels. The ratio
threshold is chosen once, on the ambient-0 gate-off dataset, as the best shadow F1 against that reference
(never on test views, never on the level being reported).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from benchmarks.harness import Suite, runners
from benchmarks.harness.report import fmt
from benchmarks.suites.ablations import Settings as AblationSettings
from benchmarks.suites.ablations import dataset, fit_row

# log-spaced: two-bounce intensity falls off steeply (1/r^2, grazing cosines), so lit pixels reach
# ratios of 1e-3 to the brightest spot on the cave-chair scene
RATIO_CANDIDATES = (0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.15, 0.2, 0.3, 0.5, 0.7)
LASER_OFF_SEED = 7
VARIANTS = ("lidar gate off", "lidar gate 32", "intensity shadows", "intensity - laser-off", "no shadows (control)")


@dataclass(frozen=True)
class Settings(AblationSettings):
    variants: tuple[str, ...] = VARIANTS    # which of VARIANTS to fit (a shorter run on a busy machine)


def spot_intensities(ds, meas) -> np.ndarray:
    """(K, H, W) time-integrated intensity of each measured spot, from a gate-off dataset (a gated one
    has lost the light outside its window)."""
    from torch_recon.rgb_shadow import integrated_intensity
    if ds.manifest.sensor.time_gate.enabled:
        raise ValueError(f"{ds.root}: the sensor's time gate is on; intensity shadows need a gate-off dataset")
    return np.stack([integrated_intensity(ds.read_transient(s.spot_id)) for s in meas.spots])


def masks_of(meas):
    """(shadow, labelled, excluded) (K, H, W) bool of a Measurements."""
    sh = np.stack([np.asarray(s.shadow, bool) for s in meas.spots])
    sig = np.stack([np.asarray(s.signal, bool) & np.isfinite(s.path_length) for s in meas.spots])
    ex = np.stack([np.asarray(s.excluded, bool) for s in meas.spots])
    return sh & ~ex, (sh | sig) & ~ex, ex


def _none_for_nan(d: dict) -> dict:
    return {k: (None if isinstance(v, float) and np.isnan(v) else v) for k, v in d.items()}


def agreement(meas, ref) -> dict:
    """mask_agreement of meas's shadows with the reference masks (NaN: nothing to judge -> None)."""
    from torch_recon.rgb_shadow import mask_agreement
    return _none_for_nan(mask_agreement(masks_of(meas)[0], ref[0], ref[1]))


def threshold_table(intens, excluded, ref) -> list[dict]:
    from torch_recon.rgb_shadow import intensity_shadow_masks, mask_agreement
    return [_none_for_nan({"threshold": t, **mask_agreement(intensity_shadow_masks(intens, t, excluded)[0], *ref)})
            for t in RATIO_CANDIDATES]


def best_threshold(table) -> dict:
    """The entry with the best shadow F1 (ties: the smaller threshold)."""
    return max(table, key=lambda r: (-1.0 if r["shadow_f1"] is None else r["shadow_f1"], -r["threshold"]))


def laser_off_frame(ds, seed: int) -> np.ndarray:
    """(H, W) one exposure with the laser off: Poisson counts of the dataset's background rate over all
    T bins (the simulator's ambient light is uniform over pixels; seeded)."""
    n, s = ds.manifest.noise, ds.manifest.sensor
    rate = (n.ambient_per_bin * n.wavelength_filter_factor + n.dark_counts_per_bin) * s.bins
    return np.random.default_rng(seed).poisson(rate, (s.height, s.width)).astype(np.float64)


def run(s: Settings, ctx) -> list[dict]:
    from torch_recon.contract.dataset import load_dataset
    from torch_recon.measurements import Measurements
    from torch_recon.rgb_shadow import apply_intensity_shadows, intensity_shadow_masks

    ref_meas = Measurements.load(runners.preprocess(ctx, dataset(ctx, s), "ref-meas")["measurements"])
    ref = masks_of(ref_meas)[:2]
    ctx.log(f"  reference masks: noise-free lidar, {ref[1].sum()} labelled pairs, "
            f"{ref[0].sum() / max(ref[1].sum(), 1):.3f} shadow")

    done = {}

    def noisy(amb, gate):
        if (amb, gate) in done:
            return done[amb, gate]
        data = dataset(ctx, s, poisson=True, photons=1000, ambient=f"{amb:g}", time_gate=gate)
        prep = runners.preprocess(ctx, data, f"amb{amb:g}-gate{gate}-meas", background="median")
        done[amb, gate] = data, prep, Measurements.load(prep["measurements"])
        return done[amb, gate]

    data0, _, meas0 = noisy(0.0, 0)
    table = threshold_table(spot_intensities(load_dataset(data0), meas0), masks_of(meas0)[2], ref)
    threshold = best_threshold(table)["threshold"]
    ctx.log("  intensity ratio threshold on ambient 0 (F1 vs reference): "
            + ", ".join(f"{r['threshold']:g}:{fmt(r['shadow_f1'], '.3f')}" for r in table) + f" -> {threshold:g}")
    rows = []
    for amb in map(float, s.levels):
        common = {"ambient_per_bin": amb}
        for gate in (0, 32):
            variant = "lidar gate off" if gate == 0 else f"lidar gate {gate}"
            if gate and variant not in s.variants:
                continue
            data, prep, meas = noisy(amb, gate)
            if gate == 0:
                off = (data, prep, meas)
            if variant not in s.variants:
                continue
            rows.append(fit_row(ctx, s, f"ambient {amb:g}, gate {gate or 'off'}", data, prep, f"amb{amb:g}-gate{gate}",
                                variant=variant, gate_bins=gate, **common, **agreement(meas, ref)))
        data, prep, meas = off
        control = apply_intensity_shadows(meas, np.zeros((len(meas.spots), meas.height, meas.width), bool))
        if "no shadows (control)" in s.variants:
            rows.append(fit_row(ctx, s, f"ambient {amb:g}, no shadows", data, prep, f"amb{amb:g}-control",
                            transform=lambda _m, c=control: c, variant="no shadows (control)", gate_bins=0,
                            **common, **agreement(control, ref)))
        ds = load_dataset(data)
        intens = spot_intensities(ds, meas)
        excluded = masks_of(meas)[2]
        frame = laser_off_frame(ds, LASER_OFF_SEED)
        for variant, image in (("intensity shadows", intens), ("intensity - laser-off", np.clip(intens - frame, 0, None))):
            if variant not in s.variants:
                continue
            if variant == "intensity - laser-off" and not frame.any() and rows and rows[-1]["variant"] == "intensity shadows":
                rows.append({**rows[-1], "variant": variant, "level": f"ambient {amb:g}, {variant}",
                             "same_as": rows[-1]["level"]})
                continue
            sh, labelled = intensity_shadow_masks(image, threshold, excluded)
            rgb = apply_intensity_shadows(meas, sh)
            # the best any ratio threshold could do at this level (chosen on the reference: a bound, not a result)
            oracle = best_threshold(threshold_table(image, excluded, ref))
            rows.append(fit_row(ctx, s, f"ambient {amb:g}, {variant}", data, prep, f"amb{amb:g}-{'rgb' if variant == 'intensity shadows' else 'rgb-laser-off'}",
                                transform=lambda _m, m=rgb: m, variant=variant, gate_bins=0, **common,
                                ratio_threshold=threshold, intensity_unlabelled_pixels=int((~labelled).sum()),
                                oracle_ratio_threshold=oracle["threshold"], oracle_shadow_f1=oracle["shadow_f1"],
                                **agreement(rgb, ref)))
    rows[0]["ratio_threshold_table"] = table
    return rows


def _cell(r):
    if r is None:
        return "-"
    if runners.failure(r):
        return runners.failure(r)
    f1 = "-" if r.get("shadow_f1") is None else f"{r['shadow_f1']:.2f}"
    return f"{r['depth_l1_m']:.3f} m, F@2cm {fmt(r.get('obj_f2cm'), '.2f')} (shadow F1 {f1})"


def readme(results) -> str:
    """Depth L1, object F@2cm and shadow F1, ambient level x variant."""
    rows = results["rows"]
    lines = ["| ambient photons / pixel / bin | " + " | ".join(VARIANTS) + " |", "|" + "---|" * (len(VARIANTS) + 1)]
    for amb in dict.fromkeys(r["ambient_per_bin"] for r in rows):
        cells = [_cell(next((r for r in rows if r["ambient_per_bin"] == amb and r["variant"] == v), None))
                 for v in VARIANTS]
        lines.append(f"| {amb:g} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot(rows, settings, path) -> None:
    """Depth L1 and shadow F1 against ambient level, one line per variant."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    levels = sorted({r["ambient_per_bin"] for r in rows})
    xs = {a: i for i, a in enumerate(levels)}      # categorical: 0 cannot sit on a log axis
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(10, 4))
    for variant, style in zip(VARIANTS, ("o-", "s--", "^:", "v-.", "x:")):
        rs = [r for r in rows if r["variant"] == variant]
        x = [xs[r["ambient_per_bin"]] for r in rs]
        ax.plot(x, [np.nan if r["depth_l1_m"] is None else r["depth_l1_m"] for r in rs], style, label=variant)
        bx.plot(x, [np.nan if r["shadow_f1"] is None else r["shadow_f1"] for r in rs], style, label=variant)
    for a, lab in ((ax, "test-view depth L1 (m)"), (bx, "shadow F1 vs noise-free lidar")):
        a.set_xticks(range(len(levels)), [f"{v:g}" for v in levels])
        a.set_xlabel("ambient photons per pixel per bin")
        a.set_ylabel(lab)
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    ax.set_title("ablation: ambient light")
    bx.set_title("shadow masks")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


SUITE = Suite("ablation_ambient", "ablation: ambient light, lidar +- time gate vs intensity (RGB) shadows",
              quick=Settings(levels=("0", "1"), resolution=32, grid=48, steps=20, budget_s=60.0, test_views=6,
                             test_view_resolution=32),
              full=Settings(levels=("0", "0.1", "1", "10")), run=run, plot=plot,
              readme=readme, row_id=("method", "scene", "level"))
