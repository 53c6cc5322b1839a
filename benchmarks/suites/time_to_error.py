"""Time to error: test-view depth L1 against wall time for the fast and the platonerf mode.

Both fits run in this process on the chosen device; at checkpoints (every `*_eval_every_s` seconds of
training, and at the end) the fitted density is rendered on the dataset's test views with the evaluator's
density renderer (torch_recon.evaluate.render_density_depth, its default samples and opacity threshold)
and scored with its depth_metrics. A row per checkpoint: wall_s = setup (preprocess, rays, initial field)
+ training seconds so far (evaluation time excluded). The printout gives the time each method needs to
reach the other's best error and the ratio. The authors'-code curve is carried as cited reference rows
(measured outside this project; see AUTHORS_CURVE).
"""

from __future__ import annotations

import os
import resource
import time
from dataclasses import dataclass

from benchmarks.harness import Suite

#: PlatoNeRF's published code (facebookresearch/PlatoNeRF, src/run_platonerf.py, configs/chair.txt) run by a
#: previous session on our cave-chair dataset (128 x 128, 16 spots) exported to their layout, one H100,
#: scored with our evaluate metric on our 139 test views (issue 12). Not measured by this suite.
AUTHORS_CURVE = {
    "method": "authors' code (reference, measured outside the project)",
    "scene": "cave-chair", "resolution": 128, "spots": 16, "device": "NVIDIA H100",
    "note": "23.8 steps/s before step 25k (distance-only warm-up), 14 steps/s after",
    "points": [  # (step, depth L1 m, PSNR dB or None, training seconds or None)
        (2060, 1.68, None, None), (10029, 0.93, None, None), (21040, 0.63, None, None),
        (25599, 0.287, None, None), (27248, 0.128, 25.62, 1333.0)],
}


@dataclass
class Settings:
    """Defaults (= full): the 2-core CPU run that finishes in about 20 minutes; on a GPU see GPU_COMMAND."""

    example: str = "cave-chair"
    resolution: int = 64
    spots: int = 16
    device: str = "cpu"                    # 'cpu', 'cuda' or 'auto' (the fit's device setting)
    threads: int = 2
    view_stride: int = 10                  # every n-th test view (both methods see the same ones)
    pixel_stride: int = 4                  # every n-th pixel of each view, in rows and columns
    fast_steps: int | None = None          # None: the fast mode's default
    fast_eval_every_s: float = 10.0
    platonerf_budget_s: float = 300.0      # training seconds (their full schedule is 200k steps)
    platonerf_eval_every_s: float = 100.0
    platonerf_volume_resolution: int = 64  # the final mesh (object metrics): 64^3 MLP queries
    platonerf_timing_steps: int = 1        # steps of each phase (warm-up, with shadow loss) timed in a subprocess
    methods: tuple[str, ...] = ("fast", "platonerf")


#: the GPU run (issue 12's setting: 128 px, all 139 test views, 30 minutes of platonerf), one command:
GPU_COMMAND = ("python -m benchmarks run time_to_error --set device=cuda --set resolution=128 --set view_stride=1 "
               "--set pixel_stride=1 --set fast_eval_every_s=1 --set platonerf_budget_s=1800 "
               "--set platonerf_eval_every_s=300 --set platonerf_volume_resolution=128 --set platonerf_timing_steps=200")


def _test_views(ds_path, stride):
    from torch_recon.contract.dataset import load_dataset

    ds = load_dataset(ds_path)
    tv = ds.test_views()
    if tv is None:
        raise ValueError(f"{ds_path}: dataset has no test views")
    views, cams, gt = tv
    return views, cams[::stride], gt[::stride]


def _scorer(views, cams, gt, device, stride):
    import numpy as np

    from torch_recon.evaluate import EvalSettings, depth_metrics, render_density_depth

    es = EvalSettings()
    rows, cols = np.meshgrid(np.arange(0, views.height, stride), np.arange(0, views.width, stride), indexing="ij")
    pixels = (rows * views.width + cols).reshape(-1)
    gt_px = gt.reshape(len(cams), 1, -1)[:, :, pixels]

    def score(model, bbox_min, bbox_max):
        preds = np.stack([render_density_depth(model.density, c, views.width, views.height, views.fov_rad,
                                               bbox_min, bbox_max, views.fov_axis, es.density_samples,
                                               es.density_min_opacity, device, pixels=pixels)[None] for c in cams])
        m = depth_metrics(preds, gt_px, es.miss_depth)
        return {"depth_l1_m": m["depth_l1_m"], "depth_psnr_db": m["depth_psnr_db"], "hit_fraction": m["hit_fraction"]}
    return score


def _model_box(model):
    if hasattr(model, "grid"):
        return model.grid.box.bbox_min.cpu().numpy(), model.grid.box.bbox_max.cpu().numpy()
    return model.bbox[0].cpu().numpy(), model.bbox[1].cpu().numpy()


def _object_metrics(ctx, ds_path, r, mode) -> dict:
    """Object metrics (torch_recon.evaluation.objects, as `evaluate` computes them) of the mesh the fit
    would export from its final field (no UVs); an empty field (no surface) gives None values."""
    from torch_recon.contract.dataset import load_dataset
    from torch_recon.evaluate import _load_gt_mesh
    from torch_recon.evaluation.objects import ObjectMetricSettings, object_surface_metrics
    from torch_recon.evaluation.report import load_gt_objects
    from torch_recon.mesh_export import MeshExportError
    from torch_recon.recon.api import export_volume

    ds = load_dataset(ds_path)
    gt = _load_gt_mesh(ds)
    cfg, model = r.model.cfg, r.model
    vol, level = model.surface_volume() if hasattr(model, "surface_volume") else (r.volume, cfg.mesh_level)
    free = model.free_evidence() if hasattr(model, "free_evidence") else None
    try:
        _, mesh = export_volume(vol, r.bbox_min, r.bbox_max, level, ctx.work_dir / f"{mode}_mesh", {}, uv=False,
                                free_space=free, smooth_iterations=cfg.mesh_smooth_iterations)
    except MeshExportError as exc:
        ctx.log(f"  {mode}: no mesh for the object metrics ({exc})")
        mesh = None
    objects, _ = load_gt_objects(ds, gt)
    om = object_surface_metrics(mesh, gt, objects, ds.manifest.sensor, ObjectMetricSettings())
    summ, scene = om.get("summary", {}), om.get("scene", {})
    return {"object_fscore_2cm": summ.get("fscore@2cm"), "object_recall_hidden_2cm": summ.get("recall_hidden@2cm"),
            "object_chamfer_m": summ.get("chamfer_m"), "spurious_fraction": scene.get("spurious_fraction"),
            "objects": ",".join(om.get("objects", {}))}


def _fit_curve(ctx, ds_path, mode, settings, score):
    """Checkpoint rows of one fit: (rows, fit result)."""
    from torch_recon.recon import FitConfig, fit

    cfg = FitConfig(mode=mode, device=settings.device, threads=settings.threads, progress=False, resume=False)
    if mode == "fast":
        cfg.steps = settings.fast_steps
        cfg.eval_every_s = settings.fast_eval_every_s
    else:
        cfg.max_seconds = settings.platonerf_budget_s
        cfg.eval_every_s = settings.platonerf_eval_every_s
        cfg.platonerf.volume_resolution = settings.platonerf_volume_resolution
    points = []

    def on_eval(model, step, seconds):
        t0 = time.perf_counter()
        m = score(model, *_model_box(model))
        points.append({"step": step, "train_s": seconds, "eval_s": time.perf_counter() - t0, **m})
        ctx.log(f"  {mode}: step {step}, {seconds:.1f} s training: L1 {m['depth_l1_m']:.4f} m")
        return m

    with ctx.timed() as t:
        r = fit(str(ds_path), mode=mode, config=cfg, export=False, on_eval=on_eval)
    if not points or points[-1]["step"] != r.train.steps_done:
        on_eval(r.model, r.train.steps_done, r.train.train_seconds)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    hist = r.train.history
    rows = []
    for p in points:
        rows.append({"method": mode, "scene": settings.example, "wall_s": round(r.setup_seconds + p["train_s"], 3),
                     "cpu_s": None, "peak_rss_mb": round(rss, 1), "depth_l1_m": p["depth_l1_m"],
                     "depth_psnr_db": p["depth_psnr_db"], "hit_fraction": p["hit_fraction"], "step": p["step"],
                     "setup_s": round(r.setup_seconds, 3), "train_s": round(p["train_s"], 3),
                     "eval_s": round(p["eval_s"], 2), "device": str(r.metadata.get("device")),
                     "kind": "checkpoint"})
    sps = len(hist) / hist[-1]["seconds"] if hist and hist[-1]["seconds"] > 0 else None
    rows[-1].update(_object_metrics(ctx, ds_path, r, mode))
    rows[-1].update({"kind": "final", "fit_wall_s": round(t.wall_s, 2), "fit_cpu_s": round(t.cpu_s, 2),
                     "steps_per_s": sps, "stopped": r.train.stopped,
                     "reinitialised_after_steps": r.metadata.get("reinitialised_after_steps")})
    return rows, r


def _phase_timing(ctx, ds_path, settings, phase):
    """Seconds per platonerf step in `phase` ('warmup': distance loss only; 'shadow': with the shadow terms),
    wall and CPU, with the 1-minute load average, from a run of `platonerf_timing_steps` steps in a subprocess
    (a shadow step holds several GB of activations on a CPU; an out-of-memory kill gives None)."""
    import json

    run = ctx.run_cli(["python", "-m", "benchmarks.suites.time_to_error", str(ds_path), settings.device,
                       str(settings.threads), str(settings.platonerf_timing_steps), phase], check=False)
    if run.returncode != 0:
        ctx.log(f"  platonerf {phase} step timing failed (exit {run.returncode}): {run.stderr.strip()[-300:]}")
        return {"peak_rss_mb": run.peak_rss_mb}
    t = json.loads(run.stdout.strip().splitlines()[-1])
    ctx.log(f"  platonerf {phase}: {t['wall_s_per_step']:.2f} s per step ({t['cpu_s_per_step']:.2f} CPU s), "
            f"{t['steps']} steps of {t['rays_per_step']} rays, {t['threads']} threads, load {t['load_start']}"
            f" -> {t['load_end']}, peak RSS {run.peak_rss_mb:.0f} MB")
    return {**t, "peak_rss_mb": run.peak_rss_mb}


def _time_steps(ds_path, device, threads, steps, phase) -> dict:
    """The timing subprocess: `steps` training steps of the platonerf mode, all in `phase`, timed around
    train() (setup and the mesh volume excluded); seconds per step, wall and CPU (all threads)."""
    import torch

    from torch_recon.device import resolve_device
    from torch_recon.recon import FitConfig
    from torch_recon.recon.api import load_source
    from torch_recon.recon.data import build_ray_data
    from torch_recon.recon.models import build_model
    from torch_recon.recon.trainer import train

    cfg = FitConfig(mode="platonerf", device=device, threads=threads, progress=False, resume=False, steps=steps)
    cfg.loss.warmup_fraction = 1.0 if phase == "warmup" else 0.0
    dev = resolve_device(cfg.device, cfg.threads)
    data = build_ray_data(load_source(ds_path, False, dev)[0]).to(dev)
    gen = torch.Generator(device=dev)
    gen.manual_seed(cfg.seed)
    model = build_model(data, cfg, {}, gen)
    sync = torch.cuda.synchronize if dev.type == "cuda" else (lambda: None)
    load0, w0, c0 = os.getloadavg()[0], time.perf_counter(), time.process_time()
    r = train(model, data, cfg, gen)
    sync()
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    return {"phase": phase, "steps": r.steps_done, "rays_per_step": cfg.platonerf.rays_per_batch,
            "wall_s_per_step": wall / r.steps_done, "cpu_s_per_step": cpu / r.steps_done, "device": str(dev),
            "threads": torch.get_num_threads(), "load_start": round(load0, 2), "load_end": round(os.getloadavg()[0], 2)}


def time_to_reach(rows, target):
    """Wall seconds of the first checkpoint at or below `target` depth L1 (None: never)."""
    for r in sorted(rows, key=lambda r: r["wall_s"]):
        if r["depth_l1_m"] <= target:
            return r["wall_s"]
    return None


def estimated_reference_seconds(step: int) -> float:
    """Training seconds of the authors' run at `step` from its measured rates (23.8 steps/s in the
    warm-up, 14 after step 25k): an estimate for plotting only (their last point, 1,333 s, was measured)."""
    return step / 23.8 if step <= 25_000 else 25_000 / 23.8 + (step - 25_000) / 14.0


def reference_rows():
    a = AUTHORS_CURVE
    return [{"method": a["method"], "scene": a["scene"], "wall_s": secs, "cpu_s": None, "peak_rss_mb": None,
             "depth_l1_m": l1, "depth_psnr_db": psnr, "step": step, "device": a["device"], "kind": "reference",
             "note": a["note"]} for step, l1, psnr, secs in a["points"]]


def run(settings: Settings, ctx) -> list[dict]:
    from torch_recon.device import resolve_device

    ds = ctx.dataset(settings.example, settings.resolution, settings.spots)
    device = str(resolve_device(settings.device, settings.threads))
    views, cams, gt = _test_views(ds, settings.view_stride)
    ctx.log(f"  {len(cams)} test views of {views.width} x {views.height}, every {settings.pixel_stride}. pixel, "
            f"device {device}")
    score = _scorer(views, cams, gt, device, settings.pixel_stride)
    rows, best = [], {}
    for mode in settings.methods:
        curve, r = _fit_curve(ctx, ds, mode, settings, score)
        if mode == "platonerf" and settings.platonerf_timing_steps > 0:
            for phase in ("warmup", "shadow"):
                t = _phase_timing(ctx, ds, settings, phase)
                curve[-1].update({f"{phase}_{k}": t.get(k) for k in ("wall_s_per_step", "cpu_s_per_step",
                                                                     "load_start", "load_end", "peak_rss_mb")})
        rows += curve
        best[mode] = min(c["depth_l1_m"] for c in curve)
    from benchmarks.harness import report

    ctx.log(f"  on {report.machine_line(report.machine_info())}, device {device}, {settings.threads} threads, "
            f"1-minute load {os.getloadavg()[0]:.1f}:\n" + _summary(rows, best))
    return rows + reference_rows()


def _summary(rows, best) -> str:
    lines = []
    modes = list(best)
    for a in modes:
        for b in modes:
            if a == b:
                continue
            t = time_to_reach([r for r in rows if r["method"] == a], best[b])
            tb = time_to_reach([r for r in rows if r["method"] == b], best[b])
            ratio = (tb / t) if t and tb else None
            lines.append(f"  {a} reaches {b}'s best L1 {best[b]:.4f} m in "
                         f"{'never (within its run)' if t is None else f'{t:.1f} s'}; {b} needed "
                         f"{tb:.1f} s" + (f" (ratio {ratio:.1f}x)" if ratio else ""))
    return "\n".join(lines)


def plot(rows, settings, path):
    from benchmarks.harness import report

    colours = {"fast": "tab:blue", "platonerf": "tab:red"}
    with report.figure(path, (7, 4.5)) as ax:
        for mode in dict.fromkeys(r["method"] for r in rows):
            rs = sorted((r for r in rows if r["method"] == mode and r["wall_s"] is not None), key=lambda r: r["wall_s"])
            if not rs:
                continue
            ref = rs[0]["kind"] == "reference"
            ax.plot([r["wall_s"] for r in rs], [r["depth_l1_m"] for r in rs], "s--" if ref else "o-",
                    color=colours.get(mode, "gray"), label=f"{mode} ({rs[0].get('device')})")
        ref = sorted((r for r in rows if r["kind"] == "reference"), key=lambda r: r["step"])
        if ref:                             # their points without a measured time: placed by their steps/s
            ax.plot([r["wall_s"] or estimated_reference_seconds(r["step"]) for r in ref],
                    [r["depth_l1_m"] for r in ref], "s:", mfc="none", color="gray",
                    label="authors' code, time from their steps/s (estimate)")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("wall time: setup + training (s)")
        ax.set_ylabel("test-view depth L1 (m)")
        ax.set_title(f"time to error, {settings.example} {settings.resolution} px, {settings.spots} spots, "
                     f"{settings.device}", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)


def readme(results) -> str:
    from benchmarks.harness.report import markdown_table

    rows = [r for r in results["rows"] if r.get("kind") in ("final", "reference")]
    cols = [("method", "method"), ("device", "device"), ("step", "steps"), ("wall_s", "wall s"),
            ("depth_l1_m", "depth L1 m"), ("depth_psnr_db", "PSNR dB"), ("steps_per_s", "steps/s")]
    return markdown_table(rows, cols)


SUITE = Suite(
    name="time_to_error",
    description="depth L1 against wall time, fast vs platonerf (checkpoints), with the authors'-code curve as reference",
    quick=Settings(view_stride=70, pixel_stride=8, fast_steps=30, fast_eval_every_s=20.0, platonerf_budget_s=60.0,
                   platonerf_eval_every_s=1e9, platonerf_volume_resolution=32, platonerf_timing_steps=0),
    full=Settings(),
    run=run, plot=plot, readme=readme,
)


if __name__ == "__main__":      # the step-timing subprocess: DATASET DEVICE THREADS STEPS PHASE -> a JSON line
    import json
    import sys

    print(json.dumps(_time_steps(sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5])))
