"""One spot's expected transient from the passes: shade, refine edge pixels, bin into windows.

Per spot (shading='lambertian', the default):
1. the base samples (Cycles passes, S per pixel) are shaded (spot_shading.two_bounce_radiance);
2. adaptive_sampling.flag_pixels picks the pixels whose footprint spans a path spread, a
   shadow edge or a silhouette; their base samples are replaced by n stratified Embree
   samples (cached across spots) shaded the same way;
3. every sample goes at its optical path |l - o| + |x - l| + |c - x| into per-pixel windows
   (transient_binning.bin_windows), with the first-bounce return at the pixel that sees l.
No bpy here.
"""

from __future__ import annotations

import time

import numpy as np

from pipeline import adaptive_sampling, transient_binning
from pipeline.spot_shading import SceneRays, ShadingSamples, two_bounce_radiance


#: at most this many interpolated samples per side of a smooth pixel (spacing <= 0.5 bin up to 4 bins)
MAX_FOOTPRINT_SIDE = 8


class SpotSampler:
    """What all spots of a run share: base samples, the ray caster and the refined-sample cache."""

    def __init__(self, sensor, geometry, triangles, object_albedos, adaptive_samples: int, spread_bins: float,
                 laser_power_w: float, corner_normals=None, rays: SceneRays | None = None):
        pos, nrm, alb, valid = geometry
        self.sensor = sensor
        self.s = pos.shape[0]
        self.side = int(round(self.s ** 0.5))
        self.n_pixels = sensor.width * sensor.height
        self.pos = pos.reshape(self.s, -1, 3)
        self.nrm = nrm.reshape(self.s, -1, 3)
        self.alb = alb.reshape(self.s, -1, alb.shape[-1]).mean(axis=-1)
        self.valid = valid.reshape(self.s, -1)
        v, f, owner, _ = triangles
        # rays: the caller's SceneRays of these triangles (with face albedos and corner normals), else built here
        self.rays = rays if rays is not None else SceneRays(
            v, f, np.asarray(object_albedos, np.float64)[np.asarray(owner, np.int64)], corner_normals)
        self.refined = (adaptive_sampling.RefinedGeometry(self.rays, sensor, geometry, int(round(adaptive_samples ** 0.5)))
                        if adaptive_samples else None)
        self.spread_bins = float(spread_bins)
        self.breaks = adaptive_sampling.surface_breaks(pos, nrm, valid) if adaptive_samples else None
        self.creases = adaptive_sampling.normal_breaks(nrm, valid) if adaptive_samples else None
        self.power = float(laser_power_w)
        iv = self.valid.reshape(-1)
        self.base = ShadingSamples(self.pos.reshape(-1, 3)[iv], self.nrm.reshape(-1, 3)[iv], self.alb.reshape(-1)[iv],
                                   sensor.sensor_origin)
        self.o = np.asarray(sensor.laser_origin, np.float64)
        self.c = np.asarray(sensor.sensor_origin, np.float64)

    def _shade(self, x, n, rho, valid, spot, prepared=None):
        """Radiance and optical path of samples (..., 3) (0 and NaN where not valid)."""
        shape = valid.shape
        iv = valid.reshape(-1)
        if prepared is None:
            prepared = ShadingSamples(x.reshape(-1, 3)[iv], n.reshape(-1, 3)[iv], rho.reshape(-1)[iv], self.c)
        rad = np.zeros(iv.size, np.float32)
        path = np.full(iv.size, np.nan)
        rad[iv], path[iv] = two_bounce_radiance(self.rays, prepared, spot.first_bounce, spot.normal, spot.albedo,
                                                self.power, self.o)
        return rad.reshape(shape), path.reshape(shape)

    def expected_windows(self, spot, window_bins: int):
        """(start (P,), window (P, G) float32, needed bins, {reason: pixel count, stage: seconds}) of one spot."""
        t0 = time.perf_counter()
        rad, path = self._shade(self.pos, self.nrm, self.alb, self.valid, spot, self.base)     # (S, P)
        keep = np.ones(self.n_pixels, bool)
        pix_parts, path_parts, amp_parts = [], [], []
        counts = {}

        def add(pixels, paths, amps):
            lit = amps > 0
            pix_parts.append(np.broadcast_to(pixels[:, None], lit.shape)[lit])
            path_parts.append(paths[lit])
            amp_parts.append(amps[lit].astype(np.float64) / amps.shape[1])

        if self.refined is not None:
            h, w = self.sensor.height, self.sensor.width
            flags = adaptive_sampling.flag_pixels(path.reshape(self.s, h, w), rad.reshape(self.s, h, w) > 0,
                                                  self.valid.reshape(self.s, h, w), self.sensor.bin_width_m,
                                                  self.spread_bins, self.breaks, self.creases,
                                                  rad.reshape(self.s, h, w))
            edge = np.flatnonzero(flags["resample"])
            counts = {"edge": len(edge), "crease": int(flags["shading"].sum())}
            if len(edge):                       # new rays: shadow, depth and silhouette edges
                keep[edge] = False
                prepared, vr = self.refined.shading_samples(edge)
                rad_r, path_r = self._shade(None, None, None, vr, spot, prepared)        # (M, n)
                add(edge, path_r, rad_r)
            spread = np.flatnonzero(flags["spread"].reshape(-1) & self.valid.all(axis=0))
            counts["spread"] = len(spread)
            if len(spread) and self.s > 1:     # smooth grazing surfaces: interpolate over the footprint
                keep[spread] = False
                p_s = path[:, spread]
                extent = (np.nanmax(p_s, axis=0) - np.nanmin(p_s, axis=0)) * self.side / (self.side - 1)
                sides = np.clip(np.ceil(2.0 * extent / self.sensor.bin_width_m), self.side,
                                MAX_FOOTPRINT_SIDE).astype(int)
                for side in np.unique(sides):
                    sel = sides == side
                    add(spread[sel], adaptive_sampling.footprint_samples(p_s[:, sel], side),
                        np.maximum(adaptive_sampling.footprint_samples(rad[:, spread[sel]], side), 0.0))
        counts["render_s"] = time.perf_counter() - t0      # shading + new rays: the per-spot 'render'
        t0 = time.perf_counter()
        base = np.flatnonzero(keep)
        add(base, path[:, base].T, rad[:, base].T)
        if spot.pixel is not None and spot.first_bounce_radiance > 0:
            r, c = spot.pixel
            pix_parts.append(np.array([r * self.sensor.width + c]))
            path_parts.append(np.array([transient_binning.first_bounce_path(spot.first_bounce, self.o, self.c)]))
            amp_parts.append(np.array([spot.first_bounce_radiance]))
        del rad, path                   # (S, P) arrays: freed before binning (memory of parallel spots)
        samples = [np.concatenate(parts) for parts in (pix_parts, path_parts, amp_parts)]
        pix_parts.clear(), path_parts.clear(), amp_parts.clear()
        start, window, needed = transient_binning.bin_windows(*samples, self.n_pixels, self.sensor, window_bins)
        counts["binning_s"] = time.perf_counter() - t0
        return start, window, needed, counts


def windows_to_dense(start, window, bins: int) -> np.ndarray:
    """(P,) starts and (P, G) windows -> a dense (P, T) float32 cube (for the gate/background/3rd-bounce path)."""
    p, g = window.shape
    cube = np.zeros((p, bins), np.float32)
    np.put_along_axis(cube, start[:, None] + np.arange(g)[None, :], window, axis=1)
    return cube
