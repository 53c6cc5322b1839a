"""Measurements benchmark: preprocessing speed, closed-form visible depth error, BF Lidar on the cave-chair.

Figures (each row says its data source):
- 'analytic': torch_recon.contract.analytic (trimesh/Embree) transients of the cave-chair geometry
  (torch_recon/contract/scenes.py, 16 paper spots, 391 bins of 128 ps, Gaussian 128 ps pulse), in memory;
  'analytic+poisson' adds Poisson counts and an ambient floor.
- 'cycles': datasets written by pipeline/simulate.py (--cycles DIR ...), read from disk (read time
  reported apart); BF Lidar then uses the dataset's own test views and ground-truth mesh.
1. Preprocessing time (first bounce, pulse, gate, matched filter, sub-bin peaks, parallel
   filter; fusion of the visible depth) at 128x128 and 512x512 x 16 spots x 391 bins, dense
   cubes and windowed (32 bins) cubes. Rendering and file reading are not counted.
2. Visible-surface depth error (fused closed form vs ground-truth range at pixel centres) on
   pixels with a fused depth: median and 95th percentile in mm, and coverage.
3. BF Lidar depth L1 / PSNR on the paper's 139 test views (rendered at --test-res), its run
   time, Chamfer and F-score; thresholds grid-searched on every 4th test view, as the paper
   tuned them per scene against ground truth.

    python benchmarks/bench_measurements.py [--skip-512] [--cycles DIR ...] [--test-res 128] [--threads 1 2]
Writes benchmarks/results/measurements.json and benchmarks/results/measurements.png.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from benchmarks.common import RESULTS_DIR, machine_info, peak_rss_mb, timer, write_json  # noqa: E402
from torch_recon.contract.analytic import range_image, render_two_bounce  # noqa: E402
from torch_recon.contract.dataset import Spot, Transient  # noqa: E402
from torch_recon.evaluate import depth_metrics, render_mesh_depth, surface_metrics  # noqa: E402
from torch_recon.contract.frames import paper_test_view_cameras  # noqa: E402
from torch_recon.measurements import Measurements  # noqa: E402
from torch_recon.preprocess import PreprocessSettings, process_spot, world_pixel_directions  # noqa: E402
from torch_recon.contract.synthetic import cave_chair_scene, default_sensor, paper_laser_directions  # noqa: E402
from torch_recon.visible_depth import fuse_visible_depth  # noqa: E402

CHAIR_CROP = ((-0.5, 2.5, -2.0), (0.5, 3.5, -0.9))   # the chair's region (Chamfer/F-score on the object)


def depth_error_mm(depth, gt):
    ok = np.isfinite(depth) & np.isfinite(gt)
    e = np.abs(depth - gt)[ok] * 1e3
    return {"median_mm": float(np.median(e)), "p95_mm": float(np.percentile(e, 95)), "max_mm": float(e.max()),
            "coverage": float(ok.sum() / max(np.isfinite(gt).sum(), 1))}, e


def make_meas(sensor, spots):
    return Measurements(width=sensor.width, height=sensor.height, fov_rad=sensor.fov_rad, fov_axis=sensor.fov_axis,
                        camera_to_world=np.asarray(sensor.camera_to_world), laser_origin=np.asarray(sensor.laser_origin),
                        bin_width_m=sensor.bin_width_m, shadow_threshold=0.15, spots=spots)


def _timed_spot(tr, sensor, spot, settings, dirs, threads):
    """process_spot with each thread count: (result, {threads: seconds})."""
    import torch
    res, times = None, {}
    for th in threads:
        torch.set_num_threads(th)
        with timer() as t:
            res = process_spot(tr, sensor, spot, settings, dirs=dirs)
        times[th] = t.seconds
    torch.set_num_threads(threads[0])
    return res, times


def run_analytic(mesh, res, lds, subpixel, photons=None, ambient=0.0, window=32, seed=0, threads=(1,)):
    """Render spot by spot (a 512^2 x 391 cube is 400 MB), time preprocessing of each (dense and windowed)."""
    sensor = default_sensor(res, res, bins=391)
    dirs = world_pixel_directions(sensor)
    settings = PreprocessSettings()
    rng = np.random.default_rng(seed)
    t_dense, t_win, spots, spots_w = {th: 0.0 for th in threads}, {th: 0.0 for th in threads}, [], []
    scale = None
    for k, ld in enumerate(lds):
        cube = render_two_bounce(mesh, sensor, [ld], subpixel=subpixel)[0]
        if photons is not None:
            if scale is None:   # photons of the brightest two-bounce pixel of the first spot
                two = render_two_bounce(mesh, sensor, [ld], subpixel=subpixel, include_first_bounce=False)[0]
                scale = photons / max(float(two.sum(-1).max()), 1e-30)
            cube = rng.poisson(cube * scale + ambient).astype(np.float32)
        spot = Spot(id=k, laser_direction=list(map(float, ld)), transient_file="")
        tr = Transient.from_dense(cube)
        r, tt = _timed_spot(tr, sensor, spot, settings, dirs, threads)
        spots.append(r)
        trw = Transient.from_dense(cube, window)
        del cube, tr
        rw, ttw = _timed_spot(trw, sensor, spot, settings, dirs, threads)
        spots_w.append(rw)
        for th in threads:
            t_dense[th] += tt[th]
            t_win[th] += ttw[th]
    meas = make_meas(sensor, spots)
    with timer() as tf:
        fused = fuse_visible_depth(meas)
    meas.visible_depth, meas.visible_confidence = fused.depth, fused.confidence
    gt = range_image(mesh, sensor.camera_to_world, res, res, sensor.fov_rad)
    err, e = depth_error_mm(fused.depth, gt)
    return meas, {"resolution": res, "spots": len(lds), "bins": 391, "subpixel": subpixel,
                  "photons": photons, "ambient_per_bin": ambient,
                  "preprocess_dense_s": round(t_dense[threads[0]] + tf.seconds, 3),
                  "preprocess_windowed_s": round(t_win[threads[0]] + tf.seconds, 3),
                  "preprocess_dense_s_by_threads": {th: round(t_dense[th] + tf.seconds, 3) for th in threads},
                  "preprocess_windowed_s_by_threads": {th: round(t_win[th] + tf.seconds, 3) for th in threads},
                  "threads": threads[0], "window_bins": window, "fuse_s": round(tf.seconds, 3),
                  "visible_depth": err}, e


def bflidar_eval(meas, mesh_gt, cams, test_res, fov, grid=True, base=None, gt=None):
    from torch_recon.bflidar import BFLidarSettings, carve, grid_search
    if gt is None:
        gt = np.stack([range_image(mesh_gt, c, test_res, test_res, fov) for c in cams])
    sub = slice(None, None, 4)

    def score(mesh):
        pred = np.stack([render_mesh_depth(mesh, c, test_res, test_res, fov) for c in cams[sub]])
        return depth_metrics(pred, gt[sub])["depth_l1_m"]
    base = base or BFLidarSettings(voxels=128)
    table = None
    with timer() as t:
        res0 = carve(meas, base)
    if grid:
        res, _, table = grid_search(meas, score, base, occupancy_thresholds=(0.1, 0.2, 0.3, 0.5),
                                    shadow_thresholds=(0.15, 0.25))
    else:
        res = res0
    mesh = res.mesh()
    pred = np.stack([render_mesh_depth(mesh, c, test_res, test_res, fov) for c in cams])
    dm = depth_metrics(pred, gt)
    sm = surface_metrics(mesh, mesh_gt, n_samples=100_000, crop_min=CHAIR_CROP[0], crop_max=CHAIR_CROP[1])
    return {"carve_s": round(t.seconds, 3), "voxels": base.voxels, "best_settings": {
        k: res.settings[k] for k in ("occupancy_threshold", "carve_shadow_threshold")},
        "grid_search": table, "depth_l1_m": dm["depth_l1_m"], "depth_psnr_db": dm["depth_psnr_db"],
        "depth_l1_m_on_hits": dm["depth_l1_m_on_hits"], "hit_fraction": dm["hit_fraction"],
        "n_test_views": len(cams), "test_res": test_res, "n_excluded_pixels": dm["n_excluded_pixels"],
        "reconstruction_misses": dm["n_reconstruction_misses"], "chair_chamfer_m": sm["chamfer_m"],
        "chair_fscore_5cm": sm["fscore"]}, res


def run_cycles(path):
    """A Cycles dataset from disk: read time, preprocessing time, visible depth error, BF Lidar on its test views."""
    import trimesh

    from torch_recon.contract.dataset import load_dataset
    from torch_recon.preprocess import preprocess
    ds = load_dataset(path)
    with timer() as tr:
        pairs = [(s, ds.read_transient(s.id)) for s in ds.manifest.enabled_spots]
    with timer() as t:
        meas = preprocess(ds.sensor, pairs)
    del pairs
    err, e = depth_error_mm(meas.visible_depth, ds.train_depth())
    views, cams, gt = ds.test_views()
    gt_mesh = trimesh.load(ds.path(ds.manifest.ground_truth.mesh_file), force="mesh")
    bl, _ = bflidar_eval(meas, gt_mesh, cams, views.width, views.fov_rad, gt=gt)
    return {"source": "cycles", "dataset": str(path), "resolution": ds.sensor.width, "spots": len(meas.spots),
            "layout": f"{ds.manifest.layout.kind} ({ds.manifest.layout.window_bins} bins)",
            "noise": {"photon_counts": ds.manifest.noise.photon_counts,
                      "photons_per_pixel": ds.manifest.noise.photons_per_pixel},
            "read_s": round(tr.seconds, 3), "preprocess_s": round(t.seconds, 3), "visible_depth": err,
            "bflidar": bl}, e


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--skip-512", action="store_true")
    ap.add_argument("--cycles", nargs="*", default=[], help="pipeline/simulate.py cave-chair dataset directories")
    ap.add_argument("--test-res", type=int, default=128)
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2],
                    help="torch thread counts to time preprocessing with; the first is used for everything "
                         "(default 1 2: on a shared 2-core machine one thread avoids OpenMP stalls)")
    args = ap.parse_args()
    import os

    import torch
    torch.set_num_threads(args.threads[0])
    load0 = os.getloadavg()
    mesh, src = cave_chair_scene()
    lds = paper_laser_directions()
    import subprocess
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=Path(__file__).resolve().parents[1]).stdout.strip() or None
    out = {"benchmark": "measurements", "machine": machine_info(), "git_commit": commit, "geometry": src, "rows": []}
    print(f"machine: {out['machine']['cpu']} x{out['machine']['cpu_count']}, torch {out['machine']['torch']}")
    print(f"geometry: {src}; 16 paper spots, 391 bins")
    runs = [("analytic", 128, 3, None, 0.0)] + ([("analytic", 512, 1, None, 0.0)] if not args.skip_512 else []) \
        + [("analytic+poisson", 128, 3, 2000.0, 0.01)]
    errs, meas128, meas512 = {}, None, None
    for source, res, sp, ph, amb in runs:
        meas, row, e = run_analytic(mesh, res, lds, sp, ph, amb, threads=tuple(args.threads))
        row["source"] = source
        out["rows"].append(row)
        errs[f"{source} {res}"] = e
        if source == "analytic" and res == 128:
            meas128 = meas
        if source == "analytic" and res == 512:
            meas512 = meas
        v = row["visible_depth"]
        by = ", ".join(f"{th} thr {row['preprocess_dense_s_by_threads'][th]:.2f}/"
                       f"{row['preprocess_windowed_s_by_threads'][th]:.2f} s" for th in args.threads)
        print(f"[{source}] {res}x{res} (subpixel {sp}): preprocess dense/windowed({row['window_bins']}): {by}; "
              f"visible depth median "
              f"{v['median_mm']:.3f} mm, p95 {v['p95_mm']:.3f} mm, coverage {100 * v['coverage']:.1f} %")
    cams = paper_test_view_cameras()
    fov = np.pi / 2
    bl, _ = bflidar_eval(meas128, mesh, cams, args.test_res, fov)
    bl["source"], bl["resolution"] = "analytic", 128
    out["bflidar"] = [bl]
    print(f"[analytic] BF Lidar 128x128: carve {bl['carve_s']:.2f} s; depth L1 {bl['depth_l1_m']:.4f} m, "
          f"PSNR {bl['depth_psnr_db']:.2f} dB ({bl['n_test_views']} views at {args.test_res}^2), chair Chamfer "
          f"{bl['chair_chamfer_m']:.4f} m, F@5cm {bl['chair_fscore_5cm']:.3f}; best {bl['best_settings']}")
    if not args.skip_512:
        from torch_recon.bflidar import BFLidarSettings
        best = BFLidarSettings(voxels=128, occupancy_threshold=bl["best_settings"]["occupancy_threshold"],
                               carve_shadow_threshold=bl["best_settings"]["carve_shadow_threshold"])
        bl5, _ = bflidar_eval(meas512, mesh, cams, args.test_res, fov, grid=False, base=best)
        bl5["source"], bl5["resolution"] = "analytic", 512
        out["bflidar"].append(bl5)
        print(f"[analytic] BF Lidar 512x512 (thresholds from 128): carve {bl5['carve_s']:.2f} s; depth L1 "
              f"{bl5['depth_l1_m']:.4f} m, PSNR {bl5['depth_psnr_db']:.2f} dB")
    out["cycles"] = []
    for cpath in args.cycles:
        cy, e = run_cycles(cpath)
        out["cycles"].append(cy)
        errs[f"cycles {cy['resolution']}"] = e
        v, b = cy["visible_depth"], cy["bflidar"]
        print(f"[cycles] {cy['resolution']}^2: read {cy['read_s']:.2f} s, preprocess {cy['preprocess_s']:.2f} s, "
              f"visible depth median {v['median_mm']:.3f} mm p95 {v['p95_mm']:.3f} mm coverage "
              f"{100 * v['coverage']:.1f} %; BF Lidar carve {b['carve_s']:.2f} s L1 {b['depth_l1_m']:.4f} m "
              f"PSNR {b['depth_psnr_db']:.2f} dB, best {b['best_settings']}")
    out["peak_rss_mib"] = round(peak_rss_mb(), 1)
    out["load_average_start_end"] = [round(load0[0], 2), round(os.getloadavg()[0], 2)]
    out["note"] = ("timings on a shared machine: other processes ran meanwhile (load average above); "
                   "rendering and file reading are not in the preprocessing times")
    write_json(RESULTS_DIR / "measurements.json", out)
    plot(out, errs, RESULTS_DIR / "measurements.png")
    print_table(out)
    print(f"-> {RESULTS_DIR / 'measurements.json'}, {RESULTS_DIR / 'measurements.png'}")


def print_table(out):
    print(f"\nthreads {out['rows'][0]['threads']}, load average {out['load_average_start_end']}")
    print("source            res   preprocess dense  windowed   depth median  p95 (mm)  coverage")
    for r in out["rows"]:
        v = r["visible_depth"]
        print(f"{r['source']:17s} {r['resolution']:4d}  {r['preprocess_dense_s']:10.2f} s  {r['preprocess_windowed_s']:7.2f} s"
              f"  {v['median_mm']:10.3f}  {v['p95_mm']:8.3f}  {100 * v['coverage']:7.1f} %")
    for b in out["bflidar"]:
        print(f"BF Lidar {b['source']} {b['resolution']}: carve {b['carve_s']:.2f} s, depth L1 {b['depth_l1_m']:.4f} m "
              f"(on hits {b['depth_l1_m_on_hits']:.4f} m, {100 * b['hit_fraction']:.1f} % hit), "
              f"PSNR {b['depth_psnr_db']:.2f} dB, chair Chamfer {b['chair_chamfer_m']:.4f} m, F {b['chair_fscore_5cm']:.3f}")
    for c in out["cycles"]:
        b = c["bflidar"]
        print(f"cycles {c['resolution']} {c['layout']}: read {c['read_s']:.2f} s + preprocess {c['preprocess_s']:.2f} s, "
              f"depth median {c['visible_depth']['median_mm']:.3f} mm p95 {c['visible_depth']['p95_mm']:.3f} mm; "
              f"BF Lidar carve {b['carve_s']:.2f} s, L1 {b['depth_l1_m']:.4f} m, PSNR {b['depth_psnr_db']:.2f} dB, "
              f"chair Chamfer {b['chair_chamfer_m']:.4f} m, F {b['chair_fscore_5cm']:.3f}")


def plot(out, errs, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    labels = [f"{r['source']}\n{r['resolution']}^2" for r in out["rows"]]
    x = np.arange(len(labels))
    ax[0].bar(x - 0.2, [r["preprocess_dense_s"] for r in out["rows"]], 0.4, label="dense (391 bins)")
    ax[0].bar(x + 0.2, [r["preprocess_windowed_s"] for r in out["rows"]], 0.4, label="windowed (32 bins)")
    ax[0].set_xticks(x, labels, fontsize=8)
    ax[0].set_ylabel("preprocessing, 16 spots (s)")
    ax[0].legend()
    for name, e in errs.items():
        s = np.sort(e)
        ax[1].plot(np.maximum(s, 1e-4), np.linspace(0, 1, len(s)), label=name)
    ax[1].set_xscale("log")
    ax[1].set_xlabel("visible depth error (mm)")
    ax[1].set_ylabel("fraction of pixels")
    ax[1].legend(fontsize=8)
    fig.suptitle(f"measurements on the cave-chair ({out['machine']['cpu']}, {out['machine']['cpu_count']} cores)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
