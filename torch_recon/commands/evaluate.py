"""`evaluate`: a reconstruction mesh against a dataset's ground truth -> report.json + error images."""

from __future__ import annotations


EVAL_FLAGS = ("fscore_threshold_m", "n_surface_samples", "miss_depth", "cull_back_faces", "error_images", "seed")


def register(sub) -> None:
    from ..contract.settings import add_arguments
    from ..evaluate import EvalSettings

    p = sub.add_parser("evaluate", help="depth L1/PSNR on test views, Chamfer, F-score -> report.json",
                       description="Renders the mesh (Embree) from every ground-truth test view and compares "
                                   "ranges; samples both surfaces for Chamfer and F-score.")
    p.add_argument("reconstruction", help="mesh file (.ply/.glb/.obj as written by this project, world frame)")
    p.add_argument("--dataset", required=True, help="dataset directory with ground truth")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--two-sided", action="store_true",
                   help="count hits on back faces too (same as --no-cull-back-faces)")
    add_arguments(p, EvalSettings, EVAL_FLAGS)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..contract.dataset import load_dataset
    from ..contract.settings import from_args
    from ..evaluate import EvalSettings, evaluate
    from ..mesh_export import load_mesh_world

    ds = load_dataset(args.dataset)
    mesh = load_mesh_world(args.reconstruction)
    s = from_args(EvalSettings, args, extra={"cull_back_faces": False} if args.two_sided else None)
    rep = evaluate(ds, args.out, mesh=mesh, settings=s, progress=True, extra={"reconstruction": args.reconstruction})

    def fmt(v, f):
        return "n/a" if v is None else format(v, f)
    print(f"test views {rep['n_test_views']}, excluded pixels (GT miss) {rep['n_excluded_pixels']}, "
          f"reconstruction misses {rep.get('n_reconstruction_misses', 0)}")
    print(f"depth L1 {fmt(rep['depth_l1_m'], '.4f')} m   depth PSNR {fmt(rep['depth_psnr_db'], '.2f')} dB   "
          f"Chamfer {fmt(rep['chamfer_m'], '.4f')} m   F-score@{s.fscore_threshold_m} {fmt(rep['fscore'], '.3f')}")
    print(f"report -> {args.out}/report.json")
    return 0
