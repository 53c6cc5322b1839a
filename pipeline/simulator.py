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
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field

import bpy
import numpy as np
from scipy.ndimage import maximum_filter, minimum_filter

from pipeline import blender_scene as bs
from pipeline import sensor_model, third_bounce, transient_binning
from pipeline.spot_samples import SpotSampler, windows_to_dense
from torch_recon.contract import ground_truth, spots
from torch_recon.contract.errors import PlatolidarError
from pipeline.cycles_render import EMITTER_OFFSET_M, CyclesRenderer
from torch_recon.contract.dataset import (DatasetError, DatasetWriter, Manifest, NoiseSpec, Provenance, PulseSpec,
                                 SensorSpec, Spot, TimeGate, TransientLayout, load_dataset, transient_relpath)
from torch_recon.contract.frames import focal_length_px, project_points
from torch_recon.contract.units import ps_to_m

SIM_VERSION = "1.2"   # 1.1: deferred Lambertian shading, adaptive edge sampling; 1.2: edge samples shade with corner normals
LASER_POWER_W = 1.0          # expected values are in units of this power; the sensor model rescales
RGB_POWER_W = 100.0          # point light of the RGB-shadow images (exposure only)
DEFAULT_ALBEDO = 0.8
#: spots whose transients may wait for the background writer
WRITE_QUEUE = 1


class SimulationError(PlatolidarError, RuntimeError):
    """A scene/setting combination that cannot be simulated; the message says which and why."""


class WindowTooSmall(Exception):
    def __init__(self, spot_id: int, needed: int):
        super().__init__(spot_id, needed)
        self.spot_id, self.needed = spot_id, needed


@dataclass
class SpotPlan:
    id: int
    name: str
    direction: np.ndarray
    first_bounce: np.ndarray | None = None
    normal: np.ndarray | None = None
    albedo: float = DEFAULT_ALBEDO
    pixel: tuple | None = None               # (row, col) that sees l, when it is visible
    first_bounce_radiance: float = 0.0


def log(msg: str):
    print(msg, file=sys.stderr, flush=True)


def sensor_spec(cfg, c2w, fov_rad, fov_axis, laser_origin) -> SensorSpec:
    return SensorSpec(width=cfg.width, height=cfg.height, fov_rad=float(fov_rad), fov_axis=fov_axis,
                      camera_to_world=np.asarray(c2w).tolist(), laser_origin=[float(v) for v in laser_origin],
                      pulse=PulseSpec(cfg.pulse_shape, float(cfg.pulse_fwhm_ps)), bin_width_ps=float(cfg.bin_ps),
                      bin_width_m=float(cfg.bin_m if cfg.bin_m is not None else ps_to_m(cfg.bin_ps)), bins=cfg.bins, start_m=float(cfg.start_m),
                      time_gate=TimeGate(bool(cfg.time_gate), cfg.gate_window_bins if cfg.time_gate else 0))


def noise_spec(cfg) -> NoiseSpec:
    return NoiseSpec(photon_counts=cfg.photon_counts, photons_per_pixel=float(cfg.photons_per_pixel),
                     ambient_per_bin=float(cfg.ambient_per_bin),
                     wavelength_filter_factor=float(cfg.wavelength_filter_factor),
                     dark_counts_per_bin=float(cfg.dark_counts_per_bin), seed=cfg.seed)


# -- spots ---------------------------------------------------------------------------------
def plan_spots(cfg, scene, depsgraph, sensor, keep_requested: bool) -> list:
    """Spots to simulate, laser ray cast done (l, normal); misses warned about and dropped."""
    o = np.asarray(sensor.laser_origin)
    forward = -np.asarray(sensor.camera_to_world)[:3, 2]
    rng = np.random.default_rng(cfg.seed)
    laser_object = scene.objects.get(cfg.laser_object) if cfg.laser_object else None
    exclude = (laser_object.original,) if laser_object is not None else ()   # the laser's own housing
    if cfg.spots:
        plans = []
        for i, s in enumerate(cfg.spots):
            d = np.asarray(s.direction if s.direction is not None else np.subtract(s.target, o), np.float64)
            n = np.linalg.norm(d)
            if n < 1e-9:
                raise SimulationError(f"spots[{i}]: the target coincides with the laser origin")
            d /= n
            if np.dot(d, forward) <= 1e-6:
                raise SimulationError(f"spots[{i}] ({s.name or 'unnamed'}): the laser aims behind the sensor "
                                      f"(direction {np.round(d, 3).tolist()}, sensor looks along "
                                      f"{np.round(forward, 3).tolist()})")
            plans.append((SpotPlan(i, s.name or f"spot_{i}", d), s.enabled))
        pool = [p for p, en in plans if en]
        if keep_requested and cfg.random_keep > len(pool):
            pool = [p for p, _ in plans]
    else:
        # the same recipe (and seed) as the add-on's "Generate Spots": selection already done
        targets, _, found = bs.random_spot_targets(scene, depsgraph, sensor, cfg.random_candidates, cfg.random_keep,
                                                   cfg.seed, exclude)
        if found < cfg.random_candidates:
            log(f"warning: only {found} of {cfg.random_candidates} random candidates hit a surface the laser reaches")
        pool = []
        for i, t in enumerate(targets):
            d = (t - o) / np.linalg.norm(t - o)
            pool.append(SpotPlan(i, f"random_{i}", d))
    hits = []
    for p in pool:
        hit = bs.ray_cast(scene, depsgraph, o + 1e-4 * p.direction, p.direction, exclude=exclude)
        if hit is None:
            log(f"warning: spot {p.id} ({p.name}): the laser ray hits nothing; spot skipped")
            continue
        p.first_bounce, n_l, obj = hit
        p.normal = n_l if np.dot(n_l, o - p.first_bounce) >= 0 else -n_l   # the side facing the laser
        p.albedo = bs.object_albedo(obj) or DEFAULT_ALBEDO
        hits.append(p)
    if not hits:
        raise SimulationError("no laser spot hits the scene (check the spot targets and that the scene has geometry)")
    if keep_requested and cfg.spots:
        k = cfg.random_keep
        if k < len(hits):
            idx = spots.select_diverse_spots(np.array([p.first_bounce for p in hits]),
                                             np.array([p.normal for p in hits]), k, rng)
            hits = [hits[int(i)] for i in idx]   # selection order: the first k are a spread-out subset
        elif k > len(hits):
            log(f"warning: {k} spots requested, {len(hits)} available")
    return hits


def first_bounce_pixel(p: SpotPlan, sensor, scene, depsgraph, geometry):
    """Pixel that sees l, albedo at l from the Diffuse Color pass, first-bounce radiance."""
    c2w = np.asarray(sensor.camera_to_world)
    c = c2w[:3, 3]
    col, row, depth = project_points(c2w, sensor.width, sensor.height, sensor.fov_rad, p.first_bounce,
                                     sensor.fov_axis)
    if not (depth > 0 and 0 <= col < sensor.width and 0 <= row < sensor.height):
        log(f"warning: spot {p.id}: l is outside the sensor's view; no first-bounce return recorded")
        return
    r, cl = int(row), int(col)
    dist_lc = float(np.linalg.norm(p.first_bounce - c))
    to_l = (p.first_bounce - c) / max(dist_lc, 1e-12)
    hit = bs.ray_cast(scene, depsgraph, c + 1e-4 * to_l, to_l)
    if hit is not None and np.linalg.norm(hit[0] - c) < dist_lc - 1e-3:   # something in front of l
        log(f"warning: spot {p.id}: l is hidden from the sensor; no first-bounce return recorded")
        return
    pos, _, alb, valid = geometry
    d = np.linalg.norm(pos[:, r, cl] - p.first_bounce, axis=-1)
    d[~valid[:, r, cl]] = np.inf
    f_px = focal_length_px(sensor.width, sensor.height, sensor.fov_rad, sensor.fov_axis)
    footprint = dist_lc / f_px
    k = int(np.argmin(d))
    if d[k] < max(0.01, footprint):   # a sub-sample on the spot: albedo from the Diffuse Color pass (textures)
        p.albedo = float(np.mean(alb[k, r, cl]))
    cos_view = abs(float(np.dot(p.normal, (c - p.first_bounce) / max(dist_lc, 1e-9))))
    a_pix = footprint ** 2 / max(cos_view, 1e-3)
    p.pixel = (r, cl)
    p.first_bounce_radiance = (p.albedo / math.pi) * LASER_POWER_W / a_pix


def window_bins_bound(plans, sensor, geometry, footprint_m: float, neighbourhood: bool = False) -> int:
    """A window length holding every non-zero bin of every spot (one layout for the dataset).

    neighbourhood: bound each pixel's paths over its 3 x 3 neighbours (adaptive sampling).
    Also checks, before any rendering, that every path that could be lit (the sample faces l
    and l faces the sample) fits the bin range. float32 (+2 bins of margin): it is a bound.
    """
    kernel = transient_binning.PulseKernel(sensor)
    pos, nrm, _, valid = geometry
    f32 = np.float32
    to_camera = np.linalg.norm(pos - sensor.sensor_origin.astype(f32), axis=-1)   # spot-independent
    n_dot_x = np.einsum("shwc,shwc->shw", nrm, pos)
    spread = 0.0
    for p in plans:
        l = p.first_bounce.astype(f32)
        v = l - pos
        # faces some point of the emitter disk (radius + offset), not only its centre
        tol = f32(footprint_m + EMITTER_OFFSET_M + 1e-4)
        facing = valid & (nrm @ l - n_dot_x > -tol) & (v @ p.normal.astype(f32) < tol)
        d_lo = f32(np.linalg.norm(p.first_bounce - np.asarray(sensor.laser_origin)))
        paths = d_lo + np.linalg.norm(v, axis=-1) + to_camera
        lit_paths = paths[facing]
        if lit_paths.size and (lit_paths.max() >= kernel.end_m or lit_paths.min() < kernel.start_m):
            need = int(math.ceil((lit_paths.max() - sensor.start_m) / sensor.bin_width_m)) + 1
            raise SimulationError(
                f"spot {p.id}: optical paths up to {lit_paths.max():.2f} m exceed the bin range "
                f"[{kernel.start_m:.2f}, {kernel.end_m:.2f}) m; raise 'bins' to at least {need} "
                f"(--bins) or the bin width (--bin-ps)")
        hi = np.where(facing, paths, -np.inf).max(axis=0)
        lo = np.where(facing, paths, np.inf).min(axis=0)
        if neighbourhood:           # edge pixels are sampled again: their samples may see what a neighbour sees
            hi, lo = maximum_filter(hi, size=3), minimum_filter(lo, size=3)
        if p.pixel is not None:     # the first-bounce return shares its pixel with two-bounce samples
            p1 = transient_binning.first_bounce_path(p.first_bounce, sensor.laser_origin, sensor.sensor_origin)
            hi[p.pixel] = max(hi[p.pixel], p1)
            lo[p.pixel] = min(lo[p.pixel], p1)
        ok = np.isfinite(hi)
        if ok.any():
            spread = max(spread, float((hi[ok] - lo[ok]).max()))
    g = int(math.ceil(spread / sensor.bin_width_m)) + kernel.support_bins + 2
    return min(g, sensor.bins)


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
    mesh: object
    vpl: object
    timings: dict
    objects: dict = field(default_factory=dict)   # {label: (trimesh, part names)}: the GT writer's objects
    room_mesh: object = None                      # the GT without those objects
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

    renderer = CyclesRenderer(scene, cam, cfg.width, cfg.height, side, seed=cfg.seed)
    try:
        t0 = time.perf_counter()
        geometry = renderer.render_geometry()
        timings["geometry_pass_s"] = time.perf_counter() - t0
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
        albedos = [bs.object_albedo(bpy.data.objects[n]) or DEFAULT_ALBEDO for n in triangles[3]]
        common = {"version": SIM_VERSION, "sensor": asdict(sensor), "noise": asdict(noise), "seed": cfg.seed,
                  "bounces": cfg.bounces, "footprint": cfg.footprint_radius_m, "window_bound": g_bound,
                  "geometry": geometry_hash(triangles, geometry, albedos), "shading": cfg.shading,
                  "subpixel": cfg.subpixel_samples, "adaptive": cfg.adaptive_subpixel_samples,
                  "adaptive_spread_bins": cfg.adaptive_spread_bins,
                  "ambient": None if ambient_scale is None else hashlib.sha256(ambient_scale.tobytes()).hexdigest()}
        ctx = RunContext(cfg, scene_label, renderer, sensor, noise, geometry, g_bound, ambient_scale, common,
                         _previous_dataset(out_dir), ground_truth.scene_mesh(triangles[0], triangles[1]),
                         third_bounce.ThirdBounce(scene, depsgraph, cfg) if cfg.bounces == 3 else None, timings)
        ctx.objects = ground_truth.object_meshes(*triangles, labelled=bs.labelled_objects())
        ctx.room_mesh = ground_truth.room_mesh(triangles, ctx.objects)
        if cfg.shading == "lambertian":
            t0 = time.perf_counter()
            ctx.sampler = SpotSampler(sensor, geometry, triangles, albedos, cfg.adaptive_subpixel_samples,
                                      cfg.adaptive_spread_bins, LASER_POWER_W, corner_normals=corner_normals)
            _tick(timings, "ray_setup_s", t0)
        while True:   # a second pass only if a spot's signal outgrew the geometric window bound
            try:
                write_dataset(out_dir, plans, ctx)
                break
            except WindowTooSmall as exc:
                # 25 % headroom so one more pass is very likely enough
                ctx.window_bound = min(max(int(math.ceil(1.25 * exc.needed)), ctx.window_bound + 1), sensor.bins)
                common["window_bound"] = ctx.window_bound
                log(f"note: spot {exc.spot_id} needs {exc.needed} bins per pixel; writing again with "
                    f"{ctx.window_bound}")
    finally:
        renderer.close()
    timings["total_s"] = time.perf_counter() - t_start
    log("timings: " + ", ".join(f"{k} {v:.2f}" for k, v in timings.items() if not k.endswith("_pixels")))
    log(f"adaptive sampling (pixel-spots): {timings.get('edge_pixels', 0)} edge pixels re-sampled, "
        f"{timings.get('spread_pixels', 0)} smooth wide-spread pixels interpolated")
    return {"spots": len(plans), "timings": timings}


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


def check_spots_in_view(plans, sensor) -> None:
    """Every spot's l must lie in the sensor's view: its first bounce locates it (else preprocess refuses)."""
    c2w = np.asarray(sensor.camera_to_world)
    outside = []
    for p in plans:
        col, row, depth = project_points(c2w, sensor.width, sensor.height, sensor.fov_rad, p.first_bounce,
                                         sensor.fov_axis)
        if not (depth > 0 and 0 <= col < sensor.width and 0 <= row < sensor.height):
            outside.append(f"{p.id} ({p.name})")
    if outside:
        raise SimulationError(f"spot(s) {', '.join(outside)} lie outside the sensor's {sensor.width}x{sensor.height} "
                              f"view (their first bounce cannot be measured): aim them inside the view or change "
                              f"the width/height or the camera")


def write_dataset(out_dir, plans, ctx: RunContext):
    """Render (or reuse) every spot, write ground truth and commit: one atomic dataset."""
    cfg, timings, old = ctx.cfg, ctx.timings, ctx.old
    old_files = {s.content_hash: old.root / s.transient_file for s in old.manifest.spots} if old else {}
    # transients are written by one background thread (zlib in OpenEXR runs without the GIL) while
    # the next spot is shaded; at most WRITE_QUEUE spots wait, bounding memory
    with DatasetWriter(out_dir) as writer, ThreadPoolExecutor(max_workers=1) as write_pool:
        spots, rgb_files, layout, pending = [], [], None, []
        for k, p in enumerate(plans):
            t0 = time.perf_counter()
            h = spot_hash(p, ctx.common)
            rel = transient_relpath(p.id)
            if h in old_files and _reusable(old_files[h], old):
                writer.reuse_file(old_files[h], rel)
                what, lay = "unchanged, reused", old.manifest.layout
            else:
                tr, lay = simulate_spot(p, ctx.renderer, ctx.sensor, ctx.noise, ctx.geometry, ctx.window_bound,
                                        ctx.ambient_scale, cfg, ctx.vpl, timings, ctx.sampler)
                t1 = time.perf_counter()
                while len(pending) >= WRITE_QUEUE:
                    pending.pop(0).result()
                pending.append(write_pool.submit(_timed_write, writer, p.id, tr, lay.sample_type, timings))
                _tick(timings, "write_wait_s", t1)
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
        gt = ground_truth.write_ground_truth(writer, ctx.mesh, ctx.sensor, cfg, ctx.objects,
                                             ctx.room_mesh)   # overlaps the last transient writes
        for f in pending:
            f.result()
        timings["ground_truth_s"] = time.perf_counter() - t0
        manifest = Manifest(sensor=ctx.sensor, spots=spots, layout=layout, noise=ctx.noise, ground_truth=gt,
                            rgb_files=rgb_files,
                            provenance=Provenance(generator="pipeline/simulate.py", generator_version=SIM_VERSION,
                                                  seed=cfg.seed, blender_version=bs.blender_version(),
                                                  scene=ctx.scene_label,
                                                  extra={"config": cfg.to_dict(), "bounces": cfg.bounces,
                                                         "subpixel_samples": cfg.subpixel_samples,
                                                         "laser_power_w": LASER_POWER_W}))
        writer.commit(manifest)


def _timed_write(writer, spot_id, tr, sample_type, timings):
    t0 = time.perf_counter()
    writer.write_transient(spot_id, tr, sample_type)
    timings["write_s"] = timings.get("write_s", 0.0) + time.perf_counter() - t0   # one writer thread


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
                                                               first_bounce_pixel=p.pixel)
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
