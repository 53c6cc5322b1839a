"""Thin parts: world points of parts narrower than a pixel (a chair leg, a lamp pole) from each pixel's
earliest significant two-bounce return, for the fast mode's start field (`voxel_evidence.evidence_grid`).

A pixel whose strongest return lies well behind its earliest one sees a part in front of the surface behind
it; the part's voxels are occupied in the start field so that camera rays end there (session 8, issue 11;
docs/reconstruction.md "Thin parts from the earliest return")."""

from __future__ import annotations

import torch

from .data import RayData, pixel_angle
from .fields import dilate_cube


def _shifted(t, dy, dx, fill):
    """(H, W) `t` moved so that [y, x] holds t[y + dy, x + dx] (`fill` beyond the image)."""
    h, w = t.shape[:2]
    p = torch.nn.functional.pad(t.movedim(-1, 0) if t.dim() == 3 else t[None], (1, 1, 1, 1), value=fill)
    p = p[:, 1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
    return p.movedim(0, -1) if t.dim() == 3 else p[0]


_AROUND = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1)]


def part_coverage(data: RayData, thin, voxel: float):
    """(H, W) fraction of each `thin` pixel's footprint the part in front covers, NaN where unknown (and on the
    other pixels): the rest of
    the footprint sees the surface behind, so its strongest return is that much weaker than the return of a
    neighbour seeing only that surface (an 8-neighbour not `thin`, whose strongest return lies within `voxel` of
    the pixel's). 1 - the ratio of the strengths (matched-filter peaks), median over the spots lit at both: a
    pole covering half a pixel halves the wall's return there (thin-structures: 0.52 of the wall beside it,
    and 0.88 in the neighbour its edge grazes)."""
    h, w = data.height, data.width
    if data.amplitude is None:
        return torch.full((h, w), float("nan"), device=thin.device)
    a = data.amplitude.reshape(-1, h, w).permute(1, 2, 0)
    d = torch.nan_to_num(data.visible_depth.reshape(h, w), nan=float("inf"))
    pure = ~thin & torch.isfinite(d)
    ref, n = torch.zeros_like(a), torch.zeros_like(a)
    for dy, dx in _AROUND:
        if dy == dx == 0:
            continue
        aq = _shifted(a, dy, dx, float("nan"))
        ok = (_shifted(pure, dy, dx, False) & ((_shifted(d, dy, dx, float("inf")) - d).abs() < voxel))[..., None]
        ok = ok & torch.isfinite(aq)
        ref += torch.where(ok, aq, 0.0)
        n += ok
    ratio = a / (ref / n)                   # NaN where the pixel is not lit or no neighbour is a reference
    cov = 1.0 - torch.nanmedian(ratio, -1).values.clamp(0.0, 1.0)
    return torch.where(thin, cov, torch.full_like(cov, float("nan")))


def thin_part_points(data: RayData, voxel: float, samples: int = 4, edges: bool = True, centre: str = "off"):
    """World points of parts thinner than a pixel, chunk by chunk: the nearest surface of each pixel whose
    strongest return lies more than `voxel` behind it (`nearest_depth`), and the segments joining it to the
    8-neighbouring pixels' nearest surfaces at the same range (within `voxel`): a pole or a leg seen
    over a column of pixels is one continuous part, not a dotted line with gaps where the pixel rows
    (3.7 cm apart at 3 m, 128 px) step over a 3.2 cm voxel.
    Without `edges`, a pixel next to a broad surface at its range (a neighbour whose strongest return is that
    surface, with at least 5 of its own 8 neighbours on it) is left out: it sees the silhouette edge of a
    part the visible surface already holds (a backrest's outline), and a whole voxel there fattens the part
    by up to a voxel. A part a pixel or so wide (a chair leg seen strongest in a column of single pixels)
    keeps its edge pixels: the visible surface alone does not hold it.
    `centre` 'depth' or 'mean': a point lies a quarter of the pixel's footprint behind the earliest return (the
    part's expected half width: the earliest return comes from its front, the voxel should hold its middle);
    'mean': and it is the mean of the 3 x 3 pixels' points at the same range (a 2 cm leg seen in two pixels
    side by side lies between their centres, 3.7 cm apart, not at both); 'coverage': that mean weighted by how
    much of each pixel the part covers (`part_coverage`; 1 where unknown, and for a neighbour seeing the part
    strongest): the pixel a pole's edge grazes pulls its point less than the one the pole half fills; 'seen': the mean of its own and those
    of the neighbours that see that surface strongest (pulled onto a leg or a backrest the visible surface
    holds; parts nobody sees strongest keep their width); 'off': the earliest return itself."""
    h, w = data.height, data.width
    d = data.visible_depth.reshape(h, w)
    r = torch.fmin(data.nearest_depth.reshape(h, w), d)
    thin = front = torch.isfinite(d) & (r < d - voxel)
    inf = float("inf")
    dn = torch.nan_to_num(d, nan=inf)
    broad = torch.stack([(_shifted(dn, dy, dx, inf) - dn).abs() < voxel for dy, dx in _AROUND]).sum(0) >= 6
    if not edges:
        beside = torch.stack([((_shifted(dn, dy, dx, inf) - r).abs() < voxel) & _shifted(broad, dy, dx, False)
                              for dy, dx in _AROUND]).any(0)
        thin = thin & ~beside
    if centre == "coverage":
        # a pixel seeing the part strongest where its neighbours see it only in front of the surface behind (no
        # broad surface of its own): the part's own pixel, a point of it too (its visible-surface ramp alone
        # erodes in training, and a pole breaks at those heights)
        rn = torch.nan_to_num(r, nan=inf)
        seen = torch.stack([_shifted(front, dy, dx, False) & ((_shifted(rn, dy, dx, inf) - dn).abs() < voxel)
                            for dy, dx in _AROUND]).any(0)
        thin = thin | (torch.isfinite(d) & ~front & ~broad & seen)
    back = 0.25 * (pixel_angle(data, at_centre=True) or 0.0) * r if centre != "off" else torch.zeros_like(r)
    x = data.sensor_origin + data.pixel_dirs.reshape(h, w, 3) * (r + back)[..., None]
    if centre in ("mean", "seen", "coverage"):
        rn = torch.nan_to_num(r, nan=inf)
        # 'seen': only the pixel itself and neighbours that see the part strongest pull it
        rs = torch.where(rn < torch.nan_to_num(d, nan=inf) - voxel, torch.full_like(rn, inf), rn) \
            if centre == "seen" else rn
        weight = torch.ones_like(r)
        if centre == "coverage":
            weight = torch.where(thin, torch.nan_to_num(part_coverage(data, front, voxel), nan=1.0), weight)
            weight = weight.clamp_min(0.02)
        wsum, xsum = torch.zeros_like(r), torch.zeros_like(x)
        for dy, dx in _AROUND:
            wk = ((_shifted(rs, dy, dx, inf) - rn).abs() < voxel) | ((dy == 0) & (dx == 0))
            wk = wk * _shifted(weight, dy, dx, 0.0)
            wsum += wk
            xsum += wk[..., None] * _shifted(torch.nan_to_num(x), dy, dx, 0.0)
        x = torch.where(thin[..., None], xsum / wsum.clamp_min(1e-6)[..., None], x)
    r = r + back
    yield x[thin]
    s = torch.linspace(0.0, 1.0, samples + 2, device=d.device)[1:-1]
    for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
        a = (slice(0, h - dy), slice(max(0, -dx), w - max(dx, 0)))
        b = (slice(dy, h), slice(max(0, dx), w + min(dx, 0)))
        same = (thin[a] | thin[b]) & torch.isfinite(r[a]) & torch.isfinite(r[b]) & ((r[a] - r[b]).abs() < voxel)
        pa, pb = x[a][same], x[b][same]
        yield (pa[:, None] + s[None, :, None] * (pb - pa)[:, None]).reshape(-1, 3)


def _voxels_of(box, pts) -> torch.Tensor:
    """Voxels (nx, ny, nz) bool of `box` holding at least one of the points (N, 3)."""
    n = int(box.shape[0] * box.shape[1] * box.shape[2])
    idx, inside = box.cell_index(pts)
    flat = (idx[:, 0] * box.shape[1] + idx[:, 1]) * box.shape[2] + idx[:, 2]
    return (torch.bincount(flat[inside], minlength=n) > 0).reshape(box.shape)


def thin_part_cloud(data: RayData, voxel: float, edges: bool = True, centre: str = "off") -> torch.Tensor:
    """All `thin_part_points` chunks as one (N, 3) tensor: the start field and the frozen thin-part mask of a
    fit share one (`FastModel.thin_points`), passed as `points` below."""
    return torch.cat(list(thin_part_points(data, voxel, edges=edges, centre=centre)))


def thin_part_voxels(data: RayData, box, edges: bool = True, centre: str = "off", points=None) -> torch.Tensor:
    """Voxels (nx, ny, nz) bool of `box` holding a `thin_part_points` point (`points`: `thin_part_cloud` when
    already computed): the start field occupies them (`voxel_evidence.evidence_grid`, label NEAREST where no visible
    surface point lies) and `fast.thin_part_training` keeps training from eroding them."""
    return _voxels_of(box, thin_part_cloud(data, box.voxel, edges, centre) if points is None else points)


def thin_part_signed_distance(data: RayData, box, radius: float, edges: bool = True, centre: str = "off",
                              points=None):
    """(nx, ny, nz): `radius` minus the distance from each voxel centre to the nearest `thin_part_points` point,
    on the thin parts' voxels and their 26 neighbours (NaN elsewhere): a tube of that radius round the points.
    As a raw-density ramp it puts a part under a voxel wide where its points are, to a fraction of a voxel
    (trilinear interpolation of a ramp in the distance); a whole occupied voxel puts it at the voxel's centre,
    up to half a voxel beside the points, once they are centred on the part (`centre` 'mean').
    points: `thin_part_cloud` when already computed."""
    from scipy.spatial import cKDTree

    pts = thin_part_cloud(data, box.voxel, edges, centre) if points is None else points
    sd = torch.full(tuple(box.shape), float("nan"), device=pts.device)
    if len(pts) == 0:
        return sd
    near = dilate_cube(_voxels_of(box, pts).float(), 1) > 0
    dist, _ = cKDTree(pts.cpu().double().numpy()).query(box.centres()[near].cpu().double().numpy())
    sd[near] = radius - torch.as_tensor(dist, dtype=sd.dtype, device=sd.device)
    return sd
