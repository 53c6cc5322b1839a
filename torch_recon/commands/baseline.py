"""`baseline`: the Bounce Flash Lidar baseline (visible depth + probabilistic shadow carving) -> mesh."""

from __future__ import annotations


def register(sub) -> None:
    from .preprocess import add_device_arg, add_preprocess_args
    p = sub.add_parser("baseline", help="Bounce Flash Lidar baseline -> mesh",
                       description="Preprocess the dataset (or reuse --measurements), carve, mesh; optionally "
                                   "grid-search the thresholds on the dataset's test views as the paper did.")
    p.add_argument("dataset", help="dataset directory")
    p.add_argument("--out", required=True, help="output directory (mesh.glb/.ply/.obj, mesh.mesh.json)")
    p.add_argument("--measurements", default=None, help="reuse a preprocess .npz instead of preprocessing")
    p.add_argument("--voxels", type=int, default=128, help="voxels along the longest axis (default 128)")
    p.add_argument("--occupancy-threshold", type=float, default=0.3, help="occupancy probability threshold")
    p.add_argument("--grid-search", action="store_true",
                   help="pick shadow/occupancy thresholds by depth L1 on the test views (uses ground truth)")
    p.add_argument("--evaluate", action="store_true", help="also write report.json for the mesh")
    add_preprocess_args(p)
    add_device_arg(p)
    p.set_defaults(func=run)


def run(args) -> int:
    import time
    from pathlib import Path

    import numpy as np

    from ..bflidar import BFLidarSettings, carve, grid_search
    from ..contract.dataset import load_dataset
    from ..evaluate import EvalSettings, depth_metrics, evaluate, render_mesh_depth
    from ..measurements import Measurements
    from ..mesh_export import export_mesh
    from ..preprocess import preprocess_dataset
    from .preprocess import resolve_device, settings_from_args, summarize

    device = resolve_device(args.device, args.threads)
    ds = load_dataset(args.dataset)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    if args.measurements:
        meas = Measurements.load(args.measurements)
    else:
        meas = preprocess_dataset(ds, settings_from_args(args), device=device, progress=True)
    t_pre = time.perf_counter() - t0
    print(summarize(meas))
    bs = BFLidarSettings(voxels=args.voxels, occupancy_threshold=args.occupancy_threshold)
    t1 = time.perf_counter()
    table = None
    if args.grid_search:
        tv = ds.test_views()
        if tv is None:
            raise ValueError(f"{ds.root}: --grid-search needs ground_truth.test_views")
        views, cams, gt = tv

        def score(mesh):
            pred = np.stack([render_mesh_depth(mesh, c, views.width, views.height, views.fov_rad, views.fov_axis)
                             for c in cams])
            return depth_metrics(pred, gt)["depth_l1_m"]

        res, best, table = grid_search(meas, score, bs, shadow_thresholds=(0.05, 0.15, 0.25, 0.5),
                                       device=device, progress=True)
        print("grid search (shadow threshold, occupancy threshold, depth L1 m):")
        for st, ot, sc in table:
            print(f"  {st!s:>5}  {ot:4.2f}  {sc:.4f}" + ("  (no surface)" if not np.isfinite(sc) else ""))
    else:
        res = carve(meas, bs, device=device, progress=True)
    t_carve = time.perf_counter() - t1
    meta = {"method": "bflidar", "settings": res.settings, "preprocess_settings": meas.settings,
            "seconds": {"preprocess": round(t_pre, 3), "carve": round(t_carve, 3)},
            "dataset_hash": ds.content_hash(),
            "grid_search": None if table is None else [[st, ot, sc if np.isfinite(sc) else None] for st, ot, sc in table]}
    exp = export_mesh(res.occupancy, res.bbox_min, res.bbox_max, res.level, out / "mesh.glb", meta,
                      extra_formats=(".ply", ".obj"))
    print(f"BF Lidar: preprocess {t_pre:.2f} s, carving {t_carve:.2f} s; mesh {exp.n_faces} faces "
          f"-> {', '.join(str(p) for p in exp.paths)}")
    if args.evaluate:
        rep = evaluate(ds, out / "eval", mesh=exp.mesh, settings=EvalSettings(), progress=True,
                       extra={"method": "bflidar"})
        print(f"depth L1 {rep['depth_l1_m']} m, PSNR {rep['depth_psnr_db']} dB, Chamfer {rep['chamfer_m']} m, "
              f"F-score {rep['fscore']}")
    return 0
