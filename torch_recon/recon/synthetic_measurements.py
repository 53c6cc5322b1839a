"""Ideal measurements straight from a mesh (no transients): what a perfect preprocessing would give.

Used by tests and benchmarks to develop and check the reconstructor independently of the
simulator and of preprocessing noise. Built with the analytic renderer's Embree ray casts
(torch_recon.contract.analytic): pixel hit points, first-bounce points l_k, exact shadows, and the
two-bounce path |l - o| + |x - l| + |c - x| at pixel centres.
"""

from __future__ import annotations

import numpy as np

from ..contract.analytic import RAY_EPS, first_hits, visible
from ..contract.frames import pixel_rays
from ..measurements import Measurements, SpotMeasurement


def ideal_measurements(mesh, camera_to_world, width: int, height: int, laser_targets, fov_rad: float = np.pi / 2,
                       fov_axis: str = "x", laser_origin=None, bin_width_m: float = 0.0384) -> Measurements:
    """Measurements of `mesh` seen by a co-located lidar whose laser aims at each of `laser_targets`.

    A pixel is lit for spot k when its surface point faces l_k, l_k faces it, and the segment is
    unobstructed; shadowed when it hits the scene but is not lit; excluded when its ray hits nothing.
    Spots whose laser ray hits nothing are dropped.
    """
    c2w = np.asarray(camera_to_world, np.float64)
    c = c2w[:3, 3]
    o = c if laser_origin is None else np.asarray(laser_origin, np.float64)
    _, dirs = pixel_rays(c2w, width, height, fov_rad, fov_axis)
    dirs = dirs.reshape(-1, 3)
    hit, x, tri, dist = first_hits(mesh, c + RAY_EPS * dirs, dirs)
    rng = np.where(hit, dist + RAY_EPS, np.nan)
    nrm = np.zeros_like(x)
    nrm[hit] = mesh.face_normals[tri[hit]]
    flip = np.einsum("ij,ij->i", nrm, c - np.nan_to_num(x)) < 0
    nrm[flip] *= -1
    spots = []
    for k, target in enumerate(np.asarray(laser_targets, np.float64)):
        ld = target - o
        ld /= np.linalg.norm(ld)
        lh, lp, lt, _ = first_hits(mesh, (o + RAY_EPS * ld)[None], ld[None])
        if not lh[0]:
            continue
        l, nl = lp[0], mesh.face_normals[lt[0]]
        if np.dot(nl, o - l) < 0:
            nl = -nl
        idx = np.flatnonzero(hit)
        v = l - x[idx]
        r = np.linalg.norm(v, axis=1)
        u = v / np.maximum(r, 1e-9)[:, None]
        lit_i = (r > 1e-6) & (np.einsum("ij,ij->i", nrm[idx], u) > 0) & ((-u) @ nl > 0)
        sel = idx[lit_i]
        lit_i[lit_i] = visible(mesh, x[sel] + RAY_EPS * nrm[sel], np.broadcast_to(l + RAY_EPS * nl, x[sel].shape))
        lit = np.zeros(len(dirs), bool)
        lit[idx[lit_i]] = True
        path = np.full(len(dirs), np.nan, np.float32)
        path[lit] = (np.linalg.norm(l - o) + np.linalg.norm(x[lit] - l, axis=1) + rng[lit]).astype(np.float32)
        shape = (height, width)
        spots.append(SpotMeasurement(
            spot_id=k, first_bounce=l.astype(np.float32), laser_direction=ld.astype(np.float32),
            path_length=path.reshape(shape), signal=lit.reshape(shape),
            shadow_confidence=lit.astype(np.float32).reshape(shape), shadow=(hit & ~lit).reshape(shape),
            excluded=(~hit).reshape(shape)))
    return Measurements(width=width, height=height, fov_rad=float(fov_rad), fov_axis=fov_axis,
                        camera_to_world=c2w, laser_origin=o, bin_width_m=bin_width_m, shadow_threshold=0.5,
                        spots=spots, visible_depth=rng.reshape(height, width).astype(np.float32),
                        visible_confidence=hit.reshape(height, width).astype(np.float32))
