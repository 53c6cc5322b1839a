"""Surface-to-surface distances shared by the whole-scene and the object-level evaluation.

- chamfer_m: symmetric mean distance (not squared) from points sampled (seeded) on each surface to the OTHER
  surface (point-to-triangle, so identical meshes give 0): 0.5 (mean d(pred -> gt) + mean d(gt -> pred)); with
  `crop_min/crop_max` both point sets are first cropped to that box.
- fscore: 2 P R / (P + R) with precision P = share of reconstruction samples within the threshold of the GT
  surface, recall R the converse.
Nearest triangles come from a k-d tree over surface samples (scipy), exact distances from trimesh's
point-triangle `closest_point`.
"""

from __future__ import annotations

import numpy as np

from ..contract.errors import EvaluationError


def sample_surface(mesh, n, seed, crop_min, crop_max):
    import trimesh
    pts, face = trimesh.sample.sample_surface(mesh, n, seed=seed)
    if crop_min is not None and crop_max is not None:
        ok = np.all((pts >= np.asarray(crop_min)) & (pts <= np.asarray(crop_max)), axis=1)
        pts, face = pts[ok], face[ok]
    return pts, face


def point_to_mesh_distance(points, mesh, samples, sample_faces, k=6, return_faces=False, max_m=None, tree=None):
    """Distance from points to a mesh surface: exact point-triangle distance to the faces of the
    k nearest surface samples (an upper bound that is exact once the samples are dense).
    With `return_faces`, also the index of the nearest face per point (-1 where none was in reach).
    max_m: only distances up to max_m are asked for: the k-d search stops at max_m + the longest face's diameter
    (every sample of a face within max_m lies that close), so a distance <= max_m comes out as without the bound
    and a larger one as some value > max_m (inf where no sample is in reach). Points far from a dense surface make
    the unbounded k-nearest search slow (a chair's points against the room's samples: 30 s for 85k points).
    tree: a cKDTree of `samples`, when the caller keeps one."""
    from scipy.spatial import cKDTree
    from trimesh.triangles import closest_point
    if len(points) == 0:
        return (np.zeros(0), np.zeros(0, np.int64)) if return_faces else np.zeros(0)
    k = min(k, len(samples))
    tree = cKDTree(samples) if tree is None else tree
    tri_all = np.asarray(mesh.triangles)
    if max_m is None:
        _, nn = tree.query(points, k=k, workers=-1)
    else:
        reach = float(np.linalg.norm(tri_all - np.roll(tri_all, 1, axis=1), axis=2).max())
        _, nn = tree.query(points, k=k, workers=-1, distance_upper_bound=float(max_m) + reach + 1e-9)
    nn = nn.reshape(len(points), k)
    found = nn < len(samples)                                   # the bounded search marks a miss with n
    faces = np.sort(np.where(found, sample_faces[np.minimum(nn, len(samples) - 1)], -1), axis=1)
    first = faces >= 0                                          # each (point, face) pair measured once
    first[:, 1:] &= faces[:, 1:] != faces[:, :-1]
    rows, cols = np.nonzero(first)
    tris = tri_all[faces[rows, cols]]
    q = points[rows]
    d = np.full(faces.shape, np.inf)
    d[rows, cols] = np.linalg.norm(closest_point(tris, q) - q, axis=1)
    if return_faces:
        j = d.argmin(axis=1)
        return d[np.arange(len(points)), j], faces[np.arange(len(points)), j]
    return d.min(axis=1)


def within_distance(points, mesh, radius_m: float, chunk: int = 4096) -> np.ndarray:
    """bool (N,): points closer than radius_m to `mesh`'s surface, exactly (the same point-triangle distance as
    `exact_point_to_mesh_distance`), measuring only the faces whose bounding sphere (centroid, farthest vertex)
    comes within radius_m of the point: the others are provably farther."""
    from scipy.spatial import cKDTree
    from trimesh.triangles import closest_point
    points = np.asarray(points, np.float64).reshape(-1, 3)
    out = np.zeros(len(points), bool)
    tris = np.asarray(mesh.triangles)
    if len(points) == 0 or len(tris) == 0:
        return out
    centre = tris.mean(axis=1)
    sphere = np.linalg.norm(tris - centre[:, None], axis=2).max(axis=1)
    tree = cKDTree(centre)
    for i in range(0, len(points), chunk):
        q = points[i:i + chunk]
        cand = tree.query_ball_point(q, radius_m + float(sphere.max()) + 1e-9, workers=-1)
        counts = np.fromiter((len(c) for c in cand), np.int64, len(cand))
        if not counts.any():
            continue
        rows = np.repeat(np.arange(len(q)), counts)
        cols = np.concatenate([np.asarray(c, np.int64) for c in cand if len(c)])
        keep = np.linalg.norm(q[rows] - centre[cols], axis=1) - sphere[cols] < radius_m + 1e-9
        rows, cols = rows[keep], cols[keep]
        d = np.linalg.norm(closest_point(tris[cols], q[rows]) - q[rows], axis=1)
        out[i + rows[d < radius_m]] = True
    return out


def surface_metrics(pred_mesh, gt_mesh, threshold_m=0.05, n_samples=100_000, seed=0, crop_min=None,
                    crop_max=None) -> dict:
    """Chamfer distance (m) and F-score between two meshes (see module doc).

    Points sampled on each surface are measured against the other SURFACE (point-to-triangle),
    so identical meshes give 0 whatever the sample count.
    """
    if pred_mesh is None or len(pred_mesh.faces) == 0:
        return {"chamfer_m": None, "fscore": 0.0, "precision": 0.0, "recall": 0.0,
                "fscore_threshold_m": threshold_m, "note": "empty reconstruction"}
    p, pf = sample_surface(pred_mesh, n_samples, seed, crop_min, crop_max)
    g, gf = sample_surface(gt_mesh, n_samples, seed + 1, crop_min, crop_max)
    if len(g) == 0:
        raise EvaluationError("the ground-truth mesh has no surface inside the crop box")
    if len(p) == 0:
        return {"chamfer_m": None, "fscore": 0.0, "precision": 0.0, "recall": 0.0,
                "fscore_threshold_m": threshold_m, "note": "no reconstruction surface inside the crop box"}
    # candidates come from all samples (uncropped would be better near the crop border; the effect is small)
    d_pg = point_to_mesh_distance(p, gt_mesh, g, gf)
    d_gp = point_to_mesh_distance(g, pred_mesh, p, pf)
    prec = float((d_pg < threshold_m).mean())
    rec = float((d_gp < threshold_m).mean())
    f = 0.0 if prec + rec == 0 else 2 * prec * rec / (prec + rec)
    return {"chamfer_m": float(0.5 * (d_pg.mean() + d_gp.mean())), "fscore": float(f), "precision": prec,
            "recall": rec, "accuracy_m": float(d_pg.mean()), "completeness_m": float(d_gp.mean()),
            "fscore_threshold_m": float(threshold_m), "n_samples": [int(len(p)), int(len(g))]}


def exact_point_to_mesh_distance(points, mesh, max_pairs: int = 50_000_000):
    """Distance from points (N, 3) to every face of `mesh` (brute force, in chunks): the exact value that
    `point_to_mesh_distance` bounds from above. None when N x faces exceeds max_pairs (too slow to ask)."""
    from trimesh.triangles import closest_point
    tris = np.asarray(mesh.triangles)
    if len(points) * len(tris) > max_pairs:
        return None
    out = np.full(len(points), np.inf)
    chunk = max(1, 2_000_000 // max(len(tris), 1))
    for i in range(0, len(points), chunk):
        q = np.asarray(points[i:i + chunk], np.float64)
        qq = np.repeat(q, len(tris), axis=0)
        d = np.linalg.norm(closest_point(np.tile(tris, (len(q), 1, 1)), qq) - qq, axis=1)
        out[i:i + chunk] = d.reshape(len(q), len(tris)).min(axis=1)
    return out

