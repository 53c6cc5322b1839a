"""Light between lit pixels: secondary segments from the surface between two neighbouring lit pixels (fast start).

Shadow carving marches the segment x -> l of every lit pixel's centre. Where the sensor sees a surface at a
grazing angle (the floor two metres below it, 3 m ahead: cos 0.55) neighbouring pixels' points lie up to
8 cm apart at 128 px, so their segments pass 2-3 voxels (3.2 cm) apart near the surface, and the voxels
between them stay in the shadow hull although light from the spot reached the surface on both sides.
Organic-occluded (session 9): of the start's 898 reported hull-boundary voxels more than 1.5 voxels from
any true surface, outside the objects, 399 lie on a line from a spot to a camera-visible point of the
true scene that nothing blocks; for those (voxel, spot) pairs the pixel seeing that point is lit in 2,182
of 3,314 cases, and its centre's segment passes a median 0.89 voxel from the voxel centre.

The rule: two neighbouring pixels (4 directions) both lit by a spot, on one surface (each point within
`same_surface_voxels` of the other's tangent plane: no depth edge between them), have the surface between
them lit too; the segment from their midpoint to the spot is free. A shadow thinner than the pixel spacing
falling between the two centres is the exception (a leg's shadow, about a pixel wide: `shadow_decision`
marks a pixel it covers in part as shadow, so such a pair is not both lit).
"""

from __future__ import annotations

import numpy as np
import torch

from .data import RayData


def lit_midpoints(data: RayData, normals: torch.Tensor, rows: torch.Tensor, cols: torch.Tensor, voxel: float,
                  same_surface_voxels: float = 0.5):
    """Per spot k: (k, midpoints (M, 3)) of the neighbouring carving pixels (the grid `rows` x `cols`) that
    are both lit by k and lie on one surface. normals: (H * W, 3) unit surface normals (NaN where none)."""
    h, w = data.height, data.width
    d = data.visible_depth.reshape(h, w)
    x = (data.sensor_origin + data.pixel_dirs.reshape(h, w, 3) * d[..., None])[rows][:, cols]
    nrm = normals.reshape(h, w, 3)[rows][:, cols]
    good = torch.isfinite(x).all(-1) & torch.isfinite(nrm).all(-1)
    tol = same_surface_voxels * voxel
    pairs = []
    for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
        a = (slice(0, x.shape[0] - dy), slice(max(0, -dx), x.shape[1] - max(dx, 0)))
        b = (slice(dy, x.shape[0]), slice(max(0, dx), x.shape[1] + min(dx, 0)))
        step = x[b] - x[a]
        same = good[a] & good[b] & ((step * nrm[a]).sum(-1).abs() <= tol) & ((step * nrm[b]).sum(-1).abs() <= tol)
        ia = (rows[:, None] * w + cols[None, :])[a]
        ib = (rows[:, None] * w + cols[None, :])[b]
        pairs.append((ia[same], ib[same], 0.5 * (x[a] + x[b])[same]))
    lit_pixel = torch.zeros(h * w, dtype=torch.bool, device=d.device)
    for k in torch.unique(data.pair_spot[data.lit]).tolist():
        lit_pixel.zero_()
        lit_pixel[data.pair_pixel[data.lit & (data.pair_spot == k)]] = True
        mids = [m[lit_pixel[ia] & lit_pixel[ib]] for ia, ib, m in pairs]
        yield k, torch.cat(mids, 0)


def lit_between_segments(data: RayData, normals: torch.Tensor, rows, cols, voxel: float, off: float,
                         same_surface_voxels: float = 0.5):
    """Segments (origins, unit directions, near, far) from the lit midpoints (`lit_midpoints`) to their spot,
    `off` short of both ends, all spots together."""
    o, u, ln = [], [], []
    for k, mids in lit_midpoints(data, normals, rows, cols, voxel, same_surface_voxels):
        v = data.spot_points[k] - mids
        length = torch.linalg.vector_norm(v, dim=-1)
        ok = length > 2 * off
        o.append(mids[ok])
        u.append(v[ok] / length[ok, None])
        ln.append(length[ok])
    if not o:
        z = data.pixel_dirs.new_zeros((0, 3))
        return z, z, z[:, 0], z[:, 0]
    length = torch.cat(ln)
    return torch.cat(o), torch.cat(u), torch.full_like(length, off), length - off


def normals_image(data: RayData, surface) -> torch.Tensor:
    """(H * W, 3) float32 unit normals of `visible_surface`'s points scattered back to their pixels (NaN elsewhere)."""
    pts, nrm = surface
    valid = torch.isfinite(data.visible_depth).cpu().numpy()
    out = np.full((data.height * data.width, 3), np.nan, np.float32)
    if int(valid.sum()) == len(nrm):
        out[valid] = nrm
    return torch.from_numpy(out).to(data.pixel_dirs.device)
