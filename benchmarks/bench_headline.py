"""Headline benchmark: test-view depth error against wall time, fast mode vs the PlatoNeRF reference vs BF Lidar.

    python benchmarks/bench_headline.py --quick        # 64 x 64, 6 test views, short budgets (a few minutes)
    python benchmarks/bench_headline.py                # 64 and 128 px, 24 test views, budgets up to 300 s
    python benchmarks/bench_headline.py --scenes cave-chair --res 128 --budgets 60 300 --grids 128

Data: Cycles datasets of the example scenes 'cave-chair' (the paper's room and chair) and
'occluders' (two boxes hiding each other), 16 of the paper's spots, 391 bins of 128 ps, from
pipeline/simulate.py, cached under benchmarks/results/data/. Methods, each on the same
preprocessed measurements and the same machine:
- fast mode (torch_recon.recon, mode 'fast') at several time budgets and grid resolutions;
- the 'platonerf' reference mode (the published NeRF method) with a time budget;
- the BF Lidar baseline (torch_recon.bflidar), occupancy threshold tuned on half the test views.
Error: depth L1 (m) and PSNR (dB) on the dataset's test views (the paper's dolly + orbit, subsampled),
volume-rendered depth for density fields, ray-cast depth for BF Lidar's mesh. Wall time: preprocessing +
fit setup + training (or carving); evaluation excluded. Curves: the fits are evaluated every few
seconds of training, so each run also gives the time at which it first reached the paper's 0.0862 m.
Writes benchmarks/results/headline.json and headline.png (L1 and PSNR against time, Pareto front marked).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.common import RESULTS_DIR, machine_info, machine_line, peak_rss_mb, timer, write_json  # noqa: E402
from benchmarks.recon_harness import (PAPER_L1_M, PAPER_PSNR_DB, Views, ensure_dataset, pareto,  # noqa: E402
                                      preprocess, run_bflidar, run_fit, time_to_reach)


def parse(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="64 x 64, budgets 15/45 s, reference 30 s")
    ap.add_argument("--scenes", nargs="+", default=["cave-chair", "occluders"])
    ap.add_argument("--res", type=int, nargs="+", help="sensor resolutions (default quick 64; full 64 128)")
    ap.add_argument("--budgets", type=float, nargs="+", help="fast-mode training budgets, s")
    ap.add_argument("--grids", type=int, nargs="+", help="fast-mode grid resolutions")
    ap.add_argument("--reference-budget", type=float, help="platonerf-mode training budget, s")
    ap.add_argument("--ref-volume", type=int, help="platonerf volume grid for its mesh (default quick 64, full 128)")
    ap.add_argument("--test-views", type=int, help="test views simulated (default 24: 7 dolly + 17 orbit)")
    ap.add_argument("--view-res", type=int, help="test-view resolution (default quick 64, full 128)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--no-reference", action="store_true", help="skip the platonerf mode")
    ap.add_argument("--out", default=str(RESULTS_DIR / "headline.json"))
    a = ap.parse_args(argv)
    q = a.quick
    a.res = a.res or ([64] if q else [64, 128])
    a.budgets = a.budgets or ([15.0, 45.0] if q else [30.0, 60.0, 120.0, 300.0])
    a.grids = a.grids or ([64] if q else [96, 128, 160])
    a.reference_budget = a.reference_budget or (30.0 if q else 900.0)
    a.ref_volume = a.ref_volume or (64 if q else 128)
    a.test_views = a.test_views or 24
    a.view_res = a.view_res or (64 if q else 128)
    return a


def scene_runs(scene, a, log=print) -> list:
    runs = []
    for res in a.res:
        path, sim_s = ensure_dataset(scene, res, a.test_views, a.view_res)
        ds, meas, prep_s = preprocess(path)
        views = Views(ds)
        log(f"  {scene} {res}px: dataset {path.name} ({'cached' if sim_s is None else f'simulated in {sim_s:.0f} s'}),"
            f" preprocessing {prep_s:.1f} s, {len(views.cams)} test views")
        common = {"scene": scene, "resolution": res, "dataset": path.name}
        for grid in a.grids:
            for b in (a.budgets if grid == a.grids[0] else a.budgets[-1:]):   # all budgets on the first grid
                r = run_fit(meas, views, "fast", b, grid, eval_every_s=max(3.0, b / 6), threads=a.threads,
                            prep_seconds=prep_s, label=f"fast g{grid} {b:g}s {res}px")
                runs.append({**common, **r})
                log(f"    {r['label']:26s} L1 {r['depth_l1_m']:.4f} m  PSNR {r['depth_psnr_db']:5.2f} dB  "
                    f"wall {r['wall_seconds']:6.1f} s  ({r['steps']} steps, {r['stopped']})")
        if res == a.res[-1] and not a.no_reference:
            b = a.reference_budget
            # no curve: each evaluation would need the MLP's volume (minutes); volume grid as --ref-volume
            r = run_fit(meas, views, "platonerf", b, threads=a.threads, prep_seconds=prep_s,
                        label=f"platonerf {b:g}s {res}px", sets=[f"platonerf.volume_resolution={a.ref_volume}"])
            runs.append({**common, **r})
            log(f"    {r['label']:26s} L1 {r['depth_l1_m']:.4f} m  PSNR {r['depth_psnr_db']:5.2f} dB  "
                f"wall {r['wall_seconds']:6.1f} s  ({r['steps']} steps)")
        r = run_bflidar(meas, views, prep_seconds=prep_s)
        runs.append({**common, **r, "label": f"bflidar {res}px"})
        log(f"    {'bflidar ' + str(res) + 'px':26s} L1 {r['depth_l1_m']:.4f} m  PSNR {r['depth_psnr_db']:5.2f} dB  "
            f"wall {r['wall_seconds']:6.1f} s  (threshold {r['occupancy_threshold']})")
    return runs


def summarise(runs, log=print) -> dict:
    """Per scene: table, Pareto front, time to reach the paper's L1 and the ratio to the reference mode."""
    out = {}
    for scene in dict.fromkeys(r["scene"] for r in runs):
        rs = [r for r in runs if r["scene"] == scene]
        front = {rs[i]["label"] for i in pareto([(r["wall_seconds"], r["depth_l1_m"]) for r in rs])}
        ref = next((r for r in rs if r["mode"] == "platonerf"), None)
        t_ref = time_to_reach(ref) if ref else None
        log(f"\n{scene}: depth L1 / PSNR on the test views against wall time (* = Pareto front)")
        log(f"  {'method':26s} {'wall s':>7s} {'L1 m':>7s} {'PSNR dB':>7s} {'t(L1<=0.0862) s':>16s} "
            f"{'vs reference':>13s} {'median view L1':>14s}")
        rows = []
        for r in sorted(rs, key=lambda r: r["wall_seconds"]):
            t = time_to_reach(r)
            if r is ref:
                ratio = "1 (ref)" if t else "-"
            elif t is None:
                ratio = "-"
            elif t_ref is not None:
                ratio = f"{t_ref / t:.1f}x faster"
            elif ref is not None:
                ratio = f">{ref['wall_seconds'] / t:.1f}x faster"      # the reference never got there
            else:
                ratio = "-"
            log(f"{'*' if r['label'] in front else ' '} {r['label']:26s} {r['wall_seconds']:7.1f} "
                f"{r['depth_l1_m']:7.4f} {r['depth_psnr_db']:7.2f} {('-' if t is None else f'{t:.1f}'):>16s} "
                f"{ratio:>13s} {r.get('view_l1_median_m', float('nan')):14.4f}")
            rows.append({"label": r["label"], "wall_seconds": r["wall_seconds"], "depth_l1_m": r["depth_l1_m"],
                         "depth_psnr_db": r["depth_psnr_db"], "view_l1_median_m": r.get("view_l1_median_m"),
                         "time_to_paper_l1_s": t, "vs_reference": ratio,
                         "pareto": r["label"] in front})
        log(f"  paper (PlatoNeRF, 512 px, GPU hours): L1 {PAPER_L1_M} m, PSNR {PAPER_PSNR_DB} dB")
        same = []
        if ref is not None:     # the other comparison: time to the reference's own final error
            log(f"  time to reach the reference mode's final L1 ({ref['depth_l1_m']:.4f} m after "
                f"{ref['wall_seconds']:.0f} s):")
            for r in rs:
                if r is ref:
                    continue
                t = time_to_reach(r, ref["depth_l1_m"])
                ratio = None if t is None else ref["wall_seconds"] / t
                same.append({"label": r["label"], "time_s": t, "reference_time_ratio": ratio})
                log(f"    {r['label']:26s} " + ("not reached" if t is None else
                                                 f"{t:.1f} s ({ratio:.1f}x less than the reference)"))
        out[scene] = {"rows": rows, "reference_time_to_paper_l1_s": t_ref, "time_to_reference_l1": same}
    return out


def plot(runs, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    scenes = list(dict.fromkeys(r["scene"] for r in runs))
    fig, axes = plt.subplots(2, len(scenes), figsize=(6 * len(scenes), 8), squeeze=False)
    colours = {"fast": "tab:blue", "platonerf": "tab:red", "bflidar": "tab:green"}
    for j, scene in enumerate(scenes):
        rs = [r for r in runs if r["scene"] == scene]
        for i, (key, paper) in enumerate((("depth_l1_m", PAPER_L1_M), ("depth_psnr_db", PAPER_PSNR_DB))):
            ax = axes[i, j]
            for r in rs:
                xs = [c["wall_seconds"] for c in r["curve"]]
                ax.plot(xs, [c[key] for c in r["curve"]], "-", lw=0.8, alpha=0.5, color=colours[r["mode"]])
                ax.plot(r["wall_seconds"], r[key], "o" if r["mode"] == "fast" else "s", color=colours[r["mode"]])
                ax.annotate(r["label"], (r["wall_seconds"], r[key]), fontsize=6, alpha=0.8)
            sign = 1 if key == "depth_l1_m" else -1
            fr = sorted((rs[k] for k in pareto([(r["wall_seconds"], sign * r[key]) for r in rs])),
                        key=lambda r: r["wall_seconds"])
            ax.step([r["wall_seconds"] for r in fr], [r[key] for r in fr], where="post", color="k", lw=1.5,
                    label="Pareto front")
            ax.axhline(paper, color="gray", ls="--", lw=1, label="paper PlatoNeRF (GPU, hours)")
            ax.set_xscale("log")
            ax.set_xlabel("wall time (s): preprocessing + fit")
            ax.set_ylabel("test-view depth L1 (m)" if i == 0 else "test-view depth PSNR (dB)")
            ax.set_title(f"{scene}")
            ax.grid(alpha=0.3)
            for m, c in colours.items():
                ax.plot([], [], "o", color=c, label=m)
            ax.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    a = parse(argv)
    info = machine_info()
    print(machine_line(info), f"(fits use {a.threads} threads)")
    runs = []
    with timer() as t:
        for scene in a.scenes:
            runs += scene_runs(scene, a)
    summary = summarise(runs)
    out = Path(a.out)
    write_json(out, {"machine": info, "command": "python benchmarks/bench_headline.py " + " ".join(argv or sys.argv[1:]),
                     "settings": vars(a), "paper": {"depth_l1_m": PAPER_L1_M, "depth_psnr_db": PAPER_PSNR_DB},
                     "summary": summary, "runs": runs, "total_seconds": t.seconds, "peak_rss_mb": peak_rss_mb()})
    plot(runs, out.with_suffix(".png"))
    print(f"\ntotal {t.seconds:.0f} s, peak memory {peak_rss_mb():.0f} MiB; wrote {out} and {out.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
