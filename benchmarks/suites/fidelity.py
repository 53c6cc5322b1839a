"""Simulator fidelity: Cycles simulator vs the analytic renderer, per spot and pooled, with time beside each.

For each sampling setting (the default adaptive sampling, and fixed sub-sample counts), runs
pipeline/simulate.py (noise-free, radiance units) and compares every spot with
torch_recon.contract.analytic rendered at `reference_subpixel`^2 stratified samples per pixel
(the footprint-integrated expectation):
- within_1_bin: lit pixels (reference energy above 1e-3 of its median; the first-bounce pixel
  left out) whose histogram peak lies within +-1 bin of the reference's peak;
- shadow_iou: IoU of the lit masks (energy above 1e-6 of the median lit pixel's: penumbra pixels
  count as lit, rounding noise ~1e-16 on surfaces coplanar with the spot does not);
- energy ratio simulated / reference per lit pixel: 1st, 50th and 99th percentile.
Goals (issue 14): within_1_bin >= 0.99 and shadow_iou >= 0.98.

Suite fidelity_mitransient (setting reference='mitransient'; its own results JSON): the same
metrics against mitransient, an independent path tracer (benchmarks/mitransient_reference.py,
optional: refused with one line when it is not installed), `reference_spp` jittered samples per
pixel. Its laser is a point light (energy ~ cos(theta_in) / |l - o|^2 at the spot, in its own units)
where the simulator's is a collimated beam, so each spot's reference cube is first scaled by one
factor: the simulated / reference energy summed over the pixels both light (first-bounce pixel
out). laser_constant = factor * cos(theta_in) / |l - o|^2 must then be the same for every spot.
It records no one-bounce return: the first-bounce pixel (the simulated cube's brightest) is left
out. Both sample the spot as a point, so partly lit pixels are footprint-partial only.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from benchmarks.harness import Suite
from torch_recon.contract.errors import SettingsError

SIMULATE = "pipeline/simulate.py"
LIT_FLOOR = 1e-6
#: (label, extra simulate.py options); 'default' is the adaptive sampling the simulator uses by default
SAMPLINGS = {"default": [], "fixed 1": ["--subpixel", "1", "--adaptive", "0"],
             "fixed 4": ["--subpixel", "4", "--adaptive", "0"], "fixed 16": ["--subpixel", "16", "--adaptive", "0"],
             "fixed 64": ["--subpixel", "64", "--adaptive", "0"]}


@dataclass(frozen=True)
class Settings:
    example: str = "cave-chair"
    resolution: int = 128
    spots: int = 16
    samplings: tuple[str, ...] = ("default", "fixed 1", "fixed 4", "fixed 16", "fixed 64")
    reference_subpixel: int = 16       # the analytic reference's samples per pixel side
    reference_batch: int = 4           # spots per analytic call (memory: batch x H x W x T float64)
    reference: str = "analytic"        # or "mitransient" (suite fidelity_mitransient)
    reference_spp: int = 1024          # mitransient's samples per pixel
    reference_seeds: int = 2           # mitransient renders per spot: the 2nd measures the reference's own noise

    def __post_init__(self):
        if self.reference not in REFERENCES:
            raise SettingsError("reference", f"expected one of {', '.join(REFERENCES)}, got {self.reference!r}")


REFERENCES = {"analytic": "fidelity", "mitransient": "fidelity_mitransient"}     # reference -> the suite that runs it


@dataclass(frozen=True)
class FidelitySuite(Suite):
    """A fidelity suite: its settings also refuse a reference it does not write (each reference has its
    own suite, so its own results JSON) and mitransient when it is not installed."""

    def settings(self, quick: bool, overrides=()):
        st = super().settings(quick, overrides)
        if st.reference == "mitransient":
            from benchmarks.mitransient_reference import missing
            why = missing()
            if why:
                raise SettingsError("reference", why)
        if REFERENCES[st.reference] != self.name:
            raise SettingsError("reference", f"suite {self.name} does not measure against {st.reference}: "
                                f"run `python -m benchmarks run {REFERENCES[st.reference]}` (its own results JSON)")
        return st


def reference_cubes(example: str, sensor, directions, subpixel: int, batch: int) -> list:
    """Analytic expected transients (H, W, T) per laser direction."""
    from torch_recon.contract import analytic, scenes

    mesh, albedo = scenes.example(example).trimesh()
    out = []
    for a in range(0, len(directions), batch):
        cubes = analytic.render_two_bounce(mesh, sensor, directions[a:a + batch], albedo=albedo, subpixel=subpixel)
        out.extend(list(cubes))
    return out


def compare(cube: np.ndarray, ref: np.ndarray, first_bounce=None) -> dict:
    """Agreement of one spot's simulated (H, W, T) cube with the reference cube (same units).
    `first_bounce`: the (row, column) left out; default the reference's brightest pixel."""
    e, e_ref = cube.sum(-1, dtype=np.float64), ref.sum(-1, dtype=np.float64)
    fb = np.unravel_index(np.argmax(e_ref), e_ref.shape) if first_bounce is None else first_bounce
    e[fb] = e_ref[fb] = 0.0
    floor = LIT_FLOOR * np.median(e_ref[e_ref > 0]) if (e_ref > 0).any() else 0.0
    mask, mask_ref = e > floor, e_ref > floor
    union = (mask | mask_ref).sum()
    lit = e_ref > 1e-3 * np.median(e_ref[mask_ref]) if mask_ref.any() else mask_ref
    peak_ok = np.abs(cube.argmax(-1).astype(np.int64) - ref.argmax(-1)) <= 1
    ratio = e[lit] / e_ref[lit]
    return {"lit_pixels": int(lit.sum()), "within_1_bin": float(peak_ok[lit].mean()) if lit.any() else float("nan"),
            "shadow_iou": float((mask & mask_ref).sum() / union) if union else 1.0,
            "dark_where_lit": int((~mask & mask_ref).sum()), "lit_where_dark": int((mask & ~mask_ref).sum()),
            "ratios": ratio, "mask": mask, "mask_ref": mask_ref, "lit": lit, "peak_ok": peak_ok}


def _row(label, scene, times, spot, m):
    p1, p50, p99 = np.percentile(m["ratios"], [1, 50, 99]) if len(m["ratios"]) else (np.nan,) * 3
    return {"method": label, "scene": scene, **times, "spot": spot, "lit_pixels": m["lit_pixels"],
            "within_1_bin": m["within_1_bin"], "shadow_iou": m["shadow_iou"], "dark_where_lit": m["dark_where_lit"],
            "lit_where_dark": m["lit_where_dark"], "energy_ratio_p1": float(p1), "energy_ratio_p50": float(p50),
            "energy_ratio_p99": float(p99)}


def run(s: Settings, ctx) -> list[dict]:
    from torch_recon.contract.dataset import load_dataset

    rows, refs = [], None
    for label in s.samplings:
        out = ctx.work_dir / label.replace(" ", "_")
        r = ctx.run_cli(["python", SIMULATE, "--example", s.example, "--resolution", str(s.resolution),
                         "--spots", str(s.spots), "--photons", "0", "--no-gt", *SAMPLINGS[label], "--out", str(out)])
        times = r.times()
        ds = load_dataset(out)
        spots = [(spot, tr.dense()) for spot, tr in ds.iter_transients()]
        if refs is None and s.reference == "mitransient":
            from benchmarks.suites.fidelity_mitransient import reference_spots
            refs = reference_spots(s, ds.sensor, spots, ctx)
        elif refs is None:
            with ctx.timed() as t:
                refs = reference_cubes(s.example, ds.sensor, [sp.laser_direction for sp, _ in spots],
                                       s.reference_subpixel, s.reference_batch)
            ctx.log(f"  analytic reference ({s.reference_subpixel}^2 samples/pixel): {t.wall_s:.1f} s")
        per = []
        for (spot, cube), ref in zip(spots, refs):
            if s.reference == "mitransient":
                from benchmarks.suites.fidelity_mitransient import compare_to_mitransient
                m, extra = compare_to_mitransient(cube, ref)
            else:
                m, extra = compare(cube, ref), {}
            per.append(m)
            rows.append({**_row(label, s.example, times, spot.id, m), **extra})
        pooled = {"lit_pixels": sum(m["lit_pixels"] for m in per),
                  "within_1_bin": float(np.average([m["within_1_bin"] for m in per],
                                                   weights=[m["lit_pixels"] for m in per])),
                  "shadow_iou": float(np.mean([m["shadow_iou"] for m in per])),
                  "dark_where_lit": sum(m["dark_where_lit"] for m in per),
                  "lit_where_dark": sum(m["lit_where_dark"] for m in per),
                  "ratios": np.concatenate([m["ratios"] for m in per])}
        rows.append(_row(label, s.example, times, "pooled", pooled))
        worst = min(m["within_1_bin"] for m in per)
        ctx.log(f"  {label}: {times['wall_s']:.1f} s wall, {times['cpu_s']:.1f} s CPU; within +-1 bin "
                f"{100 * pooled['within_1_bin']:.2f} % (worst spot {100 * worst:.2f} %), shadow IoU mean "
                f"{pooled['shadow_iou']:.4f} (worst {min(m['shadow_iou'] for m in per):.4f})")
    return rows


def plot(rows, settings, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pooled = [r for r in rows if r["spot"] == "pooled"]
    scenes = list(dict.fromkeys(r["scene"] for r in pooled))
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    for ax, key, goal, name in ((axes[0], "within_1_bin", 0.99, "lit pixels with peak within +-1 bin"),
                                (axes[1], "shadow_iou", 0.98, "shadow-mask IoU (mean over spots)")):
        for r in pooled:
            ax.plot(r["wall_s"], r[key], "o")
            label = r["method"] if len(scenes) == 1 else f"{r['method']} ({r['scene']})"     # runs merged
            ax.annotate(label, (r["wall_s"], r[key]), fontsize=7, xytext=(3, 3), textcoords="offset points")
        ax.axhline(goal, color="r", ls="--", lw=1, label=f"goal {goal}")
        ax.set_xlabel("simulate.py wall s")
        ax.set_title(name, fontsize=9)
        ax.legend(fontsize=7)
    fig.suptitle(f"{' + '.join(scenes)} {settings.resolution} x {settings.resolution}, {settings.spots} spots, "
                 f"vs {_reference_name(settings)}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _reference_name(s) -> str:
    if s.reference == "mitransient":
        return f"mitransient at {s.reference_seeds} x {s.reference_spp} samples/pixel"
    return f"analytic at {s.reference_subpixel}^2 samples/pixel"


def readme(results) -> str:
    lines = ["| sampling | wall s | CPU s | within +-1 bin (pooled / worst spot) | shadow IoU (mean / worst) | "
             "energy ratio p1 / p50 / p99 |", "|---|---|---|---|---|---|"]
    rows = results["rows"]
    for r in rows:
        if r["spot"] != "pooled":
            continue
        per = [q for q in rows if q["method"] == r["method"] and q["spot"] != "pooled"]
        lines.append(f"| {r['method']} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | {100 * r['within_1_bin']:.2f} % / "
                     f"{100 * min(q['within_1_bin'] for q in per):.2f} % | {r['shadow_iou']:.4f} / "
                     f"{min(q['shadow_iou'] for q in per):.4f} | {r['energy_ratio_p1']:.3f} / "
                     f"{r['energy_ratio_p50']:.3f} / {r['energy_ratio_p99']:.3f} |")
    return "\n".join(lines)


SUITE = FidelitySuite("fidelity", __doc__.splitlines()[0], run=run, plot=plot, readme=readme,
              quick=Settings(resolution=64, spots=2, samplings=("default", "fixed 4"), reference_subpixel=8),
              full=Settings())
