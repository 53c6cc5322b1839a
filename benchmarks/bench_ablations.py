"""The paper's ablations, run with the fast mode: one table + one plot per ablation.

    python benchmarks/bench_ablations.py --quick            # subsets of the levels, 64 px, short budgets
    python benchmarks/bench_ablations.py                    # every level (spatial 512 px included)
    python benchmarks/bench_ablations.py --only spots       # one ablation: spots, shadow, spatial,
                                                            # temporal, ambient, scenes

Data: Cycles datasets of the example scenes (pipeline/simulate.py, 16 of the paper's spots, 391
bins of 128 ps, noise-free unless stated), cached under benchmarks/results/data/. Every row is a
fast-mode fit (torch_recon.recon) with the same grid and training budget, evaluated by depth L1 /
PSNR on the dataset's test views (volume-rendered depth; benchmarks/recon_harness.py).
- spots: 16 / 8 / 4 / 2 spots: every 2nd / 4th / 8th of the 16 (by id), measurements re-fused
  (paper, its Table: 0.0862 / 0.0912 / 0.1347 / 0.2147 m);
- shadow: matched-filter shadow threshold 0 to 1 in steps of 0.125 (paper default 0.15);
- spatial: sensor resolution 512 / 128 / 64 / 32 px (simulated at each);
- temporal: 128 / 256 / 512 / 1024 ps bins, by summing 1 / 2 / 4 / 8 adjacent bins of the 128 ps
  dataset (as the paper did; recon_harness.integrate_bins);
- ambient: Poisson counts (1000 photons for the brightest pixel) plus ambient photons per pixel per bin,
  without and with a 32-bin time gate; preprocessing subtracts each pixel's median (background 'median');
  plus intensity (RGB) shadows from the gate-off transients summed over time (with and without a
  subtracted laser-off frame), and every variant's shadow-mask agreement with the noise-free lidar
  masks (benchmarks/ablation_rgb.py);
- scenes: cave-chair vs low-albedo walls vs a curved back wall.
Writes benchmarks/results/ablation_<name>.json and .png.
"""

from __future__ import annotations

import argparse
import copy
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import ablation_rgb  # noqa: E402
from benchmarks.common import RESULTS_DIR, machine_info, machine_line, timer, write_json  # noqa: E402
from torch_recon.recon import UnconstrainedMeasurementsError  # noqa: E402
from benchmarks.recon_harness import DATA_DIR, Views, ensure_dataset, integrate_bins, preprocess, run_fit  # noqa: E402

PAPER_SPOTS = {16: 0.0862, 8: 0.0912, 4: 0.1347, 2: 0.2147}
ABLATIONS = ("spots", "shadow", "spatial", "temporal", "ambient", "scenes")


def parse(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="subsets of the levels, short budgets")
    ap.add_argument("--only", help=f"comma-separated ablations of {list(ABLATIONS)}")
    ap.add_argument("--res", type=int, help="sensor resolution of the base dataset (default 64)")
    ap.add_argument("--budget", type=float, help="fast-mode training budget per row, s (quick 10, full 60)")
    ap.add_argument("--steps", type=int, help="fixed training steps per row (no time budget unless --budget): "
                    "rows stay comparable on a machine shared with other jobs")
    ap.add_argument("--grid", type=int, default=96, help="fast-mode grid resolution")
    ap.add_argument("--test-views", type=int, help="test views (default 24)")
    ap.add_argument("--threads", type=int, default=2)
    a = ap.parse_args(argv)
    a.only = a.only.split(",") if a.only else list(ABLATIONS)
    bad = set(a.only) - set(ABLATIONS)
    if bad:
        ap.error(f"unknown ablation(s) {sorted(bad)}; choose from {list(ABLATIONS)}")
    a.res = a.res or 64
    if a.steps is not None and a.steps < 1:
        ap.error(f"--steps: expected a positive step count, got {a.steps}")
    a.budget = a.budget or (None if a.steps else 10.0 if a.quick else 60.0)
    a.test_views = a.test_views or 24
    a.view_res = 64
    return a


class Runner:
    def __init__(self, a):
        self.a = a

    def dataset(self, scene="cave-chair", res=None, extra=()):
        return ensure_dataset(scene, res or self.a.res, self.a.test_views, self.a.view_res, extra)[0]

    def fit_row(self, level, meas, views, prep_s, **extra):
        signal = float(sum(s.signal.mean() for s in meas.spots) / len(meas.spots))
        try:
            r = run_fit(meas, views, "fast", self.a.budget, self.a.grid, threads=self.a.threads,
                        prep_seconds=prep_s, steps=self.a.steps)
        except UnconstrainedMeasurementsError as exc:   # e.g. a threshold that marks every pixel shadow
            print(f"    {str(level):>24s}  refused: {exc}", flush=True)
            return {"level": level, "depth_l1_m": None, "depth_psnr_db": None, "refused": str(exc),
                    "preprocess_seconds": prep_s, "signal_fraction": signal, **extra}
        row = {"level": level, "depth_l1_m": r["depth_l1_m"], "depth_psnr_db": r["depth_psnr_db"],
               "view_l1_median_m": r.get("view_l1_median_m"),
               "wall_seconds": r["wall_seconds"], "preprocess_seconds": prep_s, "steps": r["steps"],
               "signal_fraction": signal, **extra}
        print(f"    {str(level):>24s}  L1 {row['depth_l1_m']:.4f} m  PSNR {row['depth_psnr_db']:5.2f} dB  "
              f"wall {row['wall_seconds']:5.1f} s  signal {row['signal_fraction']:.2f}", flush=True)
        return row

    def path_row(self, level, path, **prep):
        ds, meas, prep_s = preprocess(path, **prep)
        return self.fit_row(level, meas, Views(ds), prep_s)

    # -- ablations --------------------------------------------------------------------------
    def spots(self):
        from torch_recon.visible_depth import fuse_visible_depth
        ds, meas, prep_s = preprocess(self.dataset())
        views, rows = Views(ds), []
        for k in (16, 8, 4, 2):
            m = copy.copy(meas)
            m.spots = meas.spots[::max(1, len(meas.spots) // k)][:k]
            fused = fuse_visible_depth(m)
            m.visible_depth, m.visible_confidence = fused.depth, fused.confidence
            rows.append(self.fit_row(k, m, views, prep_s, paper_depth_l1_m=PAPER_SPOTS.get(k)))
        return rows

    def shadow(self):
        path = self.dataset()
        levels = [0.0, 0.125, 0.25, 0.5, 1.0] if self.a.quick else [i * 0.125 for i in range(9)]
        return [self.path_row(t, path, shadow_threshold=t) for t in levels]

    def spatial(self):
        levels = [32, 64] if self.a.quick else [32, 64, 128, 512]
        return [self.path_row(res, self.dataset(res=res)) for res in levels]

    def temporal(self):
        base = self.dataset()
        rows = []
        for f in (1, 2, 4, 8):
            path = base if f == 1 else integrate_bins(base, DATA_DIR / f"{base.name}-x{f}", f)
            rows.append(self.path_row(f"{128 * f} ps", path))
        return rows

    def ambient(self):
        """Lidar gate off / gate 32 / intensity (RGB) shadows per ambient level (benchmarks/ablation_rgb.py)."""
        return ablation_rgb.ambient_rows(self, [0.0, 1.0] if self.a.quick else [0.0, 0.1, 1.0, 10.0])

    def scenes(self):
        return [self.path_row(s, self.dataset(scene=s)) for s in ("cave-chair", "low-albedo", "curved-wall")]


def plot(name, rows, path):
    if name == "ambient":
        return ablation_rgb.plot(rows, path)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.5, 4))
    xs = list(range(len(rows)))
    nan = float("nan")      # refused rows (no result) leave a gap
    ax.plot(xs, [nan if r["depth_l1_m"] is None else r["depth_l1_m"] for r in rows], "o-",
            label="fast mode (this machine)")
    if name == "spots":
        ax.plot(xs, [r["paper_depth_l1_m"] for r in rows], "s--", color="gray", label="paper PlatoNeRF")
    ax.set_xticks(xs, [str(r["level"]) for r in rows], rotation=30 if name == "ambient" else 0, fontsize=8)
    ax.set_ylabel("test-view depth L1 (m)")
    ax.set_title(f"ablation: {name}")
    ax.grid(alpha=0.3)
    ax2 = ax.twinx()
    ax2.plot(xs, [nan if r["depth_psnr_db"] is None else r["depth_psnr_db"] for r in rows], "^:",
             color="tab:orange", label="PSNR (dB)")
    ax2.set_ylabel("PSNR (dB)", color="tab:orange")
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    a = parse(argv)
    info = machine_info()
    print(machine_line(info) + f"; fits use {a.threads} threads, fast mode grid {a.grid}, " +
          (f"{a.steps} steps" if a.steps else "") + (" and " if a.steps and a.budget else "") +
          (f"{a.budget:g} s" if a.budget else "") + f" per row, base {a.res} px")
    runner = Runner(a)
    for name in a.only:
        print(f"\nablation: {name}", flush=True)
        with timer() as t:
            rows = getattr(runner, name)()
        print(f"  {'level':>24s} {'L1 m':>8s} {'PSNR dB':>8s} {'wall s':>7s}" + ("  paper L1 m" if name == "spots" else ""))
        for r in rows:
            if r.get("refused"):
                print(f"  {str(r['level']):>24s} refused by fit: {r['refused']}")
                continue
            print(f"  {str(r['level']):>24s} {r['depth_l1_m']:8.4f} {r['depth_psnr_db']:8.2f} {r['wall_seconds']:7.1f}"
                  + (f"  {r['paper_depth_l1_m']}" if name == "spots" else ""))
        if name == "ambient":
            ablation_rgb.print_table(rows)
        out = RESULTS_DIR / f"ablation_{name}.json"
        write_json(out, {**({"rgb_threshold_table": runner.rgb_threshold_table} if name == "ambient" else {}),
                         "machine": info, "command": "python benchmarks/bench_ablations.py " +
                         " ".join(argv if argv is not None else sys.argv[1:]), "ablation": name,
                         "settings": {k: v for k, v in vars(a).items() if k != "only"}, "rows": rows,
                         "seconds": t.seconds})
        plot(name, rows, out.with_suffix(".png"))
        print(f"  ({t.seconds:.0f} s) wrote {out} and {out.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
