"""`evaluate`: a reconstruction mesh against a dataset's ground truth -> report.json + error images."""

from __future__ import annotations


EVAL_FLAGS = ("fscore_threshold_m", "n_surface_samples", "miss_depth", "cull_back_faces", "error_images", "seed",
              "objects", "pictures", "picture_size", "check_test_views", "view_clearance_m")


def register(sub) -> None:
    from ..evaluate import EvalSettings
    from . import add_stage

    add_stage(sub, "evaluate", run, EvalSettings, EVAL_FLAGS,
              help="depth L1/PSNR on test views, Chamfer, F-score -> report.json",
              description="Renders the mesh (Embree) from every ground-truth test view and compares ranges; "
                          "samples both surfaces for Chamfer and F-score.",
              arguments=((("reconstruction",), {"help": "mesh file (.ply/.glb/.obj as written by this project, "
                                                        "world frame)"}),
                         (("--dataset",), {"required": True, "help": "dataset directory with ground truth"}),
                         (("--out",), {"required": True, "help": "output directory"}),
                         (("--two-sided",), {"action": "store_true", "help": "count hits on back faces too "
                                                                             "(same as --no-cull-back-faces)"})))


#: top-level names evaluations of earlier versions wrote (they kept no record of them)
EVAL_ENTRIES = ("report.json", "views", "test_depths.npz", "*.png", "*.html")


def run(args) -> int:
    from ..contract.dataset import load_dataset
    from ..contract.dataset.staging import StagedDir
    from ..contract.errors import EvaluationError
    from ..contract.settings import from_args
    from ..evaluate import EvalSettings, evaluate
    from ..mesh_export import load_mesh_world

    ds = load_dataset(args.dataset)
    mesh = load_mesh_world(args.reconstruction)
    gt = ds.manifest.ground_truth
    if gt.test_views is None and gt.mesh_file is None:
        raise EvaluationError(f"{ds.root}: the dataset has no ground truth (dataset.json ground_truth.test_views "
                              f"and mesh_file are empty): nothing to evaluate against; simulate it without --no-gt")
    if gt.mesh_file is not None:    # a damaged ground-truth mesh is refused before anything is computed
        load_mesh_world(ds.path(gt.mesh_file))
    s = from_args(EvalSettings, args, extra={"cull_back_faces": False} if args.two_sided else None)
    with StagedDir(args.out, "evaluation", legacy=EVAL_ENTRIES, marker="report.json") as st:
        rep = evaluate(ds, st.path, mesh=mesh, settings=s, progress=True,
                       extra={"reconstruction": args.reconstruction})
        st.commit()     # report and images replace the previous evaluation's together, never mixed

    def fmt(v, f):
        return "n/a" if v is None else format(v, f)
    print(f"test views {rep['n_test_views']}, excluded pixels (GT miss) {rep['n_excluded_pixels']}, "
          f"reconstruction misses {rep.get('n_reconstruction_misses', 0)}")
    print(f"depth L1 {fmt(rep['depth_l1_m'], '.4f')} m   depth PSNR {fmt(rep['depth_psnr_db'], '.2f')} dB   "
          f"Chamfer {fmt(rep['chamfer_m'], '.4f')} m   F-score@{s.fscore_threshold_m} {fmt(rep['fscore'], '.3f')}")
    n_bad = rep.get("n_test_views_invalid", 0)
    if n_bad:
        print(f"test views dropped (camera not in free space): {n_bad}")
    om = rep.get("object_metrics")
    if om and om.get("summary"):
        su, sc = om["summary"], om["scene"]
        print(f"objects ({', '.join(om['objects'])}): F@1/2/5cm {fmt(su.get('fscore@1cm'), '.3f')} / "
              f"{fmt(su.get('fscore@2cm'), '.3f')} / {fmt(su.get('fscore@5cm'), '.3f')}   hidden recall@2cm "
              f"{fmt(su.get('recall_hidden@2cm'), '.3f')}   spurious {fmt(sc.get('spurious_fraction'), '.3f')}   "
              f"degenerate faces {sc.get('degenerate_faces')}")
    if rep.get("pictures"):
        print(f"summary -> {args.out}/summary.html, {args.out}/summary.png")
    print(f"report -> {args.out}/report.json")
    return 0
