"""Analytic two-bounce transients by ray casting (numpy + trimesh/Embree, no Cycles, no torch).

An independent reference for the Cycles simulator's tests and a fast source of
synthetic data with known answers for the reconstructor's tests.

Radiometry (laser of power P fully landing on a Lambertian spot l of albedo rho_l;
scene point x of albedo rho_x seen by pixel p, r = |x - l|):
    two-bounce radiance  L2(x) = (rho_l / pi) (rho_x / pi) P cos_l cos_x / r^2
    with cos_l = n_l . (x - l) / r and cos_x = n_x . (l - x) / r, zero when x is in
    shadow from l (the segment x -> l is blocked) or faces away.
    first-bounce radiance of the spot, averaged over the pixel that sees it:
    L1 = (rho_l / pi) P / A_pix, A_pix the pixel footprint area at l.
Optical path of the two-bounce return: |l - o| + |x - l| + |c - x|.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .frames import camera_ray_directions, focal_length_px
from .units import fwhm_to_sigma, ps_to_m

RAY_EPS = 1e-4


@dataclass
class AnalyticSpot:
    laser_direction: np.ndarray
    first_bounce: np.ndarray | None     # l (None: the laser hits nothing)
    normal: np.ndarray | None
    albedo: float


def _caster(mesh):
    return mesh.ray  # trimesh picks Embree (embreex) when installed


def first_hits(mesh, origins, dirs, cull_back_faces: bool = False, max_layers: int = 16):
    """Nearest hit per ray: (hit mask (N,), points (N, 3), face index (N,), distance (N,)).

    With `cull_back_faces`, faces whose normal points along the ray are passed through
    (one-sided surfaces): a camera just inside a reconstructed solid sees what lies beyond
    the face it is behind, as a renderer with back-face culling would. Needs outward normals.
    """
    origins = np.asarray(origins, np.float64).reshape(-1, 3)
    dirs = np.asarray(dirs, np.float64).reshape(-1, 3)
    if cull_back_faces:
        return _first_front_hits(mesh, origins, dirs, max_layers)
    n = len(dirs)
    loc, idx_ray, idx_tri = _caster(mesh).intersects_location(origins, dirs, multiple_hits=False)
    hit = np.zeros(n, bool)
    pts = np.full((n, 3), np.nan)
    tri = np.full(n, -1, np.int64)
    hit[idx_ray] = True
    pts[idx_ray] = loc
    tri[idx_ray] = idx_tri
    dist = np.full(n, np.inf)
    dist[idx_ray] = np.linalg.norm(loc - origins[idx_ray], axis=1)
    return hit, pts, tri, dist


def _first_front_hits(mesh, origins, dirs, max_layers):
    hit, pts, tri, dist = first_hits(mesh, origins, dirs)
    back = hit.copy()
    back[hit] = np.einsum("ij,ij->i", dirs[hit], mesh.face_normals[tri[hit]]) > 0
    for _ in range(max_layers):
        idx = np.flatnonzero(back)
        if not len(idx):
            break
        h2, p2, t2, d2 = first_hits(mesh, pts[idx] + RAY_EPS * dirs[idx], dirs[idx])
        hit[idx], pts[idx], tri[idx] = h2, p2, t2
        dist[idx] = np.where(h2, dist[idx] + RAY_EPS + d2, np.inf)
        back[:] = False
        back[idx[h2]] = np.einsum("ij,ij->i", dirs[idx[h2]], mesh.face_normals[t2[h2]]) > 0
    hit[back] = False          # still behind a back face after max_layers: treat as a miss
    dist[back] = np.inf
    return hit, pts, tri, dist


def visible(mesh, a, b, eps=RAY_EPS):
    """True where the open segment a -> b is unobstructed (a, b: (N, 3))."""
    d = b - a
    length = np.linalg.norm(d, axis=1)
    ok = length > 2 * eps
    u = np.zeros_like(d)
    u[ok] = d[ok] / length[ok, None]
    hit, _, _, dist = first_hits(mesh, a[ok] + eps * u[ok], u[ok])
    res = np.ones(len(a), bool)
    res[np.flatnonzero(ok)] = ~(hit & (dist < length[ok] - 2 * eps))
    return res


def face_albedo(mesh, albedo) -> np.ndarray:
    a = np.asarray(albedo, np.float64)
    return np.full(len(mesh.faces), float(a)) if a.ndim == 0 else a


def pulse_bin_weights(path_m, start_m, bin_width_m, bins, fwhm_m, shape="gaussian"):
    """Fraction of a unit pulse centred at each path that falls in each bin: (N, T).

    Gaussian pulses are integrated over each bin (erf differences), so the weights
    sum to 1 when the pulse lies inside the range; 'box' puts it all in one bin.
    """
    path_m = np.asarray(path_m, np.float64).reshape(-1)
    edges = start_m + bin_width_m * np.arange(bins + 1)
    if shape == "box":
        out = np.zeros((len(path_m), bins))
        k = np.floor((path_m - start_m) / bin_width_m).astype(np.int64)
        ok = (k >= 0) & (k < bins)
        out[np.flatnonzero(ok), k[ok]] = 1.0
        return out
    sigma = fwhm_to_sigma(fwhm_m)
    from scipy.special import erf
    z = (edges[None, :] - path_m[:, None]) / (sigma * math.sqrt(2.0))
    cdf = 0.5 * (1.0 + erf(z))
    return np.diff(cdf, axis=1)


def render_two_bounce(mesh, sensor, laser_directions, albedo=0.8, laser_power=1.0, subpixel=1,
                      include_first_bounce=True, return_parts=False):
    """Noise-free transients (S, H, W, T) of expected radiance for each laser direction.

    `sensor` is a dataset SensorSpec (Blender frame). `subpixel` n gives n x n
    stratified samples per pixel (a pixel spanning a depth edge spreads over bins).
    With `return_parts`, also returns a dict with per-spot AnalyticSpot, the pixel
    hit points at pixel centres, normals and the two-bounce path at pixel centres.
    """
    c2w = np.asarray(sensor.camera_to_world, np.float64)
    o = np.asarray(sensor.laser_origin, np.float64)
    c = c2w[:3, 3]
    h, w, t = sensor.height, sensor.width, sensor.bins
    alb = face_albedo(mesh, albedo)
    fwhm_m = ps_to_m(sensor.pulse.fwhm_ps)
    g = (np.arange(subpixel) + 0.5) / subpixel - 0.5
    offsets = np.stack(np.meshgrid(g, g, indexing="xy"), -1).reshape(-1, 2)
    if subpixel == 1:
        offsets = np.zeros((1, 2))
    dirs_all = camera_ray_directions(w, h, sensor.fov_rad, sensor.fov_axis, offsets) @ c2w[:3, :3].T
    samples = []
    for dirs in dirs_all:
        hit, x, tri, nrm, dist = _camera_hits(mesh, c, dirs.reshape(-1, 3))
        samples.append((hit, x, tri, nrm, dist))
    f_px = focal_length_px(w, h, sensor.fov_rad, sensor.fov_axis)
    cubes = np.zeros((len(laser_directions), h * w, t), np.float64)
    spots = []
    for k, ld in enumerate(laser_directions):
        ld = np.asarray(ld, np.float64)
        ld = ld / np.linalg.norm(ld)
        lh, lp, lt, ldist = first_hits(mesh, (o + RAY_EPS * ld)[None], ld[None])
        if not lh[0]:
            spots.append(AnalyticSpot(ld, None, None, 0.0))
            continue
        l, nl, rho_l = lp[0], mesh.face_normals[lt[0]], alb[lt[0]]
        if np.dot(nl, o - l) < 0:  # two-sided surfaces: face the laser
            nl = -nl
        spots.append(AnalyticSpot(ld, l, nl, rho_l))
        d_lo = np.linalg.norm(l - o)
        for hit, x, tri, nrm, dist in samples:
            idx = np.flatnonzero(hit)
            xs, ns = x[idx], nrm[idx].copy()
            flip = np.einsum("ij,ij->i", ns, c - xs) < 0
            ns[flip] *= -1
            v = l - xs
            r = np.linalg.norm(v, axis=1)
            safe = r > 1e-6
            u = np.zeros_like(v)
            u[safe] = v[safe] / r[safe, None]
            cos_x = np.einsum("ij,ij->i", ns, u)
            cos_l = -(u @ nl)
            lit = safe & (cos_x > 0) & (cos_l > 0)
            lit[lit] &= visible(mesh, xs[lit] + RAY_EPS * ns[lit], np.broadcast_to(l + RAY_EPS * nl, xs[lit].shape))
            rad = np.zeros(len(idx))
            rad[lit] = (rho_l / math.pi) * (alb[tri[idx][lit]] / math.pi) * laser_power \
                * cos_x[lit] * cos_l[lit] / r[lit] ** 2
            path = d_lo + r + dist[idx]
            wts = pulse_bin_weights(path[lit], sensor.start_m, sensor.bin_width_m, t, fwhm_m, sensor.pulse.shape)
            cubes[k, idx[lit]] += rad[lit, None] * wts / len(samples)
        if include_first_bounce:
            # the pixel whose centre ray passes nearest to l sees the spot
            col, row = _project(c2w, w, h, f_px, l)
            if 0 <= col < w and 0 <= row < h:
                p = int(row) * w + int(col)
                cos_view = abs(np.dot(nl, (c - l) / np.linalg.norm(c - l)))
                a_pix = (np.linalg.norm(l - c) / f_px) ** 2 / max(cos_view, 1e-3)
                amp = (rho_l / math.pi) * laser_power / a_pix
                wts = pulse_bin_weights([d_lo + np.linalg.norm(l - c)], sensor.start_m, sensor.bin_width_m, t,
                                        fwhm_m, sensor.pulse.shape)
                cubes[k, p] += amp * wts[0]
    cubes = cubes.reshape(len(laser_directions), h, w, t).astype(np.float32)
    if not return_parts:
        return cubes
    hit, x, tri, nrm, dist = samples[0] if subpixel == 1 else _centre_samples(mesh, c, c2w, sensor)
    parts = {"spots": spots, "hit": hit.reshape(h, w), "points": x.reshape(h, w, 3),
             "normals": nrm.reshape(h, w, 3), "range": dist.reshape(h, w)}
    return cubes, parts


def _centre_samples(mesh, c, c2w, sensor):
    dirs = camera_ray_directions(sensor.width, sensor.height, sensor.fov_rad, sensor.fov_axis) @ c2w[:3, :3].T
    return _camera_hits(mesh, c, dirs.reshape(-1, 3))


def _camera_hits(mesh, c, dirs, cull_back_faces=False):
    """Pixel rays from the sensor centre; start RAY_EPS ahead so a surface through c is skipped."""
    hit, x, tri, dist = first_hits(mesh, c + RAY_EPS * dirs, dirs, cull_back_faces)
    nrm = np.zeros_like(x)
    nrm[hit] = mesh.face_normals[tri[hit]]
    return hit, x, tri, nrm, dist + RAY_EPS


def _project(c2w, w, h, f_px, p):
    q = np.linalg.inv(c2w) @ np.append(p, 1.0)
    if q[2] >= 0:
        return -1.0, -1.0
    return 0.5 * w + f_px * q[0] / -q[2], 0.5 * h - f_px * q[1] / -q[2]


def range_image(mesh, c2w, width, height, fov_rad, fov_axis="x", cull_back_faces=False):
    """Range along each pixel-centre ray (H, W); inf where nothing is hit (see first_hits for culling)."""
    c2w = np.asarray(c2w, np.float64)
    dirs = camera_ray_directions(width, height, fov_rad, fov_axis) @ c2w[:3, :3].T
    _, _, _, _, dist = _camera_hits(mesh, c2w[:3, 3], dirs.reshape(-1, 3), cull_back_faces)
    return dist.reshape(height, width)
