"""Space no measurement constrains: a scene-independent completion outside the sensor's view.

The sensor sees a cone; the floor, ceiling and walls next to it lie outside, and no camera ray,
lit or shadowed secondary ray crosses them (a secondary ray joins two points in the cone, so it stays
inside the cone). Nothing measured says what is there. The prior used here is geometric, not a rule
for one room: **the large planes that bound everything the sensor saw continue through unobserved
space**. A plane bounds the observation when (almost) every measured point and every laser spot
lies on its sensor side: walls, floor, ceiling (a table top or a seat has the floor behind it and
does not qualify; neither does the inner wall of an L-shaped room, which has the other arm behind it).
Outside the view, space behind any bounding plane is solid and space in front of all of them is
empty; together they clip each other into a convex shell (the intersection of their half-spaces,
cut by the grid box). Space the measurements proved free is never filled, and nothing inside the
view changes.

Planes are found by sequential RANSAC (`skimage.measure.ransac`) on the visible surface points with
their image normals (an inlier must lie within a distance of the plane and have a normal within an
angle of it, so a strip of a curved wall or a line across two walls does not form a plane). Each plane is
then fitted again to the inliers within a few times their own scatter (`refit_plane`): RANSAC's least squares
over every inlier within the tolerance let a floor's grazing far rows and its junctions (ranges a few mm short)
tilt it, and continued 2 m past the view it was 5 mm low (session 19).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch


@dataclass
class Plane:
    """n . x = offset, n the unit normal facing the sensor; `support` the fraction of the points on it."""

    normal: np.ndarray
    offset: float
    support: float

    def signed_distance(self, x: np.ndarray) -> np.ndarray:
        """+ on the sensor's side (in front), - behind."""
        return x @ self.normal - self.offset


class _PlaneModel:
    """A plane for skimage.measure.ransac: fitted to points (N, 3) with their normals (N, 3)."""

    max_angle_cos = float(np.cos(np.radians(20.0)))

    def __init__(self, normal, offset):
        self.normal, self.offset = normal, offset

    @classmethod
    def from_estimate(cls, points, normals):
        centre = points.mean(0)
        try:
            _, s, vt = np.linalg.svd(points - centre, full_matrices=False)
        except np.linalg.LinAlgError:
            return None
        if len(points) >= 3 and s[1] < 1e-9:       # collinear sample: no plane
            return None
        n = vt[-1]
        return cls(n, float(n @ centre))

    def residuals(self, points, normals):
        r = np.abs(points @ self.normal - self.offset)
        agree = np.abs(normals @ self.normal) >= self.max_angle_cos
        return np.where(agree, r, np.inf)


def refit_plane(points, normal, offset: float, mad_factor: float, iterations: int = 5):
    """(normal, offset) of the plane fitted by least squares to `points` (N, 3) within `mad_factor` robust standard
    deviations (1.4826 x the median |residual|) of the previous fit, from (`normal`, `offset`), `iterations` times:
    the points' own scatter, not the RANSAC tolerance, decides which are off the plane. The normal keeps its side."""
    n, off = np.asarray(normal, np.float64), float(offset)
    for _ in range(iterations):
        res = np.abs(points @ n - off)
        keep = res <= max(mad_factor * 1.4826 * float(np.median(res)), 1e-9)
        if keep.sum() < 3:
            break
        fit = _PlaneModel.from_estimate(points[keep], None)
        if fit is None:
            break
        n, off = (fit.normal, fit.offset) if fit.normal @ n >= 0 else (-fit.normal, -fit.offset)
    return n, off


def bounding_planes(points, normals, sensor, spots, tolerance_m: float, min_support: float = 0.03,
                    max_planes: int = 12, max_behind: float = 0.002, max_points: int = 20000,
                    trials: int = 300, seed: int = 0, refit_mad: float = 0.0) -> list[Plane]:
    """The large planes of the visible surface that bound the observation (see the module doc).

    points, normals: (N, 3) visible surface points and their unit normals (NaN-free); a plane needs at
    least `min_support` of the points within `tolerance_m` (and normals within 20 degrees);
    it bounds the observation when at most `max_behind` of the points and no spot lie more than
    2 `tolerance_m` behind it. refit_mad > 0: each plane fitted again to its inliers within that many robust
    standard deviations of it (`refit_plane`). Seeded: the same input gives the same planes."""
    from skimage.measure import ransac

    rng = np.random.default_rng(seed)
    pts, nrm = np.asarray(points, np.float64), np.asarray(normals, np.float64)
    if len(pts) > max_points:
        keep = rng.choice(len(pts), max_points, replace=False)
        pts, nrm = pts[keep], nrm[keep]
    n_all = len(pts)
    sensor = np.asarray(sensor, np.float64)
    spots = np.asarray(spots, np.float64).reshape(-1, 3)
    planes: list[Plane] = []
    left = np.ones(n_all, bool)
    while len(planes) < max_planes and left.sum() >= max(3, min_support * n_all):
        idx = np.flatnonzero(left)
        model, inliers = ransac((pts[idx], nrm[idx]), _PlaneModel, 3, tolerance_m, max_trials=trials, rng=rng)
        if model is None or inliers is None or inliers.sum() < min_support * n_all:
            break
        left[idx[inliers]] = False
        n, off = model.normal, model.offset
        if refit_mad > 0:
            n, off = refit_plane(pts[idx[inliers]], n, off, refit_mad)
        if n @ sensor - off < 0:          # face the sensor
            n, off = -n, -off
        plane = Plane(n, float(off), float(inliers.sum()) / n_all)
        behind = plane.signed_distance(pts) < -2.0 * tolerance_m
        if behind.mean() <= max_behind and not np.any(plane.signed_distance(spots) < -2.0 * tolerance_m):
            planes.append(plane)
    return planes


def on_planes(points, normals, planes: list[Plane], tolerance_m: float) -> np.ndarray:
    """bool (N,): the point lies within `tolerance_m` of one of `planes` with its normal within 20 degrees of
    the plane's (the RANSAC inlier test of `bounding_planes`)."""
    pts, nrm = np.asarray(points, np.float64).reshape(-1, 3), np.asarray(normals, np.float64).reshape(-1, 3)
    out = np.zeros(len(pts), bool)
    for p in planes:
        out |= (np.abs(p.signed_distance(pts)) <= tolerance_m) & (np.abs(nrm @ p.normal) >= _PlaneModel.max_angle_cos)
    return out


def shell_signed_distance(centres: torch.Tensor, planes: list[Plane]) -> torch.Tensor:
    """Signed distance (m, + behind / inside solid) of points (..., 3) to the convex shell in front of
    every plane: max over planes of the distance behind it (exact inside the shell, a bound outside)."""
    if not planes:
        return torch.full(centres.shape[:-1], -float("inf"), dtype=centres.dtype, device=centres.device)
    n = torch.as_tensor(np.stack([p.normal for p in planes]), dtype=centres.dtype, device=centres.device)
    off = torch.as_tensor([p.offset for p in planes], dtype=centres.dtype, device=centres.device)
    return (off - centres @ n.T).amax(-1)

