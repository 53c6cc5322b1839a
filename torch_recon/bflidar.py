"""Bounce Flash Lidar baseline (Henley et al. 2022), as used in the PlatoNeRF paper, vectorised in torch.

1. Visible geometry: the closed-form ellipsoid depth per (spot, pixel), fused per
   pixel (torch_recon.visible_depth) -> one point x_p per pixel.
2. Occluded geometry by probabilistic shadow carving over a voxel grid. For each
   spot k, the segments l_k -> x_p of lit pixels (matched-filter confidence >=
   the carving threshold) and of shadowed pixels are rasterised into the grid
   (dense samples every half voxel). Per spot a voxel is 'outside' when lit rays
   cross it and no shadow ray does, 'inside' when a shadow ray crosses it. Over
   the spots, M = number of 'outside' spots, N = number of 'inside' spots, and
       P(occupied | M, N) = p1 eta^M (1-eta)^N / (p0 (1-xi)^M xi^N + p1 eta^M (1-eta)^N)
   (eta: chance an occupied voxel is crossed by a lit ray, xi: chance an empty
   voxel is crossed by a shadow ray; p0, p1 priors), thresholded at
   `occupancy_threshold`. The defaults are those of the PlatoNeRF authors' port.
   Unlike that port, each segment stops `end_margin_voxels` short of l_k and of
   x_p (the port traced rays through the whole grid, past the surface).
3. Voxels holding visible points are occupied; the occupancy volume is lightly
   smoothed and meshed (torch_recon.mesh_export). The paper grid-searched the
   shadow and occupancy thresholds per scene against ground truth: `grid_search`.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass

import numpy as np

from .contract.errors import SettingsError, UnconstrainedMeasurementsError


@dataclass
class BFLidarSettings:
    SETTINGS_META = {"voxels": {"range": (4, None)}, "occupancy_threshold": {"range": (0.0, 1.0)},
                     "bbox_padding_m": {"unit": "m"}}

    voxels: int = 128                  # voxels along the longest bbox axis
    bbox_min: tuple | None = None      # None: visible points' bounds + padding
    bbox_max: tuple | None = None
    bbox_padding_m: float = 0.05
    occupancy_threshold: float = 0.3   # T of the port
    carve_shadow_threshold: float | None = None   # None: the measurements' threshold
    eta: float = 0.05
    xi: float = 0.5
    p0: float = 0.8
    p1: float = 0.2
    end_margin_voxels: float = 1.5     # segments stop this far from l and from x (surfaces are not free space)
    min_visible_confidence: float = 0.0
    smooth_sigma_voxels: float = 0.75  # Gaussian blur of the binary occupancy before marching cubes
    mesh_level: float = 0.25           # marching-cubes level on the blurred occupancy (a 1-voxel sheet peaks ~0.5)
    surface_depth_jump: float = 0.05   # neighbouring pixels farther apart (relative depth) are not joined
    max_rays_per_spot: int = 65536     # carve from every n-th pixel beyond this (rays of neighbours coincide)
    chunk_rays: int = 65536

    def validate(self):
        if self.voxels < 4:
            raise SettingsError("voxels", f"expected an integer >= 4, got {self.voxels}")
        if not 0 < self.occupancy_threshold < 1:
            raise SettingsError("occupancy_threshold", f"expected a value in (0, 1), got {self.occupancy_threshold}")
        for name in ("eta", "xi", "p0", "p1"):
            if not 0 < getattr(self, name) < 1:
                raise SettingsError(name, f"expected a value in (0, 1), got {getattr(self, name)}")


@dataclass
class BFLidarResult:
    occupancy: np.ndarray        # (X, Y, Z) float32 in [0, 1] (smoothed binary occupancy, for meshing)
    probability: np.ndarray      # (X, Y, Z) float32 P(occupied | M, N), 1 at visible voxels
    bbox_min: np.ndarray
    bbox_max: np.ndarray
    counts_outside: np.ndarray   # (X, Y, Z) int16 M
    counts_inside: np.ndarray    # (X, Y, Z) int16 N
    visible: np.ndarray          # (X, Y, Z) bool: voxels holding visible points
    settings: dict
    seconds: float

    @property
    def level(self) -> float:
        return float(self.settings.get("mesh_level", 0.25))

    def mesh(self):
        from .mesh_export import mesh_from_volume
        return mesh_from_volume(self.occupancy, self.bbox_min, self.bbox_max, self.level)[0]


def occupancy_posterior(m, n, eta, xi, p0, p1):
    """P(occupied | M lit-only spots, N shadow spots) (torch or numpy), computed in log space."""
    import torch
    m, n = torch.as_tensor(m, dtype=torch.float64), torch.as_tensor(n, dtype=torch.float64)
    lo = math.log(p1) + m * math.log(eta) + n * math.log(1 - eta)
    le = math.log(p0) + m * math.log(1 - xi) + n * math.log(xi)
    return torch.sigmoid(lo - le)


def visible_surface_points(points_img, ok, spacing, max_jump):
    """Points filling each quad of 4 neighbouring visible pixels (bilinear), at most `spacing` apart.

    A quad is skipped when its corners' ranges differ by more than `max_jump` (relative):
    a depth edge, not a surface. Returns (N, 3) including the pixel points themselves.
    """
    p = points_img
    corners = [p[:-1, :-1], p[:-1, 1:], p[1:, :-1], p[1:, 1:]]
    okq = ok[:-1, :-1] & ok[:-1, 1:] & ok[1:, :-1] & ok[1:, 1:]
    out = [p[ok]]
    if not okq.any():
        return out[0]
    c = [q[okq] for q in corners]
    r = np.stack([np.linalg.norm(q, axis=-1) for q in c], -1)
    flat = (r.max(-1) - r.min(-1)) <= max_jump * r.min(-1)
    c = [q[flat] for q in c]
    if not len(c[0]):
        return out[0]
    size = max(float(np.percentile(np.linalg.norm(c[3] - c[0], axis=-1), 95)), 1e-9)
    f = int(min(16, max(1, math.ceil(size / spacing))))
    if f > 1:
        g = (np.arange(f + 1) / f)
        u, v = np.meshgrid(g, g, indexing="ij")
        u, v = u.reshape(-1, 1, 1), v.reshape(-1, 1, 1)
        fill = (1 - u) * (1 - v) * c[0] + (1 - u) * v * c[1] + u * (1 - v) * c[2] + u * v * c[3]
        out.append(fill.reshape(-1, 3))
    return np.concatenate(out)


def _grid(meas, points, s: BFLidarSettings):
    if s.bbox_min is not None and s.bbox_max is not None:
        lo, hi = np.asarray(s.bbox_min, float), np.asarray(s.bbox_max, float)
    else:
        if len(points) == 0:
            raise UnconstrainedMeasurementsError("no visible points: cannot place the carving grid "
                                                 "(give bbox_min/bbox_max)")
        lo = points.min(0) - s.bbox_padding_m
        hi = points.max(0) + s.bbox_padding_m
        lo = np.minimum(lo, np.asarray([sp.first_bounce for sp in meas.spots]).min(0) - s.bbox_padding_m)
        hi = np.maximum(hi, np.asarray([sp.first_bounce for sp in meas.spots]).max(0) + s.bbox_padding_m)
    if not np.all(hi > lo):
        raise UnconstrainedMeasurementsError(f"empty carving box {lo.tolist()} .. {hi.tolist()}")
    vox = float((hi - lo).max()) / s.voxels
    shape = np.maximum(np.ceil((hi - lo) / vox).astype(int), 2)
    return lo, lo + shape * vox, vox, tuple(int(v) for v in shape)


def _mark_segments(vol, a, b, lo, vox, shape, margin, chunk, torch):
    """Set vol (flat bool) at every voxel crossed by segments a -> b (torch (N, 3)), ends trimmed by `margin`.

    Works in voxel units; samples every half voxel (a segment crossing a voxel's
    corner by less than that may skip it, which the per-spot 'any ray' rule tolerates).
    """
    if len(b) == 0:
        return
    dims = torch.tensor(shape, device=b.device, dtype=b.dtype)
    lo_t = torch.as_tensor(lo, dtype=b.dtype, device=b.device)
    av = (a - lo_t) / vox
    bv = (b - lo_t) / vox
    m = margin / vox
    inside = bool(((av >= 0) & (av < dims)).all()) and bool(((bv >= 0) & (bv < dims)).all())
    sv = torch.tensor([shape[1] * shape[2], shape[2], 1], device=b.device, dtype=torch.int32)
    for s in range(0, len(bv), chunk):
        bb = bv[s:s + chunk]
        aa = av if av.ndim == 1 else av[s:s + chunk]
        seg = bb - aa
        length = torch.linalg.norm(seg, dim=-1)
        keep = length > 2 * m
        bb, seg, length = bb[keep], seg[keep], length[keep]
        if len(bb) == 0:
            continue
        aa = aa if aa.ndim == 1 else aa[keep]
        # sort by length so each sub-batch samples only as far as its longest segment
        order = torch.argsort(length)
        seg, length = seg[order], length[order]
        aa = aa if aa.ndim == 1 else aa[order]
        step = 2048
        for q in range(0, len(seg), step):
            sg, ln = seg[q:q + step], length[q:q + step]
            a0 = aa if aa.ndim == 1 else aa[q:q + step]
            n = int(math.ceil(float(ln[-1]) * 2.0)) + 1
            u = torch.linspace(0, 1, n, device=b.device, dtype=b.dtype)
            u0 = (m / ln)[:, None]
            uu = u0 + (1 - 2 * u0) * u[None]                         # (R, n): margin .. length - margin
            pts = (a0[..., None, :] if a0.ndim == 2 else a0) + sg[:, None, :] * uu[..., None]
            if not inside:
                ok = ((pts >= 0) & (pts < dims)).all(-1)
                pts = pts[ok]
            idx = pts.to(torch.int32)                                  # floor: coordinates are >= 0
            vol[(idx * sv).sum(-1, dtype=torch.int64)] = True


def carve(meas, settings: BFLidarSettings | None = None, device="cpu", progress=False) -> BFLidarResult:
    """Run BF Lidar on preprocessed measurements (needs their fused visible depth)."""
    import torch
    from scipy.ndimage import gaussian_filter

    s = settings or BFLidarSettings()
    s.validate()
    t0 = time.perf_counter()
    if meas.visible_depth is None:
        raise UnconstrainedMeasurementsError("measurements carry no visible depth: preprocess with "
                                             "compute_visible_depth=True")
    d = meas.pixel_directions()
    o = np.broadcast_to(meas.sensor_origin, d.shape)
    depth = meas.visible_depth
    ok = np.isfinite(depth)
    if meas.visible_confidence is not None:
        ok &= meas.visible_confidence >= s.min_visible_confidence
    pts_img = np.where(ok[..., None], o + d * np.nan_to_num(depth)[..., None], np.nan)
    points = pts_img[ok]
    lo, hi, vox, shape = _grid(meas, points, s)
    stride = max(1, math.ceil(math.sqrt(meas.width * meas.height / max(s.max_rays_per_spot, 1))))
    ray_px = np.zeros_like(ok)
    ray_px[::stride, ::stride] = True
    nvox = shape[0] * shape[1] * shape[2]
    thr = meas.shadow_threshold if s.carve_shadow_threshold is None else s.carve_shadow_threshold
    m_cnt = torch.zeros(nvox, dtype=torch.int16, device=device)
    n_cnt = torch.zeros(nvox, dtype=torch.int16, device=device)
    margin = s.end_margin_voxels * vox
    it = meas.spots
    if progress:
        from tqdm import tqdm
        it = tqdm(it, desc="shadow carving", unit="spot")
    for sp in it:
        use = ok & ray_px & ~np.asarray(sp.excluded, bool)
        lit = use & (np.asarray(sp.shadow_confidence) >= thr)
        shadow = use & ~lit
        l = torch.as_tensor(sp.first_bounce, dtype=torch.float32, device=device)
        lit_vol = torch.zeros(nvox, dtype=torch.bool, device=device)
        sh_vol = torch.zeros(nvox, dtype=torch.bool, device=device)
        _mark_segments(lit_vol, l, torch.as_tensor(pts_img[lit], dtype=torch.float32, device=device), lo, vox,
                       shape, margin, s.chunk_rays, torch)
        _mark_segments(sh_vol, l, torch.as_tensor(pts_img[shadow], dtype=torch.float32, device=device), lo, vox,
                       shape, margin, s.chunk_rays, torch)
        m_cnt += (lit_vol & ~sh_vol).to(torch.int16)
        n_cnt += sh_vol.to(torch.int16)
    prob = occupancy_posterior(m_cnt, n_cnt, s.eta, s.xi, s.p0, s.p1).to(torch.float32)
    vis = torch.zeros(nvox, dtype=torch.bool, device=device)
    surf = visible_surface_points(np.nan_to_num(pts_img), ok, 0.5 * vox, s.surface_depth_jump)
    if len(surf):
        idx = np.floor((surf - lo) / vox).astype(np.int64)
        idx = idx[np.all((idx >= 0) & (idx < np.array(shape)), axis=1)]
        vis[torch.as_tensor(idx @ np.array([shape[1] * shape[2], shape[2], 1]), device=device)] = True
    prob = torch.where(vis, torch.ones_like(prob), prob)
    binary = (prob > s.occupancy_threshold).reshape(shape).cpu().numpy().astype(np.float32)
    occ = gaussian_filter(binary, s.smooth_sigma_voxels) if s.smooth_sigma_voxels > 0 else binary
    # grid points of mesh_export sit at voxel centres here: shift the bbox by half a voxel
    return BFLidarResult(occupancy=occ.astype(np.float32), probability=prob.reshape(shape).cpu().numpy(),
                         bbox_min=lo + 0.5 * vox, bbox_max=lo + (np.array(shape) - 0.5) * vox,
                         counts_outside=m_cnt.reshape(shape).cpu().numpy(),
                         counts_inside=n_cnt.reshape(shape).cpu().numpy(),
                         visible=vis.reshape(shape).cpu().numpy(), settings=asdict(s),
                         seconds=time.perf_counter() - t0)


def rethreshold(result: BFLidarResult, occupancy_threshold: float) -> BFLidarResult:
    """The same carving counts with another occupancy threshold (cheap: no re-carving)."""
    from dataclasses import replace

    from scipy.ndimage import gaussian_filter
    sig = result.settings.get("smooth_sigma_voxels", 0.0)
    binary = (result.probability > occupancy_threshold).astype(np.float32)
    occ = gaussian_filter(binary, sig) if sig > 0 else binary
    return replace(result, occupancy=occ.astype(np.float32),
                   settings={**result.settings, "occupancy_threshold": occupancy_threshold})


def test_view_depth_l1(cameras, gt_depths, width: int, height: int, fov_rad: float, fov_axis: str = "x",
                       stride: int = 1):
    """score(mesh) for `grid_search`: depth L1 (m) of the mesh on every `stride`-th test view (the paper's way)."""
    from .evaluate import depth_metrics, render_mesh_depth

    sub = slice(None, None, int(stride))

    def score(mesh):
        pred = np.stack([render_mesh_depth(mesh, c, width, height, fov_rad, fov_axis) for c in cameras[sub]])
        return depth_metrics(pred, np.asarray(gt_depths)[sub])["depth_l1_m"]
    return score


def grid_search(meas, score, settings: BFLidarSettings | None = None, occupancy_thresholds=(0.1, 0.2, 0.3, 0.5, 0.7),
                shadow_thresholds=(None,), device="cpu", progress=False):
    """Pick the thresholds minimising score(mesh) (e.g. depth L1 on test views, as the paper did).

    Returns (best result, best score, table of (shadow threshold, occupancy threshold, score)).
    """
    from dataclasses import replace
    base = settings or BFLidarSettings()
    best, best_score, table = None, math.inf, []
    for st in shadow_thresholds:
        res = carve(meas, replace(base, carve_shadow_threshold=st), device, progress)
        for ot in occupancy_thresholds:
            r = rethreshold(res, ot)
            try:
                sc = float(score(r.mesh()))
            except ValueError:   # no surface at this threshold
                sc = math.inf
            table.append((st, ot, sc))
            if sc < best_score:
                best, best_score = r, sc
    if best is None:
        raise UnconstrainedMeasurementsError("no threshold gave a surface")
    return best, best_score, table
