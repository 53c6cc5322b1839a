"""`fit`: measurements (a dataset directory or a measurements .npz) -> density field -> mesh."""

from __future__ import annotations


FIT_FLAGS = ("mode", "steps", "max_seconds", "seed", "device", "threads", "resume", "progress")


def register(sub) -> None:
    from ..recon.config import FitConfig
    from . import add_stage

    add_stage(sub, "fit", run, FitConfig, FIT_FLAGS,
              help="reconstruct visible and hidden geometry (fast grid or PlatoNeRF MLP)",
              description="Fit a density field to two-bounce lidar measurements and export a mesh (.glb/.ply/.obj "
                          "in the Blender world frame) with its metadata.",
              arguments=((("source",), {"help": "dataset directory (preprocessed on the fly) or a measurements "
                                                ".npz"}),
                         (("--out",), {"required": True, "help": "output directory (checkpoint, volume.npz, "
                                                                 "mesh.*, fit.json)"}),
                         (("--quiet",), {"action": "store_true", "help": "no progress bar (same as "
                                                                         "--no-progress)"}),
                         (("--no-mesh",), {"action": "store_true", "help": "skip the mesh export (volume.npz "
                                                                           "only)"}),
                         (("--no-uv",), {"action": "store_true", "help": "skip the xatlas UV atlas (about 4 CPU-s "
                                         "of a 128 px fit; only texture painting or baking in Blender "
                                         "needs it)"})))


def run(args) -> int:
    from pathlib import Path

    from ..contract.settings import from_args
    from ..recon import FitConfig, fit

    cfg = from_args(FitConfig, args, extra={"progress": False} if args.quiet else None)
    r = fit(args.source, mode=cfg.mode, out=args.out, config=cfg, export=not args.no_mesh, uv=not args.no_uv)
    t = r.train
    if t.stopped == "interrupted":     # not done: the checkpoint is kept, earlier results are untouched
        import sys
        print(f"interrupted at step {t.steps_done}; checkpoint saved in {Path(args.out) / 'checkpoint.pt'} "
              f"(run the same command again to continue); earlier results left as they were", file=sys.stderr)
        return 130
    if "grid_from_sensor" in r.metadata:
        from ..recon.grid_size import describe
        print(describe(r.metadata["grid_from_sensor"]))
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
