"""Laser spots before any rendering: which spots, where each lands (l), which pixel sees it,
and the window length that holds every spot's signal (needs bpy for the scene's ray casts).

The sensor and noise descriptions of the dataset come from a SimulationConfig here too.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass

import numpy as np

from pipeline import blender_scene as bs
from pipeline import transient_binning
from pipeline.pulse_kernel import PulseKernel
from pipeline.neighbourhood import maximum_filter3, minimum_filter3
from pipeline.cycles_render import EMITTER_OFFSET_M
from torch_recon.contract import spots
from torch_recon.contract.dataset import NoiseSpec, PulseSpec, SensorSpec, TimeGate
from torch_recon.contract.errors import PlatolidarError
from torch_recon.contract.frames import focal_length_px, project_points
from torch_recon.contract.units import ps_to_m

LASER_POWER_W = 1.0          # expected values are in units of this power; the sensor model rescales
DEFAULT_ALBEDO = 0.8


class SimulationError(PlatolidarError, RuntimeError):
    """A scene/setting combination that cannot be simulated; the message says which and why."""


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
        return          # an out-of-view spot (check_spots_in_view names it): no first-bounce return
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
    kernel = PulseKernel(sensor)
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
            hi, lo = maximum_filter3(hi), minimum_filter3(lo)
        if p.pixel is not None:     # the first-bounce return shares its pixel with two-bounce samples
            p1 = transient_binning.first_bounce_path(p.first_bounce, sensor.laser_origin, sensor.sensor_origin)
            hi[p.pixel] = max(hi[p.pixel], p1)
            lo[p.pixel] = min(lo[p.pixel], p1)
        ok = np.isfinite(hi)
        if ok.any():
            spread = max(spread, float((hi[ok] - lo[ok]).max()))
    g = int(math.ceil(spread / sensor.bin_width_m)) + kernel.support_bins + 2
    return min(g, sensor.bins)


def check_spots_in_view(plans, sensor) -> None:
    """At least one spot's l must lie in the sensor's view: its first bounce locates it, and the visible depth
    measured with it is what preprocessing fits an out-of-view spot's range to (first_bounce.fit_out_of_view_spot).
    Out-of-view spots (a laser scanning a wider field than the camera sees) are allowed and named in a note."""
    c2w = np.asarray(sensor.camera_to_world)
    outside = []
    for p in plans:
        col, row, depth = project_points(c2w, sensor.width, sensor.height, sensor.fov_rad, p.first_bounce,
                                         sensor.fov_axis)
        if not (depth > 0 and 0 <= col < sensor.width and 0 <= row < sensor.height):
            outside.append(f"{p.id} ({p.name})")
    if outside and len(outside) == len(plans):
        raise SimulationError(f"every spot lies outside the sensor's {sensor.width}x{sensor.height} view: at least one "
                              f"must lie inside (its first bounce is measured; out-of-view spots are located from "
                              f"the depth it gives): aim one inside the view or change the camera")
    if outside:
        log(f"note: spot(s) {', '.join(outside)} lie outside the sensor's view: no first-bounce return; "
            f"preprocessing fits their range from two-bounce arrival times")
