"""`evaluate`: a reconstruction mesh against a dataset's ground truth -> report.json + error images."""

from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser("evaluate", help="depth L1/PSNR on test views, Chamfer, F-score -> report.json",
                       description="Renders the mesh (Embree) from every ground-truth test view and compares "
                                   "ranges; samples both surfaces for Chamfer and F-score.")
    p.add_argument("reconstruction", help="mesh file (.ply/.glb/.obj as written by this project, world frame)")
    p.add_argument("--dataset", required=True, help="dataset directory with ground truth")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--fscore-threshold", type=float, default=0.05, help="F-score distance threshold (m)")
    p.add_argument("--samples", type=int, default=100_000, help="surface samples for Chamfer/F-score")
    p.add_argument("--miss-depth", choices=("zero", "max"), default="zero",
                   help="depth a reconstruction ray that hits nothing counts as (default zero)")
    p.add_argument("--two-sided", action="store_true",
                   help="count hits on back faces too (default: one-sided, back faces are passed through)")
    p.add_argument("--error-images", type=int, default=1, help="write every n-th view's error PNG (0: none)")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..contract.dataset import load_dataset
    from ..evaluate import EvalSettings, evaluate
    from ..mesh_export import load_mesh_world

    ds = load_dataset(args.dataset)
    mesh = load_mesh_world(args.reconstruction)
    s = EvalSettings(fscore_threshold_m=args.fscore_threshold, n_surface_samples=args.samples,
                     miss_depth=args.miss_depth, seed=args.seed, error_images=args.error_images,
                     cull_back_faces=not args.two_sided)
    rep = evaluate(ds, args.out, mesh=mesh, settings=s, progress=True, extra={"reconstruction": args.reconstruction})

    def fmt(v, f):
        return "n/a" if v is None else format(v, f)
    print(f"test views {rep['n_test_views']}, excluded pixels (GT miss) {rep['n_excluded_pixels']}, "
          f"reconstruction misses {rep.get('n_reconstruction_misses', 0)}")
    print(f"depth L1 {fmt(rep['depth_l1_m'], '.4f')} m   depth PSNR {fmt(rep['depth_psnr_db'], '.2f')} dB   "
          f"Chamfer {fmt(rep['chamfer_m'], '.4f')} m   F-score@{args.fscore_threshold} {fmt(rep['fscore'], '.3f')}")
    print(f"report -> {args.out}/report.json")
    return 0
