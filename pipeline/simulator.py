"""One simulation run: Blender scene + SimulationConfig -> dataset directory (needs bpy).

Per spot k: l = first hit of the laser ray in the evaluated scene; Cycles renders the
sensor view lit only by a Lambertian disk at l (direct light only); each sub-pixel
sample's radiance is binned at |l - o| + |x - l| + |c - x| (x from the Position pass)
with the laser pulse; the first-bounce return goes to the pixel that sees l; then the
sensor model. Positions, normals and albedo are spot-independent and rendered once.
A spot whose content hash (everything that affects its file) matches a spot of the
dataset already at the output is not rendered again: its file is reused.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass

import bpy
import numpy as np

from pipeline import blender_scene as bs
from pipeline import sensor_model, third_bounce, transient_binning
from pipeline.cycles_render import CyclesRenderer
from pipeline.spot_planning import (DEFAULT_ALBEDO, LASER_POWER_W, SimulationError, SpotPlan,  # noqa: F401 (re-exported)
                                    check_spots_in_view, first_bounce_pixel, log, noise_spec, plan_spots, sensor_spec,
                                    window_bins_bound)
from pipeline.spot_samples import SpotSampler, windows_to_dense
from pipeline.spot_shading import SceneRays
from torch_recon.contract import ground_truth
from torch_recon.contract.dataset import (DatasetError, DatasetWriter, GroundTruth, Manifest, NoiseSpec, Provenance,
                                          SensorSpec, Spot, TransientLayout, load_dataset, transient_relpath)

SIM_VERSION = "1.2"   # 1.1: deferred Lambertian shading, adaptive edge sampling; 1.2: edge samples shade with corner normals
RGB_POWER_W = 100.0          # point light of the RGB-shadow images (exposure only)
#: spots whose transients may wait for the background writer
WRITE_QUEUE = 1
#: spots shaded and binned at once (threads; the target machine has 2 cores)
SPOT_THREADS = 2


class WindowTooSmall(Exception):
    def __init__(self, spot_id: int, needed: int):
        super().__init__(spot_id, needed)
        self.spot_id, self.needed = spot_id, needed


def geometry_hash(triangles, geometry, albedos) -> str:
    h = hashlib.sha256()
    v, f, owner, _ = triangles
    for a in (np.asarray(v, np.float32), np.asarray(f, np.int64), np.asarray(owner, np.int64),
              np.asarray(albedos, np.float64), *geometry):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def spot_hash(p: SpotPlan, common: dict) -> str:
    d = dict(common, id=p.id, direction=np.round(p.direction, 9).tolist(),
             l=np.round(p.first_bounce, 6).tolist(), n=np.round(p.normal, 6).tolist(), albedo=round(p.albedo, 6),
             pixel=p.pixel, fb=float(f"{p.first_bounce_radiance:.6g}"))
    return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()


def _previous_dataset(out):
    try:
        return load_dataset(out)
    except (DatasetError, OSError):
        return None


# -- the run ---------------------------------------------------------------------------------
@dataclass
class RunContext:
    """What every spot of one run shares."""

    cfg: object
    scene_label: str
    renderer: CyclesRenderer
    sensor: SensorSpec
    noise: NoiseSpec
    geometry: tuple
    window_bound: int
    ambient_scale: np.ndarray | None
    common: dict
    old: object
    vpl: object
    timings: dict
    sampler: object = None                        # SpotSampler (shading 'lambertian')


def run(cfg, out_dir, scene_label: str, keep_requested: bool) -> dict:
    """Simulate and commit the dataset at out_dir; returns timings and counts."""
    t_start = time.perf_counter()
    timings = {}
    check_size(cfg)
    DatasetWriter.check_target(out_dir)     # an output folder holding others' files: refused before rendering
    scene = bpy.context.scene
    bs.match_viewport_to_render(scene)
    cam = bs.sensor_camera(scene, cfg.camera)
    fov_rad, fov_axis = bs.camera_fov(cam, cfg.width, cfg.height)
    c2w = bs.rigid_c2w(cam)
    if cfg.laser_object:
        lo = scene.objects.get(cfg.laser_object)
        if lo is None:
            raise SimulationError(f"setting 'laser_object': no object named {cfg.laser_object!r} in the scene")
        laser_origin = np.asarray(lo.matrix_world.translation, np.float64)
    else:
        laser_origin = c2w[:3, 3].copy()
    sensor = sensor_spec(cfg, c2w, fov_rad, fov_axis, laser_origin)
    noise = noise_spec(cfg)
    side = math.isqrt(cfg.subpixel_samples)
    if side * side != cfg.subpixel_samples:
        raise SimulationError(f"setting 'subpixel_samples': expected a square number (1, 4, 9, ...), "
                              f"got {cfg.subpixel_samples}")
    depsgraph = bpy.context.evaluated_depsgraph_get()
    triangles, corner_normals = bs.world_geometry(depsgraph)
    if len(triangles[1]) == 0:
        raise SimulationError("the scene has no render-visible mesh geometry")
    plans = plan_spots(cfg, scene, depsgraph, sensor, keep_requested)
    check_spots_in_view(plans, sensor)

    more_renders = (cfg.shading != "lambertian" or cfg.bounces == 3 or cfg.rgb or cfg.ambient_per_bin > 0)
    renderer = CyclesRenderer(scene, cam, cfg.width, cfg.height, side, seed=cfg.seed, persistent_data=more_renders)
    # the ground truth needs no spot: it runs on its own thread from after the Cycles pass (beside it, its
    # Python would make Cycles wait for the GIL) to the end; leaving the block waits for it, then the
    # writer discards everything unless committed
    with DatasetWriter(out_dir) as writer, ThreadPoolExecutor(max_workers=1) as gt_pool:
        try:
            _simulate(cfg, scene, depsgraph, renderer, sensor, noise, triangles, corner_normals, plans, scene_label,
                      out_dir, writer, gt_pool, timings)
        finally:
            renderer.close()
    timings["total_s"] = time.perf_counter() - t_start
    log("timings: " + ", ".join(f"{k} {v:.2f}" for k, v in timings.items() if not k.endswith("_pixels")))
    log(f"adaptive sampling (pixel-spots): {timings.get('edge_pixels', 0)} edge pixels re-sampled, "
        f"{timings.get('spread_pixels', 0)} smooth wide-spread pixels interpolated")
    return {"spots": len(plans), "timings": timings}


def _simulate(cfg, scene, depsgraph, renderer, sensor, noise, triangles, corner_normals, plans, scene_label, out_dir,
              writer, gt_pool, timings):
    t0 = time.perf_counter()
    geometry = renderer.render_geometry()
    timings["geometry_pass_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    albedos = [bs.object_albedo(bpy.data.objects[n]) or DEFAULT_ALBEDO for n in triangles[3]]
    rays = SceneRays(triangles[0], triangles[1], np.asarray(albedos, np.float64)[np.asarray(triangles[2], np.int64)],
                     corner_normals)      # Embree: shadow rays, edge samples and the ground truth's ranges
    gt_job = gt_pool.submit(_timed_ground_truth, writer, triangles, bs.labelled_objects(), rays, sensor, cfg,
                            timings)
    _tick(timings, "ray_setup_s", t0)
    for p in plans:
        first_bounce_pixel(p, sensor, scene, depsgraph, geometry)
    t0 = time.perf_counter()
    g_bound = window_bins_bound(plans, sensor, geometry, cfg.footprint_radius_m,
                                neighbourhood=cfg.shading == "lambertian" and cfg.adaptive_subpixel_samples > 0)
    if cfg.bounces == 3:      # third-order light spreads over long paths: keep every bin
        g_bound = sensor.bins
    _tick(timings, "window_bound_s", t0)
    ambient = renderer.render_ambient() if (cfg.ambient_per_bin > 0) else None
    ambient_scale = None
    if ambient is not None:
        valid_px = geometry[3].any(axis=0)
        mean = float(ambient[valid_px].mean()) if valid_px.any() else 0.0
        ambient_scale = (ambient / mean if mean > 0 else np.ones_like(ambient)).astype(np.float64)
    common = {"version": SIM_VERSION, "sensor": asdict(sensor), "noise": asdict(noise), "seed": cfg.seed,
              "bounces": cfg.bounces, "footprint": cfg.footprint_radius_m, "window_bound": g_bound,
              "geometry": geometry_hash(triangles, geometry, albedos), "shading": cfg.shading,
              "subpixel": cfg.subpixel_samples, "adaptive": cfg.adaptive_subpixel_samples,
              "adaptive_spread_bins": cfg.adaptive_spread_bins,
              "ambient": None if ambient_scale is None else hashlib.sha256(ambient_scale.tobytes()).hexdigest()}
    ctx = RunContext(cfg, scene_label, renderer, sensor, noise, geometry, g_bound, ambient_scale, common,
                     _previous_dataset(out_dir),
                     third_bounce.ThirdBounce(scene, depsgraph, cfg) if cfg.bounces == 3 else None, timings)
    if cfg.shading == "lambertian":
        t0 = time.perf_counter()
        ctx.sampler = SpotSampler(sensor, geometry, triangles, albedos, cfg.adaptive_subpixel_samples,
                                  cfg.adaptive_spread_bins, LASER_POWER_W, rays=rays)
        _tick(timings, "ray_setup_s", t0)
    while True:   # a second pass only if a spot's signal outgrew the geometric window bound
        try:
            write_dataset(writer, plans, ctx, gt_job)
            break
        except WindowTooSmall as exc:
            # 25 % headroom so one more pass is very likely enough
            ctx.window_bound = min(max(int(math.ceil(1.25 * exc.needed)), ctx.window_bound + 1), sensor.bins)
            common["window_bound"] = ctx.window_bound
            log(f"note: spot {exc.spot_id} needs {exc.needed} bins per pixel; writing again with "
                f"{ctx.window_bound}")


def _reusable(path, old) -> bool:
    """An earlier run's transient may be reused only if it still reads back whole and valid."""
    from torch_recon.contract.dataset import read_transient_file
    if not path.is_file():
        return False
    try:
        read_transient_file(path, old.manifest, "reused transient")
    except (DatasetError, OSError, ValueError) as exc:
        log(f"note: {path.name} of the earlier dataset is damaged ({str(exc)[:120]}); rendering it again")
        return False
    return True


def check_size(cfg) -> None:
    """Refuse, before anything is built, a sensor no machine can hold (with the estimate)."""
    from torch_recon.contract.units import transient_size_problem

    problem = transient_size_problem(cfg.width, cfg.height, cfg.bins)
    if problem:
        key = "bins" if max(cfg.width, cfg.height) <= 8192 else "width' / 'height"
        raise SimulationError(f"setting '{key}': {problem}")
    side = math.isqrt(max(cfg.subpixel_samples, 1))
    if max(cfg.width, cfg.height) * side > 65536:
        raise SimulationError(f"setting 'subpixel_samples': {cfg.width} x {cfg.height} pixels x {side}^2 samples "
                              f"exceed Cycles' 65536 x 65536 render limit")


def write_dataset(writer, plans, ctx: RunContext, gt_job):
    """Render (or reuse) every spot, wait for the ground truth (gt_job) and commit: one atomic dataset."""
    cfg, timings, old = ctx.cfg, ctx.timings, ctx.old
    old_files = {s.content_hash: old.root / s.transient_file for s in old.manifest.spots} if old else {}
    # spots are shaded, binned and written SPOT_THREADS at a time (numpy, Embree and OpenEXR release the
    # GIL in their loops): on 2 cores two threads keep both busy, and a spot's windows are freed once
    # written (a separate writer thread held up to two more spots' windows, 67 MB each at 512 x 512).
    # Cycles (shading 'cycles', the third bounce, RGB) stays on the main thread, bpy is not thread-safe;
    # there the transients go to a writer thread, overlapping the next spot's render
    parallel = ctx.sampler is not None and ctx.vpl is None
    reuse = {}
    for p in plans:
        h = spot_hash(p, ctx.common)
        reuse[p.id] = (h, old_files[h] if h in old_files and _reusable(old_files[h], old) else None)
    todo = [p for p in plans if reuse[p.id][1] is None]

    def shade(p, write: bool):
        spot_timings = {}
        tr, lay = simulate_spot(p, ctx.renderer, ctx.sensor, ctx.noise, ctx.geometry, ctx.window_bound,
                                ctx.ambient_scale, cfg, ctx.vpl, spot_timings, ctx.sampler)
        if write:
            _timed_write(writer, p.id, tr, lay.sample_type, spot_timings)
            tr = None
        return tr, lay, spot_timings

    with ThreadPoolExecutor(max_workers=1) as write_pool, \
            ThreadPoolExecutor(max_workers=SPOT_THREADS if parallel else 1) as spot_pool:
        spots, rgb_files, layout, pending, shading = [], [], None, [], {}
        for k, p in enumerate(plans):
            t0 = time.perf_counter()
            h, reused = reuse[p.id]
            rel = transient_relpath(p.id)
            if reused is not None:
                writer.reuse_file(reused, rel)
                what, lay = "unchanged, reused", old.manifest.layout
            else:
                if parallel:           # keep SPOT_THREADS spots in flight, in order
                    while len(shading) < SPOT_THREADS and todo:
                        q = todo.pop(0)
                        shading[q.id] = spot_pool.submit(shade, q, True)
                else:                  # Cycles on this thread overlaps the previous spot's write
                    result = shade(p, False)
                t1 = time.perf_counter()
                while len(pending) >= WRITE_QUEUE:    # first: no finished spot waits in memory meanwhile
                    pending.pop(0).result()
                _tick(timings, "write_wait_s", t1)
                tr, lay, spot_timings = shading.pop(p.id).result() if parallel else result
                result = None
                for key, v in spot_timings.items():
                    timings[key] = timings.get(key, 0) + v
                if tr is not None:
                    pending.append(write_pool.submit(_timed_write, writer, p.id, tr, lay.sample_type, timings))
                del tr
                what = "rendered"
            if layout is not None and (lay.kind, lay.window_bins) != (layout.kind, layout.window_bins):
                raise SimulationError(f"internal: spot {p.id} has layout {lay} unlike {layout}")
            layout = lay
            spots.append(Spot(id=p.id, laser_direction=p.direction.tolist(), transient_file=rel,
                              first_bounce=p.first_bounce.tolist(), content_hash=h))
            if cfg.rgb:
                rgb_rel = f"rgb/spot_{p.id:04d}.png"
                ctx.renderer.render_rgb(p.first_bounce + 0.01 * p.normal, RGB_POWER_W * p.albedo,
                                        str(writer.path(rgb_rel)))
                rgb_files.append(rgb_rel)
            dt = time.perf_counter() - t0
            log(f"spot {k + 1}/{len(plans)} (id {p.id}, {p.name}): l = {np.round(p.first_bounce, 3).tolist()}, "
                f"albedo {p.albedo:.2f}, {what} in {dt:.2f} s")
        t0 = time.perf_counter()
        gt = gt_job.result()
        for f in pending:
            f.result()
        timings["finish_wait_s"] = time.perf_counter() - t0
        manifest = Manifest(sensor=ctx.sensor, spots=spots, layout=layout, noise=ctx.noise, ground_truth=gt,
                            rgb_files=rgb_files,
                            provenance=Provenance(generator="pipeline/simulate.py", generator_version=SIM_VERSION,
                                                  seed=cfg.seed, blender_version=bs.blender_version(),
                                                  scene=ctx.scene_label,
                                                  extra={"config": cfg.to_dict(), "bounces": cfg.bounces,
                                                         "subpixel_samples": cfg.subpixel_samples,
                                                         "laser_power_w": LASER_POWER_W}))
        writer.commit(manifest)


def _timed_ground_truth(writer, triangles, labelled, rays, sensor, cfg, timings):
    """Mesh, labelled objects, test-view placement and range images (Embree, not trimesh's ray casts)."""
    t0 = time.perf_counter()
    if not (cfg.train_depth or cfg.gt_mesh or cfg.test_views_dolly + cfg.test_views_orbit > 0):
        return GroundTruth()       # --no-gt: what write_ground_truth would return, without importing trimesh
    mesh = ground_truth.scene_mesh(triangles[0], triangles[1])
    objects = ground_truth.object_meshes(*triangles, labelled=labelled)
    gt = ground_truth.write_ground_truth(writer, mesh, sensor, cfg, objects, ground_truth.room_mesh(triangles, objects),
                                         rays.range_image)
    timings["ground_truth_s"] = time.perf_counter() - t0
    return gt


def _timed_write(writer, spot_id, tr, sample_type, timings):
    t0 = time.perf_counter()
    writer.write_transient(spot_id, tr, sample_type)
    timings["write_s"] = timings.get("write_s", 0.0) + time.perf_counter() - t0   # one thread per dict


def _tick(timings, key, t0):
    timings[key] = timings.get(key, 0.0) + time.perf_counter() - t0
    return time.perf_counter()


def simulate_spot(p, renderer, sensor, noise, geometry, g_bound, ambient_scale, cfg, vpl, timings, sampler=None):
    """Render, bin and apply the sensor model for one spot: (Transient, TransientLayout).

    With a SpotSampler (shading 'lambertian'): deferred shading + adaptive edge samples, binned
    straight into the dataset's windows; the dense (H, W, T) cube is built only for a time gate,
    a background or third-order light. Else a Cycles render of the spot at the base samples.
    """
    pos, nrm, alb, valid = geometry
    o, c = np.asarray(sensor.laser_origin), sensor.sensor_origin
    t0 = time.perf_counter()
    try:
        if sampler is not None:
            start, window, needed, counts = sampler.expected_windows(p, g_bound)
            for k, v in counts.items():
                key = k if k.endswith("_s") else f"{k}_pixels"
                timings[key] = timings.get(key, 0) + v
            if needed > g_bound:
                raise WindowTooSmall(p.id, needed)
            t0 = time.perf_counter()
            dense = vpl is not None or sensor.time_gate.enabled or np.any(
                np.asarray(sensor_model.background_rate(noise, ambient_scale)) > 0)
            if not dense:
                h, w = sensor.height, sensor.width
                tr, layout = sensor_model.apply_sensor_windows(start.reshape(h, w), window.reshape(h, w, -1), sensor,
                                                               noise, np.random.default_rng([cfg.seed, p.id]),
                                                               first_bounce_pixel=p.pixel, in_place=True)
                _tick(timings, "sensor_model_s", t0)
                return tr, layout
            expected = windows_to_dense(start, window, sensor.bins).reshape(sensor.height, sensor.width, -1)
        else:
            radiance = renderer.render_emitter(p.first_bounce, p.normal, p.albedo * LASER_POWER_W,
                                               cfg.footprint_radius_m, name=f"spot_{p.id}")
            t0 = _tick(timings, "render_s", t0)
            expected = transient_binning.bin_two_bounce(pos, radiance, valid, p.first_bounce, o, c, sensor,
                                                        first_bounce_pixel=p.pixel,
                                                        first_bounce_radiance=p.first_bounce_radiance)
            t0 = _tick(timings, "binning_s", t0)
        if vpl is not None:
            vpl.add(expected, p, renderer, sensor, geometry)
            t0 = _tick(timings, "third_bounce_s", t0)
        path = (transient_binning.expected_return_path(pos, valid, p.first_bounce, o, c)
                if sensor.time_gate.enabled else None)   # only the gate needs it
        rng = np.random.default_rng([cfg.seed, p.id])   # per spot: a spot's noise does not depend on the others
        tr, layout = sensor_model.apply_sensor(expected, sensor, noise, rng, path, first_bounce_pixel=p.pixel,
                                               ambient_scale=ambient_scale)
        t0 = _tick(timings, "sensor_model_s", t0)
    except ValueError as exc:
        raise SimulationError(f"spot {p.id}: {exc}") from None
    if layout.kind == "windowed" and not sensor.time_gate.enabled and layout.window_bins != g_bound:
        if layout.window_bins > g_bound:
            raise WindowTooSmall(p.id, layout.window_bins)
        tr = sensor_model.widen_window(tr, g_bound)
        layout = TransientLayout("windowed" if g_bound < sensor.bins else "dense", g_bound, layout.sample_type)
    _tick(timings, "sensor_model_s", t0)
    return tr, layout
