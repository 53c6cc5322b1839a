"""Time to error: test-view depth L1 against wall time for the fast and the platonerf mode.

Both fits run in this process on the chosen device; at checkpoints (every `*_eval_every_s` seconds of
training, and at the end) the mesh `fit` would export from the current field (no UVs) is scored as
`platolidar evaluate` scores a fit's mesh: depth L1 / PSNR on the dataset's valid test views (every
`view_stride`-th), and at the end the object metrics (torch_recon.evaluation.objects). A row per checkpoint:
wall_s = setup (preprocess, rays, initial field) + training seconds so far (evaluation time excluded).
platonerf's seconds per step in each phase (warm-up; with the shadow loss) come from short subprocess runs,
wall and CPU, with the load. The printout gives the time each method needs to reach the other's best error
and the ratio, with the machine. The authors'-code curve is carried as cited reference rows
(measured outside this project; see AUTHORS_CURVE).
"""

from __future__ import annotations

import os
import resource
import time
import traceback
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
    """Defaults (= full): the 2-core CPU run that finishes in about 25 minutes on the shared machine (fast mode
    cut to 30 steps, platonerf to a 150 s budget: far from converged); on a GPU the suite time_to_error_gpu."""

    example: str = "cave-chair"
    resolution: int = 64
    spots: int = 16
    device: str = "cpu"                    # 'cpu', 'cuda' or 'auto' (the fit's device setting)
    threads: int = 2
    view_stride: int = 10                  # every n-th valid test view (both methods see the same ones)
    fast_steps: int | None = 30            # None: the fast mode's default (200)
    fast_eval_every_s: float = 120.0
    platonerf_budget_s: float = 150.0      # training seconds (their full schedule is 200k steps)
    platonerf_eval_every_s: float = 1e9    # checkpoints (each meshes the field); the end is always scored
    platonerf_volume_resolution: int = 48  # the mesh of the MLP field: 48^3 queries per checkpoint
    platonerf_timing_steps: int = 1        # steps of each phase (warm-up, with shadow loss) timed in a subprocess
    methods: tuple[str, ...] = ("fast", "platonerf")


#: the GPU run (issue 12's setting: 128 px, all 139 test views, 30 minutes of platonerf): the suite
#: `time_to_error_gpu`, whose full settings these are (its own results JSON beside the CPU one).
GPU_SETTINGS = Settings(device="cuda", resolution=128, view_stride=1, fast_steps=None, fast_eval_every_s=2.0,
                        platonerf_budget_s=1800.0, platonerf_eval_every_s=300.0, platonerf_volume_resolution=128,
                        platonerf_timing_steps=200)


class _Scorer:
    """`evaluate`'s metrics of a fit's mesh: test-view depth L1 / PSNR (every `view_stride`-th valid test view,
    mesh ray-cast as `platolidar evaluate` does with a fit's mesh.glb) and, on request, the object metrics
    (torch_recon.evaluation.objects)."""

    def __init__(self, ds_path, view_stride: int):
        from torch_recon.contract.dataset import load_dataset
        from torch_recon.evaluate import EvalSettings, _load_gt_mesh, _valid_test_views
        from torch_recon.evaluation.report import load_gt_objects

        self.ds = load_dataset(ds_path)
        self.es = EvalSettings()
        self.gt_mesh = _load_gt_mesh(self.ds)
        tv = _valid_test_views(self.ds, self.gt_mesh, self.es, {})
        if tv is None:
            raise ValueError(f"{ds_path}: dataset has no (valid) test views")
        self.views, cams, gt = tv
        self.cams, self.gt = cams[::view_stride], gt[::view_stride]
        self.objects, _ = load_gt_objects(self.ds, self.gt_mesh)

    def depth(self, mesh) -> dict:
        import numpy as np

        from torch_recon.evaluate import depth_metrics, render_mesh_depth

        v = self.views
        preds = (np.full_like(self.gt, np.inf) if mesh is None else      # an empty field: every pixel a miss
                 np.stack([render_mesh_depth(mesh, c, v.width, v.height, v.fov_rad, v.fov_axis, self.es.cull_back_faces)
                           for c in self.cams]))
        m = depth_metrics(preds, self.gt, self.es.miss_depth)
        return {"depth_l1_m": m["depth_l1_m"], "depth_psnr_db": m["depth_psnr_db"], "hit_fraction": m["hit_fraction"]}

    def volume_depth(self, model) -> dict:
        """Depth L1 of the field's own volume rendering (the mode's test rendering: the authors' depth, leftover
        transmittance at the far bound), the way a NeRF is scored without a mesh: the reference rows' kind of
        number, which a mesh at one iso level can miss entirely while the field is still diffuse."""
        import numpy as np

        from torch_recon.evaluate import depth_metrics
        from torch_recon.recon.api import render_model_depth

        v = self.views
        preds = np.stack([render_model_depth(model, c, v.width, v.height, v.fov_rad, v.fov_axis, None) for c in self.cams])
        return {"depth_l1_volume_m": depth_metrics(preds, self.gt, self.es.miss_depth)["depth_l1_m"]}

    def objects_of(self, mesh) -> dict:
        from torch_recon.evaluation.objects import ObjectMetricSettings, object_surface_metrics

        om = object_surface_metrics(mesh, self.gt_mesh, self.objects, self.ds.manifest.sensor,
                                    ObjectMetricSettings(seed=self.es.seed))
        summ, scene = om.get("summary", {}), om.get("scene", {})
        return {"object_fscore_2cm": summ.get("fscore@2cm"), "object_recall_hidden_2cm": summ.get("recall_hidden@2cm"),
                "object_chamfer_m": summ.get("chamfer_m"), "spurious_fraction": scene.get("spurious_fraction"),
                "objects": ",".join(om.get("objects", {}))}


def _mesh_of(model):
    """The mesh `fit` would export from the model's current field (no UVs, no files); None for an empty field."""
    from torch_recon.mesh_export import MeshExportError, mesh_from_volume
    from torch_recon.recon.api import mesh_inputs, voxel_centre_box

    vol, lo, hi = model.density_volume()
    free = model.free_evidence() if hasattr(model, "free_evidence") else None
    mvol, level, args = mesh_inputs(model, model.cfg, vol, free)
    try:
        mesh = mesh_from_volume(mvol, *voxel_centre_box(mvol, lo, hi), level, **args)[0]
    except MeshExportError:
        return None
    return mesh if len(mesh.faces) else None


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
    points, final = [], {}

    def on_eval(model, step, seconds, last=False):
        t0 = time.perf_counter()
        mesh = _mesh_of(model)
        m = score.depth(mesh)
        if mode == "platonerf":
            m.update(score.volume_depth(model))
        if last:
            final.update(score.objects_of(mesh))
        points.append({"step": step, "train_s": seconds, "eval_s": time.perf_counter() - t0, **m})
        ctx.log(f"  {mode}: step {step}, {seconds:.1f} s training: L1 {m['depth_l1_m']:.4f} m"
                + ("" if mesh is not None else " (no surface at the mesh level)")
                + (f", volume-rendered {m['depth_l1_volume_m']:.4f} m" if "depth_l1_volume_m" in m else ""))
        return m

    with ctx.timed() as t:
        r = fit(str(ds_path), mode=mode, config=cfg, export=False, on_eval=on_eval)
    if points and points[-1]["step"] == r.train.steps_done:
        points.pop()                    # scored again below with the object metrics
    on_eval(r.model, r.train.steps_done, r.train.train_seconds, last=True)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    hist = r.train.history
    rows = []
    for p in points:
        rows.append({"method": mode, "scene": settings.example, "wall_s": round(r.setup_seconds + p["train_s"], 3),
                     "cpu_s": None, "peak_rss_mb": round(rss, 1), "depth_l1_m": p["depth_l1_m"],
                     "depth_psnr_db": p["depth_psnr_db"], "hit_fraction": p["hit_fraction"], "step": p["step"],
                     **({"depth_l1_volume_m": p["depth_l1_volume_m"]} if "depth_l1_volume_m" in p else {}),
                     "setup_s": round(r.setup_seconds, 3), "train_s": round(p["train_s"], 3),
                     "eval_s": round(p["eval_s"], 2), "device": str(r.metadata.get("device")),
                     "kind": "checkpoint"})
    sps = len(hist) / hist[-1]["seconds"] if hist and hist[-1]["seconds"] > 0 else None
    rows[-1].update(final)
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
    score = _Scorer(ds, settings.view_stride)
    ctx.log(f"  {len(score.cams)} test views of {score.views.width} x {score.views.height}, device {device}")
    rows, best = [], {}
    for mode in settings.methods:
        try:
            curve, r = _fit_curve(ctx, ds, mode, settings, score)
        except Exception as exc:        # one device call is all a GPU run gets: the other method still runs
            ctx.log(f"  {mode} FAILED on {device}: {type(exc).__name__}: {exc}\n" + traceback.format_exc()[-2000:])
            continue
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
            vol = [r for r in rs if r.get("depth_l1_volume_m") is not None]
            if vol:                         # the field's own volume rendering: how the reference was scored
                ax.plot([r["wall_s"] for r in vol], [r["depth_l1_volume_m"] for r in vol], "o--", mfc="none",
                        color=colours.get(mode, "gray"), label=f"{mode}, volume-rendered depth (no mesh)")
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
            ("depth_l1_m", "depth L1 m"), ("depth_l1_volume_m", "L1 m, field volume-rendered"),
            ("depth_psnr_db", "PSNR dB"), ("steps_per_s", "steps/s")]
    return markdown_table(rows, cols)


SUITE = Suite(
    name="time_to_error",
    description="depth L1 against wall time, fast vs platonerf (checkpoints), with the authors'-code curve as reference",
    quick=Settings(view_stride=70, fast_steps=30, fast_eval_every_s=20.0, platonerf_budget_s=60.0,
                   platonerf_eval_every_s=1e9, platonerf_volume_resolution=32, platonerf_timing_steps=0),
    full=Settings(),
    run=run, plot=plot, readme=readme,
)

GPU_SUITE = Suite(
    name="time_to_error_gpu",
    description="time_to_error on a CUDA device at the issue's setting (128 px, all valid test views, default fast "
                "steps, 30 min of platonerf); the device tool's 10-minute calls run it with a shorter platonerf budget",
    quick=Settings(device="cuda", resolution=128, view_stride=10, fast_steps=None, fast_eval_every_s=2.0,
                   platonerf_budget_s=60.0, platonerf_eval_every_s=30.0, platonerf_volume_resolution=64,
                   platonerf_timing_steps=50),
    full=GPU_SETTINGS,
    run=run, plot=plot, readme=readme,
)
SUITES = [GPU_SUITE]


if __name__ == "__main__":      # the step-timing subprocess: DATASET DEVICE THREADS STEPS PHASE -> a JSON line
    import json
    import sys

    print(json.dumps(_time_steps(sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5])))
