"""One fast-mode setting swept on a Cycles dataset: fit wall time against test-view error per value.

    python benchmarks/bench_settings.py --set fast.lr --values 0.01 0.05 0.2 0.5
    python benchmarks/bench_settings.py --set fast.lr --values 0.01 0.2 --steps 400 --dataset DIR
    python benchmarks/bench_settings.py --set mesh_level --values 0.35 0.5 0.65

This is how the fast mode's defaults were chosen (docs/reconstruction.md). Each value is a separate
`python -m torch_recon fit DATASET --set KEY=VALUE` process followed by `python -m torch_recon evaluate`
(mesh ray-cast on every test view of the dataset), exactly what a user runs. The default dataset is the
128 x 128 cave-chair that `bench_chain.py` simulates (simulated here when missing). Prints the machine,
the load average and a table; writes benchmarks/results/settings_<key>.json and .png.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.bench_chain import fit_and_evaluate, run_stage  # noqa: E402
from torch_recon.contract.dataset import MANIFEST_NAME  # noqa: E402
from benchmarks.common import RESULTS_DIR, machine_info, machine_line, write_json  # noqa: E402

DEFAULT_DATASET = RESULTS_DIR / "data" / "chain" / "sim128"
METRICS = ("depth_l1_m", "depth_psnr_db", "chamfer_m", "fscore", "n_reconstruction_misses")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--set", required=True, dest="key", help="FitConfig setting, e.g. fast.lr or mesh_level")
    ap.add_argument("--values", nargs="+", required=True, help="values to try (parsed as JSON by --set)")
    ap.add_argument("--dataset", default=str(DEFAULT_DATASET))
    ap.add_argument("--steps", type=int, help="optimisation steps (default: the mode's)")
    ap.add_argument("--max-seconds", type=float, default=300.0, help="fit budget per value")
    ap.add_argument("--extra", nargs="*", default=[], help="more KEY=VALUE settings for every run")
    ap.add_argument("--work", default=str(RESULTS_DIR / "data" / "settings"))
    args = ap.parse_args(argv)
    py, ds = sys.executable, Path(args.dataset)
    if not (ds / MANIFEST_NAME).exists():
        if ds != DEFAULT_DATASET:
            raise SystemExit(f"--dataset {ds}: no {MANIFEST_NAME} there (expected a dataset directory)")
        run_stage([py, "pipeline/simulate.py", "--example", "cave-chair", "--resolution", "128", "--out", str(ds)])
    rows = []
    load_before = os.getloadavg()[0]
    for v in args.values:
        tag = f"{args.key}={v}".replace("/", "_")
        fit_dir, eval_dir = Path(args.work) / tag, Path(args.work) / f"{tag}-eval"
        fit_args = ["--max-seconds", args.max_seconds, "--set", f"{args.key}={v}"]
        for e in args.extra:
            fit_args += ["--set", e]
        if args.steps is not None:
            fit_args += ["--steps", args.steps]
        r = fit_and_evaluate(ds, fit_dir, eval_dir, fit_args)
        fit_rep, rep = r["fit"], r["eval"]
        rows.append({"value": v, "fit_s": r["fit_s"], "train_s": fit_rep["train_seconds"], "steps": fit_rep["steps"],
                     "stopped": fit_rep["stopped"], "peak_rss_mib_upper": r["fit_peak_rss_mib_upper"],
                     **{k: rep.get(k) for k in METRICS}})
        r = rows[-1]
        print(f"  {args.key}={v:>8s}  fit {r['fit_s']:6.1f} s ({r['steps']} steps, {r['stopped']})  L1 {r['depth_l1_m']:.4f} m"
              f"  PSNR {r['depth_psnr_db']:.2f} dB  Chamfer {r['chamfer_m']:.4f} m  misses {r['n_reconstruction_misses']}",
              flush=True)
    info = {**machine_info(), "loadavg_before": load_before, "loadavg_after": os.getloadavg()[0]}
    print(machine_line(info), f"(load average before {load_before:.2f})")
    print(f"{'value':>10} {'fit s':>7} {'steps':>6} {'L1 m':>7} {'PSNR dB':>8} {'Chamfer m':>9} {'misses':>7}")
    for r in rows:
        print(f"{r['value']:>10} {r['fit_s']:>7.1f} {r['steps']:>6} {r['depth_l1_m']:>7.4f} {r['depth_psnr_db']:>8.2f} "
              f"{r['chamfer_m']:>9.4f} {r['n_reconstruction_misses']:>7}")
    stem = "settings_" + args.key.replace(".", "_")
    write_json(RESULTS_DIR / f"{stem}.json", {"machine": info, "command": " ".join(sys.argv), "dataset": str(ds),
                                              "key": args.key, "rows": rows})
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(8, 3.2))
    xs = range(len(rows))
    a1.plot(xs, [r["depth_l1_m"] for r in rows], "o-")
    a2.plot(xs, [r["depth_psnr_db"] for r in rows], "o-", color="tab:orange")
    for ax, lab in ((a1, "test-view depth L1 (m)"), (a2, "test-view depth PSNR (dB)")):
        ax.set_xticks(list(xs), [r["value"] for r in rows])
        ax.set_xlabel(args.key)
        ax.set_ylabel(lab)
        ax.grid(alpha=0.3)
    fig.suptitle(f"fast mode, {ds.name}: fit time " + ", ".join(f"{r['fit_s']:.0f}" for r in rows) + " s", fontsize=9)
    fig.tight_layout()
    fig.savefig(RESULTS_DIR / f"{stem}.png", dpi=110)
    print(f"wrote {RESULTS_DIR / (stem + '.json')} and .png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
