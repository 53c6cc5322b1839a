"""The visible surface of the fast mode's start field: points and normals from the closed-form visible
depth, the point-to-plane signed distance of voxel centres to it, and the raw value at the surface of a
density ramp. Near visible surfaces the start field is a ramp in that signed distance (`init.py`)."""

from __future__ import annotations

import math

import numpy as np
import torch

from .data import RayData, pixel_angle
from .fields import GridBox, dilate_cube
from .voxel_evidence import far_pixel_spacing


def _depth_normals(x: np.ndarray, valid: np.ndarray, c: np.ndarray, max_jump: np.ndarray, tol: float,
                   span: int = 2):
    """Unit normals (H, W, 3) of the visible surface, facing the sensor, from the point image x (H, W, 3).

    Four candidate tangent pairs per pixel (forward or backward differences over `span` pixels along
    rows and columns, steps longer than `max_jump` per pixel left out); the candidate whose plane holds
    the most points of the (2 span + 1)^2 neighbourhood within `tol` wins. Taking the side nearer in
    range instead tilted the normal wherever the nearer neighbour lay on another surface (a seat seen
    at a grazing angle next to the chair's back: its planes disagreed by centimetres). Where no
    candidate exists (a part about a pixel wide) the normal faces the sensor. NaN where not valid.
    """
    h, w = valid.shape
    xp = np.pad(np.where(valid[..., None], x, np.nan), ((span, span), (span, span), (0, 0)),
                constant_values=np.nan)
    jump_ok = lambda t: np.nan_to_num(np.linalg.norm(t, axis=-1), nan=np.inf) <= span * max_jump  # noqa: E731

    def shifted(di, dj):
        return xp[span + di:span + di + h, span + dj:span + dj + w]

    tangents_u = [shifted(0, span) - x, x - shifted(0, -span)]
    tangents_v = [shifted(span, 0) - x, x - shifted(-span, 0)]
    neigh = [shifted(di, dj) - x for di in range(-span, span + 1) for dj in range(-span, span + 1) if di or dj]
    view = c - x
    view /= np.maximum(np.linalg.norm(view, axis=-1, keepdims=True), 1e-12)
    best_n = view.copy()
    best_support = np.full((h, w), -1.0)
    for tu in tangents_u:
        for tv in tangents_v:
            n = np.cross(np.nan_to_num(tu), np.nan_to_num(tv))
            nn = np.linalg.norm(n, axis=-1, keepdims=True)
            ok = jump_ok(tu) & jump_ok(tv) & (nn[..., 0] > 1e-12)
            n = n / np.maximum(nn, 1e-12)
            support = sum(np.nan_to_num(np.abs((q * n).sum(-1)), nan=np.inf) <= tol for q in neigh)
            better = ok & (support > best_support)
            best_n = np.where(better[..., None], n, best_n)
            best_support = np.where(better, support, best_support)
    best_n *= np.sign((best_n * view).sum(-1, keepdims=True) + 1e-12)
    best_n[~valid] = np.nan
    return best_n


def visible_surface(data: RayData, box: GridBox):
    """Visible surface points (N, 3) float64 and their unit normals facing the sensor (from the depth image)."""
    h, w = data.height, data.width
    c = data.sensor_origin.cpu().numpy().astype(np.float64)
    d = data.visible_depth.cpu().numpy().reshape(h, w).astype(np.float64)
    dirs = data.pixel_dirs.cpu().numpy().reshape(h, w, 3).astype(np.float64)
    valid = np.isfinite(d)
    x = c + dirs * np.where(valid, d, 0.0)[..., None]
    pix_angle = pixel_angle(data) or 1e-3
    # steps up to 8 pixel footprints (a surface at 7 degrees grazing); the plane support test picks the side
    max_jump = 8.0 * pix_angle * np.where(valid, d, 0.0) + box.voxel
    normals = _depth_normals(x, valid, c, max_jump, tol=0.25 * box.voxel)
    return x[valid], normals[valid]


def surface_signed_distance(data: RayData, box: GridBox, half_width_voxels: float = 2.0, k: int = 4,
                            surface=None, concave_corners: bool = False, corner_points: np.ndarray | None = None):
    """Point-to-plane signed distance (m, + behind the surface) of voxel centres within `half_width_voxels`
    of the visible surface (NaN elsewhere): the mean over the k nearest measured points of their tangent
    planes, leaving out planes that disagree with the nearest by more than a voxel (another surface).
    Planar walls give an exactly linear field, so the iso-surface is flat (no grid-aligned steps).
    concave_corners: where another surface meets the nearest point's in a concave corner and the voxel lies
    behind it, the voxel is behind (the larger distance; `_behind_concave_corner`).
    corner_points: bool (N,) over the surface points: only these can be that other surface (the room's
    bounding planes, `unobserved.on_planes`: an object's own concave corners, a seat meeting its back,
    keep the nearest plane; default every point).
    surface: (points, normals) from `visible_surface` when already computed."""
    from scipy.spatial import cKDTree

    pts, nrm = visible_surface(data, box) if surface is None else surface
    sd = np.full(box.shape, np.nan, np.float32)
    if len(pts) == 0:
        return torch.from_numpy(sd)
    lo = box.bbox_min.cpu().numpy().astype(np.float64)
    # candidate voxels: the cells holding a surface point, dilated by the half width
    idx = np.floor((pts - lo) / box.voxel).astype(np.int64)
    inside = np.all((idx >= 0) & (idx < np.array(box.shape)), 1)
    occ = torch.zeros(box.shape, dtype=torch.float32)
    occ[tuple(torch.from_numpy(idx[inside]).T)] = 1.0
    r = int(math.ceil(half_width_voxels)) + 1
    occ = dilate_cube(occ, r) > 0
    cand = torch.nonzero(occ, as_tuple=False).numpy()
    centres = lo + (cand + 0.5) * box.voxel
    tree = cKDTree(pts)
    kq = min(k, len(pts))
    dist, j = tree.query(centres, k=kq, distance_upper_bound=(half_width_voxels + 1.0) * box.voxel)
    dist, j = dist.reshape(len(cand), kq), j.reshape(len(cand), kq)
    found = np.isfinite(dist)
    jj = np.where(found, j, 0)
    plane = ((pts[jj] - centres[:, None]) * nrm[jj]).sum(-1)          # + behind the surface
    agree = found & (np.abs(plane - plane[:, :1]) <= box.voxel)
    wgt = agree * np.exp(-(np.where(found, dist, 0.0) / box.voxel) ** 2)
    val = (wgt * plane).sum(1) / np.maximum(wgt.sum(1), 1e-12)
    if concave_corners:
        # only where the voxel could still be kept: the corner rule only raises the value (half the candidates)
        may = found[:, 0] & (val <= half_width_voxels * box.voxel)
        val[may] = np.maximum(val[may], _behind_concave_corner(pts, nrm, centres[may], dist[may, 0], jj[may, 0],
                                                               box.voxel, 2 * k, (half_width_voxels + 1.0) * box.voxel,
                                                               corner_points))
    keep = found[:, 0] & (np.abs(val) <= half_width_voxels * box.voxel)
    sd[tuple(cand[keep].T)] = val[keep]
    return torch.from_numpy(sd)


def _behind_concave_corner(pts, nrm, centres, d0, j0, voxel, k, reach_m, corner_points=None):
    """How far (m) each centre lies behind another surface that meets its nearest point's (index j0, at
    distance d0) in a concave corner: its point lies in front of the nearest one's
    plane (a floor meeting a wall); -inf where none. The solid is behind either surface: the nearest plane
    alone emptied the voxels behind the other surface next to the corner (rows of pin-holes along the
    junction). The other surface's points are looked for among the k nearest of `corner_points` (default
    all) within `reach_m`, or twice the nearest point's distance plus a voxel where the points lie sparser
    (a coarse sensor: the corner's voxels lie several voxels from the nearest row of each surface)."""
    from scipy.spatial import cKDTree

    out = np.full(len(centres), -np.inf)
    cidx = np.arange(len(pts)) if corner_points is None else np.flatnonzero(corner_points)
    if len(cidx) == 0 or len(centres) == 0:
        return out
    kc = min(k, len(cidx))
    reach = np.maximum(reach_m, 2.0 * np.where(np.isfinite(d0), d0, 0.0) + voxel)
    dist, j = cKDTree(pts[cidx]).query(centres, k=kc, distance_upper_bound=float(reach.max()))
    dist, j = dist.reshape(len(centres), kc), j.reshape(len(centres), kc)
    found = np.isfinite(dist) & (dist <= reach[:, None]) & np.isfinite(d0)[:, None]
    q = cidx[np.where(found, j, 0)]
    plane = ((pts[q] - centres[:, None]) * nrm[q]).sum(-1)                 # + behind that surface
    concave = ((pts[q] - pts[j0][:, None]) * nrm[j0][:, None]).sum(-1) > 0.5 * voxel
    return np.where(found & concave & (plane > 0), plane, -np.inf).max(1)


def surface_offset(density_scale: float, voxel: float, slope: float) -> float:
    """Raw value at the surface so that a ramp raw = slope * s / voxel + b (s: signed distance along
    the ray) has half its transmittance left at s = 0: integral of density_scale * softplus = ln 2."""
    x = np.linspace(-40.0, 40.0, 80001)
    sp = np.logaddexp(0.0, x)
    cum = np.cumsum(sp) * (x[1] - x[0])                     # integral of softplus from -inf to x
    need = math.log(2.0) * slope / (density_scale * voxel)
    return float(np.interp(need, cum, x))


def in_front_of_visible_surface(surface, box: GridBox, empty: torch.Tensor,
                                depths_voxels=(0.5, 1.0, 1.5)) -> torch.Tensor:
    """Voxels (nx, ny, nz) bool just in front of the measured visible surface: those holding x + s n for s
    in `depths_voxels` voxels (x a surface point, n its normal facing the sensor), grown by one voxel and
    kept where the field is `empty` (bool (nx, ny, nz): below the surface level). The ray reached x, so
    the space just in front of it is empty; the sensor's own free-space march stops a voxel short of the
    surface along the ray, so next to a concave edge seen at a grazing angle (the ceiling meeting the
    back wall) no camera ray crosses the voxels below the surface. The growth covers the gaps between
    the footprints of neighbouring pixels (several voxels long at grazing incidence).
    surface: (points, normals) from `visible_surface`."""
    pts, nrm = surface
    out = torch.zeros(box.shape, dtype=torch.float32)
    if len(pts) == 0:
        return out > 0
    lo = box.bbox_min.cpu().numpy().astype(np.float64)
    shape = np.array(box.shape)
    for s in depths_voxels:
        idx = np.floor((pts + s * box.voxel * nrm - lo) / box.voxel).astype(np.int64)
        idx = idx[np.all((idx >= 0) & (idx < shape), 1)]
        out[tuple(torch.from_numpy(idx).T)] = 1.0
    return (dilate_cube(out, 1) > 0) & empty.cpu()


def seen_free(data: RayData, box: GridBox, camera_to_world, fov_rad: float, fov_axis: str,
              margin_voxels: float = 0.5, depth: torch.Tensor | None = None, corner_planes: bool = False) -> torch.Tensor:
    """Voxels (nx, ny, nz) bool whose centre the sensor saw through (`seen_free_points`)."""
    pts = box.centres().reshape(-1, 3).cpu().numpy().astype(np.float64)
    free = seen_free_points(data, camera_to_world, fov_rad, fov_axis, box.voxel, depth,
                            corner_planes)(pts, margin_voxels * box.voxel)
    return torch.from_numpy(free.reshape(box.shape))


def seen_depth(data: RayData, fc) -> torch.Tensor:
    """Per-pixel range the sensor saw through (FastConfig `fc`): as the camera carving, not past a thin part's
    earliest return."""
    depth = data.visible_depth
    if fc.nearest_free and data.nearest_depth is not None:
        depth = torch.fmin(data.nearest_depth, depth)
    return depth


def coarse_sensor_seen_free(data: RayData, box: GridBox, fc, meta: dict) -> torch.Tensor | None:
    """`seen_free` voxels when the sensor is coarse for `box` (neighbouring pixel rays farther apart at the far
    surfaces than `fc.carve_seen_free_beyond_voxels`: the camera carves between its rays too), else None.
    meta: camera_to_world, fov_rad, fov_axis. The fit's start field and the spot advisor both label this way."""
    spacing = far_pixel_spacing(data)
    if spacing is None or spacing <= fc.carve_seen_free_beyond_voxels * box.voxel:
        return None
    return seen_free(data, box, meta["camera_to_world"], meta["fov_rad"], meta["fov_axis"], fc.surface_margin_voxels,
                     seen_depth(data, fc), fc.seen_free_corners)


def seen_free_points(data: RayData, camera_to_world, fov_rad: float, fov_axis: str, voxel: float,
                     depth: torch.Tensor | None = None, corner_planes: bool = False):
    """A test `free(points (N, 3), margin_m) -> bool (N,)`: the sensor saw through the point, i.e. it projects
    into the image and lies more than `margin_m` (along its ray) in front of the visible surface between
    the four nearest pixels' points. That surface is the bilinear one in inverse depth (exact for a plane)
    where no point lies more than half a voxel behind another's tangent plane (one plane, or a concave
    corner: the chord lies in front of both walls), else the nearest point's depth (an occluding or convex
    edge: what lies between the pixel rays behind the nearer surface is unknown). corner_planes: in the
    first case the surface is the farther of that and the nearest of the four points' tangent planes along
    the point's ray (a concave corner: the ray stays in the room until it meets either wall; the chord cut
    the corner, and a coarse sensor's corner faces lay behind it), at most the points' depth spread
    beyond the deepest point.

    A camera ray's march carves only the voxels it crosses, a line through the grid: where pixel rays lie
    more than a voxel apart (a coarse sensor; far or grazing surfaces) the voxels between them stay
    unseen though the pixels' footprints covered them; and a point tested for free space need not be a
    voxel centre (the mesh's faces are tested a voxel in front of themselves).
    depth: (P,) range per pixel (default the visible depth; NaN unknown)."""
    from ..contract.frames import project_points

    h, w = data.height, data.width
    rng = (data.visible_depth if depth is None else depth).detach().cpu().numpy().astype(np.float64).reshape(h, w)
    c = data.sensor_origin.detach().cpu().numpy().astype(np.float64)
    dirs = data.pixel_dirs.detach().cpu().numpy().reshape(h, w, 3).astype(np.float64)
    valid = np.isfinite(rng) & (rng > 0)
    x = c + dirs * np.where(valid, rng, 0.0)[..., None]
    pix_angle = pixel_angle(data) or 1e-3
    nrm = _depth_normals(x, valid, c, 8.0 * pix_angle * np.where(valid, rng, 0.0) + voxel, 0.25 * voxel)
    zdepth = np.where(valid, rng * (dirs @ -np.asarray(camera_to_world, np.float64)[:3, 2]), np.nan)
    # cells between pixel centres (j, i) .. (j + 1, i + 1), edge pixels repeated: (h + 1, w + 1) cells
    jj = np.clip(np.arange(-1, h + 1), 0, h - 1)
    ii = np.clip(np.arange(-1, w + 1), 0, w - 1)
    corner = [(jj[:-1, None], ii[None, :-1]), (jj[:-1, None], ii[None, 1:]),
              (jj[1:, None], ii[None, :-1]), (jj[1:, None], ii[None, 1:])]
    cz = np.stack([zdepth[a, b] for a, b in corner])                        # (4, h + 1, w + 1)
    cell_valid = np.all(np.isfinite(cz), 0)
    one_surface = cell_valid.copy()
    for a in corner:
        for b in corner:
            behind = ((x[b] - x[a]) * nrm[a]).sum(-1)                       # NaN normal: not one surface
            one_surface &= np.nan_to_num(behind, nan=-np.inf) >= -0.5 * voxel
    nearest = np.where(np.isfinite(cz), cz, np.inf).min(0)
    if corner_planes:
        cx = np.stack([x[a] for a in corner])                               # (4, h + 1, w + 1, 3)
        cn = np.stack([nrm[a] for a in corner])
        deepest = np.where(np.isfinite(cz), cz, -np.inf).max(0)
        reach = deepest + (deepest - nearest) + voxel                        # how far behind the points a corner may lie

    def free(points, margin_m: float):
        pts = np.asarray(points, np.float64).reshape(-1, 3)
        col, row, z = project_points(camera_to_world, w, h, fov_rad, pts, fov_axis)
        ok = np.isfinite(col) & np.isfinite(row) & (z > 0) & (col >= 0) & (col < w) & (row >= 0) & (row < h)
        u, v = col[ok] + 0.5, row[ok] + 0.5       # cell (j, i) spans pixel centres j - 1 .. j (+ 0.5 offset)
        ci, cj = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
        fu, fv = u - ci, v - cj
        weights = np.stack([(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv])
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = (weights / cz[:, cj, ci]).sum(0)
            est = 1.0 / inv
            if corner_planes:
                # the nearest of the four tangent planes along the ray: the corner itself where two walls meet
                # (the chord cuts it), the plane where there is one
                u = (pts[ok] - c) / np.linalg.norm(pts[ok] - c, axis=1, keepdims=True)
                nq = cn[:, cj, ci]                                          # (4, M, 3)
                den = (nq * u).sum(-1)
                r_plane = ((cx[:, cj, ci] - c) * nq).sum(-1) / den
                r_plane = np.where(np.isfinite(r_plane) & (den < -0.1) & (r_plane > 0), r_plane, np.inf).min(0)
                z_plane = np.minimum(r_plane * z[ok] / np.linalg.norm(pts[ok] - c, axis=1), reach[cj, ci])
                est = np.where(np.isfinite(z_plane) & (z_plane > est), z_plane, est)
            est = np.where(one_surface[cj, ci], est, nearest[cj, ci])    # camera-space depth of the surface
        est = np.where(np.isfinite(est), est, -np.inf)                          # no measured depth: not seen free
        r = np.linalg.norm(pts[ok] - c, axis=1)
        out = np.zeros(len(pts), bool)
        out[np.flatnonzero(ok)] = r * (est / z[ok] - 1.0) > margin_m
        return out
    return free
