"""Representation: how far the fast mode's grid can go at all (issue 11's object targets).

Part 1, `oracle`: per example scene with labelled objects (torch_recon.contract.scenes.OBJECT_SCENES,
cached 128 px Cycles datasets) and grid resolution (voxels along the longest side of the fit's box), the
fit's start-field ramp on the TRUE signed distance at the voxel centres of the fit's own box, exported
through the fit's own path (mesh level, faces facing free space, Taubin smoothing, island cleanup;
benchmarks/oracle_grid.py), scored by `torch_recon evaluate` like the objects suite (object F@1/2/5 cm,
P@2cm, hidden / visible recall at 2 cm, spurious, depth L1 on the valid test views). At
`variant_resolutions`: `oracle-no-smooth` without Taubin smoothing, `oracle-raw` also without the island
cleanup (what the grid alone gives; `variants` picks which run). The oracle's
times are its build (signed distance) and export in this process; its measurements are not read.
Part 2, `fast`: real fits at `fit_resolutions` (`--set fast.resolution=N`, 2 threads, no UVs) on
`fit_scenes`, times of the fit process (read, preprocess, fit, mesh), then the same evaluation.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

from benchmarks.harness import Suite, runners
from benchmarks.harness.report import fmt, markdown_table
from torch_recon.contract.scenes import OBJECT_SCENES


@dataclass
class Settings:
    scenes: tuple = OBJECT_SCENES
    resolutions: tuple = (128, 192, 256)
    # export variants of the oracle: `oracle` (the fit's export) at every resolution; `oracle-no-smooth` (no
    # Taubin) and `oracle-raw` (no Taubin, no island cleanup) at `variant_resolutions`
    variants: tuple = ("oracle", "oracle-no-smooth")
    variant_resolutions: tuple = (128, 256)
    fit_scenes: tuple = ("cave-chair", "thin-structures")
    fit_resolutions: tuple = (128, 160, 192)
    sensor_px: int = 128
    spots: int = 16
    timeout_s: float = 1800.0


def _truth(ds):
    """(measurement rays, GT parts) of a dataset: the fit's box needs the first, the oracle the second."""
    import trimesh

    from benchmarks.oracle_grid import scene_parts
    from torch_recon.contract.dataset import load_dataset
    from torch_recon.evaluation.report import load_gt_objects
    from torch_recon.recon.api import load_source
    from torch_recon.recon.data import build_ray_data

    data = build_ray_data(load_source(ds, progress=False)[0])
    dataset = load_dataset(ds)
    gt = trimesh.load(dataset.path(dataset.manifest.ground_truth.mesh_file), force="mesh", process=False)
    objects, _ = load_gt_objects(dataset, gt)
    return data, scene_parts(gt, [m for _, m in objects], data.sensor_origin.cpu().numpy())


#: variant -> (Taubin passes, island fraction); None: the fit's
VARIANTS = {"oracle": (None, None), "oracle-no-smooth": (0, None), "oracle-raw": (0, 0.0)}


def _oracle_rows(s: Settings, ctx, scene: str, ds) -> list:
    from benchmarks.oracle_grid import export_oracle, oracle_signed_distance
    from torch_recon.recon.config import FitConfig
    from torch_recon.recon.fields import GridBox
    from torch_recon.recon.init import grid_bbox

    cfg = FitConfig()
    data, parts = _truth(ds)
    rows = []
    for res in s.resolutions:
        box = GridBox(*grid_bbox(data, res, cfg.fast.bbox_margin_voxels), res)     # the fit's box at `res`
        with ctx.timed() as t_build:
            sd = oracle_signed_distance(parts, box.bbox_min.cpu().numpy(), box.voxel, box.shape,
                                        sensor_origin=data.sensor_origin.cpu().numpy())
        todo = [v for v in s.variants if v == "oracle" or res in s.variant_resolutions]
        for method in todo:
            smooth, islands = VARIANTS[method]
            tag = f"{scene}-{method}-{res}"
            with ctx.timed() as t_exp:
                _, mesh = export_oracle(sd, box, cfg, ctx.work_dir / tag / "mesh", smooth, islands)
            ev = runners.evaluate(ctx, ctx.work_dir / tag / "mesh.ply", ds, f"{tag}-eval", timeout=s.timeout_s)
            row = {"method": method, "scene": scene, "wall_s": t_build.wall_s + t_exp.wall_s,
                   "cpu_s": t_build.cpu_s + t_exp.cpu_s, "peak_rss_mb": max(t_build.peak_rss_mb, t_exp.peak_rss_mb),
                   "resolution": res, "voxel_m": box.voxel, "grid": list(box.shape),
                   "build_s": t_build.wall_s, "export_s": t_exp.wall_s, "evaluate_s": ev["evaluate_wall_s"],
                   "faces": len(mesh.faces), "load_1min": ctx.load_1min(), "depth_l1_m": ev["depth_l1_m"],
                   **_fields(ctx, f"{tag}-eval")}
            rows.append(ctx.keep(row))
            _log(ctx, row)
    return rows


def _fit_rows(s: Settings, ctx, scene: str, ds) -> list:
    rows = []
    for res in s.fit_resolutions:
        tag = f"{scene}-fast-{res}"
        try:
            r = runners.fit(ctx, ds, tag, mode="fast", sets=[f"fast.resolution={res}"], timeout=s.timeout_s)
        except runners.Refused as exc:
            rows.append(ctx.keep(runners.refused_row("fast", scene, exc, resolution=res, load_1min=ctx.load_1min())))
            continue
        vox = json.loads((ctx.work_dir / tag / "mesh.mesh.json").read_text())["volume"]
        voxel = (vox["bbox_max"][0] - vox["bbox_min"][0]) / (vox["shape"][0] - 1)   # export box = voxel centres
        row = {"method": "fast", "scene": scene, **{k: r.get(k) for k in runners.TIMES}, "resolution": res,
               "voxel_m": voxel, "grid": vox["shape"], "steps": r.get("steps"), "train_s": r.get("train_s"),
               "evaluate_s": r.get("evaluate_wall_s"), "load_1min": ctx.load_1min(), "depth_l1_m": r.get("depth_l1_m"),
               **_fields(ctx, f"{tag}-eval")}
        rows.append(ctx.keep(row))
        _log(ctx, row)
    return rows


def _fields(ctx, eval_dir: str) -> dict:
    """The objects suite's fields plus precision at 2 cm."""
    rep = json.loads((ctx.work_dir / eval_dir / "report.json").read_text())
    summ = rep.get("object_metrics", {}).get("summary", {})
    return {**runners.object_fields(rep), "precision_2cm": summ.get("precision@2cm")}


def _log(ctx, r):
    ctx.log(f"  {r['scene']} {r['method']} {r['resolution']}: F@2cm {fmt(r['obj_f2cm'])}, hidden R@2cm "
            f"{fmt(r['hidden_recall_2cm'])}, spurious {fmt(r['spurious'])}, L1 {fmt(r['depth_l1_m'])} m, "
            f"{fmt(r['wall_s'])} s")


def run(s: Settings, ctx) -> list:
    rows = []
    for scene in s.scenes:
        rows += _oracle_rows(s, ctx, scene, ctx.dataset(scene, s.sensor_px, s.spots))
    for scene in s.fit_scenes:
        rows += _fit_rows(s, ctx, scene, ctx.dataset(scene, s.sensor_px, s.spots))
    return rows


COLUMNS = (("scene", "scene"), ("method", "method"), ("resolution", "grid"), ("voxel_m", "voxel cm", None),
           ("wall_s", "time s", ".1f"), ("cpu_s", "CPU s", ".0f"), ("peak_rss_mb", "peak MB", ".0f"),
           ("load_1min", "load", ".1f"),
           ("obj_f1cm", "F@1cm", ".3f"), ("obj_f2cm", "F@2cm", ".3f"), ("obj_f5cm", "F@5cm", ".3f"),
           ("precision_2cm", "P@2cm", ".3f"), ("hidden_recall_2cm", "hidden R@2cm", ".3f"),
           ("spurious", "spurious", ".3f"), ("depth_l1_m", "L1 m", ".4f"), ("run", "run"))
METHODS = ("oracle", "oracle-no-smooth", "oracle-raw", "fast")


def readme(results: dict) -> str:
    """Per scene: the oracle at each grid, without smoothing, then the real fits."""
    def order(r):
        sc = list(OBJECT_SCENES)
        return (sc.index(r["scene"]) if r["scene"] in sc else len(sc),
                METHODS.index(r["method"]) if r["method"] in METHODS else len(METHODS), r.get("resolution") or 0)
    rows = [{**r, "voxel_m": None if r.get("voxel_m") is None else round(100 * r["voxel_m"], 2)}
            for r in sorted(results["rows"], key=order)]
    return markdown_table(rows, COLUMNS)


def plot(rows, settings, path):
    """Object F@2cm against voxel size per scene: oracle (line), without smoothing, real fits, and the
    fast mode's committed objects.json figure (x at the 128 grid's voxel)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from benchmarks.harness.context import RESULTS_DIR

    objects = {}
    p = RESULTS_DIR / "objects.json"
    if p.is_file():
        objects = {r["scene"]: r.get("obj_f2cm") for r in json.loads(p.read_text())["rows"] if r["method"] == "fast"}
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    fig, ax = plt.subplots(figsize=(8, 5))
    for i, sc in enumerate(scenes):
        col = f"C{i}"
        for method, style in (("oracle", "-o"), ("oracle-no-smooth", "s"), ("oracle-raw", "x"), ("fast", "--^")):
            pts = sorted((100 * r["voxel_m"], r["obj_f2cm"]) for r in rows
                         if r["scene"] == sc and r["method"] == method and r.get("obj_f2cm") is not None)
            if pts:
                ax.plot(*zip(*pts), style, color=col, label=f"{sc} {method}", ms=5,
                        mfc=col if method == "oracle" else "none")
        v128 = [100 * r["voxel_m"] for r in rows if r["scene"] == sc and r.get("resolution") == 128]
        if objects.get(sc) is not None and v128:
            ax.plot(v128[0], objects[sc], "*", color=col, ms=13, mec="k", label=f"{sc} fast (objects.json)")
    ax.axhline(0.90, color="grey", lw=0.8, ls="--")
    ax.text(ax.get_xlim()[0], 0.905, " target 0.90", color="grey", fontsize=8)
    ax.set_xlabel("voxel size (cm)")
    ax.set_ylabel("object F-score at 2 cm")
    ax.set_title("representation: what the grid can reach (oracle) and what fits reach")
    ax.legend(fontsize=6, ncol=2, loc="lower left")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


SUITE = Suite("representation", "oracle density grid from the ground truth through the fit's export, per grid "
              "resolution; real fits at finer grids (issue 11: what the representation can reach)",
              quick=Settings(scenes=("cave-chair",), resolutions=(64,), fit_scenes=()),
              full=Settings(), run=run, readme=readme, plot=plot, row_id=("method", "scene", "resolution"))
