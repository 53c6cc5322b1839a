"""`baseline`: the Bounce Flash Lidar baseline (visible depth + probabilistic shadow carving) -> mesh."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..bflidar import BFLidarSettings
from ..preprocess import PreprocessSettings
from . import DEVICE_FLAGS, DeviceSettings, add_stage


@dataclass
class BaselineCommand(DeviceSettings):
    """Settings of `baseline`: preprocessing, then BF Lidar carving."""

    preprocess: PreprocessSettings = field(default_factory=PreprocessSettings)
    bflidar: BFLidarSettings = field(default_factory=BFLidarSettings)
    grid_search: bool = False         # pick shadow/occupancy thresholds by depth L1 on the test views (needs GT)
    evaluate: bool = False            # also write report.json for the mesh

    GRID_SHADOW_THRESHOLDS = (0.05, 0.15, 0.25, 0.5)


def register(sub) -> None:
    from .preprocess import PREPROCESS_FLAGS

    add_stage(sub, "baseline", run, BaselineCommand,
              ("bflidar.voxels", "bflidar.occupancy_threshold", "grid_search", "evaluate") + PREPROCESS_FLAGS
              + DEVICE_FLAGS,
              help="Bounce Flash Lidar baseline -> mesh",
              description="Preprocess the dataset (or reuse --measurements), carve, mesh; optionally grid-search "
                          "the thresholds on the dataset's test views as the paper did.",
              arguments=((("dataset",), {"help": "dataset directory"}),
                         (("--out",), {"required": True, "help": "output directory (mesh.glb/.ply/.obj, "
                                                                 "mesh.mesh.json)"}),
                         (("--measurements",), {"default": None,
                                                "help": "reuse a preprocess .npz instead of preprocessing"})))


#: top-level names baselines of earlier versions wrote (they kept no record of them)
BASELINE_ENTRIES = ("mesh.*", "eval")
#: BF Lidar keeps about 24 bytes per voxel (counts, probability, occupancy, the blurred copy)
BYTES_PER_VOXEL = 24
MAX_VOXELS = 1024


def run(args) -> int:
    from ..contract.dataset import DatasetError, load_dataset
    from ..contract.dataset.staging import StagedDir
    from ..contract.errors import SettingsError
    from ..contract.settings import from_args
    from ..contract.units import format_bytes
    from ..device import resolve_device

    cmd = from_args(BaselineCommand, args)
    if cmd.bflidar.voxels > MAX_VOXELS:       # refused up front, with the estimate
        raise SettingsError("bflidar.voxels", f"{cmd.bflidar.voxels} voxels per side would need about "
                            f"{format_bytes(BYTES_PER_VOXEL * float(cmd.bflidar.voxels) ** 3)} of memory; at most "
                            f"{MAX_VOXELS} is supported")
    device = resolve_device(cmd.device, cmd.threads)
    ds = load_dataset(args.dataset)
    if cmd.grid_search and ds.manifest.ground_truth.test_views is None:
        raise DatasetError(str(ds.root), "ground_truth.test_views", "--grid-search needs test views")
    with StagedDir(args.out, "baseline", legacy=BASELINE_ENTRIES, marker="mesh.mesh.json") as stage:
        run_staged(args, cmd, ds, device, stage)
        stage.commit()      # mesh files, sidecar and evaluation replace the previous ones together
    return 0


def run_staged(args, cmd, ds, device, stage) -> None:
    import time

    import numpy as np

    from ..bflidar import carve, grid_search, test_view_depth_l1
    from ..contract.errors import MeasurementsError
    from ..evaluate import EvalSettings, evaluate
    from ..measurements import Measurements
    from ..mesh_export import export_mesh
    from ..preprocess import preprocess_dataset
    from .preprocess import summarize

    out = stage.path
    t0 = time.perf_counter()
    if args.measurements:
        meas = Measurements.load(args.measurements)
        made_from = meas.settings.get("dataset_hash")
        if made_from is not None and made_from != ds.content_hash():
            raise MeasurementsError(f"{args.measurements}: measurements were made from another dataset than "
                                    f"{ds.root} (settings.dataset_hash differs); preprocess this dataset or "
                                    f"drop --measurements")
    else:
        meas = preprocess_dataset(ds, cmd.preprocess, device=device, progress=True)
    t_pre = time.perf_counter() - t0
    print(summarize(meas))
    bs = cmd.bflidar
    t1 = time.perf_counter()
    table = None
    if cmd.grid_search:
        views, cams, gt = ds.test_views()
        score = test_view_depth_l1(cams, gt, views.width, views.height, views.fov_rad, views.fov_axis)
        res, best, table = grid_search(meas, score, bs, shadow_thresholds=cmd.GRID_SHADOW_THRESHOLDS,
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
          f"-> {', '.join(str(stage.final(p)) for p in exp.paths)}")
    if cmd.evaluate:
        rep = evaluate(ds, out / "eval", mesh=exp.mesh, settings=EvalSettings(), progress=True,
                       extra={"method": "bflidar"})
        print(f"depth L1 {rep['depth_l1_m']} m, PSNR {rep['depth_psnr_db']} dB, Chamfer {rep['chamfer_m']} m, "
              f"F-score {rep['fscore']}")
