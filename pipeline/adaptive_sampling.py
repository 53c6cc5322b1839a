"""Adaptive sub-pixel sampling: more samples only where a sensor pixel's footprint is not uniform.

A sensor pixel's histogram is the integral of radiance over its footprint, binned by optical
path. A few stratified base samples (the Cycles passes) integrate it well where the footprint
is one lit surface whose path varies by less than about a bin. Three things break that, and
each is detected per spot from the base samples alone (flag_pixels):

- a wide path spread: the path varies by more than `spread_bins` bins across the pixel
  (grazing walls, depth edges), judged from the pixel's own samples (extrapolated to the
  full pixel width) and from the jump to its 4 neighbours;
- a shadow edge: lit and dark (in shadow or facing away) samples within the pixel's 3 x 3
  neighbourhood; this catches penumbra pixels whose base samples are all dark but which are
  partly lit (they must get their partial energy, not stay dark);
- a silhouette: samples that see a surface next to samples that see nothing;
- a shading crease: the shading normal jumps inside the pixel or to a neighbour (facets of a
  flat-shaded curved surface, too shallow for a depth edge) where the radiance there changes
  by more than `crease_contrast` (near grazing light a 2 degree facet turn changes it by tens of
  per cent, and 2 x 2 samples weight the two facets wrongly).

Flagged pixels are sampled again with n x n stratified rays (RefinedGeometry, Embree, cached
across spots since the camera rays do not depend on the light), and those samples replace the
pixel's base samples in its histogram. No bpy here.
"""

from __future__ import annotations

import threading
import warnings

import numpy as np

from pipeline.neighbourhood import binary_dilation
from pipeline.spot_shading import SceneRays, ShadingSamples
from torch_recon.contract.frames import focal_length_px

_NEIGHBOURS_8 = np.ones((3, 3), bool)
_NEIGHBOURS_4 = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], bool)
#: pixels refined per batch (bounds the (pixels, n, S, 3) nearest-sample temporaries)
CHUNK_PIXELS = 2048


def stratified_offsets(side: int) -> np.ndarray:
    """(side^2, 2) sub-pixel offsets (dx right, dy down) in [-0.5, 0.5], dx fastest (Cycles' order)."""
    g = (np.arange(side) + 0.5) / side - 0.5
    return np.stack(np.meshgrid(g, g, indexing="xy"), -1).reshape(-1, 2)


def footprint_path_spread(paths: np.ndarray):
    """Path spread across each pixel: (own (H, W), jump (H, W)) in metres from samples (S, H, W).

    own: the range of the pixel's own samples, scaled by s/(s-1) since s x s stratified samples
    span (s-1)/s of the pixel (0 for S = 1). jump: the largest difference of the pixel's mean path
    to a 4-neighbour's, which is about the spread on a smooth surface and much more at a depth
    edge. paths: NaN where a sample sees nothing; the output is NaN-free.
    """
    s2, h, w = paths.shape
    side = int(round(np.sqrt(s2)))
    any_valid = np.isfinite(paths).any(axis=0)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        own = np.nanmax(paths, axis=0) - np.nanmin(paths, axis=0)
        mean = masked_mean(paths, ~np.isnan(paths))
    own = np.where(any_valid, own, 0.0) * (side / (side - 1) if side > 1 else 1.0)
    jump = np.zeros((h, w))
    for axis in (0, 1):
        d = np.abs(np.diff(mean, axis=axis))
        d = np.where(np.isfinite(d), d, 0.0)
        lo = [slice(None)] * 2
        hi = [slice(None)] * 2
        lo[axis], hi[axis] = slice(0, -1), slice(1, None)
        jump[tuple(lo)] = np.maximum(jump[tuple(lo)], d)
        jump[tuple(hi)] = np.maximum(jump[tuple(hi)], d)
    return own, jump


def surface_breaks(positions, normals, valid, slope: float = 0.1, floor_m: float = 1e-3) -> np.ndarray:
    """Pixels (H, W) whose samples, or whose first sample and a 4-neighbour's, do not lie on one surface.

    Two samples x_i, x_j lie on one smooth surface when each lies on the other's tangent plane:
    |(x_j - x_i) . n_i| <= slope |x_j - x_i| + floor_m. A depth edge (a step) or a crease breaks it,
    whatever the lighting and however the edge crosses the pixel. Spot-independent.
    positions, normals (S, H, W, 3), valid (S, H, W).
    """
    x = np.asarray(positions, np.float64)
    n = np.asarray(normals, np.float64)
    valid = np.asarray(valid, bool)

    def breaks(xa, na, va, xb, nb, vb):
        d = xb - xa
        dist = np.linalg.norm(d, axis=-1)
        off = np.maximum(np.abs(np.einsum("...c,...c->...", d, na)), np.abs(np.einsum("...c,...c->...", d, nb)))
        return va & vb & (off > slope * dist + floor_m)

    out = np.zeros(valid.shape[1:], bool)
    for j in range(1, x.shape[0]):
        out |= breaks(x[0], n[0], valid[0], x[j], n[j], valid[j])
    right = breaks(x[0, :, :-1], n[0, :, :-1], valid[0, :, :-1], x[0, :, 1:], n[0, :, 1:], valid[0, :, 1:])
    down = breaks(x[0, :-1], n[0, :-1], valid[0, :-1], x[0, 1:], n[0, 1:], valid[0, 1:])
    out[:, :-1] |= right
    out[:, 1:] |= right
    out[:-1] |= down
    out[1:] |= down
    return out


def normal_breaks(normals, valid, max_angle_deg: float = 0.5) -> np.ndarray:
    """Pixels (H, W) whose samples' shading normals, or whose first sample's and a 4-neighbour's, differ by
    more than max_angle_deg: facet edges and curved surfaces. Spot-independent; normals (S, H, W, 3)."""
    n = np.asarray(normals, np.float64)
    n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-30)
    valid = np.asarray(valid, bool)
    cos_tol = np.cos(np.radians(max_angle_deg))

    def turn(na, va, nb, vb):
        return va & vb & (np.abs(np.einsum("...c,...c->...", na, nb)) < cos_tol)   # two-sided surfaces

    out = np.zeros(valid.shape[1:], bool)
    for j in range(1, n.shape[0]):
        out |= turn(n[0], valid[0], n[j], valid[j])
    right = turn(n[0, :, :-1], valid[0, :, :-1], n[0, :, 1:], valid[0, :, 1:])
    down = turn(n[0, :-1], valid[0, :-1], n[0, 1:], valid[0, 1:])
    out[:, :-1] |= right
    out[:, 1:] |= right
    out[:-1] |= down
    out[1:] |= down
    return out


def masked_mean(values, valid) -> np.ndarray:
    """np.nanmean(where(valid, values, nan), axis=0)'s numbers (NaN where no sample is valid), without its
    copies and warnings. values, valid (S, ...)."""
    count = valid.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(valid, values, 0.0).sum(axis=0) / count


def radiance_contrast(radiance, valid) -> np.ndarray:
    """Relative change of radiance across each pixel (H, W): the range of its samples, or the jump of its
    mean to a 4-neighbour's, over the larger value. radiance, valid (S, H, W)."""
    valid = np.asarray(valid, bool)
    r = np.where(valid, np.asarray(radiance, np.float64), np.nan)
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        hi, lo, mean = np.nanmax(r, axis=0), np.nanmin(r, axis=0), masked_mean(r, valid)
        out = np.where(hi > 0, (hi - lo) / hi, 0.0)          # >= 0: the jumps below only raise it
        for axis in (0, 1):
            first = [slice(None)] * 2
            second = [slice(None)] * 2
            first[axis], second[axis] = slice(0, -1), slice(1, None)
            a, b = mean[tuple(first)], mean[tuple(second)]
            top = np.fmax(a, b)
            d = np.where(top > 0, np.abs(a - b) / top, 0.0)
            d = np.where(np.isfinite(d), d, 0.0)
            np.fmax(out[tuple(first)], d, out=out[tuple(first)])     # the pixel and its neighbour after it
            np.fmax(out[tuple(second)], d, out=out[tuple(second)])
    return np.where(np.isfinite(out), out, 0.0)


def flag_pixels(paths, lit, valid, bin_width_m: float, spread_bins: float = 1.0, breaks=None,
                creases=None, radiance=None, crease_contrast: float = 0.1) -> dict:
    """Pixels whose footprint the base samples do not integrate well, by reason (each (H, W) bool).

    'depth': a step or crease (surface_breaks, given as `breaks`; without it, a jump to a
    neighbour well beyond the pixel's own spread); 'shadow': lit and dark samples in the 3 x 3
    neighbourhood; 'silhouette': surface next to void; 'shading': a normal turn (normal_breaks,
    given as `creases`) where the radiance (S, H, W) changes by more than crease_contrast
    (radiance_contrast); 'edge' = depth | shadow | silhouette | shading;
    'resample' = edge pixels with a lit sample in their 3 x 3 neighbourhood (new rays: only there
    can light be missing); 'spread': other lit pixels whose path spreads over more than
    `spread_bins` bins (integrated by interpolating the base samples, no new rays).
    paths (S, H, W) optical paths (any value where not valid), lit (S, H, W) radiance > 0,
    valid (S, H, W) the sample sees a surface.
    """
    valid = np.asarray(valid, bool)
    lit = np.asarray(lit, bool) & valid
    p = np.where(valid, paths, np.nan)
    own, jump = footprint_path_spread(p)
    thr = spread_bins * bin_width_m
    valid_any = valid.any(axis=0)
    if breaks is None:
        depth = valid_any & (jump > np.maximum(2.0 * own, thr))
        depth |= binary_dilation(depth, _NEIGHBOURS_4) & valid_any   # both sides of the jump
    else:
        depth = np.asarray(breaks, bool) & valid_any
    lit_any = lit.any(axis=0)
    dark_any = (valid & ~lit).any(axis=0)
    near_lit = binary_dilation(lit_any, _NEIGHBOURS_8)
    shadow = (lit_any & dark_any) | (dark_any & near_lit) | (lit_any & binary_dilation(dark_any, _NEIGHBOURS_8))
    void_any = (~valid).any(axis=0)
    silhouette = (valid_any & void_any) | (valid_any & binary_dilation(void_any, _NEIGHBOURS_8))
    shading = np.zeros_like(depth)
    if creases is not None and radiance is not None:
        shading = np.asarray(creases, bool) & lit_any & (radiance_contrast(radiance, lit) > crease_contrast)
    edge = depth | shadow | silhouette | shading
    resample = edge & near_lit
    spread = valid_any & lit_any & (np.maximum(own, jump) > thr) & ~resample
    return {"spread": spread, "depth": depth, "shadow": shadow, "silhouette": silhouette, "shading": shading,
            "edge": edge,
            "resample": resample, "any": spread | resample}


def interpolation_matrix(side_in: int, side_out: int) -> np.ndarray:
    """(side_out, side_in) linear inter/extrapolation from a stratified grid to a finer one (rows sum to 1)."""
    g_in = (np.arange(side_in) + 0.5) / side_in - 0.5
    g_out = (np.arange(side_out) + 0.5) / side_out - 0.5
    if side_in == 1:
        return np.ones((side_out, 1))
    k = np.clip(np.searchsorted(g_in, g_out) - 1, 0, side_in - 2)
    t = (g_out - g_in[k]) / (g_in[k + 1] - g_in[k])
    m = np.zeros((side_out, side_in))
    m[np.arange(side_out), k] = 1 - t
    m[np.arange(side_out), k + 1] = t
    return m


def footprint_samples(values: np.ndarray, side_out: int) -> np.ndarray:
    """Base samples (S, M) of M pixels -> (M, side_out^2) samples spread over each whole footprint.

    Bilinear through the s x s base grid, extrapolated linearly to the pixel's edges: on a smooth
    surface the path (and radiance) vary about linearly across a pixel, so this integrates the
    footprint without new rays. The mean over the new samples equals the base mean.
    """
    s2, m = values.shape
    side = int(round(np.sqrt(s2)))
    a = interpolation_matrix(side, side_out)
    # out[m, (i, j)] = sum_ab a[i, a] a[j, b] v[(a, b), m]: one (side_out^2, S) weight matrix, one product
    # (a three-operand einsum loops over every index: 10x slower at 128 x 128)
    weights = np.einsum("ia,jb->ijab", a, a).reshape(side_out ** 2, s2)
    return values.T @ weights.T


class RefinedGeometry:
    """n x n stratified camera-ray hits of flagged pixels, computed once per pixel for all spots.

    Per sample: world position, shading normal and albedo. The normal is the hit triangle's corner
    normals interpolated at the hit (what Cycles shades with: flat faces keep their face normal, a
    faceted curved wall must not borrow a neighbouring facet's). The albedo comes from the pixel's
    nearest base sample on the same surface (Cycles' Diffuse Color, so textures carry over), else
    the object's albedo.
    """

    def __init__(self, rays: SceneRays, sensor, base_geometry, side: int):
        self.rays, self.side = rays, int(side)
        self.n = self.side ** 2
        c2w = np.asarray(sensor.camera_to_world, np.float64)
        self.rot, self.centre = c2w[:3, :3], c2w[:3, 3]
        self.width, self.height = sensor.width, sensor.height
        self.f_px = focal_length_px(sensor.width, sensor.height, sensor.fov_rad, sensor.fov_axis)
        pos, _, alb, valid = base_geometry
        s = pos.shape[0]
        self.base_pos = pos.reshape(s, -1, 3)
        self.base_alb = alb.reshape(s, -1, alb.shape[-1]).mean(axis=-1)
        self.base_valid = valid.reshape(s, -1)
        self.offsets = stratified_offsets(self.side)
        p = sensor.width * sensor.height
        self.row_of = np.full(p, -1, np.int64)         # pixel -> row of the cache
        # the cache: per row n samples, flattened (row * n + k), their spot-independent shading parts
        self.sensor_origin = np.asarray(sensor.sensor_origin, np.float64)
        self.prepared = ShadingSamples(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), self.sensor_origin)
        self.valid = np.zeros((0, self.n), bool)
        self._lock = threading.Lock()      # spots are shaded in threads; the cache grows under the lock

    def shading_samples(self, pixels: np.ndarray):
        """(ShadingSamples of the valid samples, valid (M, n)) of flat pixel indices (M,), in the order of
        valid (M, n)'s True entries."""
        pixels = np.asarray(pixels, np.int64)
        with self._lock:
            new = np.unique(pixels[self.row_of[pixels] < 0])
            if len(new):
                parts = [self._cast(new[a:a + CHUNK_PIXELS]) for a in range(0, len(new), CHUNK_PIXELS)]
                x, nrm, alb, val = (np.concatenate(z) for z in zip(*parts))
                self.row_of[new] = len(self.valid) + np.arange(len(new))
                fresh = ShadingSamples(x.reshape(-1, 3), nrm.reshape(-1, 3), alb.reshape(-1), self.sensor_origin)
                self.prepared = ShadingSamples.concatenate([self.prepared, fresh])
                self.valid = np.concatenate([self.valid, val])
            prepared, all_valid = self.prepared, self.valid
        rows = self.row_of[pixels]
        valid = all_valid[rows]
        flat = rows[:, None] * self.n + np.arange(self.n)[None, :]
        return prepared.take(flat[valid]), valid

    def _cast(self, pixels):
        m, n = len(pixels), self.n
        row, col = np.divmod(pixels, self.width)
        u = (col[:, None] + 0.5 + self.offsets[None, :, 0] - 0.5 * self.width) / self.f_px
        v = -(row[:, None] + 0.5 + self.offsets[None, :, 1] - 0.5 * self.height) / self.f_px
        d_cam = np.stack([u, v, -np.ones_like(u)], -1)
        d = (d_cam / np.linalg.norm(d_cam, axis=-1, keepdims=True)) @ self.rot.T
        hit, dist, face, nrm = self.rays.first_hits(np.broadcast_to(self.centre, (m * n, 3)), d.reshape(-1, 3),
                                                    shading_normals=True)
        x = self.centre + d.reshape(-1, 3) * np.where(hit, dist, 0.0)[:, None]
        fn = self.rays.face_normals[np.maximum(face, 0)]
        alb = (self.rays.face_albedo[np.maximum(face, 0)] if self.rays.face_albedo is not None
               else np.full(m * n, 0.8))
        # nearest base sample of the same pixel lying on the hit's tangent plane: same surface
        bp = self.base_pos[:, pixels].transpose(1, 0, 2).astype(np.float64)     # (m, S, 3)
        bv = self.base_valid[:, pixels].T
        xr = x.reshape(m, n, 3)
        diff = bp[:, None, :, :] - xr[:, :, None, :]                              # (m, n, S, 3)
        dist_b = np.sqrt(np.einsum("mnsc,mnsc->mns", diff, diff))
        off_plane = np.abs(np.einsum("mnsc,mnc->mns", diff, fn.reshape(m, n, 3)))
        same = bv[:, None, :] & (off_plane <= 1e-3 + 0.1 * dist_b)
        dist_b = np.where(same, dist_b, np.inf)
        k = np.argmin(dist_b, axis=-1)                                            # (m, n)
        ok = np.isfinite(np.take_along_axis(dist_b, k[..., None], -1)[..., 0]).reshape(-1) & hit
        alb = np.where(ok, self.base_alb[k.reshape(-1), np.repeat(pixels, n)], alb)
        return (x.reshape(m, n, 3).astype(np.float32), nrm.reshape(m, n, 3).astype(np.float32),
                alb.reshape(m, n).astype(np.float32), hit.reshape(m, n))
