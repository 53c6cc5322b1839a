"""Thin parts: world points of parts narrower than a pixel (a chair leg, a lamp pole) from each pixel's
earliest significant two-bounce return, for the fast mode's start field (`init.evidence_grid`).

A pixel whose strongest return lies well behind its earliest one sees a part in front of the surface behind
it; the part's voxels are occupied in the start field so that camera rays end there (session 8, issue 11;
docs/reconstruction.md "Thin parts from the earliest return")."""

from __future__ import annotations

import torch

from .data import RayData, pixel_angle


def _shifted(t, dy, dx, fill):
    """(H, W) `t` moved so that [y, x] holds t[y + dy, x + dx] (`fill` beyond the image)."""
    h, w = t.shape[:2]
    p = torch.nn.functional.pad(t.movedim(-1, 0) if t.dim() == 3 else t[None], (1, 1, 1, 1), value=fill)
    p = p[:, 1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
    return p.movedim(0, -1) if t.dim() == 3 else p[0]


_AROUND = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1)]


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
    side by side lies between their centres, 3.7 cm apart, not at both); 'seen': the mean of its own and those
    of the neighbours that see that surface strongest (pulled onto a leg or a backrest the visible surface
    holds; parts nobody sees strongest keep their width); 'off': the earliest return itself."""
    h, w = data.height, data.width
    d = data.visible_depth.reshape(h, w)
    r = torch.fmin(data.nearest_depth.reshape(h, w), d)
    thin = torch.isfinite(d) & (r < d - voxel)
    inf = float("inf")
    if not edges:
        dn = torch.nan_to_num(d, nan=inf)
        broad = torch.stack([(_shifted(dn, dy, dx, inf) - dn).abs() < voxel for dy, dx in _AROUND]).sum(0) >= 6
        beside = torch.stack([((_shifted(dn, dy, dx, inf) - r).abs() < voxel) & _shifted(broad, dy, dx, False)
                              for dy, dx in _AROUND]).any(0)
        thin &= ~beside
    back = 0.25 * (pixel_angle(data, at_centre=True) or 0.0) * r if centre != "off" else torch.zeros_like(r)
    x = data.sensor_origin + data.pixel_dirs.reshape(h, w, 3) * (r + back)[..., None]
    if centre in ("mean", "seen"):
        rn = torch.nan_to_num(r, nan=inf)
        # 'seen': only the pixel itself and neighbours that see the part strongest pull it
        rs = torch.where(rn < torch.nan_to_num(d, nan=inf) - voxel, torch.full_like(rn, inf), rn) \
            if centre == "seen" else rn
        wsum, xsum = torch.zeros_like(r), torch.zeros_like(x)
        for dy, dx in _AROUND:
            wk = (_shifted(rs, dy, dx, inf) - rn).abs() < voxel
            wk |= (dy == 0) & (dx == 0)
            wsum += wk
            xsum += wk[..., None] * _shifted(torch.nan_to_num(x), dy, dx, 0.0)
        x = torch.where(thin[..., None], xsum / wsum.clamp_min(1)[..., None], x)
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


def thin_part_voxels(data: RayData, box, edges: bool = True, centre: str = "off") -> torch.Tensor:
    """Voxels (nx, ny, nz) bool of `box` holding a `thin_part_points` point: the start field occupies them
    (`init.evidence_grid`, label NEAREST where no visible surface point lies) and `fast.thin_part_training`
    keeps training from eroding them."""
    return _voxels_of(box, torch.cat(list(thin_part_points(data, box.voxel, edges=edges, centre=centre))))


def thin_part_signed_distance(data: RayData, box, radius: float, edges: bool = True, centre: str = "off"):
    """(nx, ny, nz): `radius` minus the distance from each voxel centre to the nearest `thin_part_points` point,
    on the thin parts' voxels and their 26 neighbours (NaN elsewhere): a tube of that radius round the points.
    As a raw-density ramp it puts a part under a voxel wide where its points are, to a fraction of a voxel
    (trilinear interpolation of a ramp in the distance); a whole occupied voxel puts it at the voxel's centre,
    up to half a voxel beside the points, once they are centred on the part (`centre` 'mean')."""
    from scipy.spatial import cKDTree

    pts = torch.cat(list(thin_part_points(data, box.voxel, edges=edges, centre=centre)))
    sd = torch.full(tuple(box.shape), float("nan"), device=pts.device)
    if len(pts) == 0:
        return sd
    near = torch.nn.functional.max_pool3d(_voxels_of(box, pts).float()[None, None], 3, 1, 1)[0, 0] > 0
    dist, _ = cKDTree(pts.cpu().double().numpy()).query(box.centres()[near].cpu().double().numpy())
    sd[near] = radius - torch.as_tensor(dist, dtype=sd.dtype, device=sd.device)
    return sd
