"""The whole chain on the Cycles-simulated cave-chair: simulate -> fit (fast) -> evaluate, per resolution.

Each stage runs as the user would run it (a subprocess of the real entry point), so the figures
include start-up and file I/O. Prints the machine and a table of wall time, peak memory (max RSS of
the stage's process) and test-view error; writes benchmarks/results/chain.json and chain.png.

    python benchmarks/bench_chain.py --resolutions 128 512
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.common import machine_info, machine_line, write_json  # noqa: E402

PAPER = {"depth_l1_m": 0.0862, "depth_psnr_db": 26.58}


def run_stage(cmd: list[str]) -> tuple[float, float]:
    """Run one stage; (wall seconds, peak RSS of that process in MiB)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    dt = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"stage failed ({proc.returncode}): {' '.join(cmd)}\n{proc.stdout[-3000:]}")
    after = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    # ru_maxrss of children is the max over all children so far: a smaller later stage reports the earlier max
    return dt, max(after, before) / 1024.0


def fit_and_evaluate(dataset, fit_dir, eval_dir, fit_args=()) -> dict:
    """`torch_recon fit DATASET --out FIT --no-resume --quiet FIT_ARGS`, then `torch_recon evaluate` of its
    mesh: wall times, the fit's peak RSS (upper bound, see run_stage) and both reports."""
    py = sys.executable
    t_fit, rss = run_stage([py, "-m", "torch_recon", "fit", str(dataset), "--out", str(fit_dir), "--no-resume",
                            "--quiet", *map(str, fit_args)])
    t_eval, _ = run_stage([py, "-m", "torch_recon", "evaluate", str(Path(fit_dir) / "mesh.ply"), "--dataset",
                           str(dataset), "--out", str(eval_dir)])
    return {"fit_s": t_fit, "fit_peak_rss_mib_upper": rss, "evaluate_s": t_eval,
            "fit": json.loads((Path(fit_dir) / "fit.json").read_text()),
            "eval": json.loads((Path(eval_dir) / "report.json").read_text())}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--resolutions", type=int, nargs="+", default=[128, 512])
    ap.add_argument("--work", default=str(ROOT / "benchmarks" / "results" / "data" / "chain"))
    ap.add_argument("--fit-seconds", type=float, default=900.0)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    py = sys.executable
    work = Path(args.work)
    rows = []
    for res in args.resolutions:
        d, f, e = work / f"sim{res}", work / f"fit{res}", work / f"eval{res}"
        t_sim, _ = run_stage([py, "pipeline/simulate.py", "--example", "cave-chair", "--resolution", str(res),
                              "--out", str(d), "--seed", str(args.seed)])
        r = fit_and_evaluate(d, f, e, ["--mode", "fast", "--max-seconds", args.fit_seconds, "--seed", args.seed])
        rep = r["eval"]
        rows.append({"resolution": res, "simulate_s": t_sim, "fit_s": r["fit_s"],
                     "fit_peak_rss_mib_upper": r["fit_peak_rss_mib_upper"],
                     "evaluate_s": r["evaluate_s"], "n_test_views": rep["n_test_views"],
                     **{k: rep[k] for k in ("depth_l1_m", "depth_psnr_db", "chamfer_m", "fscore")}})
    info = machine_info()
    print(machine_line(info))
    print(f"{'res':>5} {'simulate s':>10} {'fit s':>7} {'fit RSS MiB':>11} {'L1 m':>7} {'PSNR dB':>8} "
          f"{'Chamfer m':>9} {'F@5cm':>6}")
    for r in rows:
        print(f"{r['resolution']:>5} {r['simulate_s']:>10.1f} {r['fit_s']:>7.1f} {r['fit_peak_rss_mib_upper']:>11.0f} "
              f"{r['depth_l1_m']:>7.4f} {r['depth_psnr_db']:>8.2f} {r['chamfer_m']:>9.4f} {r['fscore']:>6.3f}")
    print(f"paper (PlatoNeRF, 512x512): L1 {PAPER['depth_l1_m']} m, PSNR {PAPER['depth_psnr_db']} dB")
    out = ROOT / "benchmarks" / "results"
    write_json(out / "chain.json", {"machine": info, "command": " ".join(sys.argv), "paper": PAPER, "rows": rows})
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for r in rows:
        ax.scatter(r["fit_s"], r["depth_l1_m"], label=f"fast, {r['resolution']} px")
    ax.axhline(PAPER["depth_l1_m"], color="k", ls="--", lw=1, label="paper (PlatoNeRF)")
    ax.set_xlabel("fit wall time (s, incl. preprocessing)")
    ax.set_ylabel("test-view depth L1 (m)")
    ax.set_title("cave-chair, Cycles-simulated, 16 spots")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "chain.png", dpi=120)
    print(f"wrote {out / 'chain.json'} and {out / 'chain.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
