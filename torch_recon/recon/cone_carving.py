"""Carving with ray footprints (cones), not lines: a voxel is free only where every measurement near it is.

A camera ray or a lit secondary ray marched as a line carves every voxel it crosses, so a part narrower
than a voxel (a 2 cm chair leg in a 3.2 cm voxel) loses its voxel to the rays passing beside it. Here each
viewpoint (the sensor; each spot, whose secondary rays x -> l are the rays of a camera at l) keeps a
direction map (octahedral, about one ray per bin) of its rays: per bin the shortest free range of a
camera or lit ray and the longest shadowed ray. A voxel at range r in direction u is free from that
viewpoint when the rays within its angular footprint (half a voxel around its centre) were measured,
all are free beyond r, and no shadowed ray among them passes it; a leg's voxel keeps its blocking
shadow rays in its footprint. Used as a veto on the line-carved voxels that shadowed rays cross
(recon/init.py `evidence_grid`), so empty space without any shadow stays carved as before.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

#: largest footprint radius (bins) a map is pooled for; a wider footprint (a voxel next to a spot) uses it
MAX_RADIUS_BINS = 4
#: finest direction map (bins per side of the octahedral square; 512: 0.4 degree bins)
MAX_BINS_PER_SIDE = 512


def octahedral_bins(u: torch.Tensor, n: int) -> torch.Tensor:
    """Flat bin (row-major, n x n) of unit directions u (M, 3) on the octahedral map of the sphere."""
    a = u / u.abs().sum(-1, keepdim=True).clamp(min=1e-12)
    p = a[:, :2]
    lower = a[:, 2] < 0
    folded = (1.0 - p.flip(-1).abs()) * torch.where(p >= 0, 1.0, -1.0)
    p = torch.where(lower[:, None], folded, p)
    ij = ((p + 1.0) * 0.5 * n).long().clamp(0, n - 1)
    return ij[:, 0] * n + ij[:, 1]


def _growing_max(x: torch.Tensor) -> torch.Tensor:
    """(MAX_RADIUS_BINS + 1, n * n): the maximum of x (1, 1, n, n) over square windows of radius 0, 1, ..."""
    out = [x.reshape(-1)]
    for _ in range(MAX_RADIUS_BINS):
        x = F.max_pool2d(F.max_pool2d(x, (3, 1), 1, (1, 0)), (1, 3), 1, (0, 1))
        out.append(x.reshape(-1))
    return torch.stack(out)


class DirectionMap:
    """Rays from one viewpoint `origin`: per direction bin the shortest free range (inf: no free ray) and the
    longest range a shadowed ray is blocked within (0: none), pooled over square windows of 0..MAX_RADIUS_BINS."""

    def __init__(self, origin: torch.Tensor, dirs: torch.Tensor, free_to: torch.Tensor, shadow_to: torch.Tensor,
                 bin_rad: float):
        self.origin = origin
        self.n = n = max(8, min(MAX_BINS_PER_SIDE, int(math.ceil(math.sqrt(4 * math.pi) / max(bin_rad, 1e-4)))))
        self.bin_rad = math.sqrt(4 * math.pi) / n
        b = octahedral_bins(dirs, n)
        inf = torch.tensor(float("inf"), device=dirs.device)
        free = torch.full((n * n,), float("inf"), device=dirs.device)
        free.scatter_reduce_(0, b, torch.where(torch.isfinite(free_to), free_to, inf), "amin")
        shadow = torch.zeros(n * n, device=dirs.device)
        shadow.scatter_reduce_(0, b, torch.nan_to_num(shadow_to, nan=0.0), "amax")
        free, shadow = free.reshape(1, 1, n, n), shadow.reshape(1, 1, n, n)
        # per radius k (square windows of 2 k + 1 bins, each one bin wider than the last, two 1-D pools):
        # min free range (empty bins ignored: +inf), max shadow range, whether any free ray
        self.free = -_growing_max(-free)
        self.shadow = _growing_max(shadow)
        self.has = self.free < float("inf")

    def free_at(self, pts: torch.Tensor, radius_m: float, margin_m: float) -> torch.Tensor:
        """Whether each point (M, 3) is free from this viewpoint: the rays within `radius_m` of it (angularly)
        include a free one, all free ones reach `margin_m` beyond it, no shadowed one is blocked beyond it."""
        v = pts - self.origin
        r = torch.linalg.vector_norm(v, dim=-1)
        b = octahedral_bins(v / r.clamp(min=1e-9)[:, None], self.n)
        k = torch.ceil(radius_m / (r.clamp(min=1e-9) * self.bin_rad)).long().clamp(0, MAX_RADIUS_BINS)
        return (self.has[k, b] & (self.free[k, b] > r + margin_m) & (self.shadow[k, b] <= r + margin_m)
                & (r > margin_m))


def cone_free(data, pts: torch.Tensor, voxel: float, camera_margin_m: float, secondary_offset_m: float,
              radius_voxels: float = 0.5) -> torch.Tensor:
    """Per point (M, 3): from how many viewpoints (the sensor, each spot) it is free under the footprint rule
    (module doc)."""
    radius = radius_voxels * voxel
    c = data.sensor_origin
    d = data.visible_depth
    ok = torch.isfinite(d)
    w = data.width
    pix_rad = float(torch.arccos((data.pixel_dirs[0] * data.pixel_dirs[1]).sum().clamp(-1, 1))) if w > 1 else 1e-3
    cam = DirectionMap(c, data.pixel_dirs[ok], d[ok], torch.zeros_like(d[ok]), pix_rad)
    free = cam.free_at(pts, radius, camera_margin_m).long()
    pairs = torch.nonzero(torch.isfinite(d[data.pair_pixel]) & (data.lit | data.shadowed), as_tuple=False).squeeze(1)
    px, sp = data.pair_pixel[pairs], data.pair_spot[pairs]
    x = c + data.pixel_dirs[px] * d[px, None]
    for k in torch.unique(sp).tolist():
        m = sp == k
        l = data.spot_points[k]
        v = x[m] - l
        length = torch.linalg.vector_norm(v, dim=-1)
        good = length > 2 * secondary_offset_m
        lit = data.lit[pairs[m]][good]
        u, length = v[good] / length[good, None], length[good]
        # about one ray per bin: the footprint of a camera pixel at x seen from l
        spacing = float(torch.median(pix_rad * d[px[m][good]] / length)) if len(length) else pix_rad
        inf = torch.full_like(length, float("inf"))
        spot = DirectionMap(l, u, torch.where(lit, length, inf), torch.where(lit, 0.0, length), spacing)
        free += spot.free_at(pts, radius, secondary_offset_m)
    return free
