"""Measurements: preprocessing speed, closed-form visible-depth error, BF Lidar on the cave-chair.

- 'analytic' rows: torch_recon.contract.analytic (trimesh/Embree) transients of the cave-chair geometry (16 paper
  spots, 391 bins of 128 ps, Gaussian 128 ps pulse) rendered in memory spot by spot; preprocessing (first
  bounce, pulse, gate, matched filter, sub-bin peaks, parallel filter, then the fusion of the visible
  depth) timed in-process on dense cubes and on windowed (32-bin) cubes; rendering is not counted.
  'analytic+poisson' adds Poisson counts and an ambient floor.
- 'cycles' rows: cached Cycles datasets through `torch_recon preprocess` (the process's time: start-up
  and reading included), then `torch_recon baseline --grid-search` (BF Lidar, thresholds picked on the
  test views as the paper tuned them per scene) and `torch_recon evaluate` on the dataset's test views.
Visible-depth error: fused closed form against the ground-truth range at pixel centres, on pixels with a
fused depth: median and 95th percentile in mm, and coverage.
- 'path estimator' rows: per example scene (Cycles 128 x 128, 16 spots, expected values) the fused visible depth
  with each two-bounce path estimator: the return's intensity centroid (the default) and the 3-bin Gaussian fit
  (`return_centroid_fraction` 0): a pixel that sees a surface at a grazing angle holds a flat-topped return
  (docs/measurements.md "Grazing returns"); median / p95 / p99 |error| and the signed median on the room's
  surfaces beside its far end (true range within 0.4 m of the farthest 1 % of the image).
- 'shadows' rows: per example scene (Cycles, 16 spots) with expected values and with Poisson counts, the
  shadow masks and two-bounce paths of each shadow decision against the ground truth ray cast in the
  scene's mesh (torch_recon.measurement_truth: lit fraction of 3 x 3 sub-pixel rays, truth shadow below
  one half): precision / recall / F1, recall on thin shadows, on shadows cast by labelled objects and on
  partly lit shadow pixels, the share of pixels an object shadows in part called lit (they carve it), the
  false-shadow rate on fully lit pixels, unlabelled pixels, path error on fully lit pixels; preprocessing
  timed in-process (1 thread).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from benchmarks.harness import Suite, report, runners


@dataclass(frozen=True)
class Settings:
    analytic_resolutions: tuple[int, ...] = (128, 512)
    poisson_resolution: int = 128              # 0: no analytic+poisson row
    cycles_resolutions: tuple[int, ...] = (128, 512)
    threads: int = 1                           # torch threads (one avoids OpenMP stalls on a shared 2-core machine)
    window_bins: int = 32
    test_views: int | None = None              # Cycles test views (None: the paper's 139)
    test_view_resolution: int = 128
    path_scenes: tuple[str, ...] = ("cave-chair", "organic-occluded", "thin-structures", "curved-wall", "dark-room", "outside-fov")
    shadow_scenes: tuple = ("cave-chair", "thin-structures", "dark-room", "organic-occluded")
    shadow_resolution: int = 128
    shadow_noise: tuple = ("expected", "poisson")   # simulator defaults / Poisson counts (1000 photons budget)


def depth_error(depth, gt) -> dict:
    ok = np.isfinite(depth) & np.isfinite(gt)
    e = np.abs(depth - gt)[ok] * 1e3
    return {"visible_depth_median_mm": float(np.median(e)), "visible_depth_p95_mm": float(np.percentile(e, 95)),
            "visible_depth_p99_mm": float(np.percentile(e, 99)),
            "visible_depth_coverage": float(ok.sum() / max(np.isfinite(gt).sum(), 1))}


def analytic_rows(ctx, s: Settings, res: int, subpixel: int, photons=None, ambient=0.0, seed=0) -> list[dict]:
    """Render spot by spot (a 512^2 x 391 cube is 400 MB); time preprocessing of each, dense and windowed."""
    from torch_recon.contract.analytic import range_image, render_two_bounce
    from torch_recon.contract.dataset import Spot, Transient
    from torch_recon.measurements import Measurements
    from torch_recon.preprocess import PreprocessSettings, process_spot, world_pixel_directions
    from torch_recon.contract.synthetic import cave_chair_scene, default_sensor, paper_laser_directions
    from torch_recon.visible_depth import fuse_visible_depth

    mesh, _ = cave_chair_scene()
    sensor = default_sensor(res, res, bins=391)
    dirs = world_pixel_directions(sensor)
    rng = np.random.default_rng(seed)
    results = {"dense": [], f"windowed {s.window_bins}": []}
    times = {k: [] for k in results}
    scale = None
    for k, ld in enumerate(paper_laser_directions()):
        cube = render_two_bounce(mesh, sensor, [ld], subpixel=subpixel)[0]
        if photons is not None:
            if scale is None:   # photons of the brightest two-bounce pixel of the first spot
                two = render_two_bounce(mesh, sensor, [ld], subpixel=subpixel, include_first_bounce=False)[0]
                scale = photons / max(float(two.sum(-1).max()), 1e-30)
            cube = rng.poisson(cube * scale + ambient).astype(np.float32)
        spot = Spot(id=k, laser_direction=list(map(float, ld)), transient_file="")
        for layout, tr in (("dense", Transient.from_dense(cube)),
                           (f"windowed {s.window_bins}", Transient.from_dense(cube, s.window_bins))):
            with ctx.timed() as t:
                results[layout].append(process_spot(tr, sensor, spot, PreprocessSettings(), dirs=dirs))
            times[layout].append(t)
        del cube
    gt = range_image(mesh, sensor.camera_to_world, res, res, sensor.fov_rad)
    source = "analytic" if photons is None else "analytic+poisson"
    rows = []
    for layout, spots in results.items():
        meas = Measurements(width=res, height=res, fov_rad=sensor.fov_rad, fov_axis=sensor.fov_axis,
                            camera_to_world=np.asarray(sensor.camera_to_world),
                            laser_origin=np.asarray(sensor.laser_origin), bin_width_m=sensor.bin_width_m,
                            shadow_threshold=0.15, spots=spots)
        with ctx.timed() as tf:
            fused = fuse_visible_depth(meas)
        ts = times[layout] + [tf]
        rows.append({"method": f"preprocess {layout}", "scene": f"cave-chair ({source})",
                     "wall_s": sum(t.wall_s for t in ts), "cpu_s": sum(t.cpu_s for t in ts),
                     "peak_rss_mb": max(t.peak_rss_mb for t in ts), "source": source, "resolution": res,
                     "spots": len(spots), "subpixel": subpixel, "photons": photons, "ambient_per_bin": ambient,
                     "fuse_s": tf.wall_s, **depth_error(fused.depth, gt)})
    return rows


def cycles_rows(ctx, s: Settings, res: int) -> list[dict]:
    from torch_recon.contract.dataset import load_dataset
    from torch_recon.measurements import Measurements
    data = ctx.dataset("cave-chair", res, test_views=s.test_views, test_view_resolution=s.test_view_resolution)
    prep = runners.preprocess(ctx, data, f"meas{res}", threads=s.threads)
    meas = Measurements.load(prep["measurements"])
    err = depth_error(meas.visible_depth, load_dataset(data).train_depth())
    b = runners.baseline(ctx, data, f"bflidar{res}", measurements=prep["measurements"], voxels=128, grid_search=True,
                         args=("--threads", s.threads))
    scene = "cave-chair (cycles)"
    return [runners.row("preprocess (torch_recon preprocess)", scene, prep, (), source="cycles", resolution=res,
                        spots=len(meas.spots), **err),
            runners.row("bflidar (grid search, reused measurements)", scene, b, source="cycles", resolution=res)]


PATH_ESTIMATORS = {"return centroid": {"return_centroid_fraction": 0.05}, "3-bin Gaussian fit": {"return_centroid_fraction": 0.0}}


def path_rows(ctx, s: Settings, scene: str) -> list[dict]:
    """The fused visible depth of each two-bounce path estimator against the training view's true range."""
    from torch_recon.contract.dataset import load_dataset
    from torch_recon.preprocess import PreprocessSettings, preprocess_dataset
    ds = load_dataset(ctx.dataset(scene, s.shadow_resolution, 16))
    gt = ds.train_depth()
    far = np.isfinite(gt) & (gt >= np.nanpercentile(np.where(np.isfinite(gt), gt, np.nan), 99) - 0.4)
    rows = []
    for name, kw in PATH_ESTIMATORS.items():
        with ctx.timed() as t:
            meas = preprocess_dataset(ds, PreprocessSettings(**kw))
        err = depth_error(meas.visible_depth, gt)
        ok = far & np.isfinite(meas.visible_depth)
        err["visible_depth_far_signed_mm"] = float(np.median(meas.visible_depth[ok] - gt[ok]) * 1e3) if ok.any() else float("nan")
        rows.append({"method": f"path: {name}", "scene": f"{scene} (cycles)", **t.times(), "source": "cycles",
                     "resolution": s.shadow_resolution, "spots": len(meas.spots), **err})
    return rows


SHADOW_DECISIONS = {"matched filter (paper)": dict(partial_shadow_ratio=0.0, shadow_false_alarm=0.0,
                                                   return_false_alarm=0.0),
                    "photon-count test": {},
                    "photon-count test, partly shadowed unlabelled": dict(partial_unlabel_ratio=0.8)}


def shadow_rows(ctx, s: Settings, scene: str, noise: str) -> list[dict]:
    """Each shadow decision's masks and paths against the ray-cast truth (see the module docstring)."""
    from torch_recon.contract.dataset import load_dataset
    from torch_recon.measurement_truth import measurement_accuracy, spot_truths
    from torch_recon.preprocess import PreprocessSettings, preprocess_dataset
    opts = {} if noise == "expected" else {"poisson": True, "test_views": "0"}
    ds = load_dataset(ctx.dataset(scene, s.shadow_resolution, 16, **opts))
    truths = spot_truths(ds)
    rows = []
    for name, kw in SHADOW_DECISIONS.items():
        with ctx.timed() as t:
            meas = preprocess_dataset(ds, PreprocessSettings(**kw))
        acc = measurement_accuracy(meas, truths, ds.sensor.bin_width_m)
        rows.append({"method": f"shadows: {name}", "scene": f"{scene} ({noise})", **t.times(), "source": "cycles",
                     "resolution": s.shadow_resolution, "noise": noise, "spots": len(meas.spots), **acc})
        ctx.log(f"  {scene} ({noise}) {name}: shadow P/R {acc['shadow_precision']:.4f}/{acc['shadow_recall']:.4f}, "
                f"thin R {acc['thin_shadow_recall']:.3f}, object R {acc['object_shadow_recall']:.3f}, "
                f"false {acc['false_shadow_rate']:.4f}, path median {acc['path_median_mm']:.3f} mm, {t.wall_s:.1f} s")
    return rows


def run(s: Settings, ctx) -> list[dict]:
    import torch
    torch.set_num_threads(s.threads)
    rows = []
    for res in s.analytic_resolutions:
        rows += analytic_rows(ctx, s, res, subpixel=3 if res <= 128 else 1)
    if s.poisson_resolution:
        rows += analytic_rows(ctx, s, s.poisson_resolution, subpixel=3, photons=2000.0, ambient=0.01)
    for res in s.cycles_resolutions:
        rows += cycles_rows(ctx, s, res)
    for scene in s.path_scenes:
        rows += path_rows(ctx, s, scene)
    for scene in s.shadow_scenes:
        for noise in s.shadow_noise:
            rows += shadow_rows(ctx, s, scene, noise)
    for r in rows:
        if "visible_depth_median_mm" in r:
            ctx.log(f"  {r['scene']} {r['resolution']} px {r['method']}: {r['wall_s']:.2f} s, visible depth median "
                    f"{r['visible_depth_median_mm']:.3f} mm, p95 {r['visible_depth_p95_mm']:.3f} mm")
    return rows


def readme(results) -> str:
    prep = [r for r in results["rows"] if "visible_depth_median_mm" in r and not r["method"].startswith("path:")]
    paths = [r for r in results["rows"] if r["method"].startswith("path:")]
    shadows = [r for r in results["rows"] if r["method"].startswith("shadows:")]
    bfl = [r for r in results["rows"] if r["method"].startswith("bflidar")]
    out = report.markdown_table(prep, [("scene", "data"), ("resolution", "px"), ("method", "stage"),
                                       ("wall_s", "wall s"), ("visible_depth_median_mm", "visible depth median mm"),
                                       ("visible_depth_p95_mm", "p95 mm"), ("visible_depth_coverage", "coverage")])
    if bfl:
        out += "\n\n" + report.markdown_table(bfl, [("scene", "BF Lidar on"), ("resolution", "px"), ("wall_s", "wall s"),
                                                   ("depth_l1_m", "depth L1 m"), ("depth_l1_m_on_hits", "L1 on hits m"),
                                                   ("depth_psnr_db", "PSNR dB"), ("n_test_views", "test views")])
    if paths:
        out += "\n\n" + report.markdown_table(paths, [
            ("scene", "scene (data)"), ("method", "two-bounce path"), ("wall_s", "preprocess s"),
            ("visible_depth_median_mm", "visible depth median mm"), ("visible_depth_p95_mm", "p95 mm"),
            ("visible_depth_p99_mm", "p99 mm"), ("visible_depth_far_signed_mm", "far end signed mm")])
    if shadows:
        out += "\n\n" + report.markdown_table(shadows, [
            ("scene", "scene (data)"), ("method", "shadow decision"), ("wall_s", "preprocess s"),
            ("shadow_precision", "precision"), ("shadow_recall", "recall"), ("shadow_f1", "F1"),
            ("thin_shadow_recall", "thin R"), ("object_shadow_recall", "object R"),
            ("partial_shadow_recall", "partial R"), ("object_lit_rate", "object-shadowed called lit"),
            ("false_shadow_rate", "false on lit"),
            ("unlabelled_rate", "unlabelled"), ("path_median_mm", "path median mm"), ("path_p95_mm", "path p95 mm")])
    return out


def plot(rows, s, path):
    prep = [r for r in rows if "visible_depth_median_mm" in r]
    if prep:
        return report.plot_rows(prep, path, y="visible_depth_median_mm", title="preprocessing time vs visible-depth error")
    return report.plot_rows([r for r in rows if r["method"].startswith("shadows:")], path, y="shadow_f1",
                            title="shadow F1 against the ray-cast truth vs preprocessing time")


SUITE = Suite("measurements", __doc__.splitlines()[0], run=run, readme=readme, plot=plot, row_id=("method", "scene", "resolution"),
              quick=Settings(analytic_resolutions=(32,), poisson_resolution=32, cycles_resolutions=(32,),
                             test_views=6, test_view_resolution=32, shadow_scenes=("thin-structures",),
                             path_scenes=("thin-structures",),
                             shadow_resolution=32),
              full=Settings())
