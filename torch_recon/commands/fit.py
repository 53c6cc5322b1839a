"""`fit`: measurements (a dataset directory or a measurements .npz) -> density field -> mesh."""

from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser("fit", help="reconstruct visible and hidden geometry (fast grid or PlatoNeRF MLP)",
                       description="Fit a density field to two-bounce lidar measurements and export a mesh "
                                   "(.glb/.ply/.obj in the Blender world frame) with its metadata.")
    p.add_argument("source", help="dataset directory (preprocessed on the fly) or a measurements .npz")
    p.add_argument("--out", required=True, help="output directory (checkpoint, volume.npz, mesh.*, fit.json)")
    p.add_argument("--mode", choices=("fast", "platonerf"), default="fast",
                   help="fast: explicit grid from visible depth + shadow carving (default); "
                        "platonerf: the published NeRF MLP (slow on a CPU)")
    p.add_argument("--config", help="JSON file of settings (FitConfig fields)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override one setting, e.g. --set fast.resolution=96 --set seed=1 (repeatable)")
    p.add_argument("--steps", type=int, help="optimisation steps (default: the mode's)")
    p.add_argument("--max-seconds", type=float, help="wall-clock budget for the optimisation")
    p.add_argument("--seed", type=int)
    p.add_argument("--device", choices=("auto", "cpu", "cuda"))
    p.add_argument("--threads", type=int, help="torch CPU threads (default 2)")
    p.add_argument("--no-resume", action="store_true", help="ignore an existing checkpoint in --out")
    p.add_argument("--no-mesh", action="store_true", help="skip the mesh export (volume.npz only)")
    p.add_argument("--no-uv", action="store_true",
                   help="skip the xatlas UV atlas (about a third of a 128 px fit's wall time; "
                        "only texture painting or baking in Blender needs it)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args) -> int:
    import json
    from pathlib import Path

    from ..recon import FitConfig, fit, override

    base = {}
    if args.config:
        path = Path(args.config)
        try:
            base = json.loads(path.read_text())
        except FileNotFoundError:
            raise FileNotFoundError(f"{path}: settings file not found") from None
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}: not valid JSON ({exc})") from None
        if not isinstance(base, dict):
            raise ValueError(f"{path}: expected a JSON object of settings (FitConfig fields), got "
                             f"{type(base).__name__}")
    cfg = FitConfig.from_dict({**base, "mode": args.mode})
    sets = list(args.set)
    for flag, key in (("steps", "steps"), ("max_seconds", "max_seconds"), ("seed", "seed"), ("device", "device"),
                      ("threads", "threads")):
        v = getattr(args, flag)
        if v is not None:
            sets.append(f"{key}={json.dumps(v)}")
    if args.no_resume:
        sets.append("resume=false")
    if args.quiet:
        sets.append("progress=false")
    cfg = override(cfg, sets)
    r = fit(args.source, mode=args.mode, out=args.out, config=cfg, export=not args.no_mesh, uv=not args.no_uv)
    t = r.train
    if t.stopped == "interrupted":     # not done: the checkpoint is kept, earlier results are untouched
        import sys
        print(f"interrupted at step {t.steps_done}; checkpoint saved in {Path(args.out) / 'checkpoint.pt'} "
              f"(run the same command again to continue); earlier results left as they were", file=sys.stderr)
        return 130
    print(f"{r.mode}: {t.steps_done} steps ({t.stopped}), setup {r.setup_seconds:.1f} s, "
          f"training {t.train_seconds:.1f} s, total {r.total_seconds:.1f} s"
          + (f", resumed from step {t.resumed_from}" if t.resumed_from else "")
          + (f", {t.nan_restores} NaN restore(s)" if t.nan_restores else ""))
    if t.history:
        h = t.history[-1]
        print(f"final loss {h['loss']:.4g} (distance {h['dist']:.3g}, shadow {h['shadow']:.3g})")
    if "mesh_error" in r.metadata:
        print(f"  no mesh: {r.metadata['mesh_error']}")
    for kind, path in r.mesh_files.items():
        print(f"  {kind:8s} {path}")
    print(f"  volume   {Path(args.out) / 'volume.npz'}\n  report   {Path(args.out) / 'fit.json'}")
    return 0 if t.stopped != "nan" else 1
