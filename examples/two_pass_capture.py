"""A two-pass capture of the issue's 16 spots: K spots, a fast fit, 16 - K spots where `advise-spots` says.

The first pass captures K spread-out spots of the scene (the simulator's `--spots K`); a fast fit of it tells
the advisor which hidden space only shadows bound; the second pass captures the K spots again with the advised
ones (the advice's `spot_list_with_existing`) and is fitted and evaluated. Every stage is the real entry point,
run as a subprocess and printed, so the commands are the recipe (README "Where to aim the next spots").

    python examples/two_pass_capture.py --example organic-occluded --first 8 --out out/two-pass
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from run_demo import ROOT, run_stage


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="out/two-pass", help="output directory (default out/two-pass)")
    ap.add_argument("--example", default="organic-occluded", help="example scene (default organic-occluded)")
    ap.add_argument("--resolution", type=int, default=128, help="sensor resolution N x N (default 128)")
    ap.add_argument("--first", type=int, default=8, help="spots of the first pass (default 8)")
    ap.add_argument("--total", type=int, default=16, help="spots of the whole capture (default 16)")
    ap.add_argument("--beyond-view-deg", type=float, default=0.0,
                    help="let the advisor aim up to this far beyond the sensor's view (default 0: in view)")
    ap.add_argument("--test-views", type=int, default=24, help="test views (dolly + orbit) for evaluation")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    if not 1 <= args.first < args.total:
        print(f"error: --first: expected 1 <= first < total ({args.total}), got {args.first}", file=sys.stderr)
        return 2

    from pipeline.launch import simulate_command

    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    recon = [sys.executable, "-m", "torch_recon"]
    sim = ["--example", args.example, "--resolution", args.resolution, "--test-views", args.test_views,
           "--seed", args.seed]
    first, second = out / "first", out / "second"
    run_stage(simulate_command([*sim, "--spots", args.first, "--out", first]), out / "simulate-first.log")
    run_stage([*recon, "fit", str(first), "--mode", "fast", "--out", str(out / "first-fit"), "--no-resume",
               "--no-uv", "--seed", str(args.seed)], out / "fit-first.log")
    advice = out / "advice.json"
    run_stage([*recon, "advise-spots", str(first), str(out / "first-fit"), "--add", str(args.total - args.first),
               "--beyond-view-deg", str(args.beyond_view_deg), "--seed", str(args.seed), "--out", str(advice)],
              out / "advise.log")
    spots = json.loads(advice.read_text())["spot_list_with_existing"]
    run_stage(simulate_command([*sim, f"--spot-list={spots}", "--out", second]), out / "simulate-second.log")
    run_stage([*recon, "fit", str(second), "--mode", "fast", "--out", str(out / "second-fit"), "--no-resume",
               "--seed", str(args.seed)], out / "fit-second.log")
    run_stage([*recon, "evaluate", str(out / "second-fit" / "mesh.ply"), "--dataset", str(second),
               "--out", str(out / "second-eval")], out / "evaluate.log")
    print(f"\ntwo-pass capture of {args.total} spots ({args.first} + {args.total - args.first} advised): "
          f"mesh {out / 'second-fit' / 'mesh.ply'}, evaluation {out / 'second-eval'}")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    raise SystemExit(main())
