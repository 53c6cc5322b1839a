"""Third-order light (--bounces 3) by virtual point lights, each rendered by Cycles (needs bpy).

Light leaving the spot l (a Lambertian reflector of power rho_l P) is traced one bounce
further: M directions from l, cosine-distributed about n_l, hit points y_m with albedo
rho_y. Each y_m becomes a Lambertian disk emitter of power rho_y rho_l P / M (the
cosine-weighted estimator of the exitance integral; its expectation is the exact
third-order radiance). Cycles renders the sensor view lit by that disk alone, direct
light only, so visibility y -> x is exact, and every sub-pixel sample is binned at
its own optical path |l - o| + |y - l| + |x - y| + |c - x|. Cost: M renders per spot.
The disk radius (VPL_RADIUS_M) bounds the 1/r^2 near-field spike of a point light.
"""

from __future__ import annotations

import math

import numpy as np

from pipeline import blender_scene as bs
from pipeline import transient_binning

VPL_RADIUS_M = 0.05
RAY_EPS = 1e-4


def cosine_directions(normal: np.ndarray, m: int, rng: np.random.Generator) -> np.ndarray:
    """m unit directions with density cos(theta)/pi about `normal` (stratified in the first coordinate)."""
    n = normal / np.linalg.norm(normal)
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t = np.cross(n, a)
    t /= np.linalg.norm(t)
    b = np.cross(n, t)
    u1 = (np.arange(m) + rng.uniform(size=m)) / m
    u2 = rng.uniform(size=m)
    r, phi = np.sqrt(u1), 2.0 * math.pi * u2
    z = np.sqrt(np.maximum(0.0, 1.0 - u1))
    return (r * np.cos(phi))[:, None] * t + (r * np.sin(phi))[:, None] * b + z[:, None] * n


class ThirdBounce:
    def __init__(self, scene, depsgraph, cfg):
        self.scene, self.depsgraph = scene, depsgraph
        self.m = int(cfg.third_bounce_vpls)
        self.seed = int(cfg.seed)

    def add(self, expected: np.ndarray, spot, renderer, sensor, geometry) -> None:
        """expected (H, W, T) += the spot's third-order transient."""
        pos, _, _, valid = geometry
        rng = np.random.default_rng([self.seed, spot.id, 3])
        l, n_l = spot.first_bounce, spot.normal
        d_lo = float(np.linalg.norm(l - np.asarray(sensor.laser_origin)))
        for k, d in enumerate(cosine_directions(n_l, self.m, rng)):
            hit = bs.ray_cast(self.scene, self.depsgraph, l + RAY_EPS * n_l, d)
            if hit is None:
                continue                     # escapes (open front of the room): no third-order light
            y, n_y, obj = hit
            if np.dot(n_y, l - y) < 0:
                n_y = -n_y
            rho_y = bs.object_albedo(obj) or 0.8
            power = rho_y * spot.albedo / self.m
            radiance = renderer.render_emitter(y, n_y, power, VPL_RADIUS_M, name=f"spot_{spot.id}_vpl{k}")
            # bin with y as the 'first bounce' and a virtual origin at |l - o| + |y - l| from y
            o_virtual = y + (d_lo + float(np.linalg.norm(y - l))) * np.array([1.0, 0.0, 0.0])
            expected += transient_binning.bin_two_bounce(pos, radiance, valid, y, o_virtual, sensor.sensor_origin,
                                                         sensor, out_of_range="drop")
